"""Which mesh format a file holds (by its first bytes, then its extension), for error messages."""
from __future__ import annotations

from pathlib import Path

#: Extension -> format name.
EXTENSIONS = {
    ".obj": "OBJ", ".ply": "PLY", ".stl": "STL", ".off": "OFF", ".glb": "GLB", ".gltf": "glTF",
    ".npz": "NumPy .npz",
}


def sniff(path: Path) -> str | None:
    """The format of ``path``: PLY, GLB or OFF by its first bytes, else by extension, or None."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(4)
    except OSError:
        head = b""
    if head[:3] == b"ply" and head[3:4] in (b"\n", b"\r"):
        return "PLY"
    if head == b"glTF":
        return "GLB"
    if head[:3] == b"OFF":
        return "OFF"
    return EXTENSIONS.get(path.suffix.lower())


def not_obj_error(path: Path, fmt: str, reader: bool) -> ValueError:
    """The ValueError for an OBJ function given another format: names it and the right function."""
    if reader:
        right = ("geofit.io.load_pointcloud" if fmt == "NumPy .npz"
                 else "geofit.io.load_mesh, which reads OBJ, PLY, STL, OFF, GLB and glTF")
        return ValueError(f"{path}: this is a {fmt} file, not OBJ; load_obj reads only Wavefront "
                          f"OBJ: read it with {right}")
    return ValueError(f"path: save_obj writes Wavefront OBJ, but {path.name!r} asks for "
                      f"{fmt}; write it with geofit.io.save_mesh (OBJ, PLY, STL, OFF, GLB)")
