"""Reading and writing triangle meshes in the common formats, through trimesh and Open3D.

OBJ keeps PyTorch3D's meaning (geofit's own :func:`~geofit.io.load_obj` /
:func:`~geofit.io.save_obj`: file vertex order, per-corner UVs). Every other format is read by
trimesh and written by trimesh or Open3D; geofit adds no parser of its own.

==========  ==========================================  ==========================================
Extension   :func:`load_mesh` reads                      :func:`save_mesh` writes
==========  ==========================================  ==========================================
``.obj``    geofit's OBJ reader: UV texture (TexturesUV)  OBJ + MTL + PNG texture (TexturesUV)
``.ply``    trimesh: vertex colours, polygons split       Open3D: float64 positions, 8-bit colours
                                                         (a UV texture baked to vertex colours)
``.stl``    trimesh, vertices merged                     trimesh: binary STL (float32), geometry
``.off``    trimesh, polygons split                      trimesh: ASCII OFF, geometry
``.glb``    trimesh: vertex colours or UVs + image       trimesh: float32 positions, colours or
                                                         UVs + PNG image
``.gltf``   trimesh (with its side files)                refused (write ``.glb``)
==========  ==========================================  ==========================================
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .._foreign import scene_to_mesh
from ..structures.mesh import Mesh, corner_mean, as_mesh
from ..structures.textures import TexturesUV, TexturesVertex
from ._formats import EXTENSIONS, sniff
from .._atomic import atomic_write, write_bytes
from ._gltf import check_gltf
from ._images import as_max_pixels
from ._paths import PathPolicy, check_input_file, trimesh_resolver
from .obj import MAX_COORD, _obj_to_mesh, save_obj
from ._off import check_off_counts
from .points import (PlyLayoutNotRead, _open3d_ok, ply_declared_counts, read_ply_mesh,
                     verify_binary_ply)

__all__ = ["load_mesh", "save_mesh", "READ_FORMATS", "WRITE_FORMATS"]

PathLike = str | os.PathLike

#: Extensions :func:`load_mesh` reads.
READ_FORMATS = (".obj", ".ply", ".stl", ".off", ".glb", ".gltf")
#: Extensions :func:`save_mesh` writes.
WRITE_FORMATS = (".obj", ".ply", ".stl", ".off", ".glb")


def load_mesh(path: PathLike, load_textures: bool = True, *, merge: bool = True,
              allow_outside: bool = False,
              max_pixels: int | None = None) -> Mesh | dict[str, Mesh]:
    """Load one triangle mesh from an OBJ, PLY, STL, OFF, GLB or glTF file.

    Parameters
    ----------
    path : str or os.PathLike
        The file. ``.obj`` is read by :func:`geofit.io.load_obj` with PyTorch3D's meaning (file
        vertex order, fan-triangulated polygons, the first texture image as a TexturesUV, as
        :func:`geofit.io.load_objs_as_meshes`). The others are read by trimesh without
        processing (vertex order kept, polygons triangulated), except that STL, which stores
        every triangle's corners separately, has its coincident vertices merged (in order of
        first use).
    load_textures : bool
        Attach the file's texture or colours: a TexturesUV (OBJ, GLB/glTF with an image), or a
        TexturesVertex from vertex colours (PLY, GLB/glTF), in [0, 1].
    merge : bool
        True: one Mesh; a GLB/glTF scene with several meshes is merged into one (node
        transforms applied, node names dropped). False: the parts as ``{node name: Mesh}``,
        each with its node transform applied (``{file stem: Mesh}`` for the
        single-mesh formats).
    allow_outside : bool
        Follow the paths a file names (OBJ: MTL and textures; glTF/GLB: buffers and images)
        outside the file's folder (see :func:`geofit.io.load_obj`). Every such path goes
        through the one path policy (:mod:`geofit.io._paths`), on the trimesh route too.
    max_pixels : int, optional
        Most pixels (width x height) a texture image may have (OBJ textures, GLB/glTF images),
        checked from the image header before decoding; default 2**24.

    Returns
    -------
    Mesh or dict of str to Mesh
        Vertices (V, 3) float64, faces (F, 3) int64 and the textures (see ``merge``).

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    ValueError
        For an extension it does not read (naming those it does), a file that trimesh cannot
        parse, a file with no faces (a point cloud: use :func:`geofit.io.load_pointcloud`), with
        non-finite vertices or coordinates beyond 1e38 in absolute value, or as
        :func:`geofit.io.load_obj`.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> from geofit import ico_sphere
    >>> from geofit.io import load_mesh, save_mesh
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "sphere.stl"
    >>> save_mesh(p, ico_sphere(4))
    >>> load_mesh(p)
    Mesh(n_verts=2562, n_faces=5120)
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in READ_FORMATS:
        raise ValueError(f"path: expected one of {', '.join(READ_FORMATS)}, got {path.name!r}"
                         + ("; a .npz holds a point cloud: use geofit.io.load_pointcloud"
                            if suffix == ".npz" else ""))
    if not isinstance(merge, bool):
        raise TypeError(f"merge: expected True or False, got {merge!r}")
    path = check_input_file(path, "mesh file")
    max_pixels = as_max_pixels(max_pixels)
    if suffix == ".obj" and sniff(path) == "OBJ":
        mesh = _obj_to_mesh(path, load_textures, allow_outside, max_pixels)
        return mesh if merge else {path.stem: mesh}
    fmt = sniff(path) or EXTENSIONS[suffix]
    try:
        mesh = _load_trimesh_route(path, fmt, allow_outside, max_pixels, merge)
    except ValueError as exc:
        if str(exc).startswith(str(path)):
            raise
        raise ValueError(f"{path}: {exc}") from None
    except Exception as exc:  # noqa: BLE001 - numpy/trimesh raise IndexError, KeyError, ...
        # on malformed data: every one becomes a ValueError naming the file
        raise ValueError(f"{path}: not a readable {fmt} mesh ({type(exc).__name__}: "
                         f"{str(exc)[:200]})") from None
    if isinstance(mesh, dict):  # merge=False on a scene: its parts by node name
        return {k: m if load_textures else Mesh(m.verts, m.faces) for k, m in mesh.items()}
    mesh = mesh if load_textures else Mesh(mesh.verts, mesh.faces)
    return mesh if merge else {path.stem: mesh}


def _load_trimesh_route(path: Path, fmt: str, allow_outside: bool, max_pixels: int,
                        merge: bool = True) -> Mesh | dict[str, Mesh]:
    """PLY, STL, OFF, GLB and glTF through trimesh, from bytes geofit read itself: the files the
    input names go through the path policy (a trimesh Resolver), images are checked against the
    pixel cap before trimesh decodes them."""
    import io

    import trimesh

    with open(path, "rb") as fh:
        data = fh.read()
    if fmt == "PLY":  # the one PLY reader (geofit's own, shared with point clouds)
        try:
            return _ply_to_mesh(path)
        except PlyLayoutNotRead:  # binary polygons of mixed sizes: trimesh, counts checked
            pass
    elif fmt == "OFF":
        check_off_counts(data, path)
    policy = PathPolicy(path.parent, allow_outside=allow_outside)
    if fmt in ("GLB", "glTF"):
        check_gltf(data, path, fmt, policy, max_pixels)
    try:
        loaded = trimesh.load(io.BytesIO(data), file_type=_TRIMESH_TYPES[fmt], process=False,
                              resolver=trimesh_resolver(policy, str(path)))
    except Exception as exc:  # noqa: BLE001 - trimesh raises many types for malformed files
        raise ValueError(f"{path}: trimesh could not read it as {fmt} "
                         f"({type(exc).__name__}: {str(exc)[:200]})") from None
    if isinstance(loaded, trimesh.Scene):
        geoms = [g for g in loaded.geometry.values() if isinstance(g, trimesh.Trimesh)]
        if not geoms:
            n = sum(len(getattr(g, "vertices", ())) for g in loaded.geometry.values())
            raise ValueError(f"{path}: the file has no faces ({n} points): "
                             "read a point cloud with geofit.io.load_pointcloud")
        if not merge:
            parts = {}
            for node in loaded.graph.nodes_geometry:  # one entry per part
                T, geometry = loaded.graph[node]
                g = loaded.geometry[geometry]
                if isinstance(g, trimesh.Trimesh) and len(g.faces):
                    g = g.copy()
                    g.apply_transform(T)
                    parts[node] = _from_trimesh(path, g, fmt, data)
            return parts
        loaded = scene_to_mesh(loaded)
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        n = len(getattr(loaded, "vertices", ()))
        raise ValueError(f"{path}: the file has no faces ({n} vertices): "
                         "read a point cloud with geofit.io.load_pointcloud")
    return _from_trimesh(path, loaded, fmt, data)


def _from_trimesh(path: Path, loaded, fmt: str, data: bytes) -> Mesh:
    """A loaded ``trimesh.Trimesh`` with faces, checked, as a Mesh."""
    if not np.isfinite(np.asarray(loaded.vertices)).all():
        raise ValueError(f"{path}: the vertex coordinates are not all finite")
    if np.abs(np.asarray(loaded.vertices)).max(initial=0.0) > MAX_COORD:
        raise ValueError(f"{path}: vertex coordinates beyond {MAX_COORD:g} in absolute value")
    if fmt == "STL":
        return _merge_corners(loaded)
    if fmt in ("PLY", "OFF"):  # trimesh's result against the counts the header declares
        declared = (ply_declared_counts(path).get("vertex") if fmt == "PLY"
                    else check_off_counts(data, path))
        if len(loaded.vertices) != declared:
            raise ValueError(f"{path}: the header declares {declared} vertices, trimesh read "
                             f"{len(loaded.vertices)}")
    return Mesh.from_trimesh(loaded)  # its ValueErrors get the file's name from load_mesh


def _ply_to_mesh(path: Path) -> Mesh:
    verts, faces, colours = read_ply_mesh(path)
    if faces is None or len(faces) == 0:
        raise ValueError(f"{path}: the file has no faces ({len(verts)} vertices): "
                         "read a point cloud with geofit.io.load_pointcloud")
    if not np.isfinite(verts).all():
        raise ValueError(f"{path}: the vertex coordinates are not all finite")
    if np.abs(verts).max(initial=0.0) > MAX_COORD:
        raise ValueError(f"{path}: vertex coordinates beyond {MAX_COORD:g} in absolute value")
    tex = None
    if colours is not None:
        if not np.isfinite(colours).all() or colours.min() < 0 or colours.max() > 1:
            raise ValueError(f"{path}: PLY colours must lie in [0, 1] (floats) or [0, 255] "
                             f"(8-bit integers)")
        tex = TexturesVertex(colours)
    return Mesh(verts, faces, tex)


#: Format name -> trimesh file_type.
_TRIMESH_TYPES = {"OBJ": "obj", "PLY": "ply", "STL": "stl", "OFF": "off", "GLB": "glb",
                  "glTF": "gltf"}


def _merge_corners(tm) -> Mesh:
    """An STL triangle soup with coincident vertices merged, numbered in order of first use."""
    tm.merge_vertices()
    V, F = np.asarray(tm.vertices), np.asarray(tm.faces, dtype=np.int64)
    used, first = np.unique(F.ravel(), return_index=True)
    order = used[np.argsort(first, kind="stable")]  # old ids in order of first use
    new_id = np.full(len(V), -1, dtype=np.int64)
    new_id[order] = np.arange(len(order))
    return Mesh(V[order], new_id[F])


def _bake_uv_colours(mesh: Mesh) -> np.ndarray:
    """(V, C) vertex colours from a UV texture: the mean of the texture at a vertex's corners."""
    tex = mesh.textures
    corner = tex.sample_uv(tex.verts_uvs[tex.faces_uvs.ravel()])  # (3F, C)
    return np.clip(corner_mean(corner, mesh.faces, mesh.n_verts), 0.0, 1.0)


def save_mesh(path: PathLike, mesh) -> None:
    """Write a triangle mesh in the format its extension names.

    Parameters
    ----------
    path : str or os.PathLike
        ``.obj`` (with an MTL and PNG when the mesh has a TexturesUV; see
        :func:`geofit.io.save_obj`), ``.ply`` (binary, float64 positions and 8-bit vertex
        colours, written by Open3D), ``.stl`` (binary, float32, geometry only), ``.off``
        (ASCII, geometry only) or ``.glb`` (binary glTF: float32 positions, 8-bit vertex colours
        or UVs with the texture as a PNG, written by trimesh).
    mesh : Mesh, trimesh.Trimesh or open3d.geometry.TriangleMesh
        The mesh. Vertex colours (a TexturesVertex with 1, 3 or 4 channels in [0, 1]) go to PLY
        and GLB; a UV texture goes to OBJ and GLB, and to PLY as vertex colours (the texture's
        mean over each vertex's corners). STL and OFF hold geometry only, and OBJ does not
        store vertex colours: those are left out.

    Raises
    ------
    ValueError
        For an extension it cannot write (``.gltf``: write ``.glb``), naming those it can; for a
        mesh without faces.
    TypeError
        If ``mesh`` is not a mesh.

    Notes
    -----
    Formats quantise: colours to 8 bits in PLY and GLB (``round(255 c)``, so they reload
    within 1/(2 * 255)), positions to float32 in STL and GLB. OBJ and PLY keep float64
    positions exactly.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in WRITE_FORMATS:
        extra = "; write .glb for glTF (one file)" if suffix == ".gltf" else ""
        raise ValueError(f"path: save_mesh writes {', '.join(WRITE_FORMATS)}, got "
                         f"{path.name!r}{extra}")
    mesh = as_mesh(mesh, "mesh")
    if mesh.n_faces == 0:
        raise ValueError("mesh: expected a mesh with at least one face, got 0 faces")
    if suffix == ".obj":
        save_obj(path, mesh)
        return
    if suffix == ".ply":
        import open3d as o3d

        tex = mesh.textures
        if isinstance(tex, TexturesUV):
            tex = TexturesVertex(_bake_uv_colours(mesh))
        plain = Mesh(mesh.verts, mesh.faces,
                     tex if isinstance(tex, TexturesVertex) and tex.n_channels in (1, 3, 4)
                     else None)
        o3d_mesh = plain.to_open3d()
        atomic_write(path, lambda tmp: _open3d_ok(o3d.io.write_triangle_mesh(
            str(tmp), o3d_mesh, write_ascii=False, write_vertex_normals=False,
            write_vertex_colors=plain.textures is not None), path), verify=verify_binary_ply)
        return
    if suffix in (".stl", ".off"):
        mesh = Mesh(mesh.verts, mesh.faces)  # geometry only
    elif not isinstance(mesh.textures, (TexturesUV, TexturesVertex)):
        mesh = Mesh(mesh.verts, mesh.faces)
    tm = mesh.to_trimesh()
    tm.metadata.clear()  # the exact-round-trip record is for in-memory conversions only
    data = tm.export(file_type=suffix[1:])  # bytes (STL, GLB) or str (OFF)
    write_bytes(path, data.encode("ascii") if isinstance(data, str) else data)
