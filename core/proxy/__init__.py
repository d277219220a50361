"""Coarse proxy derivation: detail removal, decimation, UV atlas, measured.

``derive_proxy(mesh, ProxyConfig())`` runs the whole stage; the steps are pure functions on
``(vertices, faces)`` arrays that can be used alone. Heavy libraries (libigl, open3d, xatlas,
fast-simplification) are imported inside the functions that need them.
"""

from core.proxy.atlas import Atlas, uv_atlas, uv_stats
from core.proxy.config import Correspondence, ProxyConfig, ProxyResult
from core.proxy.envelope import covered_fraction, envelope_error, radial_envelope
from core.proxy.metrics import correspond, hausdorff, transfer_to_proxy
from core.proxy.pipeline import derive_proxy, fit_template, input_scale
from core.proxy.simplify import decimate, relax, smooth_details
from core.proxy.topology import boundary_loops, drop_small_components, mesh_stats

__all__ = [
    "Atlas",
    "Correspondence",
    "ProxyConfig",
    "ProxyResult",
    "boundary_loops",
    "correspond",
    "covered_fraction",
    "decimate",
    "derive_proxy",
    "drop_small_components",
    "envelope_error",
    "fit_template",
    "hausdorff",
    "input_scale",
    "mesh_stats",
    "radial_envelope",
    "relax",
    "smooth_details",
    "transfer_to_proxy",
    "uv_atlas",
    "uv_stats",
]
