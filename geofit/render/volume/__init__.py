"""Volumes and implicit functions: PyTorch3D's ``renderer/implicit`` in numpy, with backward.

- :mod:`.raysampling`: :class:`NDCMultinomialRaysampler`, :class:`MonteCarloRaysampler`,
  :class:`RayBundle`, :func:`ray_bundle_to_ray_points`.
- :mod:`.raymarching`: :class:`EmissionAbsorptionRaymarcher`,
  :class:`AbsorptionOnlyRaymarcher` (each with its vector-Jacobian product).
- :mod:`.renderer`: :class:`VolumeRenderer` (a voxel grid, trilinear sampling);
  :mod:`.skipping`: its empty-space skipping (sample ranges and their sparse operator), shared
  with geofit's volume fit.
- :mod:`.implicit`: :class:`ImplicitRenderer`, :class:`OccupancyGrid`;
  :mod:`.radiance_field`: :class:`NeuralRadianceField` (the NeRF tutorial's network).
- :mod:`.harmonic`: :class:`HarmonicEmbedding` (and the tutorial's variant).
"""
from .harmonic import HALF_PI_F32, HarmonicEmbedding, TutorialHarmonicEmbedding
from .implicit import ImplicitRenderer, OccupancyGrid, RenderCache
from .radiance_field import ACTIVATIONS, NeuralRadianceField
from .raymarching import (
    AbsorptionOnlyRaymarcher,
    EmissionAbsorptionRaymarcher,
    RaymarchGradients,
    sample_deltas,
)
from .raysampling import (
    MonteCarloRaysampler,
    NDCMultinomialRaysampler,
    RayBundle,
    ray_bundle_to_ray_points,
)
from .renderer import VolumeGradients, VolumeRenderer

__all__ = [
    "ACTIVATIONS",
    "AbsorptionOnlyRaymarcher",
    "EmissionAbsorptionRaymarcher",
    "HALF_PI_F32",
    "HarmonicEmbedding",
    "ImplicitRenderer",
    "MonteCarloRaysampler",
    "NDCMultinomialRaysampler",
    "NeuralRadianceField",
    "OccupancyGrid",
    "RayBundle",
    "RaymarchGradients",
    "RenderCache",
    "TutorialHarmonicEmbedding",
    "VolumeGradients",
    "VolumeRenderer",
    "ray_bundle_to_ray_points",
    "sample_deltas",
]
