"""Recognising trimesh and Open3D objects without importing either library.

geofit converts foreign geometry once, at the public boundary (:func:`geofit.structures.as_mesh`,
:func:`geofit.structures.as_pointcloud`). The check looks at the object's type name and module
first, so merely asking "is this a trimesh?" never imports trimesh or Open3D.
"""
from __future__ import annotations

import numpy as np

#: (top-level module, class name) -> short kind name.
_KINDS = {
    ("trimesh", "Trimesh"): "trimesh.Trimesh",
    ("trimesh", "PointCloud"): "trimesh.PointCloud",
    ("trimesh", "Scene"): "trimesh.Scene",
    ("open3d", "TriangleMesh"): "open3d.TriangleMesh",
    ("open3d", "PointCloud"): "open3d.PointCloud",
    ("open3d.t", "TriangleMesh"): "open3d.t.TriangleMesh",
    ("open3d.t", "PointCloud"): "open3d.t.PointCloud",
}

#: How to turn each foreign kind into what a plain-array argument expects.
ARRAY_HINTS = {
    "trimesh.Trimesh": "pass mesh.vertices (and mesh.faces), or geofit.Mesh.from_trimesh(mesh)",
    "trimesh.PointCloud": "pass cloud.vertices, or geofit.PointCloud.from_trimesh(cloud)",
    "trimesh.Scene": "pass scene.to_geometry().vertices, or geofit.structures.as_mesh(scene)",
    "open3d.TriangleMesh": "pass numpy.asarray(mesh.vertices) (and numpy.asarray(mesh.triangles)),"
                           " or geofit.Mesh.from_open3d(mesh)",
    "open3d.PointCloud": "pass numpy.asarray(cloud.points), or "
                         "geofit.PointCloud.from_open3d(cloud)",
    "geofit.Mesh": "pass mesh.verts (and mesh.faces)",
    "geofit.PointCloud": "pass cloud.points",
}


def foreign_kind(obj) -> str | None:
    """``"trimesh.Trimesh"``, ``"trimesh.PointCloud"``, ``"trimesh.Scene"``,
    ``"open3d.TriangleMesh"``, ``"open3d.PointCloud"`` or None for anything else.

    Subclasses count (the class hierarchy is searched), and nothing is imported.
    """
    for cls in type(obj).__mro__:
        module = cls.__module__ or ""
        top = module.split(".", 1)[0]
        if top == "open3d" and ".t." in module + ".":  # the tensor API (open3d.t.geometry)
            top = "open3d.t"
        kind = _KINDS.get((top, cls.__name__))
        if kind is not None:
            return kind
    return None


#: The kinds a converter requires, as its TypeError names them.
_EXPECTED = {
    "trimesh.Trimesh": "a trimesh.Trimesh",
    "trimesh.PointCloud": "a trimesh.PointCloud",
    "open3d.TriangleMesh": "an open3d.geometry.TriangleMesh",
    "open3d.PointCloud": "an open3d.geometry.PointCloud",
}


def require_kind(obj, kind: str, name: str) -> None:
    """Raise TypeError naming the argument ``name`` unless ``obj`` is of foreign ``kind``
    (a key of ``_EXPECTED``)."""
    if foreign_kind(obj) != kind:
        raise TypeError(f"{name}: expected {_EXPECTED[kind]}, got {type(obj)!r}")


def geometry_kind(obj) -> str | None:
    """:func:`foreign_kind`, or ``"geofit.Mesh"`` / ``"geofit.PointCloud"`` for geofit's own."""
    kind = foreign_kind(obj)
    if kind is None:
        name = type(obj).__name__
        if type(obj).__module__.startswith("geofit.") and name in ("Mesh", "PointCloud"):
            return f"geofit.{name}"
    return kind


def to_uint8(colors: np.ndarray) -> np.ndarray:
    """Colours in [0, 1] (clipped) -> uint8 with ``round(255 c)``."""
    return np.round(np.clip(colors, 0.0, 1.0) * 255.0).astype(np.uint8)


def stash_matches(stash: np.ndarray, shown: np.ndarray) -> bool:
    """Whether float colours kept beside an 8-bit copy still agree with it (nobody edited it)."""
    return stash.shape == shown.shape and bool(np.array_equal(to_uint8(stash), shown))


def geofit_record(obj) -> dict:
    """What geofit's ``to_trimesh`` left in ``obj.metadata["geofit"]`` ({} when nothing)."""
    meta = getattr(obj, "metadata", None)
    rec = meta.get("geofit") if isinstance(meta, dict) else None
    return rec if isinstance(rec, dict) else {}


def from_uint8(rgba: np.ndarray) -> np.ndarray:
    """8-bit (n, 3 or 4) colours -> float ``c / 255``: RGB, or RGBA when some alpha is below 255."""
    c = 4 if rgba.shape[1] == 4 and np.any(rgba[:, 3] < 255) else 3
    return rgba[:, :c] / 255.0


def scene_to_mesh(scene):
    """A ``trimesh.Scene`` flattened into one ``trimesh.Trimesh`` (node transforms applied)."""
    if hasattr(scene, "to_geometry"):  # trimesh >= 4.5
        return scene.to_geometry()
    return scene.dump(concatenate=True)
