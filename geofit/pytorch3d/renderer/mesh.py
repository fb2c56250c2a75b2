"""PyTorch3D's mesh rendering API over geofit's hard (Embree) and soft renderers."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ... import render as _gr
from ..._validate import as_instance, check_int
from ...render import soft as _soft
from ...render.mesh.rasterizer import RasterizationFields
from .._common import drop_device
from ..structures import Meshes
from ..tensor import Tensor, _tracks
from ..textures import TexturesVertex

__all__ = ["AmbientLights", "BlendParams", "DirectionalLights", "HardFlatShader",
           "HardGouraudShader", "HardPhongShader", "Materials", "MeshRasterizer", "MeshRenderer",
           "MeshRendererWithFragments", "PointLights", "RasterizationSettings",
           "SoftGouraudShader", "SoftPhongShader", "SoftSilhouetteShader"]

PointLights = drop_device(_gr.PointLights)
DirectionalLights = drop_device(_gr.DirectionalLights)
AmbientLights = drop_device(_gr.AmbientLights)
Materials = drop_device(_gr.Materials)
BlendParams = _gr.BlendParams
HardPhongShader = drop_device(_gr.HardPhongShader)
SoftPhongShader = drop_device(_gr.SoftPhongShader)
HardGouraudShader = drop_device(_gr.HardGouraudShader)
SoftGouraudShader = drop_device(_gr.SoftGouraudShader)
HardFlatShader = drop_device(_gr.HardFlatShader)


class SoftSilhouetteShader(_soft.SoftSilhouetteShader):
    """``A = 1 - prod_k (1 - sigmoid(-d_k / sigma))`` (PyTorch3D's ``SoftSilhouetteShader``).

    Parameters
    ----------
    blend_params : BlendParams, optional
        ``sigma`` (default 1e-4).
    """

    def __init__(self, blend_params: BlendParams | None = None, device=None):
        super().__init__(blend_params)
        self.blend_params = blend_params if blend_params is not None else BlendParams()

    def to(self, *args, **kwargs):
        return self


@dataclass(frozen=True)
class RasterizationSettings(RasterizationFields):
    """PyTorch3D's ``RasterizationSettings`` (every field; see :mod:`geofit.render.soft` for the
    meaning of ``blur_radius``, squared NDC units).

    ``bin_size``, ``max_faces_per_bin`` and ``cull_to_frustum`` are accepted and ignored (no
    bins; off-screen faces never cover a pixel).
    """

    def __post_init__(self):  # checked at construction (types, sizes, memory estimate)
        if self._is_soft():
            self._soft()
        else:
            self._hard()

    def _is_soft(self) -> bool:
        check_int(self.faces_per_pixel, "faces_per_pixel", error=TypeError)
        return float(self.blur_radius) > 0.0 or int(self.faces_per_pixel) > 1

    def _hard(self) -> _gr.RasterizationSettings:
        return _gr.RasterizationSettings(
            image_size=self.image_size, perspective_correct=self.perspective_correct,
            cull_backfaces=self.cull_backfaces, z_clip_value=self.z_clip_value)

    def _soft(self) -> _soft.SoftRasterizationSettings:
        return _soft.SoftRasterizationSettings(
            image_size=self.image_size, blur_radius=float(self.blur_radius),
            faces_per_pixel=int(self.faces_per_pixel),
            perspective_correct=self.perspective_correct,
            clip_barycentric_coords=self.clip_barycentric_coords,
            cull_backfaces=self.cull_backfaces, z_clip_value=self.z_clip_value,
            dtype=np.float64)  # the tape's tensors are float64: store the render in float64


def _settings(s) -> RasterizationSettings:
    return as_instance(s, RasterizationSettings, "raster_settings",
                       "geofit.pytorch3d.renderer.RasterizationSettings")


def _meshes(meshes) -> Meshes:
    if not isinstance(meshes, Meshes):
        raise TypeError(f"meshes_world: expected geofit.pytorch3d.structures.Meshes, got "
                        f"{type(meshes)!r}")
    return meshes


class MeshRasterizer:
    """Meshes to fragments (PyTorch3D's ``MeshRasterizer``).

    Returns geofit's hard :class:`geofit.render.Fragments` for ``blur_radius=0`` and
    ``faces_per_pixel=1``, else the soft rasterizer's :class:`geofit.render.soft.SoftFragments`
    (both with ``pix_to_face``, ``zbuf``, ``bary_coords``, ``dists`` as (N, H, W, K) arrays).
    """

    def __init__(self, cameras=None, raster_settings: RasterizationSettings | None = None):
        self.cameras = cameras
        self.raster_settings = _settings(raster_settings)

    def to(self, *args, **kwargs):
        return self

    def __call__(self, meshes_world, **kwargs):
        m = _meshes(meshes_world)
        cams = kwargs.get("cameras", self.cameras)
        s = _settings(kwargs.get("raster_settings", self.raster_settings))
        if s._is_soft():
            gm = m._geofit()
            if len(gm) != 1:
                raise ValueError("meshes_world: the soft rasterizer takes one mesh (with N "
                                 "cameras) at a time")
            return _soft.rasterize_soft(gm[0], cams, s._soft())
        return _gr.MeshRasterizer(cams, s._hard())(
            _gr_meshes(m), **{k: v for k, v in kwargs.items() if k == "cameras"})


def _gr_meshes(m: Meshes):
    from ... import structures as _gs

    return _gs.Meshes(m._geofit(textures=True))


def _groups(m: Meshes, cams):
    """(member index, cameras) pairs: one mesh with all cameras, or mesh i with camera i."""
    N, C = len(m), len(cams)
    if N == 1:
        return [(0, cams)]
    if C == N:
        return [(i, cams[i]) for i in range(N)]
    if C == 1:
        return [(i, cams) for i in range(N)]
    raise ValueError(f"cameras: expected 1 or {N} cameras for {N} meshes, got {C}")


def _copies_of_one(m: Meshes) -> bool:
    """True when every member is the same mesh at the same positions (``mesh.extend(N)``)."""
    b0 = m._base[0]
    if any(b is not b0 for b in m._base):
        return False
    v = m.verts_packed().data.reshape(len(m), -1, 3)
    return bool(np.all(v == v[:1]))


def _soft_render(m: Meshes, cams, render_one, extra_parents=()):
    """Render every (mesh, cameras) group with ``render_one(i, cams) -> SoftRender`` and record
    the concatenated images with the renderers' vjps."""
    parents = (m.verts_packed(),) + tuple(extra_parents)
    track = _tracks(*parents)
    if not track and len(m) > 1 and len(cams) == len(m) and _copies_of_one(m):
        groups = [(0, cams)]  # one mesh, all views in one threaded call
    else:
        groups = _groups(m, cams)
    outs = [render_one(i, c) for i, c in groups]  # loop over batch members
    images = np.concatenate([o.images for o in outs])
    if not track:
        return Tensor(images)
    sizes = np.cumsum([len(o.images) for o in outs])[:-1]
    starts = m._vstarts()
    counts = m._counts

    def vjp(g):
        gv = np.zeros(m.verts_packed().shape)
        gcols = [None] * len(extra_parents)
        for (i, _), o, gi in zip(groups, outs, np.split(g, sizes)):  # loop over batch members
            r = o.vjp(gi)
            gv[starts[i]:starts[i] + counts[i]] += r.verts
            if extra_parents and r.colors is not None:
                gcols[i] = r.colors if gcols[i] is None else gcols[i] + r.colors
        return (gv, *gcols)

    return Tensor._record(images, parents, vjp)


class MeshRenderer:
    """Rasterizer plus shader: ``images = renderer(meshes, **kwargs)`` (PyTorch3D's class).

    Parameters
    ----------
    rasterizer : MeshRasterizer
    shader : SoftSilhouetteShader, SoftPhongShader, HardPhongShader, ... (this module's)

    Notes
    -----
    ``cameras=``, ``lights=``, ``materials=``, ``blend_params=`` and ``raster_settings=`` in the
    call override the stored ones for that call. The result is an (N, H, W, 4) Tensor; soft
    renders (see the module notes) are recorded on the tape. A batch of N meshes is rendered
    with N cameras (mesh i by camera i) or one camera; one mesh with N cameras gives N images.

    Raises
    ------
    NotImplementedError
        For a soft render that geofit does not differentiate: a shader other than
        ``SoftSilhouetteShader`` / ``SoftPhongShader``, or ``SoftPhongShader`` on ``TexturesUV``
        with a blur radius or several faces per pixel.
    """

    def __init__(self, rasterizer: MeshRasterizer, shader):
        if not isinstance(rasterizer, MeshRasterizer):
            raise TypeError(f"rasterizer: expected geofit.pytorch3d.renderer.MeshRasterizer, got "
                            f"{type(rasterizer)!r}")
        self.rasterizer = rasterizer
        self.shader = shader

    def to(self, *args, **kwargs):
        return self

    def __call__(self, meshes_world, **kwargs) -> Tensor:
        m = _meshes(meshes_world)
        cams = kwargs.get("cameras", self.rasterizer.cameras)
        if cams is None:
            raise ValueError("cameras: give cameras to the MeshRasterizer or to this call")
        s = _settings(kwargs.get("raster_settings", self.rasterizer.raster_settings))
        shader = self.shader
        bp = kwargs.get("blend_params", getattr(shader, "blend_params", None)) or BlendParams()
        if isinstance(shader, SoftSilhouetteShader):
            r = _soft.SoftSilhouetteRenderer(cams, s._soft(), bp)
            gm = m._geofit()
            return _soft_render(m, cams, lambda i, c: r(gm[i], c))
        tex = m.textures
        feats = tex.verts_features_list() if isinstance(tex, TexturesVertex) else []
        wants_grad = _tracks(m.verts_packed(), *feats)
        if isinstance(shader, _gr.SoftPhongShader) and (s._is_soft() or wants_grad):
            return self._soft_phong(m, cams, s, shader, bp, tex, feats, kwargs)
        if s._is_soft() or wants_grad:
            raise NotImplementedError(
                f"{type(shader).__name__}: geofit's differentiable (soft) renderer has "
                f"SoftSilhouetteShader and SoftPhongShader with TexturesVertex; for "
                f"{'a blur radius or several faces per pixel' if s._is_soft() else 'gradients'}"
                f" use one of them (hard renders: blur_radius=0, faces_per_pixel=1, no "
                f"gradient)")
        r = _gr.MeshRenderer(_gr.MeshRasterizer(cams, s._hard()), shader)
        kw = {k: v for k, v in kwargs.items()
              if k in ("cameras", "lights", "materials", "blend_params")}
        return Tensor(np.asarray(r(_gr_meshes(m), **kw), np.float64))

    def _soft_phong(self, m, cams, s, shader, bp, tex, feats, kwargs):
        if not isinstance(tex, TexturesVertex):
            raise NotImplementedError(
                "SoftPhongShader: geofit's soft (differentiable) Phong renderer shades "
                "TexturesVertex colours; for TexturesUV render with blur_radius=0 and "
                "faces_per_pixel=1 (the hard renderer), or sample the texture at the vertices "
                "into a TexturesVertex")
        r = _soft.SoftPhongRenderer(cams, kwargs.get("lights", shader.lights),
                                    kwargs.get("materials", shader.materials), s._soft(), bp)
        gm = m._geofit()
        return _soft_render(m, cams, lambda i, c: r(gm[i], feats[i].data, c), feats)


class MeshRendererWithFragments(MeshRenderer):
    """A MeshRenderer that also returns the fragments: ``images, fragments = renderer(mesh)``
    (values only: the images are not recorded on the tape)."""

    def __call__(self, meshes_world, **kwargs):
        images = super().__call__(meshes_world, **kwargs)
        return images.detach(), self.rasterizer(meshes_world, **kwargs)
