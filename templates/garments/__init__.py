"""Built-in garments: detailed targets and coarse template types, fitted to the mannequin.

Detailed targets (what the neural renderer learns to draw):

* ``multilayer-skirt``: three tiers from the waist, gathered with folds, each with a frill
  with a scalloped (lace-like) edge; parts ``layer-1..3``, ``frill-1..3``, ``waistband``.
* ``double-skirt``: a long straight layer under a short, full, folded one; ``layer-1..2``,
  ``waistband``.
* ``tango-skirt``: fitted over the hips, asymmetric hem, a slit at the front left and a
  folded flounce; ``layer-1``, ``waistband``.
* ``pleated-skirt``: short, low on the hips, knife pleats all around; ``pleats``, ``waistband``.
* ``dress``: bodice and flared skirt in one piece with shoulder straps, a sash and a bow;
  ``dress``, ``straps`` (2 pieces), ``sash``, ``bow`` (loops, knot and tails: 5 pieces).

Single-layer garments, each one connected piece of cloth with the openings of a real one (what
a pattern-making tool exports once its seams are welded; see :mod:`.tops`):

* ``tank-top``: scoop neckline, 5 cm straps, armholes (4 boundary loops).
* ``t-shirt``: neckline and short sleeves sewn into the armholes (4 loops: hem, neck, cuffs).
* ``sleeveless-dress``: a dress with armholes, its bodice and flared, folded skirt in one piece.
* ``slip-dress``: 1 cm spaghetti straps, low back.
* ``slit-skirt``: a single layer with a front slit and no waistband (2 loops).

Coarse templates (stand-in proxies, one clean open surface each, a few thousand vertices):
``long-skirt`` (full at the hem, so a twirl flares it), ``short-skirt``, ``simple-dress``.

Every part is an open 2-manifold with its normals pointing away from the body (the
folded-under layers of pleats face it, as folded cloth does). Resolution is the target edge
length in millimetres, like a simulator's particle distance.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from core.body.shape import BodyShape
from core.errors import InputError
from core.mesh import Mesh

from .dress import DressConfig, build_dress
from .fit import BodyFit, body_fit, body_mesh
from .skirts import PleatConfig, SkirtConfig, build_layered_skirt, build_pleated_skirt
from .surface import Garment, Part, assemble
from .tops import TopConfig, build_top

__all__ = [
    "DEFAULT_TARGET",
    "GARMENTS",
    "DressConfig",
    "Garment",
    "GarmentSpec",
    "PleatConfig",
    "SkirtConfig",
    "TopConfig",
    "body_fit",
    "body_mesh",
    "build_garment",
    "make_garment",
]


@dataclass(frozen=True)
class GarmentSpec:
    """A built-in garment: a generator family, its config preset and resolution limits."""

    name: str
    """Registry name."""
    kind: str
    """``"detailed"`` (a target) or ``"coarse"`` (a template proxy)."""
    description: str
    """One line for ``dng garment list``."""
    config: Any
    """The family's config dataclass (:class:`SkirtConfig`, :class:`PleatConfig`,
    :class:`DressConfig`, :class:`TopConfig`)."""
    build: Callable[[Any, float, BodyFit, int], list[Part]]
    """``build(config, resolution_m, fit, seed) -> parts``."""
    resolution_mm: float
    """Default target edge length (mm)."""
    resolution_range_mm: tuple[float, float]
    """Finest and coarsest accepted edge length (mm)."""

    def __call__(
        self, resolution_mm: float | None = None, shape: BodyShape | None = None, seed: int = 0
    ) -> Garment:
        return build_garment(self.name, resolution_mm, shape, seed)


#: Accepted edge lengths (mm) of the coarse templates.
_COARSE_RANGE = (20.0, 60.0)

GARMENTS: dict[str, GarmentSpec] = {
    spec.name: spec
    for spec in (
        GarmentSpec(
            "multilayer-skirt",
            "detailed",
            "three gathered tiers with lace-edged frills at the hems",
            SkirtConfig(
                top=0.63,
                hems=(0.29, 0.375, 0.46),
                flares=(0.09, 0.03, 0.03),
                folds=(40, 34, 28),
                fold_depths=(0.018, 0.022, 0.026),
                frill_depth=0.065,
                frill_folds=120,
                frill_fold_depth=0.012,
                scallops=90,
                waistband=0.035,
            ),
            build_layered_skirt,
            10.0,
            (8.0, 25.0),
        ),
        GarmentSpec(
            "double-skirt",
            "detailed",
            "a long straight layer under a short full folded one",
            SkirtConfig(
                top=0.63,
                hems=(0.22, 0.40),
                flares=(0.05, 0.16),
                folds=(24, 22),
                fold_depths=(0.01, 0.04),
                waistband=0.04,
            ),
            build_layered_skirt,
            9.0,
            (6.5, 22.0),
        ),
        GarmentSpec(
            "tango-skirt",
            "detailed",
            "fitted, asymmetric hem, front slit and a folded flounce",
            SkirtConfig(
                top=0.60,
                hems=(0.20,),
                flares=(0.025,),
                folds=(0,),
                fold_depths=(0.0,),
                ease=0.002,
                hem_tilt=0.14,
                hem_high_angle=0.7,
                slit_top=0.36,
                slit_angle=0.45,
                slit_opening=0.05,
                flounce_depth=0.11,
                flounce_flare=0.13,
                flounce_folds=34,
                flounce_fold_depth=0.045,
                waistband=0.03,
            ),
            build_layered_skirt,
            11.0,
            (8.0, 22.0),
        ),
        GarmentSpec(
            "pleated-skirt",
            "detailed",
            "short, low on the hips, knife pleats all around",
            PleatConfig(),
            build_pleated_skirt,
            6.0,
            (4.0, 14.0),
        ),
        GarmentSpec(
            "dress",
            "detailed",
            "fitted bodice, flared skirt, shoulder straps, sash and bow",
            DressConfig(),
            build_dress,
            9.0,
            (6.5, 22.0),
        ),
        GarmentSpec(
            "tank-top",
            "detailed",
            "single layer: scoop neckline, 5 cm straps, armholes",
            TopConfig(),
            build_top,
            5.0,
            (3.0, 10.0),
        ),
        GarmentSpec(
            "t-shirt",
            "detailed",
            "single layer: neckline, short sleeves sewn into the armholes",
            TopConfig(
                hem=0.56,
                strap_x=0.32,
                strap_width=0.095,
                neckline_front=0.06,
                neckline_back=0.02,
                armhole=0.73,
                sleeve=0.2,
            ),
            build_top,
            6.0,
            (4.0, 13.0),
        ),
        GarmentSpec(
            "sleeveless-dress",
            "detailed",
            "single layer: dress with armholes, flared folded skirt",
            TopConfig(
                hem=0.28,
                flare=0.14,
                folds=14,
                fold_depth=0.035,
                strap_width=0.06,
                neckline_front=0.07,
            ),
            build_top,
            9.0,
            (5.5, 18.0),
        ),
        GarmentSpec(
            "slip-dress",
            "detailed",
            "single layer: 1 cm spaghetti straps, low back",
            TopConfig(
                hem=0.35,
                flare=0.1,
                folds=10,
                fold_depth=0.02,
                strap_width=0.01,
                strap_x=0.27,
                neckline_front=0.04,
                neckline_back=0.1,
            ),
            build_top,
            7.0,
            (4.5, 15.0),
        ),
        GarmentSpec(
            "slit-skirt",
            "detailed",
            "single layer: front slit, no waistband",
            SkirtConfig(
                top=0.60,
                hems=(0.30,),
                flares=(0.07,),
                folds=(14,),
                fold_depths=(0.02,),
                slit_top=0.44,
                slit_angle=0.35,
                slit_opening=0.06,
            ),
            build_layered_skirt,
            7.0,
            (4.0, 13.0),
        ),
        GarmentSpec(
            "long-skirt",
            "coarse",
            "A-line skirt to the ankles, full at the hem (12 soft folds it flares into)",
            # Fullness to flare: a plain A-line frustum is developable, its hem circle as long as
            # the cloth there, so a twirl cannot widen it without stretching the fabric (its hem
            # radius stayed 1.00x standing on a converged 1 rev/s spin). With these folds the
            # hem's cloth is 1.46x its hanging circle, and on the 90-frame twirl (dng simulate
            # --garment long-skirt --motion twirl --frames 90) the hem's mean radius over the
            # second half is 1.33x frame 0's.
            SkirtConfig(top=0.63, hems=(0.10,), flares=(0.15,), folds=(12,), fold_depths=(0.10,)),
            build_layered_skirt,
            30.0,
            _COARSE_RANGE,
        ),
        GarmentSpec(
            "short-skirt",
            "coarse",
            "plain A-line skirt to mid-thigh",
            SkirtConfig(top=0.60, hems=(0.42,), flares=(0.06,)),
            build_layered_skirt,
            25.0,
            _COARSE_RANGE,
        ),
        GarmentSpec(
            "simple-dress",
            "coarse",
            "strapless dress in one plain surface",
            DressConfig(folds=0, fold_depth=0.0, straps=0.0, sash=0.0, bow=0.0, flare=0.12),
            build_dress,
            30.0,
            _COARSE_RANGE,
        ),
    )
}

#: The target ``dng demo`` uses.
DEFAULT_TARGET = "multilayer-skirt"


def build_garment(
    name: str,
    resolution_mm: float | None = None,
    shape: BodyShape | None = None,
    seed: int = 0,
) -> Garment:
    """Build the built-in garment ``name`` fitted to ``shape`` at rest.

    Parameters
    ----------
    name : a key of :data:`GARMENTS`
    resolution_mm : target edge length in millimetres (default: the garment's own)
    shape : the body to fit (default ``BodyShape()``)
    seed : seeds the irregularity of folds (same seed, same mesh)

    Raises ``InputError`` for an unknown name or a resolution outside the garment's range.
    """
    spec = GARMENTS.get(name)
    if spec is None:
        raise InputError(f"unknown garment {name!r}; built-in garments: {', '.join(GARMENTS)}")
    res = spec.resolution_mm if resolution_mm is None else resolution_mm
    lo, hi = spec.resolution_range_mm
    if isinstance(res, bool) or not isinstance(res, (int, float)) or not math.isfinite(res):
        raise InputError(f"resolution {res!r} is not a number of millimetres")
    if not lo <= res <= hi:
        raise InputError(f"resolution {res:g} mm for {name!r} is outside [{lo:g}, {hi:g}] mm")
    if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
        raise InputError(f"seed must be a non-negative integer, got {seed!r}")
    shape = BodyShape() if shape is None else shape
    if not isinstance(shape, BodyShape):
        raise InputError(f"shape must be a BodyShape, got {type(shape).__name__}")
    parts = spec.build(spec.config, res / 1000.0, body_fit(shape), seed)
    return assemble(name, parts, res)


def make_garment(
    name: str,
    resolution_mm: float | None = None,
    shape: BodyShape | None = None,
    seed: int = 0,
) -> Mesh:
    """The mesh of :func:`build_garment` (all parts in one mesh)."""
    return build_garment(name, resolution_mm, shape, seed).mesh
