"""Geometric operators: surface sampling (with its sparse Jacobian), Laplacian matrices,
topology reports and remeshing."""
from .laplacian import cot_laplacian, norm_laplacian, uniform_laplacian
from .remesh import RemeshResult, remesh
from .sampling import SampledPoints, barycentric_matrix, sample_points_from_meshes
from .topology import TopologyReport, topology

__all__ = [
    "RemeshResult",
    "SampledPoints",
    "TopologyReport",
    "barycentric_matrix",
    "cot_laplacian",
    "norm_laplacian",
    "remesh",
    "sample_points_from_meshes",
    "topology",
    "uniform_laplacian",
]
