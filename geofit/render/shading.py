"""Phong, Gouraud and flat shading with PyTorch3D's formulas, and the shaders that use them.

Every function here works on the covered pixels only (``k`` of them, in the order of
``fragments.pixel``), vectorised over all pixels of all views at once, in float32.

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

from concurrent.futures import ThreadPoolExecutor

import numpy as np

from .blending import BlendParams, hard_rgb_blend, softmax_rgb_blend
from .lighting import AmbientLights, DirectionalLights, PointLights, per_point
from .materials import Materials
from .mesh import Fragments
from .textures import sample_texels

__all__ = [
    "apply_lighting",
    "sample_textures",
    "shadow_visibility",
    "phong_shading",
    "gouraud_shading",
    "flat_shading",
    "HardPhongShader",
    "SoftPhongShader",
    "HardGouraudShader",
    "SoftGouraudShader",
    "HardFlatShader",
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


def apply_lighting(points, normals, lights, camera_position, materials, batch_idx=None,
                   visibility=None):
    """Ambient, diffuse and specular colours at surface points (PyTorch3D's ``_apply_lighting``).

    Parameters
    ----------
    points : (k, 3) float32
        World positions.
    normals : (k, 3) float32
        Normals (normalised inside with eps 1e-6).
    lights : PointLights, DirectionalLights or AmbientLights
    camera_position : (N, 3) float
        Camera centre of every view.
    materials : Materials
    batch_idx : (k,) int64, optional
        View of every point (needed when lights, materials or cameras hold more than one entry).
    visibility : (k,) float32, optional
        1 where the light reaches the point, 0 in shadow; multiplies diffuse and specular.

    Returns
    -------
    ambient : (k, 3) or (1, 3) float32
        ``Ma * La``.
    diffuse : (k, 3) float32
        ``Md * Ld * max(0, n . l)``.
    specular : (k, 3) float32
        ``Ms * Ls * max(0, r . v) ** shininess`` where ``n . l > 0``.
    """
    dt = np.float32
    cam = per_point(np.asarray(camera_position, np.float64), batch_idx, dt)
    shin = per_point(materials.shininess, batch_idx, dt)
    diffuse = lights.diffuse(normals, points, batch_idx)
    specular = lights.specular(normals, points, cam, shin, batch_idx)
    if visibility is not None:
        diffuse = diffuse * visibility[:, None]
        specular = specular * visibility[:, None]
    ambient = (per_point(materials.ambient_color, batch_idx, dt)
               * per_point(lights.ambient_color, batch_idx, dt))
    diffuse = per_point(materials.diffuse_color, batch_idx, dt) * diffuse
    specular = per_point(materials.specular_color, batch_idx, dt) * specular
    return ambient, diffuse.astype(dt, copy=False), specular.astype(dt, copy=False)


def _view_or_none(fragments: Fragments, *objs) -> np.ndarray | None:
    """Batch index per hit, or None when every object holds a single entry."""
    if all(len(o) == 1 for o in objs):
        return None
    return fragments.view


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
        :mod:`geofit.render.textures`), per-vertex colours interpolated, flat colours copied.

    Raises
    ------
    ValueError
        If the meshes of the batch have textures with different numbers of channels.
    """
    meshes = fragments.meshes
    first = fragments._ctx["face_first"]
    groups: dict[int, list[int]] = {}
    for b, m in enumerate(meshes):  # loop over views: group by shared textures and faces
        groups.setdefault(id(m), []).append(b)
    if len(groups) == 1:
        m = meshes[0]
        local = fragments.face - first[fragments.view]
        return sample_texels(m.textures, m.faces, local, fragments.bary, default)
    out = None
    for views in groups.values():  # loop over distinct meshes
        sel = np.flatnonzero(np.isin(fragments.view, views))
        m = meshes[views[0]]
        local = fragments.face[sel] - first[fragments.view[sel]]
        t = sample_texels(m.textures, m.faces, local, fragments.bary[sel], default)
        if out is None:
            out = np.zeros((fragments.n_hits, t.shape[1]), np.float32)
        elif t.shape[1] != out.shape[1]:
            raise ValueError(f"textures: every mesh of the batch needs the same number of "
                             f"channels, got {out.shape[1]} and {t.shape[1]}")
        out[sel] = t
    if out is None:
        out = np.zeros((0, len(default)), np.float32)
    return out


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
        points, interpolated normals and face normals; flat shading passes face centroids).

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
    ng = fragments.hit_face_normals if face_normals is None else face_normals
    bidx = None if len(lights) == 1 else fragments.view
    l, dist = lights.light_vector(p, bidx)
    l = np.broadcast_to(l, p.shape)
    side = np.sign(np.einsum("ki,ki->k", ng, l))
    need = (np.einsum("ki,ki->k", n, l) > 0) & (side != 0) & (dist > 0)
    view_scene = fragments._ctx["view_scene"]
    n_threads = fragments._ctx["n_threads"]
    scenes = {}
    for b, sc in enumerate(view_scene):  # loop over views
        if sc is not None:
            scenes.setdefault(id(sc), (sc, []))[1].append(b)
    for sc, views in scenes.values():  # loop over distinct meshes
        sel = np.flatnonzero(need & np.isin(fragments.view, views))
        if len(sel) == 0:
            continue
        o = p[sel] + (1e-4 * sc.scale) * side[sel, None] * ng[sel]
        if isinstance(lights, PointLights):
            loc = per_point(lights.location, None if bidx is None else bidx[sel], np.float64)
            d = loc - o
            tfar = np.full(len(sel), 1.0)
        else:
            d = np.array(l[sel])
            tfar = np.full(len(sel), np.inf)
        on = ((o - sc.center) / sc.scale).astype(np.float32)
        dn = (d / sc.scale).astype(np.float32)
        ok = np.einsum("ki,ki->k", dn, dn) > 0
        tf = np.minimum(tfar, 1e30).astype(np.float32)
        chunks = np.array_split(np.arange(len(sel)), max(1, min(4 * n_threads, len(sel) // 50_000 + 1)))

        def run(c):
            return sc.occluded(np.ascontiguousarray(on[c]), np.ascontiguousarray(dn[c]),
                               np.ascontiguousarray(tf[c]))

        if len(chunks) > 1 and n_threads > 1:
            with ThreadPoolExecutor(n_threads) as ex:
                occ = np.concatenate(list(ex.map(run, chunks)))
        else:
            occ = run(chunks[0])
        vis[sel[occ & ok]] = 0.0
    return vis


def phong_shading(fragments: Fragments, lights, cameras, materials, texels,
                  visibility=None) -> np.ndarray:
    """Per-pixel Phong colour of every covered pixel (PyTorch3D's ``phong_shading``).

    Parameters
    ----------
    fragments : Fragments
    lights, cameras, materials
        Batches of 1 or N.
    texels : (k, 3) float32
        Texture colour of every covered pixel (:func:`sample_textures`).
    visibility : (k,) float32, optional
        Shadow factor (:func:`shadow_visibility`).

    Returns
    -------
    colors : (k, 3) float32
    """
    pts = fragments.hit_points.astype(np.float32)
    nrm = fragments.hit_normals.astype(np.float32)
    centers = _camera_centers(cameras, fragments.n_views)
    bidx = _view_or_none(fragments, lights, materials, centers)
    amb, dif, spe = apply_lighting(pts, nrm, lights, centers, materials, bidx, visibility)
    return (amb + dif) * texels + spe


def flat_shading(fragments: Fragments, lights, cameras, materials, texels,
                 visibility=None) -> np.ndarray:
    """Per-face lighting (face centroid and face normal), PyTorch3D's ``flat_shading``.

    Parameters and returns as :func:`phong_shading`.
    """
    ctx = fragments._ctx
    tri = fragments._tri
    pts = ctx["verts_packed"][tri].mean(axis=1).astype(np.float32)
    nrm = fragments.hit_face_normals.astype(np.float32)
    centers = _camera_centers(cameras, fragments.n_views)
    bidx = _view_or_none(fragments, lights, materials, centers)
    amb, dif, spe = apply_lighting(pts, nrm, lights, centers, materials, bidx, visibility)
    return (amb + dif) * texels + spe


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
    from ..structures import TexturesVertex

    meshes = fragments.meshes
    for i, m in enumerate(meshes):  # loop over views
        if not isinstance(m.textures, TexturesVertex):
            raise ValueError(f"meshes[{i}]: Gouraud shading needs TexturesVertex (per-vertex "
                             f"colours), got {type(m.textures).__name__}")
    ctx = fragments._ctx
    verts = ctx["verts_packed"].astype(np.float32)
    nrm = ctx["verts_normals_packed"].astype(np.float32)
    colors = np.concatenate([m.textures.verts_features for m in meshes]).astype(np.float32)
    vidx = meshes.verts_packed_to_mesh_idx()
    centers = _camera_centers(cameras, fragments.n_views)
    bidx = None if (len(lights) == 1 and len(materials) == 1 and len(centers) == 1) else vidx
    amb, dif, spe = apply_lighting(verts, nrm, lights, centers, materials, bidx)
    shaded = colors * (amb + dif) + spe
    tri = fragments._tri
    return np.einsum("kj,kjc->kc", fragments.bary.astype(np.float32), shaded[tri])


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
            raise ValueError(f"shadows: expected True or False, got {shadows!r}")
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
        blend = kwargs.get("blend_params", self.blend_params)
        return cameras, lights, materials, blend

    def _blend(self, colors, fragments, cameras, blend):
        if self._soft:
            znear = getattr(cameras, "znear", 1.0)
            zfar = getattr(cameras, "zfar", 100.0)
            return softmax_rgb_blend(colors, fragments, blend, znear, zfar, clip=self.clip)
        return hard_rgb_blend(colors, fragments, blend, clip=self.clip)

    def _colors(self, fragments, cameras, lights, materials):  # pragma: no cover - abstract
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
        cameras, lights, materials, blend = self._setup(fragments, kwargs)
        colors = self._colors(fragments, cameras, lights, materials)
        return self._blend(colors, fragments, cameras, blend)


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

    def _colors(self, fragments, cameras, lights, materials):
        texels = sample_textures(fragments)
        vis = shadow_visibility(fragments, lights) if self.shadows else None
        return phong_shading(fragments, lights, cameras, materials, texels, vis)


class SoftPhongShader(HardPhongShader):
    """Per-pixel Phong shading with PyTorch3D's soft blending (``softmax_rgb_blend``, K = 1).

    RGB equals HardPhongShader's on covered pixels; alpha is ``sigmoid(-dists / sigma)``, the
    soft coverage of the kept face (0.5 to 1 inside it). Parameters as :class:`HardPhongShader`.
    """

    _soft = True


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

    def _colors(self, fragments, cameras, lights, materials):
        return gouraud_shading(fragments, lights, cameras, materials)


class SoftGouraudShader(HardGouraudShader):
    """Gouraud shading with PyTorch3D's soft blending (see :class:`SoftPhongShader`)."""

    _soft = True


class HardFlatShader(_Shader):
    """Flat shading (one lighting value per face, at its centroid), hard blending.

    Parameters as :class:`HardPhongShader`.
    """

    def _colors(self, fragments, cameras, lights, materials):
        texels = sample_textures(fragments)
        vis = None
        if self.shadows:  # shadow rays from the hit points, lit side given by the face normal
            fn = fragments.hit_face_normals
            vis = shadow_visibility(fragments, lights, normals=fn, face_normals=fn)
        return flat_shading(fragments, lights, cameras, materials, texels, vis)
