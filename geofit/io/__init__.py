"""Reading and writing meshes (Wavefront OBJ/MTL with textures) and point clouds (.npz, .ply)."""
from .obj import Material, ObjData, load_mesh, load_obj, load_objs_as_meshes, save_obj
from .points import load_pointcloud, save_pointcloud

__all__ = [
    "Material",
    "ObjData",
    "load_mesh",
    "load_obj",
    "load_objs_as_meshes",
    "load_pointcloud",
    "save_obj",
    "save_pointcloud",
]
