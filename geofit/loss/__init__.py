"""Losses with analytic gradients: each returns ``(value, grad)`` with ``grad`` shaped like its input.

- :func:`chamfer_distance` and :class:`ChamferTarget` (a KD-tree over a fixed target, Open3D's
  or scipy's: ``backend=``);
- :class:`PointToSurface`: exact squared distance to a fixed target surface (no sampling noise);
- :func:`huber`: the volume and NeRF tutorials' pseudo-Huber image loss;
- mesh regularisers (:mod:`geofit.loss.mesh`): :func:`mesh_edge_loss`,
  :func:`mesh_normal_consistency`, :func:`mesh_laplacian_smoothing`,
  :func:`mesh_normal_variation`.
"""
from .chamfer import ChamferResult, ChamferTarget, chamfer_distance
from .robust import huber, huber_residual
from .mesh import (
    mesh_edge_loss,
    mesh_laplacian_smoothing,
    mesh_normal_consistency,
    mesh_normal_variation,
    normal_consistency_pairs,
)
from .point_to_surface import PointToSurface

__all__ = [
    "ChamferResult",
    "ChamferTarget",
    "PointToSurface",
    "chamfer_distance",
    "huber",
    "huber_residual",
    "mesh_edge_loss",
    "mesh_laplacian_smoothing",
    "mesh_normal_consistency",
    "mesh_normal_variation",
    "normal_consistency_pairs",
]
