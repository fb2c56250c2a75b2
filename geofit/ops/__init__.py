"""Geometric operators: surface sampling (with its sparse Jacobian), Laplacian matrices,
topology reports and remeshing."""
from .laplacian import cot_laplacian, norm_laplacian, uniform_laplacian
from .sampling import SampledPoints, barycentric_matrix, sample_points_from_meshes
from .topology import TopologyReport, topology

__all__ = [
    "SampledPoints",
    "TopologyReport",
    "barycentric_matrix",
    "cot_laplacian",
    "norm_laplacian",
    "sample_points_from_meshes",
    "topology",
    "uniform_laplacian",
]
