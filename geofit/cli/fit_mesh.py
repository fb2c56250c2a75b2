"""``geofit fit-mesh [TARGET]``: fit a mesh to a target mesh or point cloud with
geofit.fit_mesh's defaults (PyTorch3D's deform tutorial).

TARGET is a mesh (.obj, .ply, .stl, .off, .glb) or a point cloud (.ply without faces, .npz with
``points``/``verts``, .xyz, .pts: anything geofit.io.load_pointcloud or trimesh reads). Without
TARGET, the tutorial's dolphin (when the tutorial data is found, see geofit.data) or geofit's
procedural stand-in. The fit is ``fit_mesh(target)`` exactly as in Python, with only the options
given here passed on. Prints progress, then the fit's own final accuracy (chamfer-L2,
chamfer-L1, F-score at 0.01 and normal consistency in the target's normalised frame) and the
vertex count; writes ``fit_mesh.obj`` (the fitted mesh in the target's original frame) and
``fit_mesh_history.json`` into ``--out``.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from ._common import (FIT_OPTIONS, add_command, add_fit_options, fit_kwargs, out_dir,
                      timing_line, write_json, wrote)

__all__ = ["API", "register", "run"]

#: The function this sub-command runs (its docstring gives the options' help).
API = ("fit/mesh.py", "fit_mesh")

#: Suffixes read as point clouds by trimesh's XYZ reader (one point a line: x y z, then
#: optional columns); ``.npz`` and a ``.ply`` without faces go to geofit.io.load_pointcloud.
XYZ_SUFFIXES = (".xyz", ".pts", ".txt")


def _ply_has_faces(path: Path) -> bool:
    """True when the PLY header declares a non-empty ``face`` element."""
    with open(path, "rb") as fh:
        for _ in range(200):
            line = fh.readline()
            if not line or line.strip() == b"end_header":
                break
            words = line.split()
            if len(words) == 3 and words[:2] == [b"element", b"face"]:
                return words[2] != b"0"
    return False


def load_target(path):
    """``(target, name)``: the mesh or point cloud at ``path`` (None: the tutorial's target),
    as ``fit_mesh`` takes it."""
    if path is None:
        from ..data import load_target_mesh

        data = load_target_mesh()
        return data.mesh, data.name
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in XYZ_SUFFIXES:
        import numpy as np
        import trimesh

        try:
            cloud = trimesh.load(path, file_type="xyz")
        except Exception as exc:  # noqa: BLE001 - trimesh's parse errors vary
            raise ValueError(f"{path}: unreadable point file ({type(exc).__name__}: "
                             f"{str(exc)[:200]})") from None
        points = np.asarray(getattr(cloud, "vertices", ()), np.float64)
        if points.ndim != 2 or points.shape[1] != 3 or len(points) == 0:
            raise ValueError(f"{path}: expected lines of x y z, got points of shape "
                             f"{points.shape}")
        return points, str(path)
    from ..io import load_mesh, load_pointcloud

    if suffix == ".npz" or (suffix == ".ply" and not _ply_has_faces(path)):
        return load_pointcloud(path), str(path)
    return load_mesh(path, load_textures=False), str(path)


def _describe(target) -> str:
    n_faces = getattr(target, "n_faces", None)
    if n_faces is None:
        return f"{len(target)} points"
    return f"{target.n_verts} vertices, {n_faces} faces"


def run(args: argparse.Namespace) -> int:
    """Run the sub-command; returns the exit code."""
    from ..fit import fit_mesh
    from ..io import save_obj

    target, name = load_target(args.target)
    kwargs = fit_kwargs(args, FIT_OPTIONS)
    print(f"target: {name} ({_describe(target)})"
          + "".join(f", {k}={v}" for k, v in kwargs.items()))
    res = fit_mesh(target, **kwargs)
    out = out_dir(args)
    obj_path = out / "fit_mesh.obj"
    save_obj(obj_path, res.mesh)
    hist = res.to_dict()
    metrics = res.metrics.as_dict() if res.metrics is not None else {}
    hist["final_metrics"] = metrics
    write_json(out / "fit_mesh_history.json", hist)
    wrote(obj_path, out / "fit_mesh_history.json")
    print(f"geofit fit-mesh: {res.status} ({res.message}); {res.n_iterations} iterations; "
          f"{timing_line(res)}; {res.n_verts} vertices, {res.mesh.n_faces} faces")
    if metrics:
        print("geofit fit-mesh: accuracy (normalised frame): "
              f"chamfer-L2 {metrics['chamfer_l2']:.3e}, chamfer-L1 {metrics['chamfer_l1']:.4f}, "
              + ", ".join(f"F@{k.split('@')[1]} {v:.4f}" for k, v in metrics.items()
                          if k.startswith("fscore@"))
              + f", normal consistency {metrics['normal_consistency']:.4f}")
    return 0 if res.ok else 1


def register(subparsers) -> None:
    """Add the ``fit-mesh`` sub-command."""
    p = add_command(subparsers, "fit-mesh", __doc__, run,
                    input=("target", "target mesh or point cloud (.obj, .ply, .stl, .off, .glb, "
                                     ".npz, .xyz, .pts); default: the tutorial dolphin if found, "
                                     "else the procedural stand-in"))
    add_fit_options(p, API, FIT_OPTIONS)
