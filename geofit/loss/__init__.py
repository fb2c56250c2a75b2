"""Losses with analytic gradients: each returns ``(value, grad)`` with ``grad`` shaped like its input.

- mesh regularisers (:mod:`geofit.loss.mesh`): :func:`mesh_edge_loss`,
  :func:`mesh_normal_consistency`, :func:`mesh_laplacian_smoothing`;
"""
from .mesh import (
    mesh_edge_loss,
    mesh_laplacian_smoothing,
    mesh_normal_consistency,
    normal_consistency_pairs,
)

__all__ = [
    "mesh_edge_loss",
    "mesh_laplacian_smoothing",
    "mesh_normal_consistency",
    "normal_consistency_pairs",
]
