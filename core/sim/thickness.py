"""A proxy's contact thickness: how deep the detailed garment's layers lie beneath it.

The proxy of a layered garment is the outer envelope of its layers (:mod:`core.proxy`) and is
simulated as one surface. With only the cloth's thin contact margin, that envelope can lie on
the body where the layers beneath it would hold it off, and a target embedded in it
(:mod:`core.sim.embed`) then has its inner layers inside the body: on the quick demo's
multilayer skirt (up to 89 mm of layers beneath its proxy, 44 mm on average) they sank up to
87 mm into the hips on CMU 01_01, and the contact step that pushes them out stretched them up
to 0.38 (the embedding alone, 0.13), where a layer 85 mm beneath the proxy had to
lie on the proxy's larger surface.

So the proxy's simulation keeps each vertex off the body by its contact margin plus the depth
of the layers beneath it (:func:`layer_thickness`), no more than it had at rest
(:func:`core.sim.simulate.contact_thickness` caps it: a rest drape inside its own shell would be thrown
off at the first step), and meets it at ``SimConfig.layer_friction``. The envelope then stands
off the body as the layered garment does, and the layers fit beneath it. On the quick demo's
project (``dng demo``; the target's rows of its report, and ``dng simulate --garment
P/garment/target.obj --embed-in P/proxy/positions.obj P/sim/CLIP-proxy/cache.npz --motion
P/motions/CLIP.bvh --no-contact --out X.npz`` for the embedding alone), the target's stretch max
/ p99 fell to 0.183 / 0.067 on the dance (0.284 / 0.055 without the thickness), 0.161 / 0.065
on CMU 01_01 (0.378 / 0.080), 0.090 / 0.041 on the twirl and 0.112 / 0.053 on the validation
window of CMU 01_03, with no torn edge and nothing inside the body; before the contact step
its layers are 8.4 mm (dance) and 18.8 mm (CMU 01_01) inside at most, and the step adds no
stretch. The proxy itself stretches more: max / p99 0.100 / 0.033 on the dance and 0.155 /
0.040 on CMU 01_01 against 0.055 / 0.009 and 0.059 / 0.011, within cotton's 0.2 (0.235 at most
over the project's 28 clips, where the thin proxy reached 0.822 on a Boxing_Toes window).

It overstates the layers where air lies between them: pressed, real layers close those gaps,
and these cannot (the embedding keeps every layer's offset from the envelope).

So, in the implicit solver (the ground truth's), the layers are soft: the margin meets the body
at ``SimConfig.contact_ke`` and the depth beyond it pushes back at ``SimConfig.layer_ke`` (10
N/m a vertex: the skirt's own weight presses them a fraction of a millimetre, a ring of cloth
pulled tight over the hips presses them flat). As a rigid shell they made the hips and thighs
fatter by up to 89 mm for the lower skirt: after a high kick the quick proxy rested on the hips
(the body's contact carried 1.66 of the skirt's 2.02 N) with its hem 20 cm up. Soft, it falls
back to 3 cm (docs/decisions.md, "layer_ke").
"""

from __future__ import annotations

import numpy as np

from core.errors import InputError
from core.mesh import vertex_normals
from core.proxy.metrics import correspond


def layer_thickness(
    proxy_vertices: np.ndarray, proxy_faces: np.ndarray, target_vertices: np.ndarray, path=None
) -> np.ndarray:
    """Depth of the target's layers beneath each proxy vertex: (Vp,) float64 metres, >= 0.

    Each target vertex's depth is its distance beneath its closest proxy point, along the
    proxy's (interpolated) outward normal there (0 above the surface); each proxy vertex takes
    the largest depth among the target vertices whose closest face it is a corner of.

    proxy_vertices : (Vp, 3) float; proxy_faces : (Fp, 3) int; target_vertices : (Vt, 3) float,
    both at rest. ``path`` is named in errors.
    """
    p = np.asarray(proxy_vertices, np.float64)
    t = np.asarray(target_vertices, np.float64)
    faces = np.asarray(proxy_faces, np.int64)
    if p.ndim != 2 or p.shape[1:] != (3,) or not len(faces) or not np.isfinite(p).all():
        raise InputError(f"proxy must be finite (Vp, 3) with faces, got {p.shape}", path)
    if t.ndim != 2 or t.shape[1:] != (3,) or not len(t) or not np.isfinite(t).all():
        raise InputError(f"target vertices must be finite (Vt, 3), got {t.shape}", path)
    closest = correspond(t, p, faces)
    corners = faces[closest.face]  # (Vt, 3)
    w = closest.barycentric.astype(np.float64)
    point = np.einsum("nk,nkj->nj", w, p[corners])
    normal = np.einsum("nk,nkj->nj", w, vertex_normals(p, faces)[corners])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    depth = np.maximum(-np.einsum("ni,ni->n", t - point, normal), 0.0)
    thickness = np.zeros(len(p))
    for k in range(3):
        np.maximum.at(thickness, corners[:, k], depth)
    return thickness
