"""Drive a detailed garment by its simulated proxy: the target is embedded in the proxy's motion.

Each target vertex is bound to a point of the proxy surface, ``c = W @ proxy``, and keeps its
offset ``x - c`` from it, carried by the proxy's local deformation ``G`` (rotation, stretch and
shear, fitted per proxy vertex to its edges and normal)::

    x(t) = (W @ p(t)) + G(t) @ (x(0) - W @ p(0)),     G(t) = W @ S @ F(t)

``W`` (Vt, Vp) starts as the barycentric coordinates of each target vertex's closest proxy point,
then is smoothed along the *target's* own edges (a diffusion over ``smoothing_m``), so every
connected patch of the target is bound consistently: neighbouring target vertices share their
proxy points and nearly their weights. ``S`` smooths the proxy's deformation field ``F`` over the
proxy's edges (``frame_smoothing_m``), so offsets several centimetres off the proxy turn with the
cloth around them rather than with one crumpled proxy vertex.

Exact at rest and under rigid motion of the proxy.

Why not the simpler bindings (measured on the quick demo's multilayer skirt, 39k vertices, in a
1033-vertex proxy simulated at 2 substeps per frame; stretch = ``len / rest - 1``):

- each target vertex blending the rigid frames of its 16 nearest proxy vertices (Gaussian
  weights): stretch max 5.23 / p99 1.21 on a 90-frame twirl, 4.65 / 0.79 on the dance. The
  16 neighbours span about 85 mm of a proxy whose folds are sharper than that; their
  predictions of a vertex disagree by centimetres and the weights change across 10 mm target
  edges, so edges tear (26 % of the edges within 5 mm of the proxy stretched past 0.3);
- the closest proxy triangle alone: worse (p99 6.1 on the twirl). 3.3 % of the target's edges
  have closest points more than 3 edge lengths apart at rest (tiers and frills up to 95 mm off
  the proxy, 20 % of the vertices more than 40 mm), so neighbours are bound across gaps.

Measured with the project's commands (multilayer skirt, 39k vertices; its 989-vertex proxy
from ``dng proxy target.obj --out proxy.obj --target-verts 1000 --texture-size 512``, simulated
with ``dng simulate --garment proxy.obj --motion twirl --frames 90 --seed 1 --substeps 2
--iterations 16 --out twirl-proxy.npz``; then ``dng simulate --garment target.obj --embed-in
proxy.obj twirl-proxy.npz --out twirl-target.npz``): stretch max 0.352, p99 0.056 on the twirl,
0.285 and 0.044 on a 150-frame dance, no torn edges. The largest stretch sits on the layers'
gathered waistline (3 mm edges), where the proxy itself stretches up to 0.28.

Compression is not a tear: where the proxy crumples, the target follows it (its edges shorten),
it does not open holes; :func:`strain_stats` reports both.

**Contact with the body** (:class:`BodyContact`, given to :func:`drive`). The proxy is the
target's outer envelope and stays out of the body, but the layers inside it keep their rest
offsets inward from it: where the proxy presses on the hips they end up inside them (the quick
project's multilayer skirt: up to 88 mm on the dance).
The contact step moves them out in three steps, each continuous over the target so it opens no
hole:

1. along the proxy's outward normal at each vertex's binding (smoothed by the binding's
   weights), only as far as its binding point's own clearance asks: the vertex's height over
   the proxy is raised to at least ``margin - D(binding point)``, then once more by the depth
   it is still inside (``D`` the signed distance to the capsules). The layers squeeze between
   the proxy and the body instead of passing through it;
2. what is still inside goes radially out of its capsule
   (:func:`core.body.colliders.push_out_of_capsules`);
3. edges the steps stretched past ``stretch_limit`` (or past their length before it, if more)
   are shortened, ``sweeps`` times, then step 2 again, ``rounds`` times. The step moves the
   vertices near the body and their neighbours; an edge with one end beyond them moves that end
   alone (moving both, it passed the stretch on to the next edge out: 0.45 on CMU 01_01 there).
   One sweep moves an edge's slack one edge along the cloth, so a layer pushed onto a hip takes
   up the slack of its compressed neighbours only after several.

Measured on the quick demo's project P (multilayer skirt, 39k vertices; ``dng simulate --garment
P/garment/target.obj --embed-in P/proxy/positions.obj P/sim/CLIP-proxy/cache.npz --motion
P/motions/CLIP.bvh --out X.npz``, and with ``--no-contact`` for the embedding alone), with the
proxy simulated without the layers' thickness (``PipelineConfig.layer_thickness`` off; with it
the proxy stands off the body and this step has less to do, :mod:`core.sim.thickness`):
penetration max 82.9 -> 0 mm on the dance, 87.1 -> 0 on CMU 01_01, 25.3 -> 0 on the twirl;
stretch max 0.134 -> 0.284, 0.134 -> 0.378 and 0.095 -> 0.150, p99 0.055, 0.080 and 0.044;
no torn edge (one sweep a round, both ends of every edge moved: 0.362, 0.451 and 0.159). The
largest stretch is where a layer 85 mm beneath the proxy sat 80 mm deep in the back while the
proxy lay on it: pushed out, the layer lies on a surface much larger than its own, and no
shortening within the surface can undo that. Each step alone does worse: the radial push of
step 2 tears the layers where it pushes neighbours out of opposite sides of a capsule's axis;
step 1 alone leaves part of the depth (its normal is not the capsules'); without step 3 the
stretch is larger still.
"""

from __future__ import annotations

import os
import zipfile
from dataclasses import dataclass, fields

import numpy as np
import scipy.sparse as sp

from core.body.colliders import DEFAULT_MARGIN_M, capsule_distance, push_out_of_capsules
from core.errors import InputError
from core.fileio import write_npz
from core.mesh import unique_edges, vertex_normals
from core.proxy.metrics import correspond
from core.strain import shorten_edges

#: Diffusion length (metres) of the target's binding along its own edges.
SMOOTHING_M = 0.15
#: Diffusion length (metres) of the proxy's deformation field along the proxy's edges.
FRAME_SMOOTHING_M = 0.2
#: Weights below this are dropped while smoothing (rows are renormalised).
WEIGHT_FLOOR = 1e-4
#: Most smoothing iterations (a very fine mesh is smoothed less than asked).
MAX_ITERATIONS = 400
#: An edge stretched past this strain (its length more than doubled) is a tear: a hole.
TEAR_STRAIN = 1.0
#: Stretch (``len / rest - 1``) the contact step may leave on an edge it moved.
CONTACT_STRETCH_LIMIT = 0.15
#: Rounds of the contact step's stretch limiting (each followed by a push out of the body).
CONTACT_ROUNDS = 10
#: Shortening sweeps per round: one sweep moves an edge's slack one edge further along the
#: cloth, so a layer pushed onto a hip takes up the slack of its compressed neighbours only
#: after several (the module's docstring).
CONTACT_SWEEPS = 5
#: Vertices further than this (metres) outside the body are left to the embedding alone. With
#: 0.05 instead, the module docstring's command on the quick project's dance gave a stretch max
#: of 0.374 against 0.420 (p99 0.069 both, no penetration) and took 88 s against 73 s (with one
#: shortening sweep a round, before ``CONTACT_SWEEPS``; not remeasured since).
CONTACT_BAND_M = 0.02


@dataclass(frozen=True)
class Embedding:
    """Target vertices embedded in a proxy mesh.

    Attributes
    ----------
    faces : (Fp, 3) int64, the proxy's faces
    rest : (Vp, 3) float64, the proxy at rest
    edges : (Ep, 2) int64, the proxy's edges
    weight : (Vt, Vp) scipy.sparse.csr_matrix float64, rows sum to 1: each target vertex's
        point on the proxy
    offset : (Vt, 3) float64, each target vertex relative to its point at rest
    smoothing : (Vp, Vp) scipy.sparse.csr_matrix float64, smoothing of the deformation field
    target_edges : (Et, 2) int64, the target's edges (empty without its faces)
    target_lengths : (Et,) float64, their rest lengths
    anchor : (Vt,) int64, each target vertex's most weighted proxy vertex
    """

    faces: np.ndarray
    rest: np.ndarray
    edges: np.ndarray
    weight: sp.csr_matrix
    offset: np.ndarray
    smoothing: sp.csr_matrix
    target_edges: np.ndarray
    target_lengths: np.ndarray
    anchor: np.ndarray


def save_embedding(path: str | os.PathLike, embedding: Embedding) -> None:
    """Write ``embedding`` as ``.npz`` (atomically), which :func:`load_embedding` reads back to
    the bit: each sparse matrix as its CSR arrays."""
    arrays = {}
    for f in fields(Embedding):
        value = getattr(embedding, f.name)
        if sp.issparse(value):
            csr = value.tocsr()
            arrays.update({f"{f.name}.{part}": getattr(csr, part) for part in _CSR})
            arrays[f"{f.name}.shape"] = np.asarray(csr.shape, np.int64)
        else:
            arrays[f.name] = np.asarray(value)
    write_npz(path, **arrays)


def load_embedding(path: str | os.PathLike) -> Embedding:
    """Read an embedding written by :func:`save_embedding`; InputError naming the file if it is
    missing or is not one."""
    if not os.path.isfile(path):
        raise InputError("no such embedding file", path)
    try:
        with np.load(path, allow_pickle=False) as z:
            values = {}
            for f in fields(Embedding):
                if f"{f.name}.shape" in z:
                    parts = tuple(z[f"{f.name}.{part}"] for part in _CSR)
                    values[f.name] = sp.csr_matrix(parts, shape=tuple(z[f"{f.name}.shape"]))
                else:
                    values[f.name] = z[f.name]
    except (OSError, ValueError, KeyError, zipfile.BadZipFile) as exc:
        raise InputError(f"not an embedding ({exc})", path) from None
    return Embedding(**values)


_CSR = ("data", "indices", "indptr")


@dataclass(frozen=True)
class ContactSettings:
    """How the contact step keeps an embedded target out of the body (the module's docstring).

    Attributes
    ----------
    margin : metres kept outside the capsules
    stretch_limit : stretch (``len / rest - 1``) the step may leave on an edge it moved, unless
        the edge was stretched more before it
    rounds : rounds of stretch limiting, each followed by a push out of the body
    sweeps : shortening sweeps over the edges in each round
    """

    margin: float = DEFAULT_MARGIN_M
    stretch_limit: float = CONTACT_STRETCH_LIMIT
    rounds: int = CONTACT_ROUNDS
    sweeps: int = CONTACT_SWEEPS


@dataclass(frozen=True)
class BodyContact:
    """The body an embedded target is kept out of (:func:`drive`).

    Attributes
    ----------
    capsule_ends : (T, K, 2, 3) float, the body's capsules at each proxy frame
    radii : (K,) float
    settings : ContactSettings
    """

    capsule_ends: np.ndarray
    radii: np.ndarray
    settings: ContactSettings = ContactSettings()


@dataclass(frozen=True)
class StrainStats:
    """Edge strain of a mesh over a clip, ``len / rest - 1`` per edge and frame.

    Attributes
    ----------
    stretch_max, stretch_p99 : the largest and the 99th-percentile stretch (>= 0)
    compression_max, compression_p99 : the same for compression (>= 0)
    torn_edges : edges stretched past ``TEAR_STRAIN`` in any frame (holes)
    """

    stretch_max: float
    stretch_p99: float
    compression_max: float
    compression_p99: float
    torn_edges: int

    def as_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def strain_stats(positions: np.ndarray, rest: np.ndarray, faces: np.ndarray) -> StrainStats:
    """Stretch, compression and tears of ``positions`` (T, V, 3) against ``rest`` (V, 3) on the
    edges of ``faces`` (F, 3)."""
    edges = unique_edges(faces)
    r = np.asarray(rest, np.float64)
    length0 = np.maximum(np.linalg.norm(r[edges[:, 1]] - r[edges[:, 0]], axis=1), 1e-12)
    p = np.asarray(positions, np.float64)
    strain = np.linalg.norm(p[:, edges[:, 1]] - p[:, edges[:, 0]], axis=-1) / length0 - 1.0
    stretch, compression = np.maximum(strain, 0.0), np.maximum(-strain, 0.0)
    return StrainStats(
        stretch_max=float(stretch.max()),
        stretch_p99=float(np.percentile(stretch, 99)),
        compression_max=float(compression.max()),
        compression_p99=float(np.percentile(compression, 99)),
        torn_edges=int((stretch.max(axis=0) > TEAR_STRAIN).sum()),
    )


def vertex_deformations(
    rest: np.ndarray, current: np.ndarray, faces: np.ndarray, edges: np.ndarray
) -> np.ndarray:
    """Each vertex's local deformation gradient: (V, 3, 3) float64.

    The linear map ``F`` that best carries the vertex's rest edges onto its current edges, and
    its rest normal onto its current normal (weighted like a mean edge, so ``F`` is full rank):
    ``F = B @ inv(A)``, ``A = sum e0 e0^T + s^2 n0 n0^T``, ``B = sum e e0^T + s^2 n n0^T``.
    The identity at rest, the rotation under a rigid motion.

    rest, current : (V, 3) float; faces : (F, 3) int; edges : (E, 2) int
    """
    r, c = np.asarray(rest, np.float64), np.asarray(current, np.float64)
    v = len(r)
    e0 = r[edges[:, 1]] - r[edges[:, 0]]
    e1 = c[edges[:, 1]] - c[edges[:, 0]]
    ends = np.concatenate([edges[:, 0], edges[:, 1]])
    count = np.maximum(np.bincount(ends, minlength=v), 1)
    scale = np.bincount(ends, np.tile(np.linalg.norm(e0, axis=1), 2), v) / count
    outer0 = np.tile(np.einsum("ei,ej->eij", e0, e0).reshape(-1, 9), (2, 1))
    outer1 = np.tile(np.einsum("ei,ej->eij", e1, e0).reshape(-1, 9), (2, 1))
    a = np.stack([np.bincount(ends, outer0[:, k], v) for k in range(9)], 1).reshape(v, 3, 3)
    b = np.stack([np.bincount(ends, outer1[:, k], v) for k in range(9)], 1).reshape(v, 3, 3)
    n0, n1 = vertex_normals(r, faces), vertex_normals(c, faces)
    s2 = (scale**2)[:, None, None]
    a += s2 * np.einsum("vi,vj->vij", n0, n0) + 1e-12 * np.eye(3)
    b += s2 * np.einsum("vi,vj->vij", n1, n0)
    return b @ np.linalg.inv(a)


def _diffusion(num_vertices: int, edges: np.ndarray) -> sp.csr_matrix:
    """One step of averaging over each vertex and its edge neighbours: (V, V) row-stochastic."""
    i = np.concatenate([edges[:, 0], edges[:, 1], np.arange(num_vertices)])
    j = np.concatenate([edges[:, 1], edges[:, 0], np.arange(num_vertices)])
    m = sp.csr_matrix((np.ones(len(i)), (i, j)), shape=(num_vertices, num_vertices))
    return sp.diags(1.0 / np.asarray(m.sum(axis=1)).ravel()) @ m


def _iterations(length_m: float, vertices: np.ndarray, edges: np.ndarray) -> int:
    """Diffusion steps that spread over ``length_m`` on edges this long (a random walk)."""
    if not len(edges) or length_m <= 0:
        return 0
    edge = float(np.median(np.linalg.norm(vertices[edges[:, 1]] - vertices[edges[:, 0]], axis=1)))
    return int(min(MAX_ITERATIONS, np.ceil((length_m / max(edge, 1e-9)) ** 2)))


def _smooth(weight: sp.csr_matrix, step: sp.csr_matrix, iterations: int) -> sp.csr_matrix:
    for _ in range(iterations):
        weight = (step @ weight).tocsr()
        weight.data[weight.data < WEIGHT_FLOOR] = 0.0
        weight.eliminate_zeros()
    return (sp.diags(1.0 / np.asarray(weight.sum(axis=1)).ravel()) @ weight).tocsr()


def embed(
    target: np.ndarray,
    proxy: np.ndarray,
    faces: np.ndarray,
    path=None,
    *,
    target_faces: np.ndarray | None = None,
    smoothing_m: float = SMOOTHING_M,
    frame_smoothing_m: float = FRAME_SMOOTHING_M,
) -> Embedding:
    """Embed ``target`` (Vt, 3) vertices in the proxy ``proxy`` (Vp, 3), ``faces`` (Fp, 3).

    ``target_faces`` (Ft, 3), when given, are the edges the binding is smoothed along (without
    them each vertex is bound to its closest proxy point alone).
    """
    target = np.asarray(target, np.float64)
    proxy = np.asarray(proxy, np.float64)
    faces = np.asarray(faces, np.int64)
    if target.ndim != 2 or target.shape[1] != 3 or not len(target) or not np.isfinite(target).all():
        raise InputError(f"target vertices must be finite (Vt, 3), got {target.shape}", path)
    if proxy.ndim != 2 or proxy.shape[1] != 3 or not np.isfinite(proxy).all() or not len(faces):
        raise InputError(f"proxy must be finite (Vp, 3) with faces, got {proxy.shape}", path)
    nt, npx = len(target), len(proxy)
    closest = correspond(target, proxy, faces)
    weight = sp.csr_matrix(
        (
            closest.barycentric.astype(np.float64).ravel(),
            (np.repeat(np.arange(nt), 3), faces[closest.face].ravel()),
        ),
        shape=(nt, npx),
    )
    tedges = (
        unique_edges(target_faces)
        if target_faces is not None and len(target_faces)
        else np.zeros((0, 2), np.int64)
    )
    tlengths = np.linalg.norm(target[tedges[:, 1]] - target[tedges[:, 0]], axis=1)
    if len(tedges):
        n = _iterations(smoothing_m, target, tedges)
        weight = _smooth(weight, _diffusion(nt, tedges), n)
    pedges = unique_edges(faces)
    step = _diffusion(npx, pedges)
    smoothing = sp.identity(npx, format="csr")
    for _ in range(_iterations(frame_smoothing_m, proxy, pedges)):
        smoothing = (step @ smoothing).tocsr()
    offset = target - weight @ proxy
    anchor = np.asarray(weight.argmax(axis=1)).ravel().astype(np.int64)
    return Embedding(faces, proxy, pedges, weight, offset, smoothing, tedges, tlengths, anchor)


def drive(
    embedding: Embedding, proxy_positions: np.ndarray, contact: BodyContact | None = None
) -> np.ndarray:
    """Target positions for every proxy frame: (T, Vt, 3) float32 from (T, Vp, 3); with
    ``contact``, kept out of the body (the module's docstring)."""
    p = np.asarray(proxy_positions, np.float64)
    e = embedding
    if p.ndim != 3 or p.shape[1:] != e.rest.shape:
        raise InputError(
            f"proxy positions must be (T, {len(e.rest)}, 3) for this proxy, got {p.shape}"
        )
    if contact is not None and np.shape(contact.capsule_ends)[:1] != (len(p),):
        raise InputError(
            f"contact capsules must be ({len(p)}, K, 2, 3) for {len(p)} proxy frames, got "
            f"{np.shape(contact.capsule_ends)}"
        )
    out = np.empty((len(p), e.weight.shape[0], 3), np.float32)
    for t, frame in enumerate(p):
        f = e.smoothing @ vertex_deformations(e.rest, frame, e.faces, e.edges).reshape(-1, 9)
        g = (e.weight @ f).reshape(-1, 3, 3)
        bound, offset = e.weight @ frame, np.einsum("nij,nj->ni", g, e.offset)
        if contact is None:
            out[t] = bound + offset
        else:
            ends = contact.capsule_ends[t]
            out[t] = keep_out_of_body(
                e, frame, bound, offset, ends, contact.radii, contact.settings
            )
    return out


def keep_out_of_body(
    e: Embedding,
    frame: np.ndarray,
    bound: np.ndarray,
    offset: np.ndarray,
    ends: np.ndarray,
    radii: np.ndarray,
    settings: ContactSettings,
) -> np.ndarray:
    """One frame of the target kept out of the body (the module's docstring).

    frame : (Vp, 3) the proxy; bound : (Vt, 3) each target vertex's binding point on it;
    offset : (Vt, 3) the vertex's offset from that point; ends : (K, 2, 3), radii : (K,) the
    body's capsules at this frame. Returns (Vt, 3) float64.
    """
    ends = np.asarray(ends, np.float64)
    margin = settings.margin
    x = bound + offset
    # The capsules' distance is 1-Lipschitz: D(x) >= D(p) - |x - p| for the vertex's anchor p on
    # the proxy, so only vertices that bound lets near the body need the full test.
    reach = capsule_distance(frame, ends, radii)[e.anchor] - np.linalg.norm(
        x - frame[e.anchor], axis=1
    )
    maybe = np.flatnonzero(reach < margin + CONTACT_BAND_M)
    near = maybe[capsule_distance(x[maybe], ends, radii) < margin + CONTACT_BAND_M]
    if not len(near):
        return x
    # Step 3 moves the vertices near the body and their neighbours, and limits every edge of
    # them; an edge's other end stays where the embedding put it (it would pass the stretch on).
    movable = np.zeros(len(x), bool)
    movable[near] = True
    movable[e.target_edges[movable[e.target_edges].any(axis=1)].ravel()] = True
    pick = movable[e.target_edges].any(axis=1)
    edges = e.target_edges[pick]
    length = np.linalg.norm(x[edges[:, 1]] - x[edges[:, 0]], axis=1)
    limit = np.maximum((1.0 + settings.stretch_limit) * e.target_lengths[pick], length)
    # 1. Along the proxy's outward normal, as far as the binding point's clearance asks.
    normal = e.weight[near] @ vertex_normals(frame, e.faces)
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    height = np.einsum("ni,ni->n", offset[near], normal)
    lift = np.maximum(height, margin - capsule_distance(bound[near], ends, radii)) - height
    clearance = capsule_distance(x[near] + lift[:, None] * normal, ends, radii)
    inside = clearance < margin
    lift[inside] += margin - clearance[inside]
    x[near] += lift[:, None] * normal
    # 2. Radially out of what it is still inside.
    deep = near[inside]
    x[deep] = push_out_of_capsules(x[deep], ends, radii, margin)
    # 3. Edges it stretched shortened back (only movable ends move), then out of the body again.
    for _ in range(settings.rounds if len(edges) else 0):
        moved = np.zeros(len(x), bool)
        for _ in range(settings.sweeps):
            hit = shorten_edges(x, edges, limit, movable)
            if not len(hit):
                break
            moved[hit] = True
        if not moved.any():
            break
        hit = np.flatnonzero(moved)
        x[hit] = push_out_of_capsules(x[hit], ends, radii, margin)
    return x
