"""Reading and writing meshes (OBJ/MTL with textures, PLY, STL, OFF, GLB/glTF), point clouds
(.npz, .ply) and multi-view captures (NeRF transforms.json, COLMAP, OpenCV).
"""
from .mesh import READ_FORMATS, WRITE_FORMATS, load_mesh, save_mesh
from .obj import Material, ObjData, load_obj, load_objs_as_meshes, save_obj
from .points import load_pointcloud, save_pointcloud
from .views import load_views, save_views

__all__ = [
    "Material",
    "ObjData",
    "READ_FORMATS",
    "WRITE_FORMATS",
    "load_mesh",
    "load_obj",
    "load_objs_as_meshes",
    "load_pointcloud",
    "load_views",
    "save_mesh",
    "save_obj",
    "save_pointcloud",
    "save_views",
]
