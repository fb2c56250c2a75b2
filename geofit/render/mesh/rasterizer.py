"""The hard mesh rasterizer: Embree ray casting with PyTorch3D's rasterizer API.

:class:`MeshRasterizer` turns meshes seen by cameras into :class:`Fragments`; the renderers that
pair it with a shader are in :mod:`geofit.render.mesh.renderer`.

The "rasterizer" casts one ray per pixel centre (PyTorch3D's pixel centres, NDC +X left, +Y up,
row 0 at the top) from the camera through the scene, all rays of all views together, in
chunks spread over geofit's threads (a few Embree calls per thread), and keeps the first hit:
the face PyTorch3D keeps with ``faces_per_pixel=1`` and ``blur_radius=0``. A ray hit gives the
*perspective-correct* barycentrics of the hit point exactly, and the view depth is the ray
parameter (ray directions have view-space z = 1). Hits are refined in float64.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np

from ..._memory import check_allocation
from ..._threads import parallel_map
from ..._validate import check_positive
from ...cameras import CamerasBase, ndc_grid
from ...raycast.embree import EmbreeScene
from ...structures import Mesh, Meshes, as_meshes
from .._fragments import DenseFragmentImages
from .._settings import image_hw
from . import _raycast

__all__ = ["Fragments", "MeshRasterizer", "RasterizationSettings"]


# ------------------------------------------------------------------------------------------
# Settings
# ------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RasterizationFields:
    """PyTorch3D's ``RasterizationSettings`` fields with its defaults, in its order: the one
    list that :class:`RasterizationSettings` and ``geofit.pytorch3d``'s settings extend."""

    image_size: Any = 256
    blur_radius: float = 0.0
    faces_per_pixel: int = 1
    bin_size: Any = None
    max_faces_per_bin: Any = None
    perspective_correct: bool | None = None
    clip_barycentric_coords: bool | None = None
    cull_backfaces: bool = False
    z_clip_value: float | None = None
    cull_to_frustum: bool = False


@dataclass(frozen=True)
class RasterizationSettings(RasterizationFields):
    """How to turn meshes into per-pixel fragments (PyTorch3D's ``RasterizationSettings``).

    Parameters
    ----------
    image_size : int or (H, W)
        Output size in pixels; an int means square. For ``H != W`` the shorter side spans NDC
        [-1, 1] (PyTorch3D's convention).
    blur_radius : float
        Must be 0: ray casting finds the face under each pixel centre (PyTorch3D's hard
        rasterization). Soft silhouettes live elsewhere.
    faces_per_pixel : int
        Must be 1 (the first hit).
    perspective_correct : bool or None
        None (default) means True for perspective cameras, False for orthographic ones, as in
        PyTorch3D. False converts the barycentrics to screen-space ones (``b_i`` proportional to
        ``w_i z_i``) and sets ``zbuf`` to ``sum b_i z_i``, as PyTorch3D's rasterizer does.
    z_clip_value : float or None
        View depth below which geometry is clipped away. None (default) means ``znear / 2``
        when perspective-correct (PyTorch3D's default) and 0 otherwise. Rays start at this
        depth, which clips faces exactly as PyTorch3D's face clipping does.
    cull_backfaces : bool
        Skip faces whose front side (counter-clockwise winding) points away from the camera;
        rays continue past them.
    supersample : int
        Beyond PyTorch3D: cast ``supersample**2`` rays per pixel on a regular sub-pixel grid and
        average the shaded RGBA (box filter). Fragments are returned at the supersampled size.
        Default 1 (no antialiasing, PyTorch3D's images).
    n_threads : int or None
        Threads for the ray casts (default: every CPU available).
    bin_size, max_faces_per_bin, clip_barycentric_coords, cull_to_frustum
        Accepted for compatibility with PyTorch3D and ignored: there are no bins, barycentrics
        of a ray hit always lie in the face, and off-screen faces are never hit.

    Raises
    ------
    ValueError
        For ``blur_radius != 0``, ``faces_per_pixel != 1``, a non-positive size or factor.
    """

    supersample: int = 1
    n_threads: int | None = None

    def __post_init__(self):
        object.__setattr__(self, "image_size", image_hw(self.image_size))
        if float(self.blur_radius) != 0.0:
            raise ValueError(
                f"blur_radius: ray casting renders hard fragments, expected 0.0, got "
                f"{self.blur_radius!r}")
        if self.faces_per_pixel != 1:
            raise ValueError(f"faces_per_pixel: ray casting keeps the first hit, expected 1, "
                             f"got {self.faces_per_pixel!r}")
        s = self.supersample
        if not isinstance(s, (int, np.integer)) or isinstance(s, bool) or s < 1:
            raise ValueError(f"supersample: expected an integer >= 1, got {s!r}")
        if self.z_clip_value is not None:
            check_positive(self.z_clip_value, "z_clip_value", strict=False)
        if self.perspective_correct not in (None, True, False):
            raise ValueError(f"perspective_correct: expected None, True or False, got "
                             f"{self.perspective_correct!r}")
        n = self.n_threads
        if n is not None and (not isinstance(n, (int, np.integer)) or n < 1):
            raise ValueError(f"n_threads: expected None or an integer >= 1, got {n!r}")

    @property
    def raster_size(self) -> tuple[int, int]:
        """(H, W) of the fragments: ``image_size`` times ``supersample``."""
        H, W = self.image_size
        return H * self.supersample, W * self.supersample


# ------------------------------------------------------------------------------------------
# Fragments
# ------------------------------------------------------------------------------------------


@dataclass(eq=False)
class Fragments(DenseFragmentImages):
    """Per-pixel results of ray casting a batch of ``N`` views (K = 1 face per pixel).

    The covered pixels are stored compactly (``k`` of them, sorted by flat pixel index); the
    PyTorch3D-shaped images (``pix_to_face``, ``zbuf``, ``bary_coords``, ``dists``, ``normals``)
    are built from them on first access and cached.

    Attributes
    ----------
    image_size : (H, W)
        Size of the fragment images (the supersampled size when ``supersample > 1``).
    n_views : int
        ``N``.
    pixel : (k,) int64
        Flat index ``(b * H + row) * W + col`` of every covered pixel, increasing.
    view : (k,) int64
        View ``b`` of every covered pixel.
    face : (k,) int64
        *Packed* index of the face seen at every covered pixel: view ``b`` sees mesh ``b`` of
        ``meshes`` and its face ``j`` has packed index ``meshes.mesh_to_faces_packed_first_idx()
        [b] + j`` (``b * F + j`` for ``mesh.extend(N)``, as PyTorch3D).
    bary : (k, 3) float64
        Perspective-correct barycentrics ``(w0, w1, w2)`` of the hit point in the corners
        ``(v0, v1, v2)`` of its face (PyTorch3D's order), or screen-space ones when
        ``perspective_correct=False``.
    depth : (k,) float64
        View-space depth (PyTorch3D's zbuf) of the hit point.
    meshes : Meshes
        The ``N`` meshes rendered (one per view; a single mesh seen by ``N`` cameras appears
        ``N`` times).
    cameras : CamerasBase
        The ``N`` cameras.
    supersample : int
        The antialiasing factor the fragments were cast with.
    """

    image_size: tuple
    n_views: int
    pixel: np.ndarray
    view: np.ndarray
    face: np.ndarray
    bary: np.ndarray
    depth: np.ndarray
    meshes: Meshes
    cameras: Any
    supersample: int = 1
    _ctx: dict = field(default_factory=dict, repr=False)

    # -------------------------------------------------------------- compact extras
    @property
    def n_hits(self) -> int:
        """``k``, the number of covered pixels."""
        return len(self.pixel)

    @property
    def n_rays(self) -> int:
        """Number of rays sent to Embree: pixels whose centre may see a face (the projected
        bounding boxes of the faces, in 8 x 8 tiles; the others cannot hit and are not cast),
        plus rays continued past culled back faces."""
        return int(self._ctx.get("n_rays", 0))

    @cached_property
    def _tri(self) -> np.ndarray:
        """(3, k) int64 packed vertex index of each corner of each hit face."""
        return np.ascontiguousarray(self._ctx["faces_packed"][self.face].T)

    @cached_property
    def _w32(self) -> np.ndarray:
        """(3, k) float32 barycentrics."""
        return np.ascontiguousarray(self.bary.T, dtype=np.float32)

    def _chunks(self) -> list[slice]:
        """Slices of the hits for the worker threads (a few per thread)."""
        k = self.n_hits
        n = self._ctx.get("n_threads", 1)
        m = 1 if (n == 1 or k < 40_000) else min(4 * n, k // 20_000 + 1)
        b = np.linspace(0, k, m + 1).astype(np.int64)
        return [slice(int(b[i]), int(b[i + 1])) for i in range(m)]

    def _parallel(self, fn) -> list:
        """``[fn(sl) for sl in chunks]``, run on the worker threads."""
        parts = self._chunks()
        n = self._ctx.get("n_threads", 1)
        return parallel_map(fn, parts, n)

    def _interp(self, table: np.ndarray, sl: slice, bary: np.ndarray | None = None) -> np.ndarray:
        """(C, len) barycentric interpolation of a (C, sum V) per-vertex table over hits ``sl``."""
        t = self._tri[:, sl]
        w = self._w32[:, sl] if bary is None else bary[:, sl]
        out = np.empty((table.shape[0], t.shape[1]), dtype=np.result_type(table, w))
        for c in range(table.shape[0]):  # loop over channels
            tc = table[c]
            out[c] = w[0] * tc[t[0]] + w[1] * tc[t[1]] + w[2] * tc[t[2]]
        return out

    def _table(self, name: str, dtype=np.float32) -> np.ndarray:
        """Cached (C, sum V) component-first copy of a packed per-vertex array."""
        key = (name, np.dtype(dtype).str)
        cache = self._ctx.setdefault("tables", {})
        if key not in cache:
            cache[key] = np.ascontiguousarray(self._ctx[name].T, dtype=dtype)
        return cache[key]

    def _points32(self, sl: slice) -> np.ndarray:
        """(3, len) float32 world positions of hits ``sl``."""
        return self._interp(self._table("verts_packed"), sl)

    def _normals32(self, sl: slice) -> np.ndarray:
        """(3, len) float32 unit interpolated vertex normals of hits ``sl`` (eps 1e-6)."""
        n = self._interp(self._table("verts_normals_packed"), sl)
        norm = np.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
        return n / np.maximum(norm, np.float32(1e-6))

    def _dists(self, sl: slice) -> np.ndarray:
        """(len,) float64 signed squared NDC edge distances of hits ``sl``.

        The corners are taken relative to the pixel centre in float64, then the (pixel-sized)
        differences are processed in float32.
        """
        t = self._tri[:, sl]
        X, Y = self._table("verts_xy_packed", np.float64)
        qx, qy = self._xy(sl)
        f32 = np.float32
        ax = [(X[t[i]] - qx).astype(f32) for i in range(3)]
        ay = [(Y[t[i]] - qy).astype(f32) for i in range(3)]
        best = None
        e = []
        for i in range(3):  # the three edges (v_i, v_i+1); q - a = -a
            j = (i + 1) % 3
            abx, aby = ax[j] - ax[i], ay[j] - ay[i]
            den = abx * abx + aby * aby
            dot = -(ax[i] * abx + ay[i] * aby)
            tt = np.clip(dot / np.where(den > 0, den, f32(1.0)), f32(0.0), f32(1.0))
            rx, ry = ax[i] + tt * abx, ay[i] + tt * aby
            d = rx * rx + ry * ry
            best = d if best is None else np.minimum(best, d)
            e.append(ay[i] * abx - ax[i] * aby)  # 2-D edge function at the pixel centre
        inside = (((e[0] > 0) & (e[1] > 0) & (e[2] > 0))
                  | ((e[0] < 0) & (e[1] < 0) & (e[2] < 0)))
        best = np.where(np.isfinite(best), best, f32(0.0)).astype(np.float64)
        return np.where(inside, -best, best)

    def _xy(self, sl: slice) -> tuple[np.ndarray, np.ndarray]:
        """NDC x and y (float64) of the pixel centres of hits ``sl``."""
        H, W = self.image_size
        rem = self.pixel[sl] % (H * W)
        row, col = np.divmod(rem, W)
        S = min(H, W)
        return (W - 1 - 2.0 * col) / S, (H - 1 - 2.0 * row) / S

    @cached_property
    def hit_points(self) -> np.ndarray:
        """(k, 3) float64 world position of every hit (interpolated vertex positions)."""
        w = np.ascontiguousarray(self.bary.T)
        return self._interp(self._table("verts_packed", np.float64), slice(None), w).T

    @cached_property
    def hit_normals(self) -> np.ndarray:
        """(k, 3) float64 unit normal at every hit: the vertex normals (area-weighted,
        PyTorch3D's) interpolated with the barycentrics, then normalised (eps 1e-6)."""
        w = np.ascontiguousarray(self.bary.T)
        n = self._interp(self._table("verts_normals_packed", np.float64), slice(None), w).T
        return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-6)

    @cached_property
    def hit_face_normals(self) -> np.ndarray:
        """(k, 3) float64 unit geometric normal ``(v1 - v0) x (v2 - v0)`` of each hit face."""
        return self._ctx["face_normals_packed"][self.face]

    @cached_property
    def hit_xy(self) -> np.ndarray:
        """(k, 2) float64 NDC x, y of each covered pixel's centre."""
        return np.stack(self._xy(slice(None)), axis=1)

    @cached_property
    def hit_dists(self) -> np.ndarray:
        """(k,) float64 signed squared NDC distance from each pixel centre to the nearest edge of
        its face's projection (negative inside), PyTorch3D's ``dists``."""
        parts = self._parallel(self._dists)
        return np.concatenate(parts) if parts else np.zeros(0)

    # -------------------------------------------------------------- PyTorch3D images
    _ENTRY_DISTS = "hit_dists"

    def _slots(self):
        return self.pixel, 0, 1

    @cached_property
    def normals(self) -> np.ndarray:
        """(N, H, W, 1, 3) float64 unit interpolated world normals, 0 where empty."""
        return self._image(self.hit_normals, 0.0, np.float64)

    @property
    def mask(self) -> np.ndarray:
        """(N, H, W) bool: pixels that see a face."""
        return self.pix_to_face[..., 0] >= 0

    # -------------------------------------------------------------- images for free
    def depth_image(self, background: float = 0.0) -> np.ndarray:
        """(N, H, W) float64 view depth, ``background`` where empty."""
        H, W = self.image_size
        out = np.full(self.n_views * H * W, background, dtype=np.float64)
        out[self.pixel] = self.depth
        return out.reshape(self.n_views, H, W)

    def normal_image(self, space: str = "world") -> np.ndarray:
        """(N, H, W, 3) float32 unit normals mapped to colours ``(n + 1) / 2``, 0 where empty.

        Parameters
        ----------
        space : {"world", "view"}
            Express the normals in world or camera (view) coordinates.
        """
        if space not in ("world", "view"):
            raise ValueError(f"space: expected 'world' or 'view', got {space!r}")
        n = self.hit_normals
        if space == "view":
            R = self.cameras.R
            n = np.einsum("ki,kij->kj", n, R[self.view]) if len(R) > 1 else n @ R[0]
        H, W = self.image_size
        out = np.zeros((self.n_views * H * W, 3), dtype=np.float32)
        out[self.pixel] = 0.5 * (n + 1.0)
        return out.reshape(self.n_views, H, W, 3)

    def face_id_image(self, local: bool = True) -> np.ndarray:
        """(N, H, W) int64 face index per pixel, -1 where empty.

        Parameters
        ----------
        local : bool
            Index into each view's own mesh's faces (default) instead of the packed index.
        """
        ids = self.face
        if local:
            ids = ids - self._ctx["face_first"][self.view]
        H, W = self.image_size
        out = np.full(self.n_views * H * W, -1, dtype=np.int64)
        out[self.pixel] = ids
        return out.reshape(self.n_views, H, W)


# ------------------------------------------------------------------------------------------
# Rasterizer
# ------------------------------------------------------------------------------------------


def _as_batch(meshes) -> Meshes:
    return as_meshes(meshes)  # geofit, trimesh or Open3D meshes


def _check_cameras(cameras) -> CamerasBase:
    if cameras is None:
        raise ValueError("cameras: none given; pass cameras to the rasterizer (or renderer) "
                         "at construction or as a keyword argument of the call")
    if not isinstance(cameras, CamerasBase):
        raise TypeError(f"cameras: expected a geofit.cameras camera batch, got {type(cameras)!r}")
    return cameras


class MeshRasterizer:
    """Per-pixel fragments of meshes by Embree ray casting (PyTorch3D's ``MeshRasterizer``).

    Parameters
    ----------
    cameras : FoVPerspectiveCameras or FoVOrthographicCameras, optional
        ``N`` cameras (or one for every mesh); can be given at call time instead.
    raster_settings : RasterizationSettings, optional
        Default ``RasterizationSettings()`` (256 x 256).

    Notes
    -----
    Batches: with ``N`` meshes and ``N`` cameras, view ``b`` shows mesh ``b``; one camera is
    used for every mesh; one mesh with ``N`` cameras renders it ``N`` times (as
    ``mesh.extend(N)``). Views are grouped by distinct mesh and every group's rays go to Embree in
    one threaded call; the Embree scene of a mesh is cached (keyed by its vertex and face arrays,
    which geofit meshes never modify in place).

    *Which pixels a face covers.* A pixel sees the first face its centre ray meets at view depth
    >= the clip depth. PyTorch3D's rasterizer tests pixel centres against projected triangles in
    float32; the two agree except where a pixel centre lies within rounding of an edge
    shared by two faces, where either face may be reported (never a gap: Embree's traversal is
    watertight).

    *Degenerate input.* Faces of zero area are never hit. An empty mesh (no faces) renders as
    background (``pix_to_face == -1`` everywhere). A camera inside a closed mesh sees the inside
    of the surface: its back faces, shaded as PyTorch3D shades them, with the outward normals
    and no shadows (a light outside lights them through the surface, a light inside leaves them
    the ambient term); set ``cull_backfaces=True`` to skip them (nothing is then seen).
    """

    _CACHE_SIZE = 8

    def __init__(self, cameras=None, raster_settings: RasterizationSettings | None = None):
        self.cameras = cameras
        self.raster_settings = raster_settings or RasterizationSettings()
        self._scenes: list[tuple[np.ndarray, np.ndarray, EmbreeScene]] = []

    def _scene(self, mesh: Mesh) -> EmbreeScene:
        for v, f, sc in self._scenes:
            if v is mesh.verts and f is mesh.faces:
                return sc
        sc = EmbreeScene([(mesh.verts, mesh.faces)])
        self._scenes.insert(0, (mesh.verts, mesh.faces, sc))
        del self._scenes[self._CACHE_SIZE:]
        return sc

    def __call__(self, meshes, **kwargs) -> Fragments:
        """Cast the rays of every pixel of every view.

        Parameters
        ----------
        meshes : Mesh, Meshes or list of Mesh
            ``N`` meshes (or one mesh for ``N`` cameras).
        **kwargs
            ``cameras=`` and ``raster_settings=`` override the stored ones for this call; other
            keywords (lights, materials, ...) are ignored here.

        Returns
        -------
        Fragments

        Raises
        ------
        ValueError
            If no cameras are given or the batch sizes of meshes and cameras do not match
            (each must be 1 or N).
        TypeError
            For objects of the wrong type.
        """
        cameras = _check_cameras(kwargs.get("cameras", self.cameras))
        settings = kwargs.get("raster_settings", self.raster_settings)
        if not isinstance(settings, RasterizationSettings):
            raise TypeError(f"raster_settings: expected RasterizationSettings, got "
                            f"{type(settings)!r}")
        meshes = _as_batch(meshes)
        nm, nc = len(meshes), len(cameras)
        if nm == 0:
            raise ValueError("meshes: expected at least one mesh, got an empty batch")
        N = max(nm, nc)
        if nm not in (1, N) or nc not in (1, N):
            raise ValueError(f"meshes and cameras: batch sizes must be 1 or N, got {nm} meshes "
                             f"and {nc} cameras")
        if nm == 1 and N > 1:
            meshes = meshes.extend(N)
        if nc == 1 and N > 1:
            cameras = cameras.extend(N)
        check_allocation(128 * N * settings.raster_size[0] * settings.raster_size[1],
                         "image_size", f"rasterizing {N} view(s) at {settings.raster_size}")
        return self._rasterize(meshes, cameras, settings)

    def _rasterize(self, meshes: Meshes, cameras, settings: RasterizationSettings) -> Fragments:
        N = len(meshes)
        H, W = settings.raster_size
        perspective = bool(cameras.is_perspective())
        pc = settings.perspective_correct
        pc = perspective if pc is None else bool(pc)
        if settings.z_clip_value is not None:
            tnear = np.full(N, float(settings.z_clip_value))
        elif pc and perspective:
            tnear = np.asarray(cameras.znear, dtype=np.float64) / 2.0
        else:
            tnear = np.zeros(N)
        n_threads = settings.n_threads or _raycast.n_threads_default()
        xy = ndc_grid((H, W))
        xs, ys = xy[0, :, 0].copy(), xy[:, 0, 1].copy()
        rays = _raycast.view_rays(cameras)

        # Per-view projections of each view's own mesh (packed), for masks and dists.
        v_first = meshes.mesh_to_verts_packed_first_idx()
        f_first = meshes.mesh_to_faces_packed_first_idx()
        nv = meshes.num_verts_per_mesh()
        xy_packed = np.zeros((int(nv.sum()), 2))
        z_packed = np.zeros(int(nv.sum()))
        # Group views by distinct mesh geometry.
        groups: dict[tuple[int, int], list[int]] = {}
        for b, m in enumerate(meshes):  # loop over views
            groups.setdefault((id(m.verts), id(m.faces)), []).append(b)
        parts = []
        n_rays = 0
        view_scene: list = [None] * N
        for views in groups.values():  # loop over distinct meshes
            mesh = meshes[views[0]]
            masks = []
            for b in views:  # loop over views: project the mesh, mark candidate pixels
                pxy, z = _raycast.project(mesh.verts, rays[b], perspective)
                sl = slice(int(v_first[b]), int(v_first[b] + nv[b]))
                xy_packed[sl], z_packed[sl] = pxy, z
                if mesh.n_faces:
                    masks.append((b, _raycast.coverage_mask(pxy, z, mesh.faces, H, W,
                                                            float(tnear[b]))))
            if not masks:
                continue  # an empty mesh: nothing to hit
            scene = self._scene(mesh)
            for b in views:
                view_scene[b] = scene
            pixels = np.concatenate([b * H * W + np.flatnonzero(mk) for b, mk in masks])
            hits = _raycast.cast_pixels(scene, pixels, rays, xs, ys, tnear, n_threads)
            n_rays += len(pixels)
            if settings.cull_backfaces:
                hits, extra = self._cull(hits, scene, mesh, rays, xs, ys, tnear, n_threads)
                n_rays += extra
            view = hits.pixel // (H * W)
            vtri = mesh.faces[hits.face] + v_first[view][:, None]  # packed vertex ids
            bary, depth = _refine_threaded(hits, vtri, xy_packed, z_packed, perspective, pc,
                                           rays, xs, ys, mesh, n_threads)
            parts.append((hits.pixel, view, hits.face + f_first[view], bary, depth))

        if parts:
            pixel, view, face, bary, depth = (np.concatenate([p[i] for p in parts])
                                              for i in range(5))
            if len(parts) > 1:
                order = np.argsort(pixel, kind="stable")
                pixel, view, face, bary, depth = (a[order] for a in (pixel, view, face, bary,
                                                                      depth))
        else:
            pixel = view = face = np.zeros(0, np.int64)
            bary, depth = np.zeros((0, 3)), np.zeros(0)

        faces_packed = meshes.faces_packed()
        ctx = {
            "faces_packed": faces_packed,
            "verts_packed": meshes.verts_packed(),
            "verts_xy_packed": xy_packed,
            "verts_z_packed": z_packed,
            "face_first": f_first,
            "verts_normals_packed": (meshes.verts_normals_packed() if N else np.zeros((0, 3))),
            "face_normals_packed": meshes.faces_normals_packed(),
            "view_scene": view_scene,
            "tnear": tnear,
            "n_threads": n_threads,
            "n_rays": n_rays,
        }
        return Fragments((H, W), N, pixel, view, face, bary, depth, meshes, cameras,
                         settings.supersample, ctx)

    @staticmethod
    def _cull(hits, scene, mesh, rays, xs, ys, tnear, n_threads, max_rounds: int = 64):
        """Continue rays that hit a back face until they hit a front face or nothing."""
        fn = mesh.face_cross
        keep = [np.ones(len(hits.pixel), bool)]
        cur = hits
        out = [hits]
        n_rays = 0
        for _ in range(max_rounds):  # loop over layers of back faces
            _, d, _ = _raycast.hit_rays(cur.pixel, rays, xs, ys)
            back = np.einsum("ij,ij->i", fn[cur.face], d) > 0
            keep[-1] = ~back
            if not np.any(back):
                break
            p = cur.pixel[back]
            # Restart just past the culled hit (a step well above float32 rounding).
            t0 = cur.depth[back] * (1.0 + 1e-5) + 1e-7
            cur = _raycast.cast_pixels(scene, p, rays, xs, ys, tnear, n_threads, tnear_pixel=t0)
            n_rays += len(p)
            out.append(cur)
            keep.append(np.ones(len(cur.pixel), bool))
        else:
            keep[-1] = np.zeros(len(cur.pixel), bool)  # give up on pathological stacks
        pix = np.concatenate([h.pixel[k] for h, k in zip(out, keep)])
        order = np.argsort(pix, kind="stable")
        cat = [np.concatenate([getattr(h, f)[k] for h, k in zip(out, keep)])[order]
               for f in ("pixel", "face", "bary", "depth")]
        return _raycast.PixelHits(*cat), n_rays


def _refine(hits, vtri, xy_packed, z_packed, perspective: bool, pc: bool, rays, xs, ys,
            mesh) -> tuple[np.ndarray, np.ndarray]:
    """Float64 barycentrics and depths of Embree's hits from the projected triangles.

    The pixel centre's 2-D barycentrics ``b`` in the projected face (edge functions, float64)
    are PyTorch3D's screen-space barycentrics; the perspective-correct ones are
    ``w_i = (b_i / z_i) / sum_j (b_j / z_j)`` with view depth ``1 / sum_j (b_j / z_j)``, and for
    screen-space interpolation (``perspective_correct=False``, or orthographic cameras) the
    depth is ``sum b_i z_i``. Hits whose face touches the camera plane (a corner at depth <= 0,
    possible only for clipped faces) or is seen edge-on fall back to a float64 ray/triangle
    intersection.
    """
    X, Y = xy_packed[:, 0], xy_packed[:, 1]
    H, W = len(ys), len(xs)
    rem = hits.pixel % (H * W)
    row, col = np.divmod(rem, W)
    qx, qy = xs[col], ys[row]
    t0, t1, t2 = vtri[:, 0], vtri[:, 1], vtri[:, 2]
    # Corners relative to the pixel centre; e_i = cross(v_j - q, v_k - q) is the 2-D edge
    # function opposite corner i, and b_i = e_i / (e0 + e1 + e2).
    ax, ay = X[t0] - qx, Y[t0] - qy
    bx, by = X[t1] - qx, Y[t1] - qy
    cx, cy = X[t2] - qx, Y[t2] - qy
    e0 = bx * cy - by * cx
    e1 = cx * ay - cy * ax
    e2 = ax * by - ay * bx
    area = e0 + e1 + e2
    ok = np.abs(area) > 1e-14
    sgn = np.sign(area)
    for e in (e0, e1, e2):  # the pixel centre lies within rounding outside the chosen face:
        np.maximum(e * sgn, 0.0, out=e)  # clip to the face (e_i now >= 0, area's sign dropped)
    Z = np.empty((len(t0), 3))
    Z[:, 0], Z[:, 1], Z[:, 2] = z_packed[t0], z_packed[t1], z_packed[t2]
    w = np.empty((len(t0), 3))
    if perspective and pc:
        ok &= (Z[:, 0] > 1e-9) & (Z[:, 1] > 1e-9) & (Z[:, 2] > 1e-9)
        Zs = np.where(ok[:, None], Z, 1.0)
        w[:, 0], w[:, 1], w[:, 2] = e0 / Zs[:, 0], e1 / Zs[:, 1], e2 / Zs[:, 2]
        s = w[:, 0] + w[:, 1] + w[:, 2]
        ok &= s > 0
        s = np.where(ok, s, 1.0)
        depth = (e0 + e1 + e2) / s
        w /= s[:, None]
    else:
        s = e0 + e1 + e2
        ok &= s > 0
        s = np.where(ok, s, 1.0)
        w[:, 0], w[:, 1], w[:, 2] = e0 / s, e1 / s, e2 / s
        depth = np.einsum("kj,kj->k", w, Z)
    bad = np.flatnonzero(~ok)
    if len(bad):
        p = hits.pixel[bad]
        o, d, _ = _raycast.hit_rays(p, rays, xs, ys)
        tri = mesh.faces[hits.face[bad]]
        V = mesh.verts
        wb, tb = _raycast.refine(o, d, V[tri[:, 0]], V[tri[:, 1]], V[tri[:, 2]],
                                 hits.bary[bad], hits.depth[bad])
        if perspective and not pc:  # screen-space barycentrics: proportional to w_i z_i
            wz = wb * Z[bad]
            wb = wz / np.maximum(wz.sum(axis=1, keepdims=True), 1e-300)
            tb = np.einsum("kj,kj->k", wb, Z[bad])
        w[bad], depth[bad] = wb, tb
    return w, depth


def _refine_threaded(hits, vtri, xy_packed, z_packed, perspective, pc, rays, xs, ys, mesh,
                     n_threads):
    """:func:`_refine` over chunks of the hits on the worker threads."""
    k = len(hits.pixel)
    m = 1 if (n_threads == 1 or k < 40_000) else min(4 * n_threads, k // 20_000 + 1)
    if m == 1:
        return _refine(hits, vtri, xy_packed, z_packed, perspective, pc, rays, xs, ys, mesh)
    bounds = np.linspace(0, k, m + 1).astype(np.int64)

    def run(i):
        sl = slice(int(bounds[i]), int(bounds[i + 1]))
        sub = _raycast.PixelHits(hits.pixel[sl], hits.face[sl], hits.bary[sl], hits.depth[sl])
        return _refine(sub, vtri[sl], xy_packed, z_packed, perspective, pc, rays, xs, ys, mesh)

    parts = parallel_map(run, range(m), n_threads)
    return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])
