"""geofit: fit and render 3D geometry on the CPU in plain numpy.

The six workflows of PyTorch3D's introductory tutorials, without PyTorch, built on Embree ray
casting, Open3D KD-trees and scipy.sparse operators with analytic gradients.
"""
from __future__ import annotations

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

__version__ = "0.1.0"

__all__ = [
    "__version__",
    # structures
    "Mesh",
    "Meshes",
    "Normalization",
    "PointCloud",
    "Pointclouds",
    "TexturesUV",
    "TexturesVertex",
    "Topology",
    # shapes
    "box",
    "ico_sphere",
    "plane",
    "subdivide",
    "tetrahedron",
    "torus",
]
