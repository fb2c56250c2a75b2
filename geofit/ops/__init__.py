"""Geometric operators: surface sampling (with its sparse Jacobian) and Laplacian matrices."""
from .laplacian import cot_laplacian, norm_laplacian, uniform_laplacian
from .sampling import (
    PointsNormals,
    PointsNormalsTextures,
    PointsTextures,
    SampledPoints,
    barycentric_matrix,
    sample_points_from_meshes,
    sample_points_with_jacobian,
)

__all__ = [
    "PointsNormals",
    "PointsNormalsTextures",
    "PointsTextures",
    "SampledPoints",
    "barycentric_matrix",
    "cot_laplacian",
    "norm_laplacian",
    "sample_points_from_meshes",
    "sample_points_with_jacobian",
    "uniform_laplacian",
]
