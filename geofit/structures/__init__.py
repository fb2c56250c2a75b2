"""Data structures: meshes, point clouds, textures, volumes, multi-view datasets."""
from .mesh import Mesh, Meshes, Normalization, Topology, as_mesh, as_meshes
from .pointcloud import PointCloud, Pointclouds, as_pointcloud, as_pointclouds
from .textures import TexturesBase, TexturesUV, TexturesVertex
from .views import MultiViewDataset
from .volume import Volume

__all__ = [
    "Mesh",
    "Meshes",
    "Normalization",
    "Topology",
    "as_mesh",
    "as_meshes",
    "PointCloud",
    "Pointclouds",
    "as_pointcloud",
    "as_pointclouds",
    "TexturesBase",
    "TexturesUV",
    "TexturesVertex",
    "Volume",
    "MultiViewDataset",
]
