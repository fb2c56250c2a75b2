"""Ray casting and closest points on triangle meshes (Embree via embreex and Open3D).

- :class:`EmbreeScene`: the one Embree scene wrapper (normalised float32 frame); every
  Embree query in geofit goes through it.
- :class:`RayCaster`: one Embree scene over a mesh or a batch; first hits and occlusion for
  many rays, hits refined in float64.
- :class:`PointToMeshDistance`: float64 closest points and (signed) distances to a mesh.
- :func:`closest_point_on_triangles`: the vectorised float64 point-triangle routine.
- :func:`intersect_rays_triangles`: a brute-force numpy reference for tests.
"""
from .closest import ClosestPoints, PointToMeshDistance, closest_point_on_triangles
from .embree import EmbreeScene, RayCaster, RayHits
from .reference import intersect_rays_triangles

__all__ = [
    "ClosestPoints",
    "EmbreeScene",
    "PointToMeshDistance",
    "RayCaster",
    "RayHits",
    "closest_point_on_triangles",
    "intersect_rays_triangles",
]
