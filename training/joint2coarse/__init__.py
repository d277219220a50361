"""Joint2Coarse: body joint motion -> coarse proxy vertices, with no simulation at test time.

Array-level API (the CLI and project folders wrap it):

- inputs: :func:`joint2coarse_inputs` (Motion -> joints (T, 20, 3), root rotations (T, 3, 3)),
  :func:`canonical_joint_order`, :func:`motion_descriptors`, :func:`heading_rotations`;
  the output frame each vertex is predicted in: :func:`to_output_frame`, :func:`from_output_frame`
  (the root frame tilted per vertex by :func:`follow_weights` of :func:`tilt_rotvecs`);
- training: :class:`Joint2CoarseClip`, :func:`train_joint2coarse` (resumable);
- prediction: :func:`load_model`, :func:`predict_proxy`, :class:`Joint2CoarseStream` (on a
  :class:`FrozenForward`: the network as plain matrix products, for one frame at a time);
- extras: :func:`prediction_stretch_limit` (the strain limit a prediction takes from its
  proxy), :func:`push_out_of_capsules`, :func:`vertex_errors`, :func:`reconstruct_proxy` (the
  shape autoencoder on known shapes: what the decoder reaches).
"""

from core.body.colliders import DEFAULT_MARGIN_M, push_out_of_capsules
from training.joint2coarse.config import PRESETS, Joint2CoarseConfig
from training.joint2coarse.descriptor import (
    JOINT2COARSE_JOINTS,
    canonical_joint_order,
    follow_weights,
    from_output_frame,
    from_root_frame,
    heading_rotations,
    joint2coarse_inputs,
    motion_descriptors,
    tilt_rotvecs,
    to_output_frame,
    to_root_frame,
)
from training.joint2coarse.metrics import VertexErrors, vertex_errors
from training.joint2coarse.model import Joint2CoarseNet, load_model, save_model
from training.joint2coarse.predict import (
    FrozenForward,
    Joint2CoarseStream,
    predict_proxy,
    prediction_stretch_limit,
    reconstruct_proxy,
)
from training.joint2coarse.train import (
    Joint2CoarseClip,
    Joint2CoarseTrainResult,
    prepare_data,
    train_joint2coarse,
)

__all__ = [
    "DEFAULT_MARGIN_M",
    "FrozenForward",
    "JOINT2COARSE_JOINTS",
    "PRESETS",
    "Joint2CoarseClip",
    "Joint2CoarseConfig",
    "Joint2CoarseNet",
    "Joint2CoarseStream",
    "Joint2CoarseTrainResult",
    "VertexErrors",
    "canonical_joint_order",
    "follow_weights",
    "from_output_frame",
    "from_root_frame",
    "heading_rotations",
    "joint2coarse_inputs",
    "load_model",
    "motion_descriptors",
    "predict_proxy",
    "prediction_stretch_limit",
    "prepare_data",
    "push_out_of_capsules",
    "reconstruct_proxy",
    "save_model",
    "tilt_rotvecs",
    "to_output_frame",
    "to_root_frame",
    "train_joint2coarse",
    "vertex_errors",
]
