"""geofit: fit and render 3D geometry on the CPU in plain numpy.

The six workflows of PyTorch3D's introductory tutorials, without PyTorch, built on Embree ray
casting, exact KD-tree searches (Open3D's and scipy's) and scipy.sparse operators with analytic
gradients.
"""
from __future__ import annotations

from . import data, fit, io, metrics, render
from ._threads import get_num_threads, set_num_threads
from .cameras import (
    CamerasBase,
    FoVOrthographicCameras,
    FoVPerspectiveCameras,
    PerspectiveCameras,
    Rays,
    camera_position_from_spherical_angles,
    cameras_from_colmap,
    cameras_from_opencv_projection,
    cameras_from_opengl,
    colmap_from_cameras,
    look_at_rotation,
    look_at_view_transform,
    ndc_grid,
    opencv_from_cameras_projection,
    opengl_from_cameras,
)
from .fit import fit_mesh, fit_mesh_to_views, fit_nerf, fit_volume
from .io import (
    load_mesh,
    load_obj,
    load_objs_as_meshes,
    load_pointcloud,
    save_mesh,
    save_obj,
    save_pointcloud,
)
from .loss import (
    ChamferResult,
    ChamferTarget,
    PointToSurface,
    chamfer_distance,
    mesh_edge_loss,
    mesh_laplacian_smoothing,
    mesh_normal_consistency,
)
from .ops import (
    SampledPoints,
    cot_laplacian,
    norm_laplacian,
    sample_points_from_meshes,
    sample_points_with_jacobian,
    uniform_laplacian,
)
from .raycast import (
    ClosestPoints,
    PointToMeshDistance,
    RayCaster,
    RayHits,
    closest_point_on_triangles,
    intersect_rays_triangles,
)
from .render import (
    AlphaCompositor,
    AmbientLights,
    BlendParams,
    DirectionalLights,
    Fragments,
    HardFlatShader,
    HardGouraudShader,
    HardPhongShader,
    Materials,
    MeshRasterizer,
    MeshRenderer,
    MeshRendererWithFragments,
    NormWeightedCompositor,
    PointLights,
    PointsRasterizationSettings,
    PointsRasterizer,
    PointsRenderer,
    RasterizationSettings,
    SoftGouraudShader,
    SoftPhongShader,
    TexturesFlat,
    image_grid,
)
from .shapes import box, ico_sphere, plane, subdivide, tetrahedron, torus
from .structures import (
    Mesh,
    Meshes,
    Normalization,
    PointCloud,
    Pointclouds,
    TexturesUV,
    TexturesVertex,
    Topology,
)

__version__ = "0.2.0"

__all__ = [
    "__version__",
    # threads
    "get_num_threads",
    "set_num_threads",
    # structures
    "Mesh",
    "Meshes",
    "Normalization",
    "PointCloud",
    "Pointclouds",
    "TexturesUV",
    "TexturesVertex",
    "Topology",
    # cameras
    "CamerasBase",
    "FoVOrthographicCameras",
    "FoVPerspectiveCameras",
    "PerspectiveCameras",
    "Rays",
    "camera_position_from_spherical_angles",
    "cameras_from_colmap",
    "cameras_from_opencv_projection",
    "cameras_from_opengl",
    "colmap_from_cameras",
    "look_at_rotation",
    "look_at_view_transform",
    "ndc_grid",
    "opencv_from_cameras_projection",
    "opengl_from_cameras",
    # fitting and metrics
    "fit",
    "fit_mesh",
    "fit_mesh_to_views",
    "fit_nerf",
    "fit_volume",
    "metrics",
    # io / data
    "data",
    "io",
    "load_mesh",
    "load_obj",
    "load_objs_as_meshes",
    "load_pointcloud",
    "save_mesh",
    "save_obj",
    "save_pointcloud",
    # sampling, operators and losses
    "ChamferResult",
    "ChamferTarget",
    "PointToSurface",
    "chamfer_distance",
    "mesh_edge_loss",
    "mesh_laplacian_smoothing",
    "mesh_normal_consistency",
    "SampledPoints",
    "cot_laplacian",
    "norm_laplacian",
    "sample_points_from_meshes",
    "sample_points_with_jacobian",
    "uniform_laplacian",
    # ray casting
    "ClosestPoints",
    "PointToMeshDistance",
    "RayCaster",
    "RayHits",
    "closest_point_on_triangles",
    "intersect_rays_triangles",
    # rendering
    "render",
    "AlphaCompositor",
    "AmbientLights",
    "BlendParams",
    "DirectionalLights",
    "Fragments",
    "HardFlatShader",
    "HardGouraudShader",
    "HardPhongShader",
    "Materials",
    "MeshRasterizer",
    "MeshRenderer",
    "MeshRendererWithFragments",
    "NormWeightedCompositor",
    "PointLights",
    "PointsRasterizationSettings",
    "PointsRasterizer",
    "PointsRenderer",
    "RasterizationSettings",
    "SoftGouraudShader",
    "SoftPhongShader",
    "TexturesFlat",
    "image_grid",
    # shapes
    "box",
    "ico_sphere",
    "plane",
    "subdivide",
    "tetrahedron",
    "torus",
]
