"""PyTorch3D's ``pytorch3d.renderer``: cameras, lights, materials, textures, mesh and point
renderers, and the volume / implicit renderers of the volume and NeRF tutorials.

Two mesh paths behind one ``MeshRenderer``:

- **hard** (``blur_radius=0``, ``faces_per_pixel=1``, nothing to differentiate): geofit's Embree
  renderer (:class:`geofit.render.MeshRenderer`), PyTorch3D's images for any shader and
  ``TexturesUV``/``TexturesVertex``;
- **soft** (``SoftSilhouetteShader``, or ``SoftPhongShader`` with a blur radius, several faces
  per pixel, or vertices/colours that require a gradient): geofit's soft rasterizer and blends
  (:mod:`geofit.render.soft`); the images are recorded on the tape with the renderer's analytic
  vjp to the vertex positions (and to ``TexturesVertex`` colours).
"""
from __future__ import annotations

from .._common import missing_names
from ..textures import TexturesUV, TexturesVertex
from .cameras import (
    FoVOrthographicCameras,
    FoVPerspectiveCameras,
    OpenGLOrthographicCameras,
    OpenGLPerspectiveCameras,
    camera_position_from_spherical_angles,
    look_at_rotation,
    look_at_view_transform,
)
from .implicit import (
    EmissionAbsorptionRaymarcher,
    HarmonicEmbedding,
    ImplicitRenderer,
    MonteCarloRaysampler,
    NDCMultinomialRaysampler,
    RayBundle,
    VolumeRenderer,
    ray_bundle_to_ray_points,
)
from .mesh import (
    AmbientLights,
    BlendParams,
    DirectionalLights,
    HardFlatShader,
    HardGouraudShader,
    HardPhongShader,
    Materials,
    MeshRasterizer,
    MeshRenderer,
    MeshRendererWithFragments,
    PointLights,
    RasterizationSettings,
    SoftGouraudShader,
    SoftPhongShader,
    SoftSilhouetteShader,
)
from .points import (
    AlphaCompositor,
    NormWeightedCompositor,
    PointsRasterizationSettings,
    PointsRasterizer,
    PointsRenderer,
)

#: PyTorch3D's older name of NDCMultinomialRaysampler (the volume and NeRF tutorials use it).
NDCGridRaysampler = NDCMultinomialRaysampler

__all__ = [
    "AlphaCompositor",
    "AmbientLights",
    "BlendParams",
    "DirectionalLights",
    "EmissionAbsorptionRaymarcher",
    "FoVOrthographicCameras",
    "FoVPerspectiveCameras",
    "HardFlatShader",
    "HardGouraudShader",
    "HardPhongShader",
    "HarmonicEmbedding",
    "ImplicitRenderer",
    "Materials",
    "MeshRasterizer",
    "MeshRenderer",
    "MeshRendererWithFragments",
    "MonteCarloRaysampler",
    "NDCGridRaysampler",
    "NDCMultinomialRaysampler",
    "NormWeightedCompositor",
    "OpenGLOrthographicCameras",
    "OpenGLPerspectiveCameras",
    "PointLights",
    "PointsRasterizationSettings",
    "PointsRasterizer",
    "PointsRenderer",
    "RasterizationSettings",
    "RayBundle",
    "SoftGouraudShader",
    "SoftPhongShader",
    "SoftSilhouetteShader",
    "TexturesUV",
    "TexturesVertex",
    "VolumeRenderer",
    "camera_position_from_spherical_angles",
    "look_at_rotation",
    "look_at_view_transform",
    "ray_bundle_to_ray_points",
]

__getattr__ = missing_names("geofit.pytorch3d.renderer", {
    "PulsarPointsRenderer": "pulsar (sphere-based differentiable point rendering) has no geofit "
                            "counterpart; use PointsRenderer with AlphaCompositor or "
                            "NormWeightedCompositor (PyTorch3D's default point renderer)",
    "PerspectiveCameras": "use FoVPerspectiveCameras, or geofit.cameras_from_opencv_projection "
                          "for pixel intrinsics",
    "OrthographicCameras": "use FoVOrthographicCameras",
    "SfMPerspectiveCameras": "use FoVPerspectiveCameras or geofit.cameras_from_opencv_projection",
    "TexturesAtlas": "use TexturesUV, or geofit.render.TexturesFlat for one colour per face",
    "MultinomialRaysampler": "use NDCMultinomialRaysampler (the tutorials' grid raysampler)",
    "GridRaysampler": "use NDCMultinomialRaysampler",
    "AbsorptionOnlyRaymarcher": "use EmissionAbsorptionRaymarcher",
    "VolumeSampler": "geofit.structures.Volume.sample(points) samples a volume trilinearly",
    "rasterize_meshes": "use MeshRasterizer(cameras, raster_settings)(meshes)",
    "rasterize_points": "use PointsRasterizer(cameras, raster_settings)(point_clouds)",
})
