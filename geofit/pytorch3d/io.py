"""PyTorch3D's ``pytorch3d.io``: ``load_obj``, ``load_objs_as_meshes``, ``save_obj``.

``verts, faces, aux = load_obj(path)`` unpacks as in PyTorch3D; the parsing is geofit's
:func:`geofit.io.load_obj` (same triangulation, MTL keys and texture reading).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .. import io as _gio
from ._common import missing_names, np_
from .structures import Meshes
from .tensor import Tensor

__all__ = ["Aux", "Faces", "load_obj", "load_objs_as_meshes", "save_obj"]


class Faces(NamedTuple):
    """Face indices of an OBJ file (PyTorch3D's ``Faces``); -1 where the file gives none.

    Attributes
    ----------
    verts_idx : (F, 3) int64 Tensor
    normals_idx : (F, 3) int64 Tensor
    textures_idx : (F, 3) int64 Tensor
    materials_idx : (F,) int64 Tensor
    """

    verts_idx: Tensor
    normals_idx: Tensor
    textures_idx: Tensor
    materials_idx: Tensor


class Aux(NamedTuple):
    """Auxiliary OBJ data (PyTorch3D's ``Aux``).

    Attributes
    ----------
    normals : (N, 3) Tensor or None
    verts_uvs : (T, 2) Tensor or None
    material_colors : dict name -> {"ambient_color", "diffuse_color", "specular_color",
        "shininess"} or None
    texture_images : dict name -> (H, W, 3) Tensor or None
    texture_atlas : None
        Texture atlases are not built (``create_texture_atlas=True`` raises).
    """

    normals: Tensor | None
    verts_uvs: Tensor | None
    material_colors: dict | None
    texture_images: dict | None
    texture_atlas: None


def _material_colors(materials: dict) -> dict:
    out = {}
    for name, m in materials.items():
        d = {}
        for key, attr in (("ambient_color", "Ka"), ("diffuse_color", "Kd"),
                          ("specular_color", "Ks")):
            v = getattr(m, attr)
            if v is not None:
                d[key] = Tensor(np.asarray(v, np.float64))
        if m.Ns is not None:
            d["shininess"] = Tensor(np.array([float(m.Ns)]))
        out[name] = d
    return out


def _no_atlas(create_texture_atlas: bool) -> None:
    if create_texture_atlas:
        raise ValueError("create_texture_atlas: geofit does not build texture atlases; use the "
                         "TexturesUV that load_objs_as_meshes returns (or geofit.render's "
                         "TexturesFlat for per-face colours)")


def load_obj(f, load_textures: bool = True, create_texture_atlas: bool = False,
             texture_atlas_size: int = 4, texture_wrap: str | None = "repeat", device="cpu",
             path_manager=None):
    """Read an OBJ file: ``verts, faces, aux`` (PyTorch3D's return layout).

    Parameters
    ----------
    f : str or os.PathLike
        The ``.obj`` file.
    load_textures : bool
        Read the MTL file and its texture images.
    create_texture_atlas, texture_atlas_size, texture_wrap, device, path_manager
        Accepted for compatibility; an atlas is not built (True raises ValueError), the other
        three are ignored.

    Returns
    -------
    verts : (V, 3) float64 Tensor
    faces : Faces
        ``faces.verts_idx`` (F, 3) int64 and the normal, UV and material indices.
    aux : Aux
    """
    _no_atlas(create_texture_atlas)
    d = _gio.load_obj(f, load_textures=load_textures)
    faces = Faces(Tensor(d.faces), Tensor(d.faces_normals_idx), Tensor(d.faces_uvs),
                  Tensor(d.face_materials))
    aux = Aux(Tensor(d.normals) if len(d.normals) else None,
              Tensor(d.verts_uvs) if len(d.verts_uvs) else None,
              _material_colors(d.materials) if d.materials else None,
              {k: Tensor(v) for k, v in d.texture_images.items()} if d.texture_images else None,
              None)
    return Tensor(d.verts), faces, aux


def load_objs_as_meshes(files, device=None, load_textures: bool = True,
                        create_texture_atlas: bool = False, texture_atlas_size: int = 4,
                        texture_wrap: str | None = "repeat", path_manager=None) -> Meshes:
    """A Meshes batch from OBJ files, with ``TexturesUV`` from each file's first texture image.

    Parameters
    ----------
    files : list of str or os.PathLike
    device, texture_atlas_size, texture_wrap, path_manager
        Ignored.
    load_textures : bool
    create_texture_atlas : bool
        Must be False.

    Returns
    -------
    Meshes
    """
    _no_atlas(create_texture_atlas)
    return Meshes._from_geofit(_gio.load_objs_as_meshes(files, load_textures=load_textures))


def save_obj(f, verts, faces, decimal_places: int | None = None, path_manager=None, *,
             normals=None, faces_normals_idx=None, verts_uvs=None, faces_uvs=None,
             texture_map=None) -> None:
    """Write ``verts`` (V, 3) and ``faces`` (F, 3) (and optionally UVs and a texture map).

    Normals are not written (``normals=`` raises ValueError): geofit's writer recomputes them
    on load.
    """
    if normals is not None or faces_normals_idx is not None:
        raise ValueError("normals: geofit.io.save_obj does not write vn lines; leave normals "
                         "None (they are recomputed from the faces)")
    v = np_(verts.detach() if isinstance(verts, Tensor) else verts, np.float64)
    _gio.save_obj(f, v, np_(faces, np.int64),
                  verts_uvs=None if verts_uvs is None else np_(verts_uvs, np.float64),
                  faces_uvs=None if faces_uvs is None else np_(faces_uvs, np.int64),
                  texture_map=None if texture_map is None else np_(texture_map, np.float64),
                  decimal_places=decimal_places)


__getattr__ = missing_names("geofit.pytorch3d.io", {
    "IO": "use load_obj / load_objs_as_meshes / save_obj here, or geofit.io.load_mesh "
          "(OBJ, and PLY/OFF/STL through trimesh)",
    "load_ply": "geofit.io.load_mesh(path) reads PLY meshes; geofit.load_pointcloud reads "
                "point-cloud PLY files",
    "save_ply": "geofit.io.save_pointcloud(path, cloud) for points; save_obj for meshes",
})
