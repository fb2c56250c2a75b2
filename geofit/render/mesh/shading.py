"""Phong, Gouraud and flat shading with PyTorch3D's formulas, and the shaders that use them.

Every function here works on the covered pixels only (``k`` of them, in the order of
``fragments.pixel``), vectorised over all pixels of all views at once, in float32, split into
chunks shaded on the worker threads (numpy releases the GIL in its array loops).

The colour of a surface point (PyTorch3D's ``_apply_lighting`` and ``phong_shading``)::

    colour = (Ma * La + Md * diffuse) * texel + Ms * specular

with ``Ma, Md, Ms`` the material colours, ``La`` the light's ambient colour and ``diffuse``,
``specular`` the light terms of :mod:`geofit.render.lighting` evaluated with the unit normal at
the point and the view vector towards the camera centre. Phong evaluates this per pixel with
interpolated vertex normals, Gouraud per vertex (then interpolates the colours), flat per face
(face centroid and face normal).

Beyond PyTorch3D, ``shadows=True`` casts one shadow ray per lit pixel towards the light and drops
the diffuse and specular terms where it is blocked (hard shadows; off by default).
"""
from __future__ import annotations


import numpy as np

from ..._threads import parallel_map
from ...structures import Mesh, TexturesUV, TexturesVertex
from ..blending import BlendParams, check_blend, new_images, scatter, soft_rgba_t
from ..lighting import AmbientLights, DirectionalLights, PointLights, per_point_t
from ..materials import Materials
from ..soft.fragments import SoftFragments
from ..soft.renderer import shade_soft_phong
from .rasterizer import Fragments
from .textures import UVTables, sample_texels_t

__all__ = [
    "HardFlatShader",
    "HardGouraudShader",
    "HardPhongShader",
    "SoftGouraudShader",
    "SoftPhongShader",
    "apply_lighting",
    "flat_shading",
    "gouraud_shading",
    "phong_shading",
    "sample_textures",
    "shadow_visibility",
]

_LIGHTS = (PointLights, DirectionalLights, AmbientLights)


def _check_batch(obj, name: str, kinds, n: int):
    if not isinstance(obj, kinds):
        names = " or ".join(k.__name__ for k in (kinds if isinstance(kinds, tuple) else (kinds,)))
        raise TypeError(f"{name}: expected {names}, got {type(obj)!r}")
    if len(obj) not in (1, n):
        raise ValueError(f"{name}: batch size must be 1 or the number of views {n}, "
                         f"got {len(obj)}")
    return obj


def _camera_centers(cameras, n: int) -> np.ndarray:
    c = np.asarray(cameras.get_camera_center(), dtype=np.float64)
    if len(c) not in (1, n):
        raise ValueError(f"cameras: batch size must be 1 or the number of views {n}, got {len(c)}")
    return c


def _lighting_t(p, n, lights, centers, materials, bidx, visibility=None, unit_normals=False):
    """Component-first ``_apply_lighting``: ``p, n (3, k)`` float32 -> ambient ``(3, 1 | k)``,
    diffuse ``(3, k)``, specular ``(3, k)``."""
    dt = p.dtype
    cam = per_point_t(centers, bidx, dt)
    shin = per_point_t(materials.shininess[:, None], bidx, dt)[0]
    diffuse, specular = lights._terms_t(n, p, cam, shin, bidx, unit_normals)
    if visibility is not None:
        diffuse = diffuse * visibility
        specular = specular * visibility
    ambient = per_point_t(materials.ambient_color, bidx, dt) * per_point_t(lights.ambient_color,
                                                                           bidx, dt)
    diffuse = per_point_t(materials.diffuse_color, bidx, dt) * diffuse
    specular = per_point_t(materials.specular_color, bidx, dt) * specular
    return ambient, diffuse, specular


def apply_lighting(points, normals, lights, camera_position, materials, batch_idx=None,
                   visibility=None):
    """Ambient, diffuse and specular colours at surface points (PyTorch3D's ``_apply_lighting``).

    Parameters
    ----------
    points : (k, 3) float
        World positions.
    normals : (k, 3) float
        Normals (normalised inside with eps 1e-6).
    lights : PointLights, DirectionalLights or AmbientLights
    camera_position : (N, 3) float
        Camera centre of every view.
    materials : Materials
    batch_idx : (k,) int64, optional
        View of every point (needed when lights, materials or cameras hold more than one entry).
    visibility : (k,) float, optional
        1 where the light reaches the point, 0 in shadow; multiplies diffuse and specular.

    Returns
    -------
    ambient : (k, 3) or (1, 3)
        ``Ma * La``.
    diffuse : (k, 3)
        ``Md * Ld * max(0, n . l)``.
    specular : (k, 3)
        ``Ms * Ls * max(0, r . v) ** shininess`` where ``n . l > 0``.
        All in the dtype of ``normals``.
    """
    n = np.asarray(normals)
    p = np.asarray(points, n.dtype)
    centers = np.atleast_2d(np.asarray(camera_position, np.float64))
    vis = None if visibility is None else np.asarray(visibility, n.dtype)
    a, d, s = _lighting_t(p.T, n.T, lights, centers, materials, batch_idx, vis)
    return a.T, d.T, s.T


def _needs_index(fragments, *objs) -> bool:
    return any(len(o) > 1 for o in objs)


def _prepare_texels(fragments: Fragments) -> list:
    """Group the views by mesh and build each UV texture's lookup tables once (before the
    worker threads start); cached in the fragments."""
    ctx = fragments._ctx
    if "texture_groups" not in ctx:
        g: dict[int, list[int]] = {}
        for b, m in enumerate(fragments.meshes):  # loop over views: group by mesh object
            g.setdefault(id(m), []).append(b)
        groups = list(g.values())
        tables = {}
        for views in groups:  # loop over distinct meshes
            tex = fragments.meshes[views[0]].textures
            if isinstance(tex, TexturesUV) and id(tex) not in tables:
                H, W, _ = tex.maps.shape
                # Many lookups: one float32 copy of the map pays for itself.
                tables[id(tex)] = UVTables(tex, float32_map=fragments.n_hits > H * W // 8)
        ctx["texture_groups"], ctx["uv_tables"] = groups, tables
    return ctx["texture_groups"]


def _texels_t(fragments: Fragments, sl: slice, default=(1.0, 1.0, 1.0)) -> np.ndarray:
    """(C, len) float32 texture colour of hits ``sl``."""
    meshes = fragments.meshes
    first = fragments._ctx["face_first"]
    view = fragments.view[sl]
    local = fragments.face[sl] - first[view]
    w = fragments._w32[:, sl]
    groups = _prepare_texels(fragments)
    tables = fragments._ctx["uv_tables"]
    if len(groups) == 1:
        m = meshes[0]
        return sample_texels_t(m.textures, m.faces, local, w, default,
                               tables.get(id(m.textures)))
    out = None
    for views in groups:  # loop over distinct meshes
        sel = np.flatnonzero(np.isin(view, views))
        if len(sel) == 0:
            continue
        m = meshes[views[0]]
        t = sample_texels_t(m.textures, m.faces, local[sel], w[:, sel], default,
                            tables.get(id(m.textures)))
        if out is None:
            out = np.zeros((t.shape[0], len(view)), np.float32)
        elif t.shape[0] != out.shape[0]:
            raise ValueError(f"textures: every mesh of the batch needs the same number of "
                             f"channels, got {out.shape[0]} and {t.shape[0]}")
        out[:, sel] = t
    if out is None:
        out = np.zeros((len(default), len(view)), np.float32)
    return out


def sample_textures(fragments: Fragments, default=(1.0, 1.0, 1.0)) -> np.ndarray:
    """Texture colour at every covered pixel (PyTorch3D's ``meshes.sample_textures``).

    Parameters
    ----------
    fragments : Fragments
    default : (C,) float
        Colour of meshes without textures (default white).

    Returns
    -------
    texels : (k, C) float32
        UV maps are sampled bilinearly with PyTorch3D's convention (see
        :mod:`geofit.render.mesh.textures`), per-vertex colours interpolated, flat colours copied.

    Raises
    ------
    ValueError
        If the meshes of the batch have textures with different numbers of channels.
    """
    _prepare_texels(fragments)
    parts = fragments._parallel(lambda sl: _texels_t(fragments, sl, default))
    if not parts:
        return np.zeros((0, len(default)), np.float32)
    return np.ascontiguousarray(np.concatenate(parts, axis=1).T)


def shadow_visibility(fragments: Fragments, lights, points=None, normals=None,
                      face_normals=None) -> np.ndarray:
    """1 where the light reaches each hit point, 0 where the mesh blocks it (shadow rays).

    A shadow ray starts at the hit point, offset by ``1e-4`` of the mesh size along the face
    normal on the light's side (so it cannot hit its own face), and runs to the light (point
    lights) or to infinity (directional lights). Points that face away from the light
    (``n . l <= 0``) or that coincide with the light get no ray (their diffuse and specular terms
    are zero anyway) and are reported as lit.

    Parameters
    ----------
    fragments : Fragments
    lights : PointLights, DirectionalLights or AmbientLights
    points, normals, face_normals : (k, 3) float, optional
        Shading points, shading normals and geometric normals (default: the fragments' hit
        points, interpolated normals and face normals).

    Returns
    -------
    (k,) float32
    """
    k = fragments.n_hits
    vis = np.ones(k, np.float32)
    if isinstance(lights, AmbientLights) or k == 0:
        return vis
    p = fragments.hit_points if points is None else np.asarray(points, np.float64)
    n = fragments.hit_normals if normals is None else np.asarray(normals, np.float64)
    ng = fragments.hit_face_normals if face_normals is None else np.asarray(face_normals)
    bidx = None if len(lights) == 1 else fragments.view
    l, dist = lights.light_vector(p, bidx)
    side = np.sign(np.einsum("ki,ki->k", ng, l))
    need = (np.einsum("ki,ki->k", n, l) > 0) & (side != 0) & (dist > 0)
    view_scene = fragments._ctx["view_scene"]
    n_threads = fragments._ctx["n_threads"]
    scenes: dict = {}
    for b, sc in enumerate(view_scene):  # loop over views
        if sc is not None:
            scenes.setdefault(id(sc), (sc, []))[1].append(b)
    for sc, views in scenes.values():  # loop over distinct meshes
        sel = np.flatnonzero(need & np.isin(fragments.view, views))
        if len(sel) == 0:
            continue
        o = p[sel] + (1e-4 * sc.scale) * side[sel, None] * ng[sel]
        if isinstance(lights, PointLights):
            loc = lights.location if bidx is None else lights.location[bidx[sel]]
            d = loc - o
            tfar = np.full(len(sel), 1.0, np.float32)
        else:
            d = l[sel]
            tfar = np.full(len(sel), 1e30, np.float32)
        on = ((o - sc.center) / sc.scale).astype(np.float32)
        dn = (d / sc.scale).astype(np.float32)
        ok = np.einsum("ki,ki->k", dn, dn) > 0
        n_chunks = max(1, min(4 * n_threads, len(sel) // 50_000 + 1))
        chunks = np.array_split(np.arange(len(sel)), n_chunks)

        def run(c, sc=sc, on=on, dn=dn, tfar=tfar):
            return sc.occluded(np.ascontiguousarray(on[c]), np.ascontiguousarray(dn[c]),
                               np.ascontiguousarray(tfar[c]))

        occ = np.concatenate(parallel_map(run, chunks, n_threads))
        vis[sel[occ & ok]] = 0.0
    return vis


# ------------------------------------------------------------------------------------------
# Per-chunk colour kernels (component-first, float32)
# ------------------------------------------------------------------------------------------


def _phong_chunk(fragments, sl, lights, centers, materials, idx, visibility, texels=None):
    p = fragments._points32(sl)
    n = fragments._normals32(sl)
    bidx = fragments.view[sl] if idx else None
    tex = _texels_t(fragments, sl) if texels is None else texels[sl].T
    vis = None if visibility is None else visibility[sl]
    amb, dif, spe = _lighting_t(p, n, lights, centers, materials, bidx, vis, unit_normals=True)
    return (amb + dif) * tex + spe


def _flat_tables(fragments):
    ctx = fragments._ctx
    if "face_centroids_t" not in ctx:
        V = ctx["verts_packed"]
        F = ctx["faces_packed"]
        ctx["face_centroids_t"] = np.ascontiguousarray(V[F].mean(axis=1).T, dtype=np.float32)
        ctx["face_normals_t"] = np.ascontiguousarray(ctx["face_normals_packed"].T,
                                                     dtype=np.float32)
    return ctx["face_centroids_t"], ctx["face_normals_t"]


def _flat_chunk(fragments, sl, lights, centers, materials, idx, visibility, texels=None):
    C, Nf = _flat_tables(fragments)
    f = fragments.face[sl]
    p = C[:, f]
    n = Nf[:, f]
    bidx = fragments.view[sl] if idx else None
    tex = _texels_t(fragments, sl) if texels is None else texels[sl].T
    vis = None if visibility is None else visibility[sl]
    amb, dif, spe = _lighting_t(p, n, lights, centers, materials, bidx, vis, unit_normals=True)
    return (amb + dif) * tex + spe


def _gouraud_table(fragments, lights, centers, materials):
    meshes = fragments.meshes
    for i, m in enumerate(meshes):  # loop over views
        if not isinstance(m.textures, TexturesVertex):  # PyTorch3D raises ValueError too
            raise ValueError(  # noqa: TRY004
                f"meshes[{i}]: Gouraud shading needs TexturesVertex (per-vertex colours), got "
                f"{type(m.textures).__name__}")
    ctx = fragments._ctx
    verts = np.ascontiguousarray(ctx["verts_packed"].T, dtype=np.float32)
    nrm = np.ascontiguousarray(ctx["verts_normals_packed"].T, dtype=np.float32)
    colors = np.concatenate([m.textures.verts_features for m in meshes]).T.astype(np.float32)
    idx = _needs_index(fragments, lights, materials, centers)
    bidx = meshes.verts_packed_to_mesh_idx() if idx else None
    amb, dif, spe = _lighting_t(verts, nrm, lights, centers, materials, bidx)
    return np.ascontiguousarray(colors * (amb + dif) + spe)  # (C, sum V)


def _run(fragments, kernel):
    parts = fragments._parallel(kernel)
    if not parts:
        return np.zeros((0, 3), np.float32)
    return np.ascontiguousarray(np.concatenate(parts, axis=1).T)


def phong_shading(fragments: Fragments, lights, cameras, materials, texels=None,
                  visibility=None) -> np.ndarray:
    """Per-pixel Phong colour of every covered pixel (PyTorch3D's ``phong_shading``).

    Parameters
    ----------
    fragments : Fragments
    lights, cameras, materials
        Batches of 1 or N.
    texels : (k, 3) float32, optional
        Texture colour of every covered pixel (default: :func:`sample_textures`).
    visibility : (k,) float32, optional
        Shadow factor (:func:`shadow_visibility`).

    Returns
    -------
    colors : (k, 3) float32
    """
    centers = _camera_centers(cameras, fragments.n_views)
    idx = _needs_index(fragments, lights, materials, centers)
    _prepare_texels(fragments)
    return _run(fragments, lambda sl: _phong_chunk(fragments, sl, lights, centers, materials,
                                                   idx, visibility, texels))


def flat_shading(fragments: Fragments, lights, cameras, materials, texels=None,
                 visibility=None) -> np.ndarray:
    """Per-face lighting (face centroid and unit face normal), PyTorch3D's ``flat_shading``.

    Parameters and returns as :func:`phong_shading`.
    """
    centers = _camera_centers(cameras, fragments.n_views)
    idx = _needs_index(fragments, lights, materials, centers)
    _prepare_texels(fragments)
    return _run(fragments, lambda sl: _flat_chunk(fragments, sl, lights, centers, materials,
                                                  idx, visibility, texels))


def gouraud_shading(fragments: Fragments, lights, cameras, materials) -> np.ndarray:
    """Per-vertex lighting interpolated over the faces (PyTorch3D's ``gouraud_shading``).

    Every vertex of every view's mesh is lit with its vertex normal and that view's camera,
    light and material; the shaded vertex colours ``c_v (Ma La + Md D) + Ms S`` are then
    interpolated with the barycentrics.

    Raises
    ------
    ValueError
        If a mesh has no :class:`~geofit.TexturesVertex` (as PyTorch3D).

    Returns
    -------
    colors : (k, C) float32
    """
    centers = _camera_centers(cameras, fragments.n_views)
    table = _gouraud_table(fragments, lights, centers, materials)
    return _run(fragments, lambda sl: fragments._interp(table, sl))


# ------------------------------------------------------------------------------------------
# Shaders
# ------------------------------------------------------------------------------------------


class _Shader:
    """Common parts: stored cameras / lights / materials / blend parameters, call-time overrides."""

    _soft = False

    def __init__(self, cameras=None, lights=None, materials=None, blend_params=None, *,
                 shadows: bool = False, clip: bool = True):
        self.cameras = cameras
        self.lights = lights if lights is not None else PointLights()
        self.materials = materials if materials is not None else Materials()
        self.blend_params = blend_params if blend_params is not None else BlendParams()
        if not isinstance(shadows, (bool, np.bool_)):
            raise TypeError(f"shadows: expected True or False, got {shadows!r}")
        self.shadows = bool(shadows)
        self.clip = bool(clip)

    def _setup(self, fragments, kwargs):
        if not isinstance(fragments, Fragments):
            raise TypeError(f"fragments: expected Fragments, got {type(fragments)!r}")
        n = fragments.n_views
        cameras = kwargs.get("cameras", self.cameras)
        if cameras is None:
            cameras = fragments.cameras
        lights = _check_batch(kwargs.get("lights", self.lights), "lights", _LIGHTS, n)
        materials = _check_batch(kwargs.get("materials", self.materials), "materials",
                                 Materials, n)
        blend, bg = check_blend(kwargs.get("blend_params", self.blend_params))
        return cameras, lights, materials, blend, bg

    def _kernel(self, fragments, cameras, lights, materials):  # pragma: no cover - abstract
        """Returns ``fn(sl) -> (3, len) float32`` colours of hits ``sl``."""
        raise NotImplementedError

    def __call__(self, fragments: Fragments, meshes=None, **kwargs) -> np.ndarray:
        """Shade fragments into RGBA images.

        Parameters
        ----------
        fragments : Fragments
            From :class:`~geofit.render.MeshRasterizer` (they carry the meshes and cameras).
        meshes : Mesh or Meshes, optional
            Accepted for PyTorch3D's signature; the fragments' meshes are used.
        **kwargs
            ``cameras=``, ``lights=``, ``materials=``, ``blend_params=`` override the stored
            objects. Without any cameras the rasterizer's are used.

        Returns
        -------
        images : (N, H, W, 4) float32 RGBA
        """
        cameras, lights, materials, blend, bg = self._setup(fragments, kwargs)
        kernel = self._kernel(fragments, cameras, lights, materials)
        out = new_images(fragments, bg, fragments._ctx.get("n_threads", 1))
        if self._soft:
            n = fragments.n_views
            zn = np.broadcast_to(np.asarray(getattr(cameras, "znear", 1.0),
                                            np.float64).reshape(-1), (n,))
            zf = np.broadcast_to(np.asarray(getattr(cameras, "zfar", 100.0),
                                            np.float64).reshape(-1), (n,))
            one = bool(np.all(zn == zn[0]) and np.all(zf == zf[0]))

        def work(sl):
            rgb = kernel(sl)
            if self._soft:
                v = fragments.view[sl]
                znear, zfar = (zn[0], zf[0]) if one else (zn[v], zf[v])
                rgb, alpha = soft_rgba_t(rgb, fragments._dists(sl), fragments.depth[sl], bg,
                                         blend, znear, zfar)
            else:
                alpha = np.float32(1.0)
            scatter(out, fragments.pixel[sl], rgb, alpha, self.clip)

        fragments._parallel(work)
        H, W = fragments.image_size
        return out.reshape(fragments.n_views, H, W, 4)


class HardPhongShader(_Shader):
    """Per-pixel Phong shading, hard blending (alpha 1 on covered pixels).

    Parameters
    ----------
    cameras : cameras, optional
        Used for the view vector; default: the rasterizer's cameras.
    lights : PointLights, DirectionalLights or AmbientLights, optional
        Default ``PointLights()`` (at (0, 1, 0)).
    materials : Materials, optional
        Default ``Materials()``.
    blend_params : BlendParams, optional
        Default ``BlendParams()`` (white background).
    shadows : bool
        Hard shadows by shadow rays (beyond PyTorch3D; default False).
    clip : bool
        Clip RGB to [0, 1] (default True).
    """

    def _kernel(self, fragments, cameras, lights, materials):
        centers = _camera_centers(cameras, fragments.n_views)
        idx = _needs_index(fragments, lights, materials, centers)
        vis = shadow_visibility(fragments, lights) if self.shadows else None
        _prepare_texels(fragments)
        return lambda sl: _phong_chunk(fragments, sl, lights, centers, materials, idx, vis)


class SoftPhongShader(HardPhongShader):
    """Phong shading with PyTorch3D's soft blending (``softmax_rgb_blend``) of the fragments.

    As in PyTorch3D, what it blends is what the rasterizer kept:

    - on :class:`Fragments` of the (hard, ray-cast) :class:`MeshRasterizer`, K = 1: RGB equals
      HardPhongShader's on covered pixels and alpha is ``sigmoid(-dists / sigma)``, the soft
      coverage of the kept face (0.5 to 1 inside it) -- the render tutorial's setting;
    - on :class:`~geofit.render.soft.SoftFragments` of :func:`~geofit.render.rasterize_soft`
      (blur radius, K faces per pixel): the differentiable blend of the K faces of each pixel,
      with ``TexturesVertex`` colours (float64 images; for the gradient use
      :class:`~geofit.render.SoftPhongRenderer`, whose result has ``vjp``).

    Parameters as :class:`HardPhongShader` (``shadows`` only on hard fragments).
    """

    _soft = True

    def __call__(self, fragments, meshes=None, **kwargs) -> np.ndarray:
        if not isinstance(fragments, SoftFragments):
            return super().__call__(fragments, meshes, **kwargs)
        if self.shadows:
            raise ValueError("shadows: shadow rays need the hard rasterizer's fragments")
        if not isinstance(meshes, Mesh) or not isinstance(meshes.textures, TexturesVertex):
            raise TypeError("meshes: expected the rasterized Mesh with TexturesVertex colours, "
                            f"got {type(meshes)!r}")
        cameras = kwargs.get("cameras", self.cameras)
        if cameras is None:
            raise ValueError("cameras: the soft fragments do not carry them; pass cameras=")
        return shade_soft_phong(fragments, meshes, meshes.textures.verts_features,
                                kwargs.get("lights", self.lights), cameras,
                                kwargs.get("materials", self.materials),
                                kwargs.get("blend_params", self.blend_params)).images


class HardGouraudShader(_Shader):
    """Gouraud shading (lighting per vertex, colours interpolated), hard blending.

    Needs :class:`~geofit.TexturesVertex`; ``shadows`` is not supported (lighting happens at the
    vertices). Other parameters as :class:`HardPhongShader`.
    """

    def __init__(self, cameras=None, lights=None, materials=None, blend_params=None, *,
                 shadows: bool = False, clip: bool = True):
        if shadows:
            raise ValueError("shadows: Gouraud shading lights the vertices, shadow rays need "
                             "per-pixel lighting; use HardPhongShader or HardFlatShader")
        super().__init__(cameras, lights, materials, blend_params, clip=clip)

    def _kernel(self, fragments, cameras, lights, materials):
        centers = _camera_centers(cameras, fragments.n_views)
        table = _gouraud_table(fragments, lights, centers, materials)
        return lambda sl: fragments._interp(table, sl)


class SoftGouraudShader(HardGouraudShader):
    """Gouraud shading with PyTorch3D's soft blending (see :class:`SoftPhongShader`)."""

    _soft = True


class HardFlatShader(_Shader):
    """Flat shading (one lighting value per face, at its centroid), hard blending.

    Parameters as :class:`HardPhongShader`.
    """

    def _kernel(self, fragments, cameras, lights, materials):
        centers = _camera_centers(cameras, fragments.n_views)
        idx = _needs_index(fragments, lights, materials, centers)
        vis = None
        if self.shadows:  # shadow rays from the hit points, lit side given by the face normal
            fn = fragments.hit_face_normals
            vis = shadow_visibility(fragments, lights, normals=fn, face_normals=fn)
        _prepare_texels(fragments)
        return lambda sl: _flat_chunk(fragments, sl, lights, centers, materials, idx, vis)
