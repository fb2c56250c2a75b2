"""Reading and writing meshes (Wavefront OBJ/MTL with textures), point clouds (.npz, .ply) and
multi-view captures (NeRF transforms.json, COLMAP, OpenCV).
"""
from .obj import Material, ObjData, load_mesh, load_obj, load_objs_as_meshes, save_obj
from .points import load_pointcloud, save_pointcloud
from .views import load_views, save_views

__all__ = [
    "Material",
    "ObjData",
    "load_mesh",
    "load_obj",
    "load_objs_as_meshes",
    "load_pointcloud",
    "load_views",
    "save_obj",
    "save_pointcloud",
    "save_views",
]
