"""A hard, differentiable image loss over Embree ray casting (the nvdiffrast recipe).

For views ``n = 1..N`` with target images ``T_n (H, W, 3)`` and optional per-pixel weights
``m_n`` (masks), the loss of a mesh with vertex colours ``C`` is::

    L = 1/(N H W) sum_n sum_pixels m(p) mean_{x in p} |I_n(x) - T_n(p)|^2,

``I_n(x)`` the *hard* image at the ray through ``x``: Phong shading (PyTorch3D's
``phong_shading`` with ``TexturesVertex``: interpolated positions, vertex normals and colours,
lights, materials and cameras as PyTorch3D) of the first face hit, or the background colour.
``x`` runs over the ``s x s`` sub-pixel centres of pixel ``p`` (``supersample = s``; ``s = 1``:
the pixel centre). It is split as nvdiffrast splits a renderer:

1. **rasterize**: one Embree cast of every (sub-)pixel ray of every view
   (:class:`geofit.raycast.EmbreeScene`, float64-refined hits) gives the face and the
   perspective-correct barycentrics ``b``;
2. **interpolate and shade**: :mod:`geofit.render.soft.shading`'s Phong kernel (the one the soft
   renderer uses) on those fragments; its vjp gives the gradient to the vertex positions (through
   the interpolated point, the vertex normals and ``b``) and, exactly, to the colours;
3. **barycentrics**: ``b`` depends on the vertices because the hit point slides along its fixed
   ray: with ``e1 = v1 - v0``, ``e2 = v2 - v0`` and the ray direction ``d``,
   ``[e1 e2 -d] (db1, db2, dt) = -sum_j b_j dv_j``, so ``u = [e1 e2 -d]^-T (g1 - g0, g2 - g0,
   0)`` and ``dL/dv_j -= b_j u`` (closed form, by cross products);
4. **edges** (in place of nvdiffrast's antialiasing pass): which face a ray hits is piecewise
   constant, so steps 1-3 miss the change of ``L`` when an outline or a self-occlusion edge
   moves. That change is a boundary integral over the contour edges of the projection
   (Reynolds transport; Li et al. 2018's edge sampling, as
   :class:`geofit.render.soft.ContourSilhouetteLoss` for silhouettes)::

       dL = S^2 / (4 N H W) sum_n contour-integral m (f_in - f_out) (dx . n_out) dl_ndc,

   ``f = |I - T|^2`` on the near side (the faces of the edge) and on the far side (background
   or the surface behind), ``S = min(H, W)``. Contour edges (folds of the projection, boundary
   edges) are sampled (``samples_per_pixel`` per pixel), a ray ``edge_offset_px`` pixels to
   each side and one through the sample tell whether the edge is visible (nothing nearer than
   the edge point on its ray, the far side's ray misses or meets something deeper) and what both sides show, and the 2-D gradient on
   the edge's ends is carried to 3-D by :meth:`geofit.cameras.CamerasBase.projection_jacobian`.

The interior gradient (1-3) is the exact gradient of the value; the edge gradient (4) is that of
the continuous loss the value approximates (``s -> infinity``): supersampling makes the value
converge to it. The per-sub-pixel squared error (not the squared error of the averaged pixel)
keeps every ray's gradient local, so forward and backward run chunk by chunk. Which face a ray
meets, which edges are contours and which are visible are piecewise constant choices: no
gradient flows through them other than the edge term's.

References
----------
S. Laine et al., "Modular Primitives for High-Performance Differentiable Rendering", SIGGRAPH
Asia 2020 (nvdiffrast). T.-M. Li et al., "Differentiable Monte Carlo Ray Tracing through Edge
Sampling", SIGGRAPH Asia 2018.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..._threads import get_num_threads, parallel_map
from ..._validate import as_array, check_positive
from ...cameras import CamerasBase, ndc_grid
from ...raycast.embree import EmbreeScene
from ...structures import Mesh, as_mesh
from ..soft.contour import contour_edges, edge_samples
from ..soft.shading import (
    _chunks, _phong_chunk, _phong_chunk_vjp, _scatter, _vertex_normals_vjp, shading_state,
)
from . import _raycast

__all__ = ["HardImageLoss", "ImageLossValue", "PixelRayHits", "ShadedHits",
           "affine_color_operator"]

_RAY_CHUNK = 65_536  # rays per Embree call on a worker thread


class ImageLossValue(NamedTuple):
    """Value and gradients of :class:`HardImageLoss` (unpacks as ``value, gv, gc``).

    Attributes
    ----------
    value : float
        The loss (see the module notes).
    grad_verts : (V, 3) float64
        Interior (shading and barycentric) plus edge gradient.
    grad_colors : (V, 3) float64
        Exact gradient to the vertex colours.
    """

    value: float
    grad_verts: np.ndarray
    grad_colors: np.ndarray


class _Hits(NamedTuple):
    face: np.ndarray   # (r,) int64, -1 on a miss
    bary: np.ndarray   # (k, 3) float64 of the hits only
    depth: np.ndarray  # (k,) view depth of the hits
    dirs: np.ndarray   # (k, 3) world ray directions of the hits (view z = 1)


class PixelRayHits(NamedTuple):
    """One cast of every (sub-)pixel ray of :class:`HardImageLoss` against one mesh.

    Built by :meth:`HardImageLoss.pixel_hits` and accepted by its ``__call__``,
    :meth:`~HardImageLoss.shaded_hits` and :meth:`~HardImageLoss.color_operator` (``hits=``),
    so that an evaluation that needs both the colour operator and the loss casts once.
    Only the rays whose sub-pixel may lie inside a projected face are cast
    (``_raycast.coverage_mask``); the others miss by construction.

    Attributes
    ----------
    mesh : Mesh
        The mesh cast against (the hits are valid for it only).
    scene : EmbreeScene
        Its Embree scene (reused by the edge term's casts).
    ray : (k,) int64
        The rays that hit, sorted: flat index into ``(N, H s, W s)``.
    face : (k,) int64
    bary : (k, 3) float64
        Perspective-correct barycentrics, refined in float64 along the ray.
    depth : (k,) float64
        View depth of the hit.
    dirs : (k, 3) float64
        World ray directions (view z = 1).
    n_cast : int
        Rays cast (of ``N H W s^2``).
    """

    mesh: Mesh
    scene: EmbreeScene
    ray: np.ndarray
    face: np.ndarray
    bary: np.ndarray
    depth: np.ndarray
    dirs: np.ndarray
    n_cast: int


class ShadedHits(NamedTuple):
    """The covered rays of :meth:`HardImageLoss.shaded_hits`.

    Attributes
    ----------
    ray : (k,) int64
        Ray index (``(view, sub-pixel row, sub-pixel column)`` flattened).
    pixel : (k,) int64
        Flat index into ``(N, H, W)`` of the ray's pixel.
    face : (k,) int64
        The face hit.
    bary : (k, 3) float64
        Perspective-correct barycentrics of the hit.
    shade : (k, 3) float64
        ``Ma La + Md Ld max(0, n.l)``: the factor of the surface colour.
    specular : (k, 3) float64
        The specular term added to it.
    n_rays : int
        ``R = N H W s^2``.
    """

    ray: np.ndarray
    pixel: np.ndarray
    face: np.ndarray
    bary: np.ndarray
    shade: np.ndarray
    specular: np.ndarray
    n_rays: int


def affine_color_operator(loss: HardImageLoss, h: ShadedHits, hit_of: np.ndarray,
                          cols: np.ndarray, weights: np.ndarray, n_cols: int):
    """``(A, y)`` of :meth:`HardImageLoss.color_operator` for any linear colour lookup.

    The surface colour at hit ``i`` of ``h`` is ``sum_{j: hit_of[j] = i} weights[j]
    x[cols[j]]`` (barycentric weights of vertex colours, bilinear weights of texels, ...);
    ``A[c]`` has the entries ``(ray of hit_of[j], cols[j]) = weights[j] shade[hit_of[j], c]``
    scaled by the ray's ``sqrt(m) / s``, and ``y`` the scaled targets minus the specular part
    (minus the background where nothing is hit), so that the loss is
    ``1/(N H W) sum_c |A[c] x[:, c] - y[:, c]|^2``. ``hit_of`` must be non-decreasing (the
    matrices are built row by row, no sort).
    """
    import scipy.sparse as sp

    R = h.n_rays
    m = np.sqrt(loss.masks.ravel()[h.pixel]) / loss.supersample  # (k,) of the hits
    # rows in order: the csr structure directly (h.ray is sorted, hit_of non-decreasing)
    indptr = np.zeros(R + 1, np.int64)
    np.cumsum(np.bincount(h.ray[hit_of], minlength=R), out=indptr[1:])
    mats = []
    for c in range(3):  # colour channels
        data = weights * (h.shade[:, c] * m)[hit_of]
        mats.append(sp.csr_matrix((data, cols, indptr), shape=(R, n_cols)))
    y = loss._miss_residual().copy()
    y[h.ray] = (loss.targets.reshape(-1, 3)[h.pixel] - h.specular) * m[:, None]
    return mats, y


def _cross(a, b):
    return np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                     a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], axis=1)


class HardImageLoss:
    """Squared error of hard Phong renders against target images, with its analytic gradient.

    Parameters
    ----------
    cameras : CamerasBase
        ``N`` cameras (PyTorch3D's conventions).
    target_images : (N, H, W, 3) float64
        RGB targets (a fourth channel is ignored).
    lights : PointLights, DirectionalLights or AmbientLights, optional
        Default ``PointLights()`` (PyTorch3D's, location (0, 1, 0)).
    materials : Materials, optional
        Default ``Materials()``.
    masks : (N, H, W) float64, optional
        Per-pixel weights ``m`` (e.g. 0 to ignore a pixel); default 1.
    background : (3,) float64
        Colour of rays that hit nothing (default white, PyTorch3D's ``BlendParams``).
    supersample : int
        ``s``: rays per pixel ``s x s`` (default 1).
    samples_per_pixel : float
        Edge samples per pixel of projected contour length (default 2).
    edge_offset_px : float
        How far (pixels) to each side of an edge sample the rays look (default 0.05).
    edges : bool
        Include the edge gradient (default True).
    depth_tolerance : float
        An edge sample is visible when the ray through it meets nothing nearer than the edge
        point's depth minus this fraction of the mesh's bounding-box diagonal, and the far-side
        ray misses or meets a surface deeper by more than that (default 1e-3).
    n_threads : int, optional
        Threads for the casts and the shading (default geofit's).

    Examples
    --------
    >>> import numpy as np
    >>> from geofit import FoVPerspectiveCameras, ico_sphere, look_at_view_transform
    >>> R, T = look_at_view_transform(2.7, 0.0, 0.0)
    >>> loss = HardImageLoss(FoVPerspectiveCameras(R=R, T=T), np.zeros((1, 16, 16, 3)))
    >>> value, gv, gc = loss(ico_sphere(2), np.full((162, 3), 0.5))
    >>> gv.shape, gc.shape, bool(value > 0)
    ((162, 3), (162, 3), True)
    """

    def __init__(self, cameras: CamerasBase, target_images, *, lights=None, materials=None,
                 masks=None, background=(1.0, 1.0, 1.0), supersample: int = 1,
                 samples_per_pixel: float = 2.0, edge_offset_px: float = 0.05,
                 edges: bool = True, depth_tolerance: float = 1e-3,
                 n_threads: int | None = None):
        from ..lighting import PointLights
        from ..materials import Materials

        if not isinstance(cameras, CamerasBase):
            raise TypeError(f"cameras: expected a geofit camera batch, got {type(cameras)!r}")
        self.cameras = cameras
        N = len(cameras)
        t = as_array(target_images, "target_images", (N, None, None, None))
        if t.shape[-1] not in (3, 4):
            raise ValueError(f"target_images: expected 3 or 4 channels, got shape {t.shape}")
        self.targets = np.ascontiguousarray(t[..., :3])
        H, W = self.targets.shape[1:3]
        if H < 2 or W < 2:
            raise ValueError(f"target_images: expected at least 2 x 2 pixels, got {(H, W)}")
        self.image_size = (H, W)
        if masks is None:
            self.masks = np.ones((N, H, W))
        else:
            self.masks = as_array(masks, "masks", (N, H, W))
        self.background = as_array(background, "background", (3,))
        s = supersample
        if not isinstance(s, (int, np.integer)) or isinstance(s, bool) or s < 1:
            raise ValueError(f"supersample: expected an integer >= 1, got {s!r}")
        self.supersample = int(s)
        self.samples_per_pixel = check_positive(samples_per_pixel, "samples_per_pixel")
        self.edge_offset_px = check_positive(edge_offset_px, "edge_offset_px")
        self.edges = bool(edges)
        self.depth_tolerance = check_positive(depth_tolerance, "depth_tolerance")
        self.lights = lights if lights is not None else PointLights()
        self.materials = materials if materials is not None else Materials()
        self.n_threads = int(n_threads) if n_threads else get_num_threads()
        self.perspective = bool(cameras.is_perspective())
        self.tnear = (np.broadcast_to(np.asarray(cameras.znear, np.float64), (N,)) / 2.0
                      if self.perspective else np.zeros(N))
        sH, sW = H * self.supersample, W * self.supersample
        g = ndc_grid((sH, sW))
        self._xs, self._ys = g[0, :, 0].copy(), g[:, 0, 1].copy()
        self._grid = (sH, sW)
        self._rays = _raycast.view_rays(cameras)
        self._coef = np.stack([np.stack(vr) for vr in self._rays])  # (N, 6, 3) for _cast
        self._miss_y = None    # (R, 3) of _miss_residual, made when first needed
        self._miss_sum = None  # float of _miss_total

    # --------------------------------------------------------------------------------------
    # rasterize
    # --------------------------------------------------------------------------------------

    def _cast(self, scene: EmbreeScene, mesh: Mesh, view, x, y) -> _Hits:
        """First hits of the rays through NDC ``(x, y)`` of ``view`` (float64 refined).

        Chunk by chunk on the threads, ray setup, Embree's cast and the float64 refinement
        alike (every step is per ray, the clipping applied over all of them: any chunking gives
        the same hits); at least
        ``4 x threads`` chunks, so that the edge term's few thousand rays share the threads.
        """
        tn = self.tnear[view]
        c, sc = scene.center, scene.scale
        r = len(x)
        if r == 0:
            return _Hits(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)))
        step = max(min(_RAY_CHUNK, -(-r // (4 * self.n_threads))), 1024)
        bounds = np.arange(0, r + step, step).clip(max=r)
        V, F = mesh.verts, mesh.faces

        def run(k):
            sl = slice(int(bounds[k]), int(bounds[k + 1]))
            cf = self._coef[view[sl]]
            xs, ys = x[sl, None], y[sl, None]
            o = cf[:, 0] + xs * cf[:, 1] + ys * cf[:, 2]
            d = cf[:, 3] + xs * cf[:, 4] + ys * cf[:, 5]
            o32 = np.ascontiguousarray((o + tn[sl, None] * d - c) / sc, np.float32)
            d32 = np.ascontiguousarray(d / sc, np.float32)
            geom, prim, u, v, t = scene.intersect(o32, d32)
            face = np.where(geom >= 0, prim.astype(np.int64), -1)
            hit = face >= 0
            u, v = u[hit].astype(np.float64), v[hit].astype(np.float64)
            tri = F[face[hit]]
            b32 = np.stack([1.0 - u - v, u, v], axis=1)
            bary, depth = _raycast.refine(o[hit], d[hit], V[tri[:, 0]], V[tri[:, 1]],
                                          V[tri[:, 2]], b32,
                                          t[hit].astype(np.float64) + tn[sl][hit], clip=False)
            return face, bary, depth, d[hit]

        parts = parallel_map(run, range(len(bounds) - 1), self.n_threads)
        face, bary, depth, dirs = (np.concatenate([p[i] for p in parts]) for i in range(4))
        return _Hits(face, _raycast.clip_bary(bary), depth, dirs)  # clipped over all rays

    def pixel_hits(self, mesh) -> PixelRayHits:
        """Cast every (sub-)pixel ray against ``mesh`` once (see :class:`PixelRayHits`).

        Each view casts only the rays of the 8 x 8 tiles of sub-pixels that a projected face's
        bounding box (grown by a sub-pixel) touches; a view that a face reaches at the near
        plane casts all its rays. Hits are refined in float64 along their rays.
        """
        mesh = as_mesh(mesh, "mesh")
        N = len(self.cameras)
        sH, sW = self._grid
        z = np.zeros(0, np.int64)
        if mesh.n_faces == 0:
            return PixelRayHits(mesh, None, z, z, np.zeros((0, 3)), np.zeros(0),
                                np.zeros((0, 3)), 0)
        scene = EmbreeScene([(mesh.verts, mesh.faces)])
        rays = self._rays

        def covered(v):  # one view's sub-pixels that a face may cover (views on the threads)
            xy, zv = _raycast.project(mesh.verts, rays[v], self.perspective)
            mk = _raycast.coverage_mask(xy, zv, mesh.faces, sH, sW, float(self.tnear[v]))
            return v * sH * sW + np.flatnonzero(mk)

        pixels = np.concatenate(parallel_map(covered, range(N), self.n_threads))
        h = _raycast.cast_pixels(scene, pixels, rays, self._xs, self._ys, self.tnear,
                                 self.n_threads)
        V, F = mesh.verts, mesh.faces
        bary = np.empty((len(h.face), 3))
        depth = np.empty(len(h.face))
        dirs = np.empty((len(h.face), 3))

        def one(sl):  # float64 hits along the rays, chunk by chunk on the workers
            o, d, _ = _raycast.hit_rays(h.pixel[sl], rays, self._xs, self._ys)
            tri = F[h.face[sl]]
            bary[sl], depth[sl] = _raycast.refine(o, d, V[tri[:, 0]], V[tri[:, 1]],
                                                  V[tri[:, 2]], h.bary[sl], h.depth[sl])
            dirs[sl] = d

        parallel_map(one, _chunks(len(h.face)), self.n_threads)
        return PixelRayHits(mesh, scene, h.pixel, h.face, bary, depth, dirs, len(pixels))

    def _hits_for(self, mesh: Mesh, hits) -> PixelRayHits:
        """``hits`` if given (checked to belong to ``mesh``), else a new cast."""
        if hits is None:
            return self.pixel_hits(mesh)
        if not isinstance(hits, PixelRayHits):
            raise TypeError(f"hits: expected the PixelRayHits of pixel_hits(mesh), got "
                            f"{type(hits)!r}")
        if hits.mesh.verts is not mesh.verts and not (
                hits.mesh.verts.shape == mesh.verts.shape
                and np.array_equal(hits.mesh.verts, mesh.verts)
                and np.array_equal(hits.mesh.faces, mesh.faces)):
            raise ValueError("hits: cast against another mesh (pixel_hits(mesh) of this one)")
        return hits

    def _ray_pixel(self, ray: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """View and flat ``(N, H, W)`` pixel of sub-pixel rays (flat ``(N, H s, W s)``)."""
        H, W = self.image_size
        s = self.supersample
        sH, sW = self._grid
        view, rem = np.divmod(ray, sH * sW)
        row, col = np.divmod(rem, sW)
        return view, (view * H + row // s) * W + col // s

    def _miss_residual(self) -> np.ndarray:
        """(R, 3): every ray's ``(target - background) sqrt(m) / s`` (computed once)."""
        if self._miss_y is None:
            N = len(self.cameras)
            sH, sW = self._grid
            _, pix = self._ray_pixel(np.arange(N * sH * sW))
            m = np.sqrt(self.masks.ravel()[pix]) / self.supersample
            self._miss_y = (self.targets.reshape(-1, 3)[pix] - self.background) * m[:, None]
        return self._miss_y

    # --------------------------------------------------------------------------------------
    # shading (chunks of hits), forward and backward
    # --------------------------------------------------------------------------------------

    @staticmethod
    def _entries(mesh: Mesh, face, bary):
        tri = mesh.faces[face]
        i = [np.ascontiguousarray(tri[:, j]) for j in range(3)]
        b = [np.ascontiguousarray(bary[:, j]) for j in range(3)]
        return b, i

    def _shade(self, s: dict, mesh: Mesh, face, bary, view) -> np.ndarray:
        """(k, 3) Phong colours of hits (no gradient)."""
        out = np.empty((len(face), 3))

        def one(sl):
            b, i = self._entries(mesh, face[sl], bary[sl])
            out[sl] = _phong_chunk(b, i, view[sl], s)[0]

        parallel_map(one, _chunks(len(face)), self.n_threads)
        return out

    def render(self, mesh, vertex_colors) -> np.ndarray:
        """(N, H, W, 3) float64 hard Phong images (sub-pixel rays averaged, box filter)."""
        mesh = as_mesh(mesh, "mesh")
        vcol = as_array(vertex_colors, "vertex_colors", (mesh.n_verts, 3))
        N = len(self.cameras)
        H, W = self.image_size
        s = shading_state(mesh, vcol, self.lights, self.cameras, self.materials, N,
                          self.n_threads)
        hits = self.pixel_hits(mesh)
        view, pix = self._ray_pixel(hits.ray)
        col = self._shade(s, mesh, hits.face, hits.bary, view)
        n_hit = np.bincount(pix, minlength=N * H * W)  # covered rays per pixel
        img = np.empty((N * H * W, 3))
        for c in range(3):  # channels
            img[:, c] = (np.bincount(pix, col[:, c], N * H * W)
                         + (self.supersample ** 2 - n_hit) * self.background[c])
        return img.reshape(N, H, W, 3) / self.supersample ** 2

    def shaded_hits(self, mesh, hits: PixelRayHits | None = None) -> ShadedHits:
        """Every ray's hit and its Phong factors, for operators linear in the surface colour.

        A covered ray's colour is ``shade * albedo + specular`` with ``albedo`` the surface
        colour at the hit (interpolated vertex colours, or a texture lookup); the image the loss
        compares is then affine in the colours (:meth:`color_operator`,
        :func:`geofit.fit.texture.fit_texture`).

        Parameters
        ----------
        mesh : Mesh
        hits : PixelRayHits, optional
            :meth:`pixel_hits` of ``mesh``, if already cast.

        Returns
        -------
        ShadedHits
        """
        mesh = as_mesh(mesh, "mesh")
        N = len(self.cameras)
        sH, sW = self._grid
        n_rays = N * sH * sW
        if mesh.n_faces == 0:
            z = np.zeros(0, np.int64)
            return ShadedHits(z, z, z, np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)),
                              n_rays)
        hits = self._hits_for(mesh, hits)
        s = shading_state(mesh, np.ones((mesh.n_verts, 3)), self.lights, self.cameras,
                          self.materials, N, self.n_threads)
        view, pix = self._ray_pixel(hits.ray)
        shade = np.empty((len(hits.ray), 3))
        spec = np.empty((len(hits.ray), 3))

        def one(sl):
            b, i = self._entries(mesh, hits.face[sl], hits.bary[sl])
            _, shade[sl], spec[sl], _ = _phong_chunk(b, i, view[sl], s)

        parallel_map(one, _chunks(len(hits.ray)), self.n_threads)
        return ShadedHits(hits.ray, pix, hits.face, hits.bary, shade, spec, n_rays)

    def color_operator(self, mesh, hits: PixelRayHits | None = None):
        """The loss's residual as an affine map of the vertex colours (geometry fixed).

        ``L = 1/(N H W) sum_c |A[c] @ colors[:, c] - y[:, c]|^2`` exactly (up to rounding).

        Parameters
        ----------
        mesh, hits : Mesh, PixelRayHits (optional)
            As in :meth:`shaded_hits`.

        Returns
        -------
        A : list of 3 scipy.sparse.csr_matrix, each (R, V)
            One row per ray (``R = N H W s^2``), scaled by ``sqrt(m) / s``.
        y : (R, 3) float64
            The targets minus the specular part (rays that hit nothing: minus the
            background), scaled alike.
        """
        mesh = as_mesh(mesh, "mesh")
        h = self.shaded_hits(mesh, hits)
        tri = mesh.faces[h.face]
        hit_of = np.repeat(np.arange(len(h.ray)), 3)
        return affine_color_operator(self, h, hit_of, tri.ravel(), h.bary.ravel(),
                                     mesh.n_verts)

    def __call__(self, mesh, vertex_colors, hits: PixelRayHits | None = None
                 ) -> ImageLossValue:
        """The loss, its gradient to the vertex positions and to the vertex colours.

        Parameters
        ----------
        mesh : Mesh
            ``V`` vertices (a trimesh or Open3D mesh is converted).
        vertex_colors : (V, 3) float64
        hits : PixelRayHits, optional
            :meth:`pixel_hits` of ``mesh``, if already cast (one cast serves the colour
            operator and the loss).

        Returns
        -------
        ImageLossValue
        """
        mesh = as_mesh(mesh, "mesh")
        Vn = mesh.n_verts
        vcol = as_array(vertex_colors, "vertex_colors", (Vn, 3))
        N = len(self.cameras)
        H, W = self.image_size
        ss = self.supersample
        norm = 1.0 / (N * H * W * ss * ss)
        s = shading_state(mesh, vcol, self.lights, self.cameras, self.materials, N,
                          self.n_threads)
        hits = self._hits_for(mesh, hits)
        T = self.targets.reshape(-1, 3)
        m = self.masks.ravel()
        bg = self.background
        # every ray that misses adds m |background - T|^2: the sum over all rays (once) minus
        # that over the hits, which add their own error instead
        value = norm * self._miss_total()
        h_view, h_pix = self._ray_pixel(hits.ray)
        h_face = hits.face
        V = mesh.verts

        def one(sl):
            b, i = self._entries(mesh, h_face[sl], hits.bary[sl])
            colors, shade, _, saved = _phong_chunk(b, i, h_view[sl], s)
            p = h_pix[sl]
            r = colors - T[p]
            val = norm * float(np.sum(m[p] * (np.sum(r * r, axis=1)
                                               - np.sum((bg - T[p]) ** 2, axis=1))))
            g = (2.0 * norm) * m[p][:, None] * r
            gP, gN, gT, gb, _ = _phong_chunk_vjp(saved, g, shade, s)
            gv = _scatter(b, gP, i, Vn)
            gn = _scatter(b, gN, i, Vn)
            gc = _scatter(b, gT, i, Vn)
            # barycentrics of the hit on its fixed ray: u = [e1 e2 -d]^-T (g1 - g0, g2 - g0, 0)
            v0, v1, v2 = V[i[0]], V[i[1]], V[i[2]]
            e1, e2, nd = v1 - v0, v2 - v0, -hits.dirs[sl]
            det = np.einsum("kj,kj->k", e1, _cross(e2, nd))
            ok = np.abs(det) > 1e-300
            inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
            u = (((gb[:, 1] - gb[:, 0]) * inv)[:, None] * _cross(e2, nd)
                 + ((gb[:, 2] - gb[:, 0]) * inv)[:, None] * _cross(nd, e1))
            for j in range(3):  # corners
                for c in range(3):  # coordinates
                    gv[:, c] -= np.bincount(i[j], b[j] * u[:, c], Vn)
            return val, gv, gn, gc

        parts = parallel_map(one, _chunks(len(h_face)), self.n_threads)
        gv = np.zeros((Vn, 3))
        gn = np.zeros((Vn, 3))
        gc = np.zeros((Vn, 3))
        for val, a, b_, c in parts:  # chunks
            value += val
            gv += a
            gn += b_
            gc += c
        gv += _vertex_normals_vjp([np.ascontiguousarray(gn[:, c]) for c in range(3)], s["vn"],
                                  s["vn_saved"], Vn)
        if self.edges and hits.scene is not None:
            gv += self._edge_grad(mesh, s, hits.scene)
        return ImageLossValue(value, gv, gc)

    def _miss_total(self) -> float:
        """``sum`` over all rays of ``m |background - T|^2`` (computed once)."""
        if self._miss_sum is None:
            d = np.sum((self.background - self.targets) ** 2, axis=-1)
            self._miss_sum = float(np.sum(self.masks * d)) * self.supersample ** 2
        return self._miss_sum

    # --------------------------------------------------------------------------------------
    # edges
    # --------------------------------------------------------------------------------------

    def edge_gradient(self, mesh, vertex_colors) -> np.ndarray:
        """(V, 3) float64: the edge (visibility) part of the gradient alone."""
        mesh = as_mesh(mesh, "mesh")
        vcol = as_array(vertex_colors, "vertex_colors", (mesh.n_verts, 3))
        if mesh.n_faces == 0:
            return np.zeros((mesh.n_verts, 3))
        s = shading_state(mesh, vcol, self.lights, self.cameras, self.materials,
                          len(self.cameras), self.n_threads)
        return self._edge_grad(mesh, s, EmbreeScene([(mesh.verts, mesh.faces)]))

    def _edge_grad(self, mesh: Mesh, s: dict, scene: EmbreeScene) -> np.ndarray:
        N = len(self.cameras)
        H, W = self.image_size
        S = min(H, W)
        Vn = mesh.n_verts
        with np.errstate(invalid="ignore", divide="ignore"):
            proj = self.cameras.projection_jacobian(mesh.verts)
        proj_z = self.cameras.transform_points_view(mesh.verts)[..., 2]  # (N, V) view depth
        lo, hi = mesh.verts.min(axis=0), mesh.verts.max(axis=0)
        tol = self.depth_tolerance * float(np.linalg.norm(hi - lo))
        views, ea, eb, ts, ws, ps, ns = [], [], [], [], [], [], []

        def samples(v):  # one view's contour edges and their samples (views on the threads)
            xy = proj.xy[v]
            if not np.all(np.isfinite(xy)):
                return None  # a vertex on the camera plane: no contour for this view
            edges, nrm = contour_edges(mesh, xy)
            e, t, w, p = edge_samples(xy[edges[:, 0]], xy[edges[:, 1]], S,
                                      self.samples_per_pixel)
            return np.full(len(e), v), edges[e, 0], edges[e, 1], t, w, p, nrm[e]

        for r in parallel_map(samples, range(N), self.n_threads):  # views, in order
            if r is None:
                continue
            for lst, a in zip((views, ea, eb, ts, ws, ps, ns), r):  # the seven arrays
                lst.append(a)
        grad = np.zeros((Vn, 3))
        if not views:
            return grad
        view, a, b, t, w, p, n = (np.concatenate(z) for z in (views, ea, eb, ts, ws, ps, ns))
        col = np.rint((W - 1 - p[:, 0] * S) / 2.0).astype(np.int64)
        row = np.rint((H - 1 - p[:, 1] * S) / 2.0).astype(np.int64)
        keep = np.flatnonzero((col >= 0) & (col < W) & (row >= 0) & (row < H))
        view, a, b, t, w, p, n, col, row = (z[keep] for z in (view, a, b, t, w, p, n, col, row))
        if len(view) == 0:
            return grad
        eps = 2.0 * self.edge_offset_px / S
        k = len(view)
        q = np.concatenate([p - eps * n, p + eps * n, p])  # near side, far side, the edge
        vv = np.concatenate([view, view, view])
        hits = self._cast(scene, mesh, vv, q[:, 0], q[:, 1])
        hit = hits.face >= 0
        hit[2 * k:] = False
        colors = np.tile(self.background, (3 * k, 1))
        colors[hit] = self._shade(s, mesh, hits.face[hit], hits.bary[hit[hits.face >= 0]],
                                  vv[hit])
        depth = np.full(3 * k, np.inf)
        depth[hits.face >= 0] = hits.depth
        # the edge point's view depth (perspective: 1/z is affine along the projected edge)
        za, zb = proj_z[view, a], proj_z[view, b]
        ze = (1.0 / ((1.0 - t) / za + t / zb)) if self.perspective else (1.0 - t) * za + t * zb
        # visible: nothing in front of the edge point (a ray through it meets nothing nearer
        # than its depth), and the far side shows the background or a deeper surface
        visible = (depth[2 * k:] > ze - tol) & (depth[k:2 * k] > ze + tol)
        pix = (view * H + row) * W + col
        T = self.targets.reshape(-1, 3)[pix]
        m = self.masks.ravel()[pix]
        f_in = np.sum((colors[:k] - T) ** 2, axis=1)
        f_out = np.sum((colors[k:2 * k] - T) ** 2, axis=1)
        coef = (S * S / (4.0 * N * H * W)) * m * (f_in - f_out) * w * visible
        ga = (coef * (1.0 - t))[:, None] * n
        gb = (coef * t)[:, None] * n
        for v in np.unique(view):  # views
            sel = view == v
            gx = np.bincount(a[sel], ga[sel, 0], Vn) + np.bincount(b[sel], gb[sel, 0], Vn)
            gy = np.bincount(a[sel], ga[sel, 1], Vn) + np.bincount(b[sel], gb[sel, 1], Vn)
            J = np.where(np.isfinite(proj.jacobian[v]), proj.jacobian[v], 0.0)
            grad += gx[:, None] * J[:, 0, :] + gy[:, None] * J[:, 1, :]
        return grad
