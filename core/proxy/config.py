"""Configuration, tolerances and the records the proxy stage passes on.

All numeric tolerances of the proxy stage are named here, in one place.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import numpy as np

from core.errors import InputError
from core.mesh import Mesh

#: Fewest vertices a proxy may be asked for: below this no garment shape survives.
MIN_TARGET_VERTS = 8
#: The decimated vertex count may miss the request by this fraction before we retry.
VERTEX_COUNT_TOLERANCE = 0.05
#: A triangle whose smallest angle is below this many degrees counts as a sliver.
SLIVER_ANGLE_DEG = 3.0
#: A UV triangle with signed area below this (in [0,1]^2 units) counts as flipped.
UV_FLIP_AREA = 0.0
#: Ratio of UV area to 3D area below which a triangle is treated as degenerate in stretch stats.
STRETCH_EPS = 1e-12
#: Extra radius (fraction of the garment's radial extent) where envelope rays start.
ENVELOPE_RAY_MARGIN = 0.1
#: Largest fraction of the garment's area that may hide behind the radial envelope (farther
#: than ``ProxyConfig.envelope_tolerance``) for ``layers="auto"`` to use the envelope.
ENVELOPE_HIDDEN_FRACTION = 0.05
#: Least fraction of the area of the parts around the axis that must have more cloth outside it
#: (:func:`core.proxy.envelope.covered_fraction`) for ``layers="auto"`` to build the envelope:
#: below this there are no stacked layers to collapse. Measured with
#: ``dng garment make NAME`` and 20000 sampled faces: single-layer tank top, T-shirt torso
#: without its sleeves, dresses and skirts 0-0.2 %; tango skirt (waistband) 1.6 %, dress (sash)
#: 3 %; T-shirt 8 %; double, multilayer and pleated skirts 26-56 %. A sewn-on pocket or a
#: narrow band stays under it.
ENVELOPE_MIN_COVERED_FRACTION = 0.05
#: Azimuth sectors, and the fraction of them a part must touch, to count as going around the
#: body axis (skirt layers, bodices, waistbands) rather than hanging beside it (straps, bows).
ENCLOSE_BINS = 36
ENCLOSE_COVERAGE = 0.75
#: A face "faces the axis" when its unit normal dotted with the outward radial direction is
#: below minus this.
INWARD_COS = 0.25
#: An envelope triangle is a "curtain" (bridging a sideways radial jump, e.g. from a sleeve to
#: the torso below it) when its normal dotted with the azimuth direction exceeds this ...
CURTAIN_COS = 0.7
#: ... and ``layers="auto"`` rejects the envelope when curtains exceed this fraction of its
#: area (built-in skirts and dress: at most 2 %; a one-piece T-shirt: 9 %).
ENVELOPE_CURTAIN_FRACTION = 0.05
#: Target vertices and faces (each) sampled, with a fixed seed, to judge the envelope.
ENVELOPE_CHECK_SAMPLES = 20000
#: Bounding-box diagonals (in the file's units) that decide the unit when ``unit="auto"``.
AUTO_UNIT_CM_ABOVE = 8.0
AUTO_UNIT_MM_ABOVE = 400.0
#: Smallest garment (bounding-box diagonal in metres) the stage accepts.
MIN_DIAGONAL_M = 1e-3
#: Unit names and their size in metres.
UNITS_M = {"m": 1.0, "cm": 0.01, "mm": 0.001}
#: Layer handling choices (see :attr:`ProxyConfig.layers`).
LAYER_MODES = ("auto", "envelope", "keep")


@dataclass(frozen=True)
class ProxyConfig:
    """Parameters of coarse proxy derivation (``dng proxy`` flags mirror these fields)."""

    target_verts: int = 2000
    """Vertex count the proxy should have (met within 10%). 2000 is what Joint2Coarse predicts
    comfortably (6000 outputs) while keeping 2-3 cm edges on a full-length skirt."""
    detail_scale: float = 0.02
    """Metres. Folds and wrinkles narrower than this are smoothed away (implicit Laplacian flow,
    libigl cotangent weights, diffusion time ``detail_scale**2 / 2``). 0 disables smoothing."""
    min_component_fraction: float = 0.005
    """A connected part that does not go around the body axis and whose area is below this
    fraction of the largest part's area is dropped (laces, bows, strings, buttons: 0.1-0.4 % on
    the built-in dress; its straps, 0.8 %, stay). Parts around the axis (layers, waistbands,
    sashes) are never dropped: they carry the waist. 0 keeps every part."""
    layers: str = "auto"
    """How stacked layers and ruffles are collapsed. ``envelope``: the parts that go around the
    vertical (Y) body axis become one open surface, their outer radial envelope (rays from
    outside); parts beside the axis (straps, separate sleeves) are carried over as they are.
    Suits skirts and dresses. ``keep``: the cleaned surface itself (trousers, one-piece
    T-shirts, single-layer garments). ``auto``: the envelope only when there are layers to
    collapse (more than ``ENVELOPE_MIN_COVERED_FRACTION`` of the area has cloth outside it) and
    the tests under ``envelope_tolerance`` and ``envelope_max_error`` accept it; a single-layer
    garment (a dress with armholes, a top, a skirt with a slit) is always kept."""
    envelope_tolerance: float = 0.03
    """Distance to the envelope, relative to the bounding-box diagonal, beyond which a part of
    the garment counts as hidden. ``auto`` rejects the envelope when more than
    ``ENVELOPE_HIDDEN_FRACTION`` of the area is hidden *and faces the axis* (the inside of a
    sleeve or trouser leg; stacked layers face outward), or when more than
    ``ENVELOPE_CURTAIN_FRACTION`` of the envelope bridges sideways jumps larger than this."""
    envelope_max_error: float = 0.15
    """Largest distance from any target vertex to the envelope, relative to the diagonal, that
    ``auto`` accepts (the inner tiers of the built-in multilayer skirt sit up to 9 % inside).
    Beyond it the layers are kept as they are unless ``layers="envelope"`` forces the envelope."""
    envelope_resolution: int = 0
    """Vertices of the envelope grid before decimation; 0 picks ``max(4 * target_verts, 8000)``."""
    texture_size: int = 512
    """Pixels per side of the square texture the UV atlas is packed for (the neural texture's
    finest level is 512 texels)."""
    padding: int = 4
    """Texels between charts, so bilinear lookups at the coarsest (64 px) level bleed little."""
    unit: str = "auto"
    """Unit of the input coordinates: ``m``, ``cm``, ``mm`` or ``auto`` (decided from the
    bounding-box diagonal: above 400 is millimetres, above 8 centimetres). The proxy is in metres."""
    hausdorff_samples: int = 20000
    """Surface points sampled on each mesh (besides its vertices) for the Hausdorff distance."""
    seed: int = 0
    """Seed of the surface sampling; the same seed gives the same report."""

    def __post_init__(self) -> None:
        def bad(name: str, why: str) -> InputError:
            return InputError(f"proxy config: {name}={getattr(self, name)!r} {why}")

        for name in ("target_verts", "envelope_resolution", "texture_size", "padding"):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or isinstance(v, bool):
                raise bad(name, "must be an integer")
        if self.target_verts < MIN_TARGET_VERTS:
            raise bad("target_verts", f"must be at least {MIN_TARGET_VERTS}")
        if self.envelope_resolution < 0:
            raise bad("envelope_resolution", "must be >= 0")
        if not 16 <= self.texture_size <= 16384:
            raise bad("texture_size", "must be in [16, 16384]")
        if not 0 <= self.padding < self.texture_size // 4:
            raise bad("padding", "must be in [0, texture_size/4)")
        for name in (
            "detail_scale",
            "min_component_fraction",
            "envelope_tolerance",
            "envelope_max_error",
        ):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise bad(name, "must be a finite number >= 0")
        if self.min_component_fraction >= 1:
            raise bad("min_component_fraction", "must be < 1")
        if self.layers not in LAYER_MODES:
            raise bad("layers", f"must be one of {', '.join(LAYER_MODES)}")
        if self.unit != "auto" and self.unit not in UNITS_M:
            raise bad("unit", f"must be auto or one of {', '.join(UNITS_M)}")
        if self.hausdorff_samples < 0:
            raise bad("hausdorff_samples", "must be >= 0")

    def as_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True)
class Correspondence:
    """Closest points from the target's vertices onto the proxy.

    Attributes
    ----------
    face : (Vt,) int64
        Proxy face holding the closest point of each target vertex.
    barycentric : (Vt, 3) float32
        Barycentric coordinates of that point in the face (rows sum to 1).
    distance : (Vt,) float32
        Distance in metres from the target vertex to the proxy.
    """

    face: np.ndarray
    barycentric: np.ndarray
    distance: np.ndarray

    def points(self, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
        """Positions on the proxy, ``(Vt, 3)`` float32, for proxy ``vertices`` (Vp, 3), ``faces``
        (Fp, 3): works for any pose of the proxy (for example a simulated or predicted frame)."""
        tri = np.asarray(vertices, np.float64)[faces[self.face]]
        return np.einsum("ni,nij->nj", self.barycentric, tri).astype(np.float32)

    def uvs(self, uvs: np.ndarray, faces: np.ndarray) -> np.ndarray:
        """Each target vertex's location in the proxy's atlas, ``(Vt, 2)`` float32 in [0, 1]:
        where to splat target colours into a texture on the proxy."""
        tri = np.asarray(uvs, np.float64)[faces[self.face]]
        return np.einsum("ni,nij->nj", self.barycentric, tri).astype(np.float32)


@dataclass(frozen=True)
class ProxyResult:
    """What :func:`core.proxy.derive_proxy` returns.

    Attributes
    ----------
    proxy : Mesh
        The proxy in metres, with per-vertex UVs (seams are split vertices).
    positions : Mesh
        The same surface without seam splits (no UVs): one vertex per surface point, what
        Joint2Coarse predicts. ``proxy.vertices == positions.vertices[seam_map]``.
    seam_map : (Vp,) int64
        For each proxy (UV) vertex, its vertex in ``positions``.
    correspondence : Correspondence
        Target vertex -> closest point on the proxy, for the target's vertices in their input
        order (after :func:`core.mesh.validate_mesh` repairs when the input needed them, which
        ``report["target"]["repaired"]`` says; meshes from ``load_mesh`` never do).
    report : dict
        JSON-ready report: counts, topology, distances, UV statistics, timings.
    target_scale : float
        Metres per input unit that was applied to the target.
    """

    proxy: Mesh
    positions: Mesh
    seam_map: np.ndarray
    correspondence: Correspondence
    report: dict = field(default_factory=dict)
    target_scale: float = 1.0
