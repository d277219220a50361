"""The proxy stage: target garment -> clean, light, unwrapped coarse proxy, with its report.

Steps (each timed in the report): ``units`` (to metres), ``clean`` (drop small parts, orient),
``layers`` (radial envelope or keep; or fit a template), ``smooth`` (folds under the detail
scale), ``decimate`` (to the vertex budget, then tangential relaxation against slivers), ``atlas`` (xatlas), ``measure`` (distances,
correspondence, statistics).
"""

from __future__ import annotations

import math
import time

import numpy as np

from core.constants import DEGENERATE_AREA_M2, MERGE_TOLERANCE_M
from core.errors import InputError
from core.mesh import Mesh, validate_mesh
from core.proxy.atlas import uv_atlas, uv_stats
from core.proxy.config import (
    AUTO_UNIT_CM_ABOVE,
    AUTO_UNIT_MM_ABOVE,
    ENVELOPE_CHECK_SAMPLES,
    ENVELOPE_CURTAIN_FRACTION,
    ENVELOPE_HIDDEN_FRACTION,
    ENVELOPE_MIN_COVERED_FRACTION,
    MIN_DIAGONAL_M,
    UNITS_M,
    ProxyConfig,
    ProxyResult,
)
from core.proxy.envelope import (
    cast_radial,
    covered_fraction,
    encloses_axis,
    envelope_error,
    garment_axis,
    radial_envelope,
)
from core.proxy.metrics import correspond, hausdorff, point_to_mesh
from core.proxy.simplify import decimate, relax, smooth_details
from core.proxy.topology import (
    compact,
    edge_counts,
    face_areas,
    face_components,
    mesh_stats,
    orient_consistently,
)

#: The keep path decimates to this many times the target before smoothing (cheaper solve).
PREDECIMATE_FACTOR = 4
#: ... but never below this many vertices, so the smoothing still sees the folds it removes.
PREDECIMATE_MIN = 8000


def input_scale(vertices: np.ndarray, unit: str, path=None) -> tuple[float, str]:
    """Metres per input unit and the unit name; ``auto`` decides from the bounding-box diagonal."""
    if unit != "auto":
        return UNITS_M[unit], unit
    v = np.asarray(vertices, np.float64)
    diag = float(np.linalg.norm(v.max(0) - v.min(0)))
    if diag > AUTO_UNIT_MM_ABOVE:
        return UNITS_M["mm"], "mm"
    if diag > AUTO_UNIT_CM_ABOVE:
        return UNITS_M["cm"], "cm"
    return 1.0, "m"


def needs_repair(vertices: np.ndarray, faces: np.ndarray) -> bool:
    """Cheap test for what :func:`core.mesh.validate_mesh` would repair: non-finite or
    coincident vertices (on its merge grid), degenerate faces, unreferenced vertices."""
    v = np.asarray(vertices, np.float64)
    if not np.isfinite(v).all() or len(faces) == 0:
        return True
    if faces.min() < 0 or faces.max() >= len(v):
        return True
    if (face_areas(v, faces) <= DEGENERATE_AREA_M2).any():
        return True
    if len(np.unique(faces)) != len(v):
        return True
    q = np.round(v / MERGE_TOLERANCE_M).astype(np.int64)
    q = q[np.lexsort(q.T)]
    return bool((np.diff(q, axis=0) == 0).all(axis=1).any())


def derive_proxy(
    target: Mesh,
    config: ProxyConfig | None = None,
    *,
    path=None,
    template: Mesh | None = None,
) -> ProxyResult:
    """Derive the coarse proxy of a detailed target garment.

    Parameters
    ----------
    target : Mesh
        The detailed garment (any unit, see ``config.unit``), for example from
        :func:`core.mesh.load_mesh`.
    config : ProxyConfig
    path : the file the target came from, for messages and the report
    template : Mesh or None
        A coarse template (metres) to fit to the target instead of deriving a proxy; its
        connectivity is kept as is (``target_verts`` does not apply).

    Returns
    -------
    ProxyResult
        The proxy in metres with UVs, its seam-free positions, the target -> proxy
        correspondence and a JSON-ready report.

    Raises
    ------
    InputError
        A target too small to be a garment, or nothing left after cleaning.
    """
    cfg = config or ProxyConfig()
    timings: dict[str, float] = {}
    notes: list[str] = []
    clock = time.perf_counter()

    def lap(step: str) -> None:
        nonlocal clock
        now = time.perf_counter()
        timings[step] = round(now - clock, 4)
        clock = now

    # units (and the repairs of core.mesh.validate_mesh: duplicate vertices, degenerate faces)
    scale, unit = input_scale(target.vertices, cfg.unit, path)
    tv = np.asarray(target.vertices, np.float64) * scale
    tf = np.asarray(target.faces, np.int64)
    repaired_input = needs_repair(tv, tf)
    if repaired_input:
        notes.append("target repaired (core.mesh.validate_mesh) before derivation")
        repaired, _ = validate_mesh(tv, tf, path=path)
        tv = np.asarray(repaired.vertices, np.float64)
        tf = np.asarray(repaired.faces, np.int64)
    diag = float(np.linalg.norm(tv.max(0) - tv.min(0)))
    if not math.isfinite(diag) or diag < MIN_DIAGONAL_M:
        raise InputError(
            f"garment is {diag:.3g} m across (unit {unit}); smaller than {MIN_DIAGONAL_M} m: "
            "wrong unit? pass --unit",
            path,
        )
    if unit != "m":
        notes.append(f"input read as {unit} (x{scale:g} to metres)")
    lap("units")

    # clean
    cv, cf, dropped, around = clean_parts(tv, tf, cfg.min_component_fraction)
    if dropped:
        notes.append(
            f"dropped {dropped} small parts beside the body axis "
            f"(< {cfg.min_component_fraction:g} of the largest part's area)"
        )
    lap("clean")

    # layers
    layers: dict = {
        "requested": cfg.layers,
        "parts_around_axis": int(len(np.unique(around[1][around[0]]))),
    }
    budget = max(PREDECIMATE_FACTOR * cfg.target_verts, PREDECIMATE_MIN)
    if template is not None:
        body = cf[around[0]] if around[0].any() else cf  # fit to the parts around the axis
        pv = fit_template(template.vertices, template.faces, cv, body)
        pf = np.asarray(template.faces, np.int64)
        layers["used"] = "template"
    else:
        pv = pf = None
        inside = around[0]
        covered = 0.0
        if cfg.layers in ("auto", "envelope") and inside.any():
            sv, sf, _ = compact(cv, cf[inside])
            covered = covered_fraction(
                sv, sf, garment_axis(sv, sf), ENVELOPE_CHECK_SAMPLES, seed=cfg.seed
            )
            layers["covered_fraction"] = covered
        if cfg.layers == "auto" and inside.any() and covered < ENVELOPE_MIN_COVERED_FRACTION:
            notes.append(
                f"radial envelope not used: {covered:.1%} of the area has cloth outside it, "
                f"no layers to collapse (needs {ENVELOPE_MIN_COVERED_FRACTION:.0%}). "
                "Kept the cleaned surface"
            )
        elif cfg.layers in ("auto", "envelope") and inside.any():
            n_env = cfg.envelope_resolution or budget
            ev, ef = radial_envelope(sv, sf, n_env, min_component_fraction=0.0)
            check = envelope_error(sv, sf, ev, ef, cfg.envelope_tolerance * diag)
            err = check["max_m"]
            layers["envelope_error_m"] = err
            layers["envelope_error_rel"] = err / diag
            layers["hidden_inward_fraction"] = check["hidden_inward"]
            layers["curtain_fraction"] = check["curtain"]
            problems = []
            if check["hidden_inward"] > ENVELOPE_HIDDEN_FRACTION:
                problems.append(
                    f"{check['hidden_inward']:.0%} of the area hides behind it facing the axis "
                    f"(limit {ENVELOPE_HIDDEN_FRACTION:.0%})"
                )
            if check["curtain"] > ENVELOPE_CURTAIN_FRACTION:
                problems.append(
                    f"{check['curtain']:.0%} of it bridges sideways gaps "
                    f"(limit {ENVELOPE_CURTAIN_FRACTION:.0%})"
                )
            if err > cfg.envelope_max_error * diag:
                problems.append(
                    f"a part lies {err / diag:.1%} of the diagonal inside it "
                    f"(limit {cfg.envelope_max_error:.1%})"
                )
            if len(ef) == 0:
                problems.append("no ray hit the garment")
            fits = not problems
            if len(ef) and (cfg.layers == "envelope" or fits):
                rest_v, rest_f, _ = compact(cv, cf[~inside])
                if len(rest_f) and len(rest_v) > budget // 2:
                    rest_v, rest_f = decimate(rest_v, rest_f, budget // 2, uniform=True)
                pv = np.concatenate([ev, rest_v]) if len(rest_f) else ev
                pf = np.concatenate([ef, rest_f + len(ev)]) if len(rest_f) else ef
                layers["used"] = "envelope"
                layers["parts_beside_axis"] = (
                    int(len(np.unique(face_components(len(rest_v), rest_f)))) if len(rest_f) else 0
                )
            elif cfg.layers == "envelope":
                raise InputError("the radial envelope is empty: no ray hit the garment", path)
            else:
                notes.append(
                    "radial envelope rejected (not skirt-like): "
                    + "; ".join(problems)
                    + ". Kept the cleaned surface"
                )
        elif cfg.layers == "envelope":
            raise InputError(
                "no part goes around the vertical axis: cannot build an envelope", path
            )
        if pv is None:
            pv, pf = cv, cf
            layers["used"] = "keep"
            if len(pv) > 1.5 * budget:
                pv, pf = decimate(pv, pf, budget, uniform=True)
    lap("layers")

    # smooth
    if template is None:
        pv = smooth_details(pv, pf, cfg.detail_scale)
    lap("smooth")

    # decimate
    if template is None:
        dv, df = decimate(pv, pf, cfg.target_verts)
        pv, pf = relax(dv, df, pv, pf), df
    else:
        pv, pf, _ = compact(np.asarray(pv, np.float64), np.asarray(pf, np.int64))
    if not np.isfinite(pv).all() or len(pf) == 0:
        raise InputError("proxy derivation produced no valid surface", path)
    lap("decimate")

    # atlas
    atlas = uv_atlas(pv, pf, cfg.texture_size, cfg.padding)
    lap("atlas")

    # measure
    positions = Mesh(pv.astype(np.float32), pf.astype(np.int64))
    proxy = Mesh(positions.vertices[atlas.seam_map], atlas.faces.astype(np.int64), atlas.uvs)
    dist = hausdorff(tv, tf, pv, pf, samples=cfg.hausdorff_samples, seed=cfg.seed)
    kept, _, _ = point_to_mesh(cv, pv, pf)
    corr = correspond(tv, positions.vertices, positions.faces)
    uv = uv_stats(proxy.vertices, proxy.faces, proxy.uvs, atlas.chart)
    uv.update(
        utilization=atlas.utilization,
        texture_size=cfg.texture_size,
        padding=cfg.padding,
        uv_vertices=int(len(atlas.seam_map)),
    )
    target_stats = mesh_stats(tv, tf)
    proxy_stats = mesh_stats(pv, pf)
    lap("measure")
    if proxy_stats["vertices"] < 0.9 * cfg.target_verts and template is None:
        notes.append(
            f"proxy has {proxy_stats['vertices']} vertices, fewer than 90% of the "
            f"{cfg.target_verts} requested"
        )
    report = {
        "target": {"path": None if path is None else str(path), "unit": unit, "scale_to_m": scale}
        | target_stats
        | {"dropped_components": dropped, "bbox_diagonal_m": diag, "repaired": repaired_input},
        "config": cfg.as_dict(),
        "layers": layers,
        "proxy": proxy_stats,
        "distance": {
            "hausdorff_m": dist["hausdorff"],
            "hausdorff_rel": dist["hausdorff"] / diag,
            "target_to_proxy_m": dist["a_to_b"],
            "proxy_to_target_m": dist["b_to_a"],
            "target_to_proxy_mean_m": dist["a_to_b_mean"],
            "proxy_to_target_mean_m": dist["b_to_a_mean"],
            "kept_target_to_proxy_m": float(kept.max()),
            "kept_target_to_proxy_rel": float(kept.max()) / diag,
            "samples_per_side": cfg.hausdorff_samples,
        },
        "uv": uv,
        "timings_s": timings,
        "total_s": round(sum(timings.values()), 4),
        "notes": notes,
    }
    return ProxyResult(
        proxy=proxy,
        positions=positions,
        seam_map=atlas.seam_map,
        correspondence=corr,
        report=report,
        target_scale=scale,
    )


def clean_parts(
    vertices: np.ndarray, faces: np.ndarray, min_fraction: float
) -> tuple[np.ndarray, np.ndarray, int, tuple[np.ndarray, np.ndarray]]:
    """Drop small parts beside the body axis and orient every part outward.

    Parts that go around the axis are never dropped; only the open ones among them are marked
    ``around`` (envelope material): a closed part has no waist or hem to keep.

    Parameters
    ----------
    vertices : (V, 3) float, faces : (F, 3) int64, min_fraction : float

    Returns
    -------
    vertices : (V', 3) float64, faces : (F', 3) int64, dropped : int,
    around : ((F',) bool, (F',) int64)
        Whether each kept face belongs to a part around the axis, and its part label.
    """
    labels = face_components(len(vertices), faces)
    area = np.bincount(labels, weights=face_areas(vertices, faces))
    present = np.unique(labels)
    encl = encloses_axis(vertices, faces, labels, garment_axis(vertices, faces))
    # Only open parts (with a waist or hem) join the envelope; closed ones are kept as they are.
    edges, counts = edge_counts(faces)
    has_boundary = np.zeros(len(area), bool)
    vert_label = np.zeros(len(vertices), np.int64)
    vert_label[faces.ravel()] = np.repeat(labels, 3)
    has_boundary[vert_label[edges[counts == 1, 0]]] = True
    keep = encl | (area >= min_fraction * area[present].max())
    encl &= has_boundary
    dropped = int(len(present) - keep[present].sum())
    sel = keep[labels]
    v, f, _ = compact(np.asarray(vertices, np.float64), faces[sel])
    f = orient_consistently(v, f)
    return v, f, dropped, (encl[labels[sel]], labels[sel])


def fit_template(
    template_vertices: np.ndarray,
    template_faces: np.ndarray,
    target_vertices: np.ndarray,
    target_faces: np.ndarray,
) -> np.ndarray:
    """Fit a coarse template onto a target garment, keeping the template's connectivity.

    The template's height range is mapped linearly onto the target's; each template vertex is
    then moved to the target's outer surface along the horizontal ray through its (height,
    angle) about the vertical axis (the radial envelope again), or to the closest target point
    where that ray misses (slits, a shorter hem). Suits skirt and dress templates.

    Parameters
    ----------
    template_vertices : (Vt, 3) float, template_faces : (Ft, 3) int, metres
    target_vertices : (V, 3) float, target_faces : (F, 3) int, metres

    Returns
    -------
    (Vt, 3) float64 fitted template vertices
    """
    p = np.asarray(template_vertices, np.float64)
    tf = np.asarray(template_faces, np.int64)
    v = np.asarray(target_vertices, np.float64)
    f = np.asarray(target_faces, np.int64)
    ta, ga = garment_axis(p, tf), garment_axis(v, f)
    tlo, thi = p[:, 1].min(), p[:, 1].max()
    glo, ghi = v[:, 1].min(), v[:, 1].max()
    frac = (p[:, 1] - tlo) / max(thi - tlo, 1e-12)
    # Stay half a percent inside the range so the top and bottom rays graze the garment.
    heights = glo + (ghi - glo) * (0.005 + 0.99 * frac)
    angles = np.arctan2(p[:, 2] - ta[1], p[:, 0] - ta[0])
    out, hit = cast_radial(v, f, heights, angles, ga)
    if (~hit).any():
        guess = np.stack([ga[0] + (p[:, 0] - ta[0]), heights, ga[1] + (p[:, 2] - ta[1])], axis=1)[
            ~hit
        ]
        _, _, closest = point_to_mesh(guess, v, f)
        out[~hit] = closest
    return out
