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

try:  # geofit.render exports every renderer
    from ...render import EmissionAbsorptionRaymarcher as _EA
    from ...render import HarmonicEmbedding as _HE
    from ...render import MonteCarloRaysampler as _MC
    from ...render import NDCMultinomialRaysampler as _NDC
    from ...render import RayBundle
    from ...render import VolumeRenderer as _VR
    from ...render import ray_bundle_to_ray_points as _points
except ImportError:  # geofit 0.1's flat module layout
    from ...render.harmonic import HarmonicEmbedding as _HE
    from ...render.raymarching import EmissionAbsorptionRaymarcher as _EA
    from ...render.raysampling import MonteCarloRaysampler as _MC
    from ...render.raysampling import NDCMultinomialRaysampler as _NDC
    from ...render.raysampling import RayBundle
    from ...render.raysampling import ray_bundle_to_ray_points as _points
    from ...render.volume import VolumeRenderer as _VR

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
        """Camera ``i`` renders volume ``i`` (or the single volume); images (B, ..., C + 1)."""
        if not isinstance(volumes, Volumes):
            raise TypeError(f"volumes: expected geofit.pytorch3d.structures.Volumes, got "
                            f"{type(volumes)!r}")
        bundle = self.raysampler(cameras, **kwargs)
        n = len(volumes)
        if n == 1:
            return Tensor(self._r.render_rays(volumes._vols[0], bundle)), bundle
        if n != len(cameras):
            raise ValueError(f"volumes: expected 1 or {len(cameras)} volumes, got {n}")
        parts = [self._r.render_rays(v, RayBundle(*(np_(a)[i:i + 1] for a in bundle)))
                 for i, v in enumerate(volumes._vols)]  # loop over batch members
        return Tensor(np.concatenate(parts)), bundle

    def to(self, *args, **kwargs):
        return self


class ImplicitRenderer:
    """Render a volumetric function (PyTorch3D's ``ImplicitRenderer``): ``images, ray_bundle``.

    ``volumetric_function(ray_bundle=..., cameras=..., **kwargs)`` returns ``(densities
    (..., n_pts, 1), features (..., n_pts, C))``; the raymarcher composites them.
    """

    def __init__(self, raysampler, raymarcher):
        self.raysampler = raysampler
        self.raymarcher = raymarcher

    def __call__(self, cameras, volumetric_function, **kwargs):
        sampler_kw = {k: kwargs.pop(k) for k in ("seed", "n_rays_per_image", "mask")
                      if k in kwargs}
        bundle = self.raysampler(cameras, **sampler_kw)
        densities, features = volumetric_function(ray_bundle=bundle, cameras=cameras, **kwargs)
        return Tensor(self.raymarcher(np_(densities), np_(features))), bundle

    def to(self, *args, **kwargs):
        return self
