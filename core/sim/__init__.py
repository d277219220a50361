"""Ground-truth cloth simulation on the moving mannequin, and simulation caches in and out.

``simulate`` (newton VBD on warp; imported lazily) turns a garment and a motion into a
:class:`SimCache`; :mod:`core.sim.cache` reads and writes caches (ours, OBJ sequences, PC2,
MDD). Importing this package does not import newton or warp.
"""

from core.sim.cache import SimCache, export_cache, import_cache, load_cache, save_cache
from core.sim.config import FABRICS, Fabric, SimConfig

__all__ = [
    "FABRICS",
    "Fabric",
    "SimCache",
    "SimConfig",
    "export_cache",
    "import_cache",
    "load_cache",
    "save_cache",
]
