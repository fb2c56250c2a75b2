"""PyTorch3D's ``pytorch3d.utils``: ``ico_sphere``."""
from __future__ import annotations

from .. import shapes as _shapes
from ._common import missing_names
from .structures import Meshes

__all__ = ["ico_sphere"]


def ico_sphere(level: int = 0, device=None) -> Meshes:
    """The unit icosphere subdivided ``level`` times, as a one-mesh Meshes batch.

    Same vertex and face order as PyTorch3D (level 4: 2562 vertices, 5120 faces); ``device``
    is ignored.

    Examples
    --------
    >>> ico_sphere(4, "cpu").verts_packed().shape
    (2562, 3)
    """
    return Meshes._from_geofit(_shapes.ico_sphere(level))


__getattr__ = missing_names("geofit.pytorch3d.utils", {
    "torus": "geofit.torus(major_radius, minor_radius, n_major, n_minor) returns a geofit.Mesh",
    "cameras_from_opencv_projection": "geofit.cameras_from_opencv_projection",
    "opencv_from_cameras_projection": "geofit.opencv_from_cameras_projection",
})
