"""Geometric operators: surface sampling (with its sparse Jacobian) and Laplacian matrices."""
from .laplacian import cot_laplacian, norm_laplacian, uniform_laplacian
from .sampling import SampledPoints, barycentric_matrix, sample_points_from_meshes

__all__ = [
    "SampledPoints",
    "barycentric_matrix",
    "cot_laplacian",
    "norm_laplacian",
    "sample_points_from_meshes",
    "uniform_laplacian",
]
