"""Mapping a source skeleton's joints onto the canonical 19 + Hips.

The matcher reads joint names as tokens (namespace and tool prefixes such as ``mixamorig:``,
``Bip001``, ``DEF-`` removed; side from ``Left``/``L``/``.L``/``_l``; camelCase split) and
classifies each joint by role (upper arm, shin, ...), then uses the hierarchy to settle what names
alone cannot:

- ``Shoulder`` is the clavicle when the same side also has an ``Arm``/``UpperArm`` (CMU, Mixamo,
  Rigify) and the upper arm when it has a ``Collar``/``Clavicle`` (Motive, Poser).
- Limb joints are picked down one chain: the forearm is a descendant of the upper arm, etc.
- The spine is the path from the hips to the neck; joints that sit exactly on their parent
  (zero offset, like CMU's ``LowerBack``) are skipped, and the 1 to n joints left are spread over
  Spine/Spine1/Spine2 (blending two neighbours where a joint is missing).
- No hips by name: the common ancestor of the two thighs. Rigify's numbered spine
  (``DEF-spine`` = hips, ``.001``-``.003`` spine, ``.004`` neck, last = head) when no neck/head names.
- A canonical joint that would sit exactly on its canonical parent (CMU's ``LeftShoulder`` on the
  chest) is moved a quarter of the way towards its canonical child, so no canonical bone has zero
  length. A missing clavicle is placed a quarter of the way from Spine2 to the upper arm.

Names are matched without the decorations that converters (glTF, FBX, Blender) add, see
:func:`clean_names`: paths and namespaces (``Armature|Hips``, ``rig:char:Spine``,
``mixamorig1:LeftArm``) and numeric exporter suffixes (``Bip001 L Clavicle_197``,
``LeftArm.001``, ``mixamorig:Hips_01``). A wrapper joint above the hips (``Armature``,
``GLTF_created_0_rootJoint``) simply maps to nothing; :func:`core.motion.bvh.clip_to_motion`
folds it into the hips when the hips carries the translation.

Where names do not suffice, a user mapping file ``{canonical_name: source_name}`` overrides any
entry. What cannot be found raises :class:`InputError` naming the canonical joints.
"""

from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass

import numpy as np

from core.errors import InputError
from core.motion.motion import Motion
from core.skeleton import CANONICAL_JOINTS, ROOT_JOINT, Skeleton, forward_kinematics

#: Hips first, then the 19 canonical joints: the row order of :func:`canonical_positions`.
MAPPED_JOINTS: tuple[str, ...] = (ROOT_JOINT, *CANONICAL_JOINTS)

#: Canonical child used to move a joint that sits on its parent (see module docstring).
_CANONICAL_CHILD = {
    "Spine": "Spine1", "Spine1": "Spine2", "Spine2": "Neck", "Neck": "Head",
    "LeftShoulder": "LeftArm", "LeftArm": "LeftForeArm", "LeftForeArm": "LeftHand",
    "RightShoulder": "RightArm", "RightArm": "RightForeArm", "RightForeArm": "RightHand",
    "LeftUpLeg": "LeftLeg", "LeftLeg": "LeftFoot", "RightUpLeg": "RightLeg", "RightLeg": "RightFoot",
}  # fmt: skip
_CANONICAL_PARENT = {
    "Spine": ROOT_JOINT, "Spine1": "Spine", "Spine2": "Spine1", "Neck": "Spine2", "Head": "Neck",
    "LeftShoulder": "Spine2", "LeftArm": "LeftShoulder", "LeftForeArm": "LeftArm",
    "LeftHand": "LeftForeArm", "RightShoulder": "Spine2", "RightArm": "RightShoulder",
    "RightForeArm": "RightArm", "RightHand": "RightForeArm", "LeftUpLeg": ROOT_JOINT,
    "LeftLeg": "LeftUpLeg", "LeftFoot": "LeftLeg", "RightUpLeg": ROOT_JOINT,
    "RightLeg": "RightUpLeg", "RightFoot": "RightLeg",
}  # fmt: skip

#: Role -> name cores (after prefixes and side are removed), best first.
_ROLE_PATTERNS: dict[str, tuple[str, ...]] = {
    "hips": ("hips", "hip", "pelvis"),
    "neck": ("neck", r"neck\d+", "necklower"),
    "head": ("head",),
    "clavicle": ("clavicle", "collar", "collarbone", "shoulder", "shldr"),
    "upperarm": ("arm", "upperarm", "uparm", "humerus", "shoulder", "shldr"),
    "forearm": ("forearm", "lowerarm", "loarm", "elbow"),
    "hand": ("hand", "wrist"),
    "thigh": ("upleg", "upperleg", "thigh", "femur", "hip", "hipjoint"),
    "shin": ("leg", "lowerleg", "loleg", "shin", "calf", "knee", "tibia"),
    "foot": ("foot", "ankle"),
}
_STRICT_CLAVICLE = ("clavicle", "collar", "collarbone")
_STRICT_UPPERARM = ("arm", "upperarm", "uparm", "humerus")
_AMBIGUOUS_SHOULDER = ("shoulder", "shldr")
_LIMBS = {
    "Arm": ("clavicle", "upperarm", "forearm", "hand"),
    "Leg": ("thigh", "shin", "foot"),
}
_CANONICAL_OF_ROLE = {
    "clavicle": "Shoulder", "upperarm": "Arm", "forearm": "ForeArm", "hand": "Hand",
    "thigh": "UpLeg", "shin": "Leg", "foot": "Foot",
}  # fmt: skip
#: Name cores (as :func:`split_name` gives them) of joints a convention names: a numeric
#: exporter suffix is stripped only when that leaves one of these (or when every joint has it).
_VOCABULARY: tuple[str, ...] = (
    *dict.fromkeys(p for ps in _ROLE_PATTERNS.values() for p in ps),
    r"spine\d*", r"neck\d*", "chest", "upperchest", "lowerback", "abdomen", "ab", "torso",
)  # fmt: skip
_PATH_SEPARATORS = re.compile(r"[|/:]")
_NUMERIC_SUFFIX = re.compile(r"(.+?)[._](\d+)")
_PREFIX = re.compile(r"^(?:(?:DEF|ORG|MCH)[-_.]|Bip\d+\s*|Character\d*_|Biped\d*_)", re.IGNORECASE)
_TOKEN = re.compile(r"[A-Z]+(?=[A-Z][a-z])|[A-Z]?[a-z]+|[A-Z]+|\d+")
#: How far (fraction) a joint on top of its parent moves towards its child; clavicle placement.
_NUDGE = 0.25

Entry = tuple[tuple[str, float], ...]


@dataclass(frozen=True)
class JointMapping:
    """Where each of Hips + the 19 canonical joints comes from in a source skeleton.

    Attributes
    ----------
    sources : tuple of 20 entries (Hips, then CANONICAL_JOINTS order)
        Each entry is ``((source_name, weight), ...)`` with weights summing to 1: the canonical
        joint's position is that blend of source joint positions. Most entries are one joint.
    rig : str
        The convention recognised: ``cmu``, ``mixamo``, ``biped``, ``rigify``, ``motive``,
        ``canonical`` or ``generic`` (``+user`` when a mapping file contributed).
    """

    sources: tuple[Entry, ...]
    rig: str = "generic"

    def __post_init__(self) -> None:
        if len(self.sources) != len(MAPPED_JOINTS):
            raise ValueError(f"need {len(MAPPED_JOINTS)} entries, got {len(self.sources)}")

    def source_of(self, canonical: str) -> str:
        """The source joint name, or a blend written ``0.5*Spine + 0.5*Spine1``."""
        entry = self.sources[MAPPED_JOINTS.index(canonical)]
        if len(entry) == 1:
            return entry[0][0]
        return " + ".join(f"{w:.3g}*{n}" for n, w in entry)

    def as_dict(self) -> dict[str, str]:
        """``{canonical: source}`` for Hips and the 19, as :meth:`source_of` writes them."""
        return {c: self.source_of(c) for c in MAPPED_JOINTS}

    def weights(self, names: tuple[str, ...]) -> np.ndarray:
        """(20, J) float64 matrix taking source joint positions to canonical ones."""
        w = np.zeros((len(MAPPED_JOINTS), len(names)))
        for row, entry in enumerate(self.sources):
            for name, weight in entry:
                w[row, names.index(name)] += weight
        return w

    def primary(self, canonical: str) -> str:
        """The source joint with the largest weight for ``canonical``."""
        entry = self.sources[MAPPED_JOINTS.index(canonical)]
        return max(entry, key=lambda e: e[1])[0]


def split_name(name: str) -> tuple[str | None, str]:
    """``(side, core)`` of a joint name: side ``"L"``, ``"R"`` or None; core lower-case.

    ``mixamorig:LeftForeArm`` -> ``("L", "forearm")``; ``Bip001 R Calf`` -> ``("R", "calf")``;
    ``DEF-upper_arm.L`` -> ``("L", "upperarm")``; ``LHipJoint`` -> ``("L", "hipjoint")``.
    """
    base = name.rsplit(":", 1)[-1].strip()
    stripped = _PREFIX.sub("", base) or base
    tokens: list[str] = []
    for part in re.split(r"[\s_\-.|]+", stripped):
        tokens.extend(t.lower() for t in _TOKEN.findall(part))
    side = None
    core = []
    for t in tokens:
        if side is None and t in ("l", "left"):
            side = "L"
        elif side is None and t in ("r", "right"):
            side = "R"
        else:
            core.append(t)
    return side, "".join(core)


def clean_names(names: tuple[str, ...]) -> tuple[str, ...]:
    """The joint names without exporter decorations, for matching only (one per name).

    - Paths and namespaces: the last part after ``|``, ``/`` or ``:`` (``Armature|Hips``,
      ``Armature/Hips``, ``rig:char:Spine``, ``mixamorig9:Hips`` -> ``Hips``).
    - A numeric suffix ``_<digits>`` or ``.<digits>`` (``Bip001 L Clavicle_197``,
      ``LeftArm.001``, ``Hips_01``), only when every joint carries the same suffix, or when
      the name without it is one a convention uses for a body joint (``hand``, ``clavicle``,
      ``spine2``, ``spine.003``...: :data:`_VOCABULARY`). Digits that are part of the name stay
      (``Spine1``, ``Neck1``, ``LeftHandIndex1`` have no separator; ``f_index.01.L`` does not
      end in digits).
    - A suffix is kept wherever stripping it would make two joints read the same (side and core,
      see :func:`split_name`): Rigify's ``DEF-spine.001``... beside ``DEF-spine``, Unreal's
      ``spine_01``/``spine_02``, Blender's duplicate ``LeftArm.001`` beside ``LeftArm``.

    Parameters
    ----------
    names : the skeleton's J joint names, as written

    Returns
    -------
    tuple of J str
    """
    bases = []
    for name in names:
        parts = [p.strip() for p in _PATH_SEPARATORS.split(name) if p.strip()]
        bases.append(parts[-1] if parts else name)
    found = [_NUMERIC_SUFFIX.fullmatch(b) for b in bases]
    suffixes = {m.group(2) for m in found if m}
    common = len(names) >= 2 and all(found) and len(suffixes) == 1
    strip = {
        k
        for k, m in enumerate(found)
        if m and (common or _rank(split_name(m.group(1))[1], _VOCABULARY) is not None)
    }
    while True:  # drop the strips that would make two joints read the same
        cleaned = [found[k].group(1) if k in strip else b for k, b in enumerate(bases)]
        keys = [split_name(c) for c in cleaned]
        clash = {k for k in strip if keys.count(keys[k]) > 1}
        if not clash:
            return tuple(cleaned)
        strip -= clash


def is_body_joint(name: str) -> bool:
    """Whether ``name`` (decorations removed, see :func:`clean_names`) is one some convention uses
    for a body joint (``Hips``, ``Bip001 Pelvis``, ``mixamorig:Spine1``...), unlike a wrapper
    above the skeleton (``Armature``, ``RootNode``, ``GLTF_created_0_rootJoint``, ``Bip001``)."""
    return _rank(split_name(clean_names((name,))[0])[1], _VOCABULARY) is not None


def _rank(core: str, patterns: tuple[str, ...]) -> int | None:
    for r, p in enumerate(patterns):
        if re.fullmatch(p, core):
            return r
    return None


def detect_rig(names: tuple[str, ...], clean: tuple[str, ...] | None = None) -> str:
    """A label for the naming convention, for reports only.

    ``clean`` : the names as :func:`clean_names` gives them (computed when not given).
    """
    if "mixamorig" in " ".join(names).lower():
        return "mixamo"
    names = clean_names(names) if clean is None else clean
    joined = " ".join(names)
    if re.search(r"(^|\s)Bip\d+", joined):
        return "biped"
    if any(n.startswith("DEF-") for n in names):
        return "rigify"
    if {"LHipJoint", "LowerBack"} <= set(names):
        return "cmu"
    if any(split_name(n)[1] == "collar" for n in names) and any(
        split_name(n)[1] == "elbow" for n in names
    ):
        return "motive"
    if set(MAPPED_JOINTS) <= set(names):
        return "canonical"
    return "generic"


def read_mapping_file(path: str | os.PathLike) -> dict[str, str]:
    """A user mapping file: JSON ``{canonical_name: source_name}`` (any subset of Hips + 19)."""
    path = os.fspath(path)
    try:
        with open(path, encoding="utf-8") as f:
            data = json.load(f)
    except FileNotFoundError:
        raise InputError("no such mapping file", path) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read mapping file: {exc}", path) from None
    except json.JSONDecodeError as exc:
        raise InputError(
            f"mapping file is not valid JSON: {exc.msg} (line {exc.lineno})", path
        ) from None
    if not isinstance(data, dict):
        raise InputError("mapping file must be a JSON object {canonical_name: source_name}", path)
    unknown = [k for k in data if k not in MAPPED_JOINTS]
    if unknown:
        raise InputError(
            f"mapping file names unknown canonical joints {unknown}; known: {list(MAPPED_JOINTS)}",
            path,
        )
    bad = [k for k, v in data.items() if not isinstance(v, str) or not v]
    if bad:
        raise InputError(f"mapping file values must be joint names (strings) for {bad}", path)
    return dict(data)


def map_skeleton(
    skeleton: Skeleton,
    user: dict[str, str] | None = None,
    path: str | os.PathLike | None = None,
    mapping_path: str | os.PathLike | None = None,
) -> JointMapping:
    """Map ``skeleton`` onto Hips + the 19 canonical joints.

    Parameters
    ----------
    skeleton : the source skeleton (any units and axes; only the rest pose's geometry is used,
        to skip zero-length bones)
    user : {canonical: source joint name}, optional
        Entries that override the matcher (from :func:`read_mapping_file`).
    path : the motion file, for error messages
    mapping_path : the mapping file, for error messages about its entries

    Raises
    ------
    InputError
        Naming every canonical joint that could not be found, or a user entry that names a
        joint the skeleton does not have.
    """
    names = skeleton.names
    user = dict(user or {})
    missing_src = [f"{c}->{s}" for c, s in user.items() if s not in names]
    if missing_src:
        raise InputError(
            f"mapping names source joints the skeleton does not have: {', '.join(missing_src)}",
            mapping_path or path,
        )
    parents = skeleton.parents
    rest = skeleton.rest_positions().astype(np.float64)
    extent = float(np.ptp(rest, axis=0).max()) if len(rest) > 1 else 0.0
    eps = max(extent, float(np.abs(skeleton.offsets).max(initial=0.0))) * 1e-3
    degenerate = np.linalg.norm(skeleton.offsets.astype(np.float64), axis=1) <= eps
    degenerate[0] = False
    depth = np.zeros(len(names), np.int64)
    for k in range(1, len(names)):
        depth[k] = depth[parents[k]] + 1
    clean = clean_names(names)
    info = [split_name(n) for n in clean]

    def ancestors(k: int) -> list[int]:
        out = []
        while k >= 0:
            out.append(k)
            k = int(parents[k])
        return out  # k itself first, root last

    def is_desc(k: int, of: int) -> bool:
        return of in ancestors(k)

    def pick(role: str, side: str | None, patterns=None, under: int | None = None) -> int | None:
        patterns = patterns or _ROLE_PATTERNS[role]
        cands = []
        for k, (s, core) in enumerate(info):
            if s != side:
                continue
            r = _rank(core, patterns)
            if r is None:
                continue
            if under is not None and not (k != under and is_desc(k, under)):
                continue
            cands.append((r, depth[k], k))
        if not cands and under is not None:
            return pick(role, side, patterns, None)
        return min(cands)[2] if cands else None

    found: dict[str, Entry] = {c: ((s, 1.0),) for c, s in user.items()}
    idx = {n: k for k, n in enumerate(names)}

    # Limbs, side by side, down one chain.
    for side, word in (("L", "Left"), ("R", "Right")):
        has_clav = any(s == side and _rank(c, _STRICT_CLAVICLE) is not None for s, c in info)
        has_arm = any(s == side and _rank(c, _STRICT_UPPERARM) is not None for s, c in info)
        for roles in _LIMBS.values():
            prev = None
            for role in roles:
                canonical = word + _CANONICAL_OF_ROLE[role]
                patterns = _ROLE_PATTERNS[role]
                if role == "clavicle":
                    patterns = _STRICT_CLAVICLE if has_clav or not has_arm else patterns
                    if not has_clav and not has_arm:
                        patterns = ()
                elif role == "upperarm" and not has_clav and has_arm:
                    patterns = _STRICT_UPPERARM
                if canonical in found:
                    prev = idx[found[canonical][0][0]]
                    continue
                k = pick(role, side, patterns, prev) if patterns else None
                if k is not None:
                    found[canonical] = ((names[k], 1.0),)
                    prev = k

    # Rigify's numbered spine: DEF-spine (hips), .001-.003, .004 neck, ..., last = head.
    numbered = sorted(
        (int(m.group(1) or 0), k)
        for k, (s, core) in enumerate(info)
        if s is None and (m := re.fullmatch(r"spine(\d{3})?", core))
    )
    rigify_spine = len(numbered) >= 6 and pick("head", None) is None

    if "Hips" not in found:
        k = pick("hips", None)
        if k is None and rigify_spine:
            k = numbered[0][1]
        if k is None:
            thighs = [found.get(f"{s}UpLeg") for s in ("Left", "Right")]
            if all(thighs):
                a = ancestors(idx[thighs[0][0][0]])
                b = set(ancestors(idx[thighs[1][0][0]]))
                k = next(x for x in a if x in b)
                while k > 0 and degenerate[k]:
                    k = int(parents[k])
            else:
                k = 0
        found["Hips"] = ((names[k], 1.0),)
    hips = idx[found["Hips"][0][0]]

    if "Head" not in found:
        k = pick("head", None)
        if k is None and rigify_spine:
            k = numbered[-1][1]
        if k is not None:
            found["Head"] = ((names[k], 1.0),)
    head = idx[found["Head"][0][0]] if "Head" in found else None

    if "Neck" not in found:
        cands = [
            k
            for k, (s, core) in enumerate(info)
            if s is None
            and _rank(core, _ROLE_PATTERNS["neck"]) is not None
            and (head is None or (k != head and is_desc(head, k)))
        ]
        if not cands and rigify_spine:
            cands = [k for n, k in numbered if n >= 4 and k != head]
        cands.sort(key=lambda k: depth[k])
        good = [k for k in cands if not degenerate[k]]
        if good or cands:
            found["Neck"] = ((names[(good or cands)[0]], 1.0),)

    # The spine: joints strictly between the hips and the neck (or the head), non-degenerate.
    top = found.get("Neck") or found.get("Head")
    if top is not None and not all(c in found for c in ("Spine", "Spine1", "Spine2")):
        path_up = ancestors(idx[top[0][0]])[1:]
        chain = []
        if hips in path_up:
            chain = [k for k in reversed(path_up[: path_up.index(hips)]) if not degenerate[k]]
        h = found["Hips"]
        t = found.get("Neck") or top
        if not chain:
            spine = [_lerp(h, t, 0.25), _lerp(h, t, 0.5), _lerp(h, t, 0.75)]
        elif len(chain) == 1:
            a = ((names[chain[0]], 1.0),)
            spine = [_lerp(h, a, 1 / 3), _lerp(h, a, 2 / 3), a]
        else:
            n = len(chain)
            first, last = ((names[chain[0]], 1.0),), ((names[chain[-1]], 1.0),)
            if n % 2:
                mid = ((names[chain[n // 2]], 1.0),)
            else:
                mid = _lerp(((names[chain[n // 2 - 1]], 1.0),), ((names[chain[n // 2]], 1.0),), 0.5)
            spine = [first, mid, last]
        for c, e in zip(("Spine", "Spine1", "Spine2"), spine):
            found.setdefault(c, e)
    if "Neck" not in found and "Head" in found and "Spine2" in found:
        found["Neck"] = _lerp(found["Spine2"], found["Head"], 0.5)
    for word in ("Left", "Right"):
        if f"{word}Shoulder" not in found and f"{word}Arm" in found and "Spine2" in found:
            found[f"{word}Shoulder"] = _lerp(found["Spine2"], found[f"{word}Arm"], _NUDGE)

    missing = [c for c in MAPPED_JOINTS if c not in found]
    if missing:
        raise InputError(
            f"could not map the skeleton onto the canonical joints: {len(missing)} of "
            f"{len(CANONICAL_JOINTS)} not found: {', '.join(missing)} (naming convention: "
            f"{detect_rig(names, clean)}); give a mapping file {{canonical_name: source_name}}",
            path,
        )

    # No canonical bone of zero length: move a joint on its parent towards its child.
    def position(entry: Entry) -> np.ndarray:
        return sum(w * rest[idx[n]] for n, w in entry)

    for c in MAPPED_JOINTS[1:]:
        if c in user or c not in _CANONICAL_CHILD:
            continue
        parent_pos = position(found[_CANONICAL_PARENT[c]])
        if np.linalg.norm(position(found[c]) - parent_pos) <= eps:
            found[c] = _lerp(found[c], found[_CANONICAL_CHILD[c]], _NUDGE)

    rig = detect_rig(names, clean) + ("+user" if user else "")
    return JointMapping(sources=tuple(found[c] for c in MAPPED_JOINTS), rig=rig)


def _lerp(a: Entry, b: Entry, t: float) -> Entry:
    """The blend ``(1 - t) * a + t * b`` of two entries, merged by joint name."""
    out: dict[str, float] = {}
    for entry, scale in ((a, 1.0 - t), (b, t)):
        for name, w in entry:
            out[name] = out.get(name, 0.0) + scale * w
    return tuple((n, w) for n, w in out.items() if w > 0)


def canonical_positions(motion: Motion, mapping: JointMapping | None = None) -> np.ndarray:
    """World positions of Hips + the 19 canonical joints.

    Parameters
    ----------
    motion : Motion (normalised: metres, Y up, for consumers that expect that)
    mapping : JointMapping, optional
        Defaults to ``motion.meta["joint_mapping"]`` (set by ``load_motion``), else the matcher.

    Returns
    -------
    (T, 20, 3) float32
        Row 0 is Hips, rows 1..19 follow ``CANONICAL_JOINTS``.
    """
    if mapping is None:
        mapping = motion.meta.get("joint_mapping") or map_skeleton(
            motion.skeleton, path=motion.meta.get("path")
        )
    w = mapping.weights(motion.skeleton.names)
    used = np.flatnonzero(w.any(axis=0))
    pos = forward_kinematics(motion.skeleton, motion.rotations, motion.root_positions)[0]
    out = np.einsum("cj,tjd->tcd", w[:, used], pos[:, used].astype(np.float64))
    return out.astype(np.float32)


def canonical_joints(
    motion: Motion, mapping: JointMapping | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The 19 canonical joints and the root: ``(joints (T, 19, 3) float32, root (T, 3) float32)``."""
    pos = canonical_positions(motion, mapping)
    return pos[:, 1:], pos[:, 0]
