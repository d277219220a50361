"""The project's motions: :class:`MotionSpec`, the real-capture clips of Debian's
assimp-testmodels, and Joint2Coarse's motion library (:data:`LIBRARY_TRAIN`) and validation
motions (:data:`LIBRARY_VALIDATION`) that the presets of :mod:`pipeline.config` train and choose
on. They live here to keep ``pipeline/config.py`` short; it imports them from here."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

#: Real motion capture used as an unseen test motion when Debian's assimp-testmodels is there.
CMU_CLIP = Path("/usr/share/assimp/models/BVH/01_01.bvh")


@dataclass(frozen=True)
class MotionSpec:
    """One motion of the project: procedural (``kind`` from PROCEDURAL_KINDS) or a BVH file."""

    name: str
    """File stem under ``motions/`` and the name in reports."""
    kind: str
    """A procedural kind (dance, twirl, walk, ...) or ``file`` for ``path``."""
    frames: int
    """Frames to keep (at the project's fps)."""
    seed: int = 0
    """Seed of a procedural motion."""
    path: str | None = None
    """The BVH file when ``kind == "file"`` (any rig; it is retargeted onto the mannequin)."""
    start_s: float = 0.0
    """Seconds to skip at the start of a file (motion capture often starts in a T-pose)."""
    speed: float = 1.0
    """Played this many times faster (``core.motion.variation.vary_motion``) ..."""
    amplitude: float = 1.0
    """... with its joint rotation angles scaled by this ..."""
    heading_deg: float = 0.0
    """... turned by this many degrees about the vertical ..."""
    turn_deg_s: float = 0.0
    """... and turning at this many degrees per second (a spin): a training-library variation."""


#: Real capture beside CMU 01_01 in Debian's assimp-testmodels: a walk-and-turn and a boxer.
CMU_0103_CLIP = CMU_CLIP.with_name("01_03.bvh")
BOXING_CLIP = CMU_CLIP.with_name("Boxing_Toes.bvh")


#: Joint2Coarse's training library beyond the quick preset's four clips: the procedural kinds
#: varied (never the twirl, a test kind) and windows of real capture (never CMU 01_01, a test
#: clip, nor the validation windows); each part kept on validation (docs/decisions.md,
#: "LIBRARY_TRAIN").
LIBRARY_TRAIN: tuple[MotionSpec, ...] = (
    MotionSpec("dance-varied", "dance", 150, seed=6, speed=1.3, amplitude=1.2, heading_deg=90.0),
    MotionSpec("walk-fast", "walk", 100, seed=8, speed=1.6, heading_deg=-45.0),
    *(
        MotionSpec(f"cmu-01_03-{s:02.0f}", "file", 150, path=str(CMU_0103_CLIP), start_s=s)
        for s in (3.0, 8.0, 13.0, 18.0, 23.0, 28.0)
    ),
    *(
        MotionSpec(f"boxing-{s:02.0f}", "file", 150, path=str(BOXING_CLIP), start_s=s)
        for s in (2.0, 17.0, 22.0, 25.5)
    ),
    MotionSpec("boxing-13", "file", 100, path=str(BOXING_CLIP), start_s=13.4),
    # Spins, both ways, at 200 to 450 degrees a second (the twirl's turns peak at 340 to 450).
    MotionSpec("walk-spin", "walk", 150, seed=30, turn_deg_s=200.0),
    MotionSpec("dance-spin", "dance", 150, seed=31, speed=1.1, turn_deg_s=330.0),
    MotionSpec("jump-spin", "jump", 150, seed=32, turn_deg_s=-250.0),
    MotionSpec(
        "cmu-01_03-spin", "file", 150, path=str(CMU_0103_CLIP), start_s=25.0, turn_deg_s=-360.0
    ),
    MotionSpec("idle-spin", "idle", 150, seed=33, amplitude=1.3, turn_deg_s=-420.0),
    MotionSpec("boxing-spin", "file", 150, path=str(BOXING_CLIP), start_s=25.0, turn_deg_s=450.0),
    # Jumps higher and lower (docs/decisions.md, "LIBRARY_TRAIN", as every comment below).
    MotionSpec("jump-high", "jump", 150, seed=50, speed=1.2, amplitude=1.3, heading_deg=-60.0),
    MotionSpec("jump-low", "jump", 150, seed=51, speed=0.9, amplitude=0.8, heading_deg=120.0),
    # Ten more procedural clips, each part kept on the validation motions.
    MotionSpec(
        "dance-spin-2", "dance", 150, seed=60, speed=1.2, heading_deg=30.0, turn_deg_s=420.0
    ),
    MotionSpec("walk-spin-2", "walk", 150, seed=61, speed=1.2, turn_deg_s=-330.0),
    MotionSpec("jump-spin-2", "jump", 150, seed=62, turn_deg_s=380.0),
    MotionSpec("circle-walk-2", "circle-walk", 150, seed=63, speed=1.3),
    # Standing long jumps, in place of two more jumps.
    MotionSpec("broad-jump", "broad-jump", 150, seed=70, heading_deg=30.0),
    MotionSpec(
        "broad-jump-2", "broad-jump", 150, seed=71, speed=1.1, amplitude=1.1, heading_deg=-100.0
    ),
    MotionSpec("dance-2", "dance", 150, seed=66, amplitude=1.3, heading_deg=45.0),
    # Runs, in place of a slower dance and a slow walk.
    MotionSpec("run", "run", 150, seed=72, heading_deg=60.0),
    MotionSpec("run-2", "run", 150, seed=73, speed=1.1, heading_deg=-150.0),
    MotionSpec("idle-2", "idle", 150, seed=69, amplitude=1.5),
)


#: Joint2Coarse's validation motions, what every choice is made on: 990 frames in nine clips
#: (why each is there: docs/decisions.md, "LIBRARY_VALIDATION").
LIBRARY_VALIDATION: tuple[MotionSpec, ...] = (
    MotionSpec(
        "val-dance-spin",
        "dance",
        100,
        seed=20,
        speed=0.85,
        amplitude=1.15,
        heading_deg=-60.0,
        turn_deg_s=-240.0,
    ),
    MotionSpec("val-cmu-01_03", "file", 100, path=str(CMU_0103_CLIP), start_s=33.0),
    MotionSpec("val-boxing", "file", 100, path=str(BOXING_CLIP), start_s=10.0),
    # Three more since the test twirl and CMU 01_01 moved against what the first three said.
    MotionSpec("val-idle-spin", "idle", 120, seed=40, amplitude=1.2, turn_deg_s=380.0),
    MotionSpec("val-jump", "jump", 120, seed=41, speed=1.1, amplitude=1.2, heading_deg=30.0),
    MotionSpec("val-boxing-07", "file", 90, path=str(BOXING_CLIP), start_s=7.0),
    # A long jump and a run, since the library has them; a plain walk, since the runs' choice
    # took a slow walk out of it (added before any choice was made with it).
    MotionSpec("val-broad-jump", "broad-jump", 120, seed=43, speed=0.95, heading_deg=170.0),
    MotionSpec("val-run", "run", 120, seed=44, speed=0.95, heading_deg=-30.0),
    MotionSpec("val-walk", "walk", 120, seed=45, speed=1.0, heading_deg=120.0),
)
