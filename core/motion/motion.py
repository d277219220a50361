"""The ``Motion`` record every stage passes around."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from core.skeleton import Skeleton, forward_kinematics


@dataclass(frozen=True)
class Motion:
    """A clip on a skeleton, in metres, Y up.

    Attributes
    ----------
    skeleton : Skeleton with J joints (joint 0 is the root)
    rotations : (T, J, 3, 3) float32
        Local joint rotations relative to the parent.
    root_positions : (T, 3) float32
        World position of the root joint per frame.
    fps : float
        Frames per second.
    name : str
        Where the clip came from (file name or procedural kind), for reports.
    meta : dict
        What loading found out: ``up_axis`` (of the source file), ``unit_scale`` (metres per
        file unit), ``unit`` (its name), ``source_joints``... Informational only.
    """

    skeleton: Skeleton
    rotations: np.ndarray
    root_positions: np.ndarray
    fps: float
    name: str = ""
    meta: dict = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        t = len(self.rotations)
        j = self.skeleton.num_joints
        if self.rotations.shape != (t, j, 3, 3):
            raise ValueError(f"rotations must be (T, {j}, 3, 3), got {self.rotations.shape}")
        if self.root_positions.shape != (t, 3):
            raise ValueError(f"root_positions must be ({t}, 3), got {self.root_positions.shape}")
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise ValueError(f"fps must be positive, got {self.fps}")

    @property
    def num_frames(self) -> int:
        return len(self.rotations)

    @property
    def duration(self) -> float:
        """Seconds from the first frame to the last."""
        return (self.num_frames - 1) / self.fps

    def joint_positions(self) -> np.ndarray:
        """World positions of all joints: (T, J, 3) float32."""
        return forward_kinematics(self.skeleton, self.rotations, self.root_positions)[0]
