"""The volume and NeRF tutorials' renderers (forward passes, values only).

The tutorials' training loops differentiate through ``torch.nn`` modules (``VolumeModel``,
``NeuralRadianceField``) that this layer does not emulate; geofit fits them with its own
analytic backward passes (:func:`geofit.fit.fit_volume`, :func:`geofit.fit.fit_nerf`). The
renderers here produce the tutorials' images from a ``Volumes`` batch or a volumetric function.
"""
from __future__ import annotations

import numpy as np

from .._common import drop_device, np_
from ..structures import Volumes
from ..tensor import Tensor

__all__ = ["EmissionAbsorptionRaymarcher", "HarmonicEmbedding", "ImplicitRenderer",
           "MonteCarloRaysampler", "NDCMultinomialRaysampler", "RayBundle", "VolumeRenderer",
           "ray_bundle_to_ray_points"]

from ...render import EmissionAbsorptionRaymarcher as _EA
from ...render import HarmonicEmbedding as _HE
from ...render import MonteCarloRaysampler as _MC
from ...render import NDCMultinomialRaysampler as _NDC
from ...render import RayBundle
from ...render import VolumeRenderer as _VR
from ...render import ray_bundle_to_ray_points as _points

NDCMultinomialRaysampler = drop_device(_NDC)
MonteCarloRaysampler = drop_device(_MC)
EmissionAbsorptionRaymarcher = drop_device(_EA)
HarmonicEmbedding = drop_device(_HE)


def ray_bundle_to_ray_points(ray_bundle) -> Tensor:
    """(B, ..., n_pts, 3) sample points ``origins + lengths * directions``."""
    return Tensor(_points(ray_bundle))


class VolumeRenderer:
    """Render a ``Volumes`` batch (PyTorch3D's ``VolumeRenderer``): ``images, ray_bundle``.

    Parameters
    ----------
    raysampler : NDCMultinomialRaysampler or MonteCarloRaysampler
    raymarcher : EmissionAbsorptionRaymarcher
    sample_mode : {"bilinear", "nearest"}
    """

    def __init__(self, raysampler, raymarcher, sample_mode: str = "bilinear"):
        self._r = _VR(raysampler, raymarcher, sample_mode)
        self.raysampler = raysampler
        self.raymarcher = raymarcher

    def __call__(self, cameras, volumes: Volumes, **kwargs):
        """Camera ``i`` renders volume ``i`` (or the single volume); images (B, ..., C + 1).

        Recorded on the tape (geofit's :meth:`geofit.render.volume.VolumeRenderer.vjp`) when
        the densities or features require a gradient.
        """
        if not isinstance(volumes, Volumes):
            raise TypeError(f"volumes: expected geofit.pytorch3d.structures.Volumes, got "
                            f"{type(volumes)!r}")
        bundle = self.raysampler(cameras, **kwargs)
        n, B = len(volumes), len(cameras)
        if n not in (1, B):
            raise ValueError(f"volumes: expected 1 or {B} volumes, got {n}")
        if len(volumes._vols) == 1:
            groups = [(0, slice(0, B), bundle)]
        else:
            groups = [(i, slice(i, i + 1), RayBundle(*(np_(a)[i:i + 1] for a in bundle)))
                      for i in range(n)]
        images = np.concatenate([self._r.render_rays(volumes._vols[i], b)
                                 for i, _, b in groups])  # loop over distinct volumes
        parents = [t for t in (volumes._densities, volumes._features) if t is not None]
        shared = len(volumes._vols) == 1 and n > 1

        def vjp(g):
            gd = np.zeros(volumes._densities.shape[1:] if shared else volumes._densities.shape)
            gf = None
            if volumes._features is not None:
                gf = np.zeros(volumes._features.shape[1:] if shared
                              else volumes._features.shape)
            for i, sl, b in groups:  # loop over distinct volumes
                r = self._r.vjp(g[sl], volumes._vols[i], b)
                tgt = slice(None) if shared else i
                gd[tgt][0] += r.densities
                if gf is not None:
                    gf[tgt] += r.features
            if shared:  # one volume expanded n times: its gradient, spread without a copy
                gd = np.broadcast_to(gd / n, volumes._densities.shape)
                gf = None if gf is None else np.broadcast_to(gf / n, volumes._features.shape)
            return (gd, gf)[:len(parents)]

        return Tensor._record(images, parents, vjp), bundle

    def to(self, *args, **kwargs):
        return self


class ImplicitRenderer:
    """Render a volumetric function (PyTorch3D's ``ImplicitRenderer``): ``images, ray_bundle``.

    ``volumetric_function(ray_bundle=..., cameras=..., **kwargs)`` returns ``(densities
    (..., n_pts, 1), features (..., n_pts, C))``, arrays or tensors; the raymarcher composites
    them. When they are tensors that require a gradient (a field built from
    :mod:`geofit.pytorch3d.nn` layers and tape arithmetic), the images record the raymarcher's
    analytic vjp to them, so ``loss.backward()`` reaches the field's parameters.
    """

    def __init__(self, raysampler, raymarcher):
        self.raysampler = raysampler
        self.raymarcher = raymarcher

    def __call__(self, cameras, volumetric_function, **kwargs):
        sampler_kw = {k: kwargs.pop(k) for k in ("seed", "n_rays_per_image", "mask")
                      if k in kwargs}
        bundle = self.raysampler(cameras, **sampler_kw)
        densities, features = volumetric_function(ray_bundle=bundle, cameras=cameras, **kwargs)
        d = densities if isinstance(densities, Tensor) else Tensor(np_(densities))
        f = features if isinstance(features, Tensor) else Tensor(np_(features))
        images = self.raymarcher(d.data, f.data)

        def vjp(g):
            r = self.raymarcher.vjp(g, d.data, f.data)
            return r.densities, r.features

        return Tensor._record(images, [d, f], vjp), bundle

    def to(self, *args, **kwargs):
        return self
