"""Our Joint2Coarse (``model="ours"``): a body-driven base plus a learnt dynamic residual.

The paper's network maps the motion descriptor to one global shape code; on a motion unlike its
training clips the code lands somewhere else and the whole garment with it. Ours predicts in
the heading frame, as the sum of

1. a **body-driven base**: the rest proxy skinned to the body by linear blending, with weights
   copied from the mannequin's own skinning (torso and legs only), fading with depth down the
   garment (``skin_fade``) towards the hips' rigid frame. The bones' rotations come from the
   joint positions of the current frame (the descriptor's first sample): the hips' from the
   hips, legs and spine (Kabsch), every other bone's as the hips' rotation followed by the
   swing from there to where the bone points now. So a new pose moves the waistband and the
   front of the skirt with the legs, whatever the training clips were;
2. a **residual** from features of the joints' history: the current pose, the velocities and
   accelerations of the spine's and legs' joints over several lags (in the heading frame, so
   they do not depend on where the body stands or faces, or, with ``feature_frame``, in the
   current frame's hips' frame, so that a pelvis tilted as no training clip tilts it gives
   familiar features, with gravity's direction beside them), the pelvis's turning rate over
   lags up to the whole window (a spin twists and flares a skirt; with its signed square), and
   the square terms of the turning rate and speed that drive a skirt's flare (the centrifugal
   push grows with the square of the turning rate). It is predicted in the hips' frame (so it
   tilts with the pelvis; ``residual_frame`` can put it in each vertex's skinned frame) and
   fitted to the simulated proxy minus the base, by small ReLU
   networks (``residual_widths``, trained with torch in seconds, ``residual_members`` of them
   averaged, their outputs weights of the training residuals' principal components, ``basis``)
   or, with no hidden layer, linearly in closed form (ridge regression, ``ridge``).

Both parts are a few matrix products per frame, so it streams a 2k-vertex proxy in under 2 ms
a frame on one core (the quick preset's model, symmetric, three networks: the README's figure,
from ``benchmarks/joint2coarse_speed.py``). Arrays are numpy float64 inside, float32 stored.

The prediction's functions (:func:`bone_transforms`, :func:`motion_features`,
:func:`predict_heading_frame`) take numpy arrays or torch tensors and compute with the library
of what they are given (the same calls, in the same order): numpy for training and the studio,
torch on any device for the torch-only path (:meth:`BodyResidualModel.to_torch`). Only
:func:`body_rig` (scipy, the mannequin) is numpy-only.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import torch

from core.body.mannequin import make_body
from core.body.shape import BodyShape
from core.errors import InputError
from training.joint2coarse.augment import MirrorMap, mirror_descriptors, reflect_positions
from training.joint2coarse.config import Joint2CoarseConfig
from training.joint2coarse.descriptor import JOINT2COARSE_JOINTS

#: Joints the garment may be skinned to: the torso and the legs (not the arms: in the A-pose
#: the hands hang beside a skirt and would otherwise carry its sides).
SKIN_JOINTS = (
    "Hips", "Spine", "Spine1", "Spine2",
    "LeftUpLeg", "LeftLeg", "LeftFoot", "RightUpLeg", "RightLeg", "RightFoot",
)  # fmt: skip
#: The child each bone's direction points to (its swing is the bone's rotation).
_CHILD = {
    "Spine": "Spine1", "Spine1": "Spine2", "Spine2": "Neck",
    "LeftUpLeg": "LeftLeg", "LeftLeg": "LeftFoot", "RightUpLeg": "RightLeg",
    "RightLeg": "RightFoot",
}  # fmt: skip
#: The joints whose velocities and accelerations feed the residual: the spine and the legs, what
#: drives a garment below the chest (the arms do not collide with one: ``core.body.colliders.
#: arms_collide``). Chosen on the quick project's validation motions (mean / p95 mm, seeds 0 to
#: 5, ``python benchmarks/joint2coarse_validation.py P --seeds 0 1 2 3 4 5``): 27.3 / 59 against
#: 28.2 / 62 with every joint's, better at every seed. (Every joint's current pose stays in:
#: without the arms' the error rose to 40.2 / 83.) Reported after, never chosen on: it cost the
#: test twirl about 7 mm (README, "Joint2Coarse on motions it has never seen"); a spinning
#: body's arms, far from the axis, carry its turning most strongly.
DYNAMIC_JOINTS = (
    "Spine2", "Spine1", "Spine", "LeftUpLeg", "LeftLeg", "LeftFoot",
    "RightUpLeg", "RightLeg", "RightFoot",
)  # fmt: skip
#: Descriptor samples (of ``stride`` frames) over which velocities and accelerations are taken.
VELOCITY_LAGS = (1, 3, 6, 12)
ACCELERATION_LAGS = (1, 3, 6)
#: Descriptor samples over which the pelvis's turning rate is taken (those inside the window).
#: Without them, on the quick project's validation motions (seeds 0, 1): 48.0 / 100 mm mean /
#: p95 against 46.3 / 96 (``benchmarks/joint2coarse_validation.py P --set model=ours
#: --no-turn-lags``). With the 19-clip library, whose spins show the turning rate directly,
#: they no longer matter: 35.1 / 76 without against 35.0 / 76 (the (256, 256) network, seeds 0
#: and 1); kept, since the model is no better without them.
TURN_LAGS = (1, 2, 3, 4, 6, 8, 12, 16)
#: Training of the residual network (``residual_widths``): AdamW (``residual_weight_decay``),
#: this many frames per step, a one-cycle learning-rate schedule peaking at ``learning_rate``.
RESIDUAL_BATCH = 128
#: ``residual_loss="distance"``: each step's loss is the mean distance over this many of the
#: proxy's vertices, drawn afresh (an unbiased estimate of the mean over all of them, at a
#: fraction of the cost of projecting every frame's coefficients onto every vertex).
DISTANCE_VERTICES = 128
#: Joint index in the descriptor's 19 joints (the root is not in it: it is the origin).
_DESC = {name: i for i, name in enumerate(JOINT2COARSE_JOINTS[1:])}
_DYNAMIC = [_DESC[name] for name in DYNAMIC_JOINTS]


def body_rig(shape: BodyShape, rest_proxy: np.ndarray, fade: float) -> tuple[np.ndarray, ...]:
    """Skinning of the rest proxy to the mannequin, faded towards the hips down the garment.

    Parameters
    ----------
    shape : BodyShape
    rest_proxy : (V, 3) float, the proxy in the rest pose (``proxy/positions.obj``)
    fade : float >= 0
        Vertex v keeps ``a_v = h_v ** fade`` of the body's weights and moves rigidly with the
        hips for the rest, ``h_v`` its height in the garment (1 at the top, 0 at the hem); 0
        skins every vertex fully.

    Returns
    -------
    weights : (V, 20) float32, rows summing to 1, columns in ``JOINT2COARSE_JOINTS`` order
    rest_joints : (20, 3) float32, rest joint positions relative to the rest root
    rest_vertices : (V, 3) float32, the rest proxy relative to the rest root
    """
    from scipy.spatial import cKDTree

    v = np.asarray(rest_proxy, np.float64)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0 or not np.isfinite(v).all():
        raise InputError(f"rest proxy must be a finite (V, 3) array, got {v.shape}")
    body = make_body(shape)
    names = list(body.skeleton.names)
    keep = np.array([n in SKIN_JOINTS for n in names])
    _, nearest = cKDTree(body.vertices).query(v, k=4)
    w = body.weights[nearest].mean(axis=1) * keep  # (V, J) mannequin order
    hips = names.index("Hips")
    w[w.sum(1) <= 1e-6, hips] = 1.0
    w /= w.sum(1, keepdims=True)
    span = max(v[:, 1].max() - v[:, 1].min(), 1e-9)
    a = ((v[:, 1] - v[:, 1].min()) / span) ** fade
    w = a[:, None] * w
    w[:, hips] += 1.0 - a
    rest = body.skeleton.rest_positions().astype(np.float64)
    order = [names.index(n) for n in JOINT2COARSE_JOINTS]
    root = rest[hips]
    return (
        w[:, order].astype(np.float32),
        (rest[order] - root).astype(np.float32),
        (v - root).astype(np.float32),
    )


def _xp(x):
    """The array library of x: torch for a tensor, else numpy (the names both share)."""
    return torch if isinstance(x, torch.Tensor) else np


def _as(x, dtype: str):
    """x as float64 or float32 (``dtype`` "float64" / "float32"), numpy or torch as it is."""
    if isinstance(x, torch.Tensor):
        return x.to(getattr(torch, dtype))
    return np.asarray(x, getattr(np, dtype))


def _new(like, kind: str, shape: tuple):
    """float64 ``zeros`` or ``ones`` of ``shape``, or the identity (``eye``, shape ``(n,)``),
    of like's library (and device)."""
    if isinstance(like, torch.Tensor):
        return getattr(torch, kind)(*shape, dtype=torch.float64, device=like.device)
    return getattr(np, kind)(*shape) if kind == "eye" else getattr(np, kind)(shape)


def _swing(a, b):
    """Minimal rotations taking unit vectors a to b, (..., 3) -> (..., 3, 3) (Rodrigues; a and
    b never opposite for the bones it is used on: clamped there)."""
    xp = _xp(a)
    v = torch.linalg.cross(a, b) if xp is torch else np.cross(a, b)
    c = xp.sum(a * b, -1)
    k = _new(a, "zeros", v.shape[:-1] + (3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    k = k - xp.swapaxes(k, -1, -2)
    return _new(a, "eye", (3,)) + k + (k @ k) / xp.clip(1.0 + c, 1e-3, None)[..., None, None]


def _unit(x):
    if isinstance(x, torch.Tensor):
        n = torch.linalg.vector_norm(x, dim=-1, keepdim=True)
    else:
        n = np.linalg.norm(x, axis=-1, keepdims=True)
    return x / _xp(x).clip(n, 1e-9, None)


def _kabsch(src, dst):
    """Rotations (B, 3, 3) best taking point sets src (P, 3) onto dst (B, P, 3) (no centring:
    both are relative to the hips)."""
    xp = _xp(dst)
    h = xp.einsum("pi,bpj->bij", src, dst)
    u, _, vt = xp.linalg.svd(h)
    d = xp.sign(xp.linalg.det(xp.matmul(xp.swapaxes(vt, 1, 2), xp.swapaxes(u, 1, 2))))
    fix = _new(dst, "ones", (len(dst), 3))
    fix[:, 2] = d
    return xp.matmul(xp.swapaxes(vt, 1, 2) * fix[:, None, :], xp.swapaxes(u, 1, 2))


def bone_transforms(pose, rest_joints):
    """Per-joint rigid transforms taking rest points to the current pose, heading frame.

    Parameters
    ----------
    pose : (B, 19, 3) float, the descriptor's first sample (canonical joints, root at origin)
    rest_joints : (20, 3) float, :func:`body_rig`
        numpy arrays or torch tensors (both of one kind, on one device).

    Returns
    -------
    (B, 20, 3, 4) float64 of the inputs' kind: ``x -> M[:, :3] @ x + M[:, 3]``.
    """
    xp = _xp(pose)
    b = len(pose)
    cur = xp.concatenate([_new(pose, "zeros", (b, 1, 3)), _as(pose, "float64")], axis=1)
    rest = _as(rest_joints, "float64")
    ix = {n: i for i, n in enumerate(JOINT2COARSE_JOINTS)}
    anchors = [ix[n] for n in ("LeftUpLeg", "RightUpLeg", "Spine", "Spine1")]
    hips = _kabsch(rest[anchors], cur[:, anchors])  # (B, 3, 3)
    # joints the garment is not skinned to turn with the hips
    rot = hips[:, None] * _new(hips, "ones", (1, len(ix), 1, 1))
    j = [ix[n] for n in _CHILD]
    c = [ix[n] for n in _CHILD.values()]
    turned = xp.matmul(_unit(rest[c] - rest[j]), xp.swapaxes(hips, 1, 2))  # (B, n, 3)
    rot[:, j] = xp.matmul(_swing(turned, _unit(cur[:, c] - cur[:, j])), hips[:, None])
    for foot, leg in (("LeftFoot", "LeftLeg"), ("RightFoot", "RightLeg")):
        rot[:, ix[foot]] = rot[:, ix[leg]]
    move = cur - xp.einsum("bjik,jk->bji", rot, rest)
    return xp.concatenate([rot, move[..., None]], axis=-1)


def descriptor_transforms(desc, rest_joints):
    """(B, D) descriptors -> (B, 20, 3, 4) float64 :func:`bone_transforms` of each frame's pose
    (the descriptor's first sample). numpy or torch."""
    return bone_transforms(_as(desc, "float64")[:, :57].reshape(-1, 19, 3), rest_joints)


def motion_features(desc, num_samples: int, frame: str = "heading", hips=None):
    """The residual's inputs from descriptors (see the module docstring).

    Parameters
    ----------
    desc : (B, K * 57) float numpy array or torch tensor,
        :func:`~training.joint2coarse.descriptor.motion_descriptors`
    num_samples : int, K
    frame : str
        ``heading``: every feature in the heading frame; ``hips``: the whole window turned
        into the current frame's hips' frame (so a tilted pelvis is the familiar pose, tilted),
        and gravity's direction there; ``hips+heading``: those and the current pose in the
        heading frame too (:attr:`~training.joint2coarse.config.Joint2CoarseConfig.feature_frame`).
    hips : (B, 3, 3) float, the hips' rotations (rest -> heading frame, the first of
        :func:`bone_transforms`) of the current frame; needed for ``hips`` frames.

    Returns
    -------
    (B, F) float64 of desc's kind
    """
    xp = _xp(desc)
    x = _as(desc, "float64").reshape(len(desc), num_samples, 19, 3)
    if frame == "heading":
        parts = [x[:, 0].reshape(len(x), -1)]
    else:
        heading = x[:, 0].reshape(len(x), -1)
        r = _as(hips, "float64")
        x = xp.einsum("bkjc,bcd->bkjd", x, r)  # row vectors: p R, the hips' frame's R^T p
        parts = [x[:, 0].reshape(len(x), -1), r[:, 1, :]]  # the pose; up, in the hips' frame
        if frame == "hips+heading":
            parts.append(heading)
    vel = [k for k in VELOCITY_LAGS if k < num_samples]
    acc = [k for k in ACCELERATION_LAGS if 2 * k < num_samples]
    d = x[:, :, _DYNAMIC]
    parts += [((d[:, 0] - d[:, k]) / k).reshape(len(x), -1) for k in vel]
    parts += [((d[:, 0] - 2 * d[:, k] + d[:, 2 * k]) / k**2).reshape(len(x), -1) for k in acc]
    hip_line = x[:, :, _DESC["LeftUpLeg"]] - x[:, :, _DESC["RightUpLeg"]]  # (B, K, 3)
    angle = xp.arctan2(-hip_line[..., 2], hip_line[..., 0])
    centre = 0.5 * (x[:, :, _DESC["LeftUpLeg"]] + x[:, :, _DESC["RightUpLeg"]])
    for k in vel:
        w = xp.angle(xp.exp(1j * (angle[:, 0] - angle[:, k]))) / k  # turning rate, rad/sample
        vx, vz = ((centre[:, 0] - centre[:, k]) / k)[:, [0, 2]].T
        parts.append(xp.stack([w * w, w * vx, w * vz, vx * vx, vz * vz, vx * vz], -1))
    # turning rate over longer lags too: the angle unwrapped sample by sample
    step = xp.angle(xp.exp(1j * (angle[:, :-1] - angle[:, 1:])))  # (B, K - 1)
    for k in (k for k in TURN_LAGS if k < num_samples):
        w = xp.sum(step[:, :k], 1) / k
        parts.append(xp.stack([w, w * xp.abs(w)], -1))
    return xp.concatenate(parts, axis=1)


def skin_matrix(weights: np.ndarray, rest_vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Linear blend skinning of the rest proxy as one product's left side.

    Parameters
    ----------
    weights : (V, 20) float, rest_vertices : (V, 3) float
        :func:`body_rig`.

    Returns
    -------
    used : (S,) int64, the joints with any weight
    skin : (V, 4 S) float32, ``[w_vj x_v, w_vj]`` over the used joints
    """
    w = np.asarray(weights, np.float32)
    used = np.flatnonzero(w.max(0) > 0)
    x = np.concatenate([np.asarray(rest_vertices, np.float32), np.ones((len(w), 1))], axis=1)
    skin = (w[:, used, None] * x[:, None, :]).reshape(len(w), -1)
    return used, skin.astype(np.float32)


def skin_weights(skin):
    """The used joints' weights (V, S) inside :func:`skin_matrix`'s ``skin`` (V, 4 S): the
    column each joint's block multiplies with the 1. numpy or torch."""
    return skin.reshape(len(skin), -1, 4)[..., 3]


def vertex_frames(transforms, used, weights):
    """Each vertex's own frame: its bones' rotations blended by its skinning weights,
    orthonormalised (Gram-Schmidt on the columns, the first kept), for a residual that is a
    displacement of the rest proxy before skinning (``residual_frame="skinned"``).

    Parameters
    ----------
    transforms : (B, 20, 3, 4) float64 :func:`bone_transforms`
    used : (S,) int, weights : (V, S) float
        :func:`skin_matrix`'s used joints and :func:`skin_weights`. numpy or torch.

    Returns
    -------
    (B, V, 3, 3) float64 rotations (rest frame -> heading frame), of the inputs' kind.
    """
    xp = _xp(transforms)
    m = xp.einsum("vs,bsij->bvij", _as(weights, "float64"), transforms[:, used, :, :3])
    e0 = _unit(m[..., 0])
    e1 = _unit(m[..., 1] - (m[..., 1] * e0).sum(-1)[..., None] * e0)
    e2 = torch.linalg.cross(e0, e1) if xp is torch else np.cross(e0, e1)
    return xp.stack([e0, e1, e2], -1)


def skinned_base(transforms, used, skin):
    """The body-driven base: (B, 20, 3, 4) float64 :func:`bone_transforms`, ``used`` and
    ``skin`` of :func:`skin_matrix` -> (B, V, 3) float32 skinned rest proxy, heading frame:
    ``skin`` times the stacked ``[R_j^T; t_j]`` (4 S, 3) of each frame. numpy or torch."""
    m = transforms[:, used]  # (B, S, 3, 4)
    stacked = _as(_xp(m).swapaxes(m, -1, -2).reshape(len(m), -1, 3), "float32")
    return _xp(m).matmul(skin, stacked)


def feature_count(config: Joint2CoarseConfig, descriptor_dim: int) -> int:
    """F, the number of :func:`motion_features` of config's ``feature_frame``."""
    z = np.zeros((1, descriptor_dim))
    return motion_features(z, config.num_samples, config.feature_frame, np.eye(3)[None]).shape[1]


def residual_inputs(desc, transforms, feat_mean, feat_std, config: Joint2CoarseConfig):
    """(B, D) descriptors and their (B, 20, 3, 4) :func:`bone_transforms` -> (B, F + 1) float64
    normalised, clamped :func:`motion_features` (config's ``feature_frame``, ``clamp_z``) and
    a 1 for the bias (feat_mean, feat_std (F,)). numpy or torch."""
    feats = motion_features(desc, config.num_samples, config.feature_frame, transforms[:, 0, :, :3])
    clamp_z = config.clamp_z
    z = (feats - feat_mean) / feat_std
    return _xp(z).concatenate(
        [_xp(z).clip(z, -clamp_z, clamp_z), _new(z, "ones", (len(z), 1))], axis=1
    )


def hidden_names(params) -> list[str]:
    """Names of the residual network's hidden layers in ``params`` (``hidden0``, ``hidden1``,
    ... in order; none for the linear residual)."""
    n = 0
    while f"hidden{n}" in params:
        n += 1
    return [f"hidden{i}" for i in range(n)]


def residual_hidden(x, layers: list):
    """The residual network's hidden layers: ``h <- [relu(h @ W), 1]`` for each ``W`` (H_in + 1,
    H) of ``layers`` (the last row is the bias), from x (B, F + 1) float32 (its last column the
    1 of :func:`residual_inputs`) -> (B, H + 1) float32 (x itself for no layer). numpy or
    torch."""
    xp = _xp(x)
    for w in layers:
        h = xp.clip(x @ w, 0.0, None)
        x = xp.concatenate([h, _as(_new(h, "ones", (len(h), 1)), "float32")], axis=1)
    return x


def predict_heading_frame(desc, params: dict, config: Joint2CoarseConfig):
    """Our prediction: the base plus the residual, turned from the hips' frame into the heading
    frame; for a model trained with mirrored clips (``mirror_corners`` in params), the mean of
    that and the reflected prediction for the mirrored motion (so the model is left-right
    symmetric, as the physics is).

    Parameters
    ----------
    desc : (B, D) float descriptors (D = config.num_samples * 57)
    params : ``rest_joints`` (20, 3), ``feat_mean``, ``feat_std`` (F,), the hidden layers
        ``hidden0``, ``hidden1``, ... (F + 1, H0), (H0 + 1, H1), ... (none for the linear
        residual) and ``coef`` (H + 1, V * 3), or (H + 1, K) with ``basis`` (K, V * 3), float32
        (:class:`BodyResidualModel`'s arrays),
        ``used`` (S,) int and ``skin`` (V, 4 S) float32 (:func:`skin_matrix`), optionally
        ``mirror_corners`` (V, 3) int and ``mirror_barycentric`` (V, 3) float32
        (:class:`~training.joint2coarse.augment.MirrorMap`): numpy arrays, or torch tensors on
        desc's device: the computation runs in their library.

    Returns
    -------
    (B, V, 3) float32 heading-frame vertices.
    """
    if "mirror_corners" not in params:
        return _predict_once(desc, params, config)
    both = _xp(desc).concatenate([desc, mirror_descriptors(desc, config.num_samples)])  # one pass
    out = _predict_once(both, params, config)
    back = reflect_positions(
        out[len(desc) :], params["mirror_corners"], params["mirror_barycentric"]
    )
    return 0.5 * (out[: len(desc)] + back)


def _predict_once(desc, params: dict, config: Joint2CoarseConfig):
    """:func:`predict_heading_frame` of one motion (no mirror)."""
    xp, p = _xp(desc), params
    desc = _as(desc, "float64")
    m = descriptor_transforms(desc, p["rest_joints"])
    x = _as(residual_inputs(desc, m, p["feat_mean"], p["feat_std"], config), "float32")
    x = residual_hidden(x, [p[n] for n in hidden_names(p)]) @ p["coef"]
    if "basis" in p:
        x = x @ p["basis"]
    residual = x.reshape(len(desc), -1, 3)
    base = skinned_base(m, p["used"], p["skin"])
    if config.residual_frame == "skinned":  # each vertex's own frame
        frames = _as(vertex_frames(m, p["used"], skin_weights(p["skin"])), "float32")
        return base + xp.einsum("bvij,bvj->bvi", frames, residual)
    hips_t = _as(xp.swapaxes(m[:, 0, :, :3], 1, 2), "float32")  # row vectors: r R^T
    return base + xp.matmul(residual, hips_t)


class BodyResidualModel:
    """Our Joint2Coarse: :func:`bone_transforms` skinning + residual (module docstring).

    Quacks like :class:`~training.joint2coarse.model.Joint2CoarseNet` where prediction needs it
    (``config``, ``n_vertices``, ``descriptor_dim``, :meth:`follow_weights`, :meth:`predict`):
    its output frame is the heading frame (no per-vertex tilt). :meth:`to_torch` gives the same
    prediction as a torch module, for any device.

    Attributes (arrays float32)
    ----------
    weights : (V, 20), rest_joints : (20, 3), rest_vertices : (V, 3)
        :func:`body_rig`.
    feat_mean, feat_std : (F,)
        Normalisation of :func:`motion_features`.
    hidden0, hidden1, ... : (F + 1, H0), (H0 + 1, H1), ...
        The residual network's hidden layers (:func:`residual_hidden`); none: linear.
    coef : (H + 1, V * 3), or (H + 1, K) with ``basis``
        Residual = ``residual_hidden([clamp(z), 1]) @ coef`` (``@ basis``).
    basis : (K, V * 3), optional
        The residual network's principal components of the training residuals and their mean
        (the last row), which ``coef`` weighs (:func:`fit_residual_network`).
    mirror_corners, mirror_barycentric : (V, 3), optional
        The proxy's :class:`~training.joint2coarse.augment.MirrorMap` (corner indices stored
        as float32) of a model trained with mirrored clips: it predicts symmetrically
        (:func:`predict_heading_frame`).
    """

    def __init__(self, config: Joint2CoarseConfig, descriptor_dim: int, arrays: dict):
        self.config = config
        self.descriptor_dim = descriptor_dim
        self.arrays = {k: np.asarray(v, np.float32) for k, v in arrays.items()}
        self.n_vertices = len(self.arrays["weights"])
        self.training = False
        self._skin: tuple[np.ndarray, np.ndarray] | None = None  # built on first use

    def follow_weights(self) -> None:
        return None

    def eval(self) -> BodyResidualModel:
        return self

    def transforms(self, desc: np.ndarray) -> np.ndarray:
        """(B, D) descriptors -> (B, 20, 3, 4) float64 :func:`bone_transforms` of each frame."""
        return descriptor_transforms(np.asarray(desc), self.arrays["rest_joints"])

    def skin(self) -> tuple[np.ndarray, np.ndarray]:
        """:func:`skin_matrix` of the rig (built once)."""
        if self._skin is None:
            self._skin = skin_matrix(self.arrays["weights"], self.arrays["rest_vertices"])
        return self._skin

    def base(self, transforms: np.ndarray) -> np.ndarray:
        """(B, 20, 3, 4) :meth:`transforms` -> (B, V, 3) float32 :func:`skinned_base`."""
        return skinned_base(transforms, *self.skin())

    def features(self, desc: np.ndarray, transforms: np.ndarray | None = None) -> np.ndarray:
        """(B, D), their :meth:`transforms` if already computed -> (B, F + 1)
        :func:`residual_inputs`."""
        m = self.transforms(desc) if transforms is None else transforms
        a = self.arrays
        return residual_inputs(desc, m, a["feat_mean"], a["feat_std"], self.config)

    def params(self) -> dict:
        """The arrays :func:`predict_heading_frame` reads (numpy)."""
        used, skin = self.skin()
        names = ("rest_joints", "feat_mean", "feat_std", "coef", *hidden_names(self.arrays))
        if "basis" in self.arrays:
            names += ("basis",)
        out = {"used": used, "skin": skin, **{k: self.arrays[k] for k in names}}
        if "mirror_corners" in self.arrays:  # stored as float32, exact for any proxy size
            out["mirror_corners"] = self.arrays["mirror_corners"].astype(np.int64)
            out["mirror_barycentric"] = self.arrays["mirror_barycentric"]
        return out

    def predict(self, desc: np.ndarray) -> np.ndarray:
        """(B, D) float descriptors -> (B, V, 3) float32 heading-frame vertices
        (:func:`predict_heading_frame`)."""
        desc = np.asarray(desc, np.float64)
        if desc.ndim != 2 or desc.shape[1] != self.descriptor_dim:
            raise InputError(f"descriptors must be (B, {self.descriptor_dim}), got {desc.shape}")
        return predict_heading_frame(desc, self.params(), self.config)

    def to_torch(self) -> BodyResidualNet:
        """The same prediction as a torch module (CPU; ``.to(device)`` moves it)."""
        return BodyResidualNet(self)

    def state_dict(self) -> dict:
        return {k: torch.from_numpy(v.copy()) for k, v in self.arrays.items()}


class BodyResidualNet(torch.nn.Module):
    """:class:`BodyResidualModel`'s prediction in torch on any device: the arrays of
    :meth:`BodyResidualModel.params` as buffers, :func:`predict_heading_frame` as forward.

    ``config``, ``n_vertices``, ``descriptor_dim`` and :meth:`follow_weights` as the model's.
    """

    def __init__(self, model: BodyResidualModel):
        super().__init__()
        self.config = model.config
        self.n_vertices = model.n_vertices
        self.descriptor_dim = model.descriptor_dim
        for name, value in model.params().items():
            self.register_buffer(name, torch.from_numpy(np.ascontiguousarray(value)))

    def follow_weights(self) -> None:
        return None

    def forward(self, desc: torch.Tensor) -> torch.Tensor:
        """(B, D) float descriptors on the module's device -> (B, V, 3) float32 heading-frame
        vertices."""
        params = dict(self.named_buffers())
        return predict_heading_frame(desc, params, self.config)


def fit_body_residual(
    config: Joint2CoarseConfig,
    desc: np.ndarray,
    verts: np.ndarray,
    rig: tuple[np.ndarray, np.ndarray, np.ndarray],
    mirror: MirrorMap | None = None,
) -> BodyResidualModel:
    """Fit the residual: ``config.residual_members`` networks of ``config.residual_widths``
    (:func:`fit_residual_network`, seeds ``seed``, ``seed + 1``, ...) folded into one
    (:func:`stack_members`), or for no hidden layer, linearly in closed form (ridge).

    Parameters
    ----------
    desc : (N, D) float32 training descriptors
    verts : (N, V * 3) float32 training proxies in the heading frame
    rig : :func:`body_rig`'s (weights, rest_joints, rest_vertices)
    mirror : MirrorMap, optional
        Kept in the model, which then predicts symmetrically (``config.mirror``: the training
        frames hold every clip's mirror too).
    """
    weights, rest_joints, rest_vertices = rig
    if len(weights) * 3 != verts.shape[1]:
        raise InputError(
            f"the rig has {len(weights)} vertices, the training proxies {verts.shape[1] // 3}"
        )
    m = descriptor_transforms(np.asarray(desc), rest_joints)
    feats = motion_features(desc, config.num_samples, config.feature_frame, m[:, 0, :, :3])
    mean, std = feats.mean(0), np.maximum(feats.std(0), 1e-6)
    arrays = {
        "weights": weights, "rest_joints": rest_joints, "rest_vertices": rest_vertices,
        "feat_mean": mean, "feat_std": std, "coef": np.zeros((feats.shape[1] + 1, verts.shape[1])),
    }  # fmt: skip
    model = BodyResidualModel(config, desc.shape[1], arrays)
    x = model.features(desc, m)
    y = np.asarray(verts, np.float64).reshape(len(desc), -1, 3) - model.base(m)
    if config.residual_frame == "skinned":  # into each vertex's own frame: F_v^T y_v
        used, skin = model.skin()
        for i in range(0, len(y), 1024):
            f = vertex_frames(m[i : i + 1024], used, skin_weights(skin))
            y[i : i + 1024] = np.einsum("bvji,bvj->bvi", f, y[i : i + 1024])
        y = y.reshape(len(desc), -1)
    else:
        y = np.matmul(y, m[:, 0, :, :3]).reshape(len(desc), -1)  # into the hips' frame: R^T y
    if config.residual_widths:
        basis = residual_basis(y, config.residual_basis)
        members = [
            fit_residual_network(replace(config, seed=config.seed + i), x, y, basis)
            for i in range(config.residual_members)
        ]
        hidden, coef = stack_members([(h, c) for h, c, _ in members])
        model.arrays.update({f"hidden{i}": w.astype(np.float32) for i, w in enumerate(hidden)})
        model.arrays["basis"] = members[0][2].astype(np.float32)
    else:
        reg = config.ridge * len(x) * np.eye(x.shape[1])
        reg[-1, -1] = 0.0  # the bias is not shrunk
        coef = np.linalg.solve(x.T @ x + reg, x.T @ y)
    model.arrays["coef"] = coef.astype(np.float32)
    if mirror is not None:
        model.arrays["mirror_corners"] = mirror.corners.astype(np.float32)
        model.arrays["mirror_barycentric"] = mirror.barycentric.astype(np.float32)
    return model


def residual_basis(y: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The mean (3V,) and the first ``k`` principal components (k', 3V) orthonormal rows,
    ``k' = min(k, N, 3V)``, of residuals y (N, 3V)."""
    y = np.asarray(y, np.float64)
    mean = y.mean(0)
    k = max(1, min(k, *y.shape))
    return mean, np.linalg.svd(y - mean, full_matrices=False)[2][:k]


def fit_residual_network(
    config: Joint2CoarseConfig,
    x: np.ndarray,
    y: np.ndarray,
    basis: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """Train the residual network: ReLU layers of ``config.residual_widths`` (dropout
    ``residual_dropout``) onto the coefficients of the first ``residual_basis`` principal
    components of the training residuals, ``residual_steps`` AdamW steps (weight decay
    ``residual_weight_decay``; batch and schedule as the module constants say), Gaussian noise
    of ``residual_input_noise`` on the inputs, the loss the residual's squared error in metres
    or, with ``residual_loss="distance"``, each vertex's distance to its target.
    Seeded by ``config.seed`` on its own random stream (the caller's is untouched).

    Parameters
    ----------
    x : (N, F + 1) float, :func:`residual_inputs` of the training frames
    y : (N, V * 3) float, their residuals in the hips' frame
    basis : :func:`residual_basis` of y with ``config.residual_basis``, when already computed

    Returns
    -------
    hidden : list of (H_in + 1, H) float64, the layers as :func:`residual_hidden` takes them
    coef : (H + 1, K + 1) float64, the last layer: weights of the K principal components and,
        in the last column, of the mean residual (1 on the bias row)
    basis : (K + 1, V * 3) float64, the principal components and the mean residual last
    """
    y = np.asarray(y, np.float64)
    mean, basis = residual_basis(y, config.residual_basis) if basis is None else basis
    k = len(basis)
    c = (y - mean) @ basis.T
    scale = np.maximum(c.std(0), 1e-9)
    # In units of scale the targets are z-scores; weighted by scale**2 the loss is the
    # residual's squared error (the basis rows are orthonormal), up to a constant factor.
    loss_weight = torch.from_numpy(k * scale**2 / (scale**2).sum()).float()
    inputs = torch.from_numpy(np.asarray(x, np.float32))
    targets = torch.from_numpy((c / scale).astype(np.float32))
    if config.residual_loss == "distance":  # coefficients (in units of scale) -> metres
        n_verts = y.shape[1] // 3
        to_metres = torch.from_numpy((scale[:, None] * basis).astype(np.float32))
        to_metres = to_metres.view(k, n_verts, 3)
        offsets = torch.from_numpy(((y - mean) - c @ basis).astype(np.float32))  # outside it
        offsets = offsets.view(len(y), n_verts, 3)
        n_sampled = min(n_verts, DISTANCE_VERTICES)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(config.seed)
        gen = torch.Generator().manual_seed(config.seed)
        layers, width = [], inputs.shape[1]
        for w in config.residual_widths:
            layers += [torch.nn.Linear(width, w), torch.nn.ReLU()]
            layers.append(torch.nn.Dropout(config.residual_dropout))
            width = w
        net = torch.nn.Sequential(*layers, torch.nn.Linear(width, k))
        opt = torch.optim.AdamW(
            net.parameters(), lr=config.learning_rate, weight_decay=config.residual_weight_decay
        )
        steps = max(1, config.residual_steps)
        sched = torch.optim.lr_scheduler.OneCycleLR(
            opt, config.learning_rate, total_steps=steps, pct_start=0.1
        )
        batch = min(RESIDUAL_BATCH, len(inputs))
        for _ in range(config.residual_steps):
            i = torch.randint(0, len(inputs), (batch,), generator=gen)
            xb = inputs[i]
            if config.residual_input_noise > 0:  # the features, not the bias column
                noise = torch.randn(xb.shape, generator=gen) * config.residual_input_noise
                noise[:, -1] = 0.0
                xb = xb + noise
            opt.zero_grad()
            if config.residual_loss == "distance":  # over a random subset of the vertices
                # The mean distance's gradient by hand: each vertex's unit error, back through
                # the basis (autograd through the gathers and the norm took longer).
                out = net(xb)
                v = torch.randperm(n_verts, generator=gen)[:n_sampled]
                to_v = to_metres[:, v].reshape(k, -1)
                with torch.no_grad():
                    d = ((out - targets[i]) @ to_v).view(len(out), n_sampled, 3)
                    d -= offsets[i[:, None], v]
                    unit = d / torch.linalg.vector_norm(d, dim=-1, keepdim=True).clamp_min(1e-12)
                    grad = unit.view(len(out), -1) @ to_v.T / (len(out) * n_sampled)
                out.backward(grad)
            else:
                loss = (((net(xb) - targets[i]) ** 2) * loss_weight).mean()
                loss.backward()
            opt.step()
            sched.step()
    linear = [m for m in net if isinstance(m, torch.nn.Linear)]
    folded = [
        np.concatenate([m.weight.detach().numpy().T, m.bias.detach().numpy()[None]], 0)
        for m in linear
    ]
    folded = [f.astype(np.float64) for f in folded]
    # the inputs' last column is already the 1: the first layer's bias goes onto its row
    first = folded[0][:-1]
    first[-1] += folded[0][-1]
    coef = np.zeros((len(folded[-1]), k + 1))
    coef[:, :k] = folded[-1] * scale
    coef[-1, k] = 1.0  # the mean residual, on the bias row
    return [first, *folded[1:-1]], coef, np.concatenate([basis, mean[None]])


def stack_members(
    members: list[tuple[list[np.ndarray], np.ndarray]],
) -> tuple[list[np.ndarray], np.ndarray]:
    """Residual networks of one shape as one network giving their mean: the first hidden layers
    side by side, the later ones block diagonal, the last layers stacked and divided by their
    number (bias rows averaged).

    Parameters
    ----------
    members : (hidden, coef) of :func:`fit_residual_network`, each the same shapes

    Returns
    -------
    hidden : list of (n H_in + 1, n H) arrays (the first (F + 1, n H0)), coef : (n H + 1, C)
    """
    if len(members) == 1:
        return members[0]
    n = len(members)
    hidden = [np.concatenate([h[0] for h, _ in members], axis=1)]
    for layer in range(1, len(members[0][0])):
        blocks = [h[layer] for h, _ in members]
        rows, cols = blocks[0].shape[0] - 1, blocks[0].shape[1]
        w = np.zeros((n * rows + 1, n * cols))
        for i, b in enumerate(blocks):
            w[i * rows : (i + 1) * rows, i * cols : (i + 1) * cols] = b[:-1]
            w[-1, i * cols : (i + 1) * cols] = b[-1]
        hidden.append(w)
    coefs = [c for _, c in members]
    coef = np.concatenate([c[:-1] / n for c in coefs] + [np.mean([c[-1:] for c in coefs], 0)])
    return hidden, coef


def body_model_from_state(
    config: Joint2CoarseConfig, descriptor_dim: int, state: dict, path=None
) -> BodyResidualModel:
    """Rebuild a saved :class:`BodyResidualModel` (its ``state_dict``)."""
    names = ("weights", "rest_joints", "rest_vertices", "feat_mean", "feat_std", "coef")
    missing = [n for n in names if n not in state]
    if missing:
        raise InputError(f"Joint2Coarse model file lacks {missing}", path)
    mirror = ("mirror_corners", "mirror_barycentric")
    optional = [n for n in mirror if n in state]
    basis = ["basis"] if "basis" in state else []
    arrays = {n: state[n].numpy() for n in (*names, *hidden_names(state), *optional, *basis)}
    if optional and (
        len(optional) != 2
        or any(arrays[n].shape != (len(arrays["weights"]), 3) for n in optional)
        or not (
            (arrays["mirror_corners"] >= 0) & (arrays["mirror_corners"] < len(arrays["weights"]))
        ).all()
    ):
        raise InputError("Joint2Coarse model file's mirror map does not fit its proxy", path)
    n_features = feature_count(config, descriptor_dim)
    if len(arrays["feat_mean"]) != n_features:
        raise InputError(
            f"Joint2Coarse model file was made for {len(arrays['feat_mean'])} motion features, "
            f"this version computes {n_features}: retrain it (dng train joint2coarse)",
            path,
        )
    width = n_features + 1
    for name in (*hidden_names(arrays), "coef"):
        if arrays[name].ndim != 2 or arrays[name].shape[0] != width:
            raise InputError(
                f"Joint2Coarse model file's {name} is {arrays[name].shape}, its rows must be "
                f"{width}",
                path,
            )
        width = arrays[name].shape[1] + 1
    out = (width - 1, 3 * len(arrays["weights"]))  # what coef gives, what the proxy needs
    if basis and (arrays["basis"].ndim != 2 or arrays["basis"].shape[0] != out[0]):
        raise InputError(
            f"Joint2Coarse model file's basis is {arrays['basis'].shape}, its rows must be "
            f"{out[0]} (coef's columns)",
            path,
        )
    columns = arrays["basis"].shape[1] if basis else out[0]
    if columns != out[1]:
        raise InputError(
            f"Joint2Coarse model file's residual has {columns} columns, its proxy's "
            f"{len(arrays['weights'])} vertices need {out[1]}",
            path,
        )
    return BodyResidualModel(config, descriptor_dim, arrays)
