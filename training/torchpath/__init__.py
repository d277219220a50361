"""The render path on torch alone: a trained project's images on any torch device (a CUDA GPU
with no open3d, warp or newton), from a bundle file (:mod:`training.torchpath.bundle`).

- rasterizer: :func:`rasterize` (face ids, barycentrics, depth as :mod:`core.raster`),
  :class:`TorchCamera`, :class:`TorchFragments`;
- body background: :func:`render_background` (:func:`core.shading.render_background`);
- the path: :class:`TorchPlayer` (Joint2Coarse -> raster -> features -> network -> composite).

Importing this package imports torch, numpy and the numpy-only parts of ``core`` and
``training``; writing a bundle (:mod:`pipeline.torch_export`) needs the whole studio and is
not imported here.
"""

from training.torchpath.bundle import BUNDLE_FORMAT, load_bundle
from training.torchpath.player import TorchPlayer
from training.torchpath.raster import TorchCamera, TorchFragments, pair_count, rasterize
from training.torchpath.shade import render_background

__all__ = [
    "BUNDLE_FORMAT",
    "TorchCamera",
    "TorchFragments",
    "TorchPlayer",
    "load_bundle",
    "pair_count",
    "rasterize",
    "render_background",
]
