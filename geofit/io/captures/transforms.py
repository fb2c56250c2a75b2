"""NeRF/Blender ``transforms.json`` (also instant-ngp), and the NeRF-synthetic split folder.

``transforms.json`` holds ``frames``, each with ``file_path`` (relative to the json, with or
without extension), optional ``mask_path`` and ``transform_matrix``, the OpenGL camera-to-world
4x4 (x right, y up, looking down -z). Intrinsics from ``fl_x``/``fl_y``/``cx``/``cy``/``w``/``h``
or ``camera_angle_x`` (horizontal field of view, radians; ``camera_angle_y`` likewise), at the top
level or per frame (a frame's value wins). Defaults: ``fl_y = fl_x``, principal point at the
image centre. Lens distortion ``k1 k2 k3 k4 p1 p2`` (instant-ngp, nerfstudio; radial
``1 + k1 r^2 + k2 r^4 + k3 r^6 + k4 r^8``) is undistorted with OpenCV; ``k4`` is refused for a
perspective camera (OpenCV's model has no ``r^8`` term). ``is_fisheye: true`` selects
OpenCV's fisheye model with ``k1..k4``.

The NeRF-synthetic (Blender) dataset's folder has no ``transforms.json`` but
``transforms_train.json`` with ``transforms_test.json`` and/or ``transforms_val.json``: it is read
as the training views with the test views (else the validation views) as ``held_out``.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ..._atomic import write_text
from ...cameras.conversions import cameras_from_opengl, opengl_from_cameras
from ._common import (
    _ROTATION_TOL,
    ReadOptions,
    _json_entries,
    _matrix,
    _number,
    _read_json,
    _rotation,
    _target,
    _write_image,
    build_dataset,
    metadata_background,
)
from ._files import _find_image

_NERF_KEYS = ("fl_x", "fl_y", "cx", "cy", "w", "h", "camera_angle_x", "camera_angle_y",
              "k1", "k2", "k3", "k4", "p1", "p2", "is_fisheye", "camera_model")
_SPLITS = ("train", "test", "val")


def _focal(d: dict, focal_key: str, angle_key: str, size: int, where: str) -> float | None:
    """A focal length in pixels from ``fl_*`` or a field of view ``camera_angle_*`` (radians)
    across ``size`` pixels; None when neither is given."""
    if focal_key in d:
        return _number(d, focal_key, where)
    if angle_key not in d:
        return None
    angle = _number(d, angle_key, where)
    if angle >= math.pi:
        raise ValueError(f"{where}.{angle_key}: expected radians in (0, pi), got {angle!r}")
    return 0.5 * size / math.tan(0.5 * angle)


def _intrinsics_nerf(d: dict, H: int, W: int, where: str) -> np.ndarray:
    """Pixel ``K`` from NeRF/instant-ngp intrinsics ``d`` for an ``H x W`` image."""
    for key, size in (("w", W), ("h", H)):
        if key in d and _number(d, key, where) != size:
            raise ValueError(f"{where}.{key}: {d[key]!r} does not match the image ({H}x{W}, "
                             "HxW)")
    fx = _focal(d, "fl_x", "camera_angle_x", W, where)
    fy = _focal(d, "fl_y", "camera_angle_y", H, where)
    fy = fx if fy is None else fy
    if fx is None:
        if fy is None:
            raise ValueError(f"{where}: no focal length (expected fl_x or camera_angle_x)")
        fx = fy
    cx = _number(d, "cx", where, positive=False) if "cx" in d else W / 2.0
    cy = _number(d, "cy", where, positive=False) if "cy" in d else H / 2.0
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def _fisheye(d: dict, where: str) -> bool:
    model = d.get("camera_model", "OPENCV")
    if model not in ("OPENCV", "PINHOLE", "SIMPLE_PINHOLE", "OPENCV_FISHEYE"):
        raise ValueError(f"{where}.camera_model: {model!r} is not supported (supported: "
                         "OPENCV, PINHOLE, SIMPLE_PINHOLE, OPENCV_FISHEYE)")
    fisheye = d.get("is_fisheye", False)
    if not isinstance(fisheye, bool):
        raise ValueError(f"{where}.is_fisheye: expected true or false, got {fisheye!r}")
    return fisheye or model == "OPENCV_FISHEYE"


def _distortion(d: dict, where: str, fisheye: bool) -> np.ndarray:
    """OpenCV's coefficients ``(k1, k2, p1, p2, k3, 0, 0, 0)`` (or fisheye ``(k1..k4)``)."""
    c = {k: (_number(d, k, where, positive=False) if k in d else 0.0)
         for k in ("k1", "k2", "k3", "k4", "p1", "p2")}
    if fisheye:
        if c["p1"] or c["p2"]:
            raise ValueError(f"{where}: p1, p2: a fisheye camera has no tangential distortion "
                             f"(got p1={c['p1']!r}, p2={c['p2']!r})")
        return np.array([c["k1"], c["k2"], c["k3"], c["k4"]])
    if c["k4"]:
        raise ValueError(f"{where}.k4: the r^8 radial term ({c['k4']!r}) has no OpenCV "
                         "equivalent; undistort the images first (e.g. ns-process-data) and "
                         "set k1..k4, p1, p2 to 0")
    return np.array([c["k1"], c["k2"], c["p1"], c["p2"], c["k3"], 0.0, 0.0, 0.0])


def load_transforms(file: Path, options: ReadOptions):
    """Read one ``transforms*.json`` (see the module notes)."""
    data, entries = _json_entries(file, "frames")
    root = file.parent
    top = {k: data[k] for k in _NERF_KEYS if k in data}
    views, c2w, intr = [], [], []
    for where, fr in entries:  # one entry per view
        for key in ("file_path", "transform_matrix"):
            if key not in fr:
                raise ValueError(f"{where}.{key}: missing")
        image = _find_image(root, fr["file_path"], f"{where}.file_path", options.allow_outside)
        mask = None
        if "mask_path" in fr:
            mask = _find_image(root, fr["mask_path"], f"{where}.mask_path",
                               options.allow_outside)
        M = _matrix(fr["transform_matrix"], (4, 4), f"{where}.transform_matrix")
        if np.abs(M[3] - [0.0, 0.0, 0.0, 1.0]).max() > _ROTATION_TOL:
            raise ValueError(f"{where}.transform_matrix: expected a bottom row (0, 0, 0, 1), "
                             f"got {M[3].tolist()}")
        M[:3, :3] = _rotation(M[:3, :3], f"{where}.transform_matrix")
        M[3] = [0.0, 0.0, 0.0, 1.0]
        c2w.append(M)
        intr.append((where, {**top, **{k: fr[k] for k in _NERF_KEYS if k in fr}}))
        views.append({"image": image, "mask": mask, "where": where})
    fisheye = {_fisheye(d, w) for w, d in intr}
    if len(fisheye) > 1:
        raise ValueError(f"{file}: frames mix fisheye and perspective cameras")
    fisheye = fisheye.pop()
    dist = np.stack([_distortion(d, w, fisheye) for w, d in intr])

    def K(H, W):
        return np.stack([_intrinsics_nerf(d, H, W, w) for w, d in intr])

    return build_dataset(views, file, K, (np.stack(c2w),), cameras_from_opengl, options, root,
                         distortion=dist, fisheye=fisheye,
                         background=metadata_background(data, str(file)))


def load_nerf_synthetic(folder: Path, options: ReadOptions):
    """The NeRF-synthetic split folder: ``transforms_train.json`` with the test (else
    validation) views attached as ``held_out``."""
    train = load_transforms(folder / "transforms_train.json", options)
    for split in ("test", "val"):
        f = folder / f"transforms_{split}.json"
        if f.is_file():
            train.held_out = load_transforms(f, options)
            break
    return train


def _has_frames(file: Path) -> bool:
    data = _read_json(file)
    return "frames" in data and "camera_model" not in data


def detect(path: Path):
    """``(layout, file)`` when ``path`` is a transforms.json capture (not nerfstudio's, which
    names a ``camera_model``) or a NeRF-synthetic split folder, else None."""
    if path.is_file():
        return ("transforms", path) if path.suffix.lower() == ".json" and _has_frames(path) \
            else None
    if (path / "transforms.json").is_file():
        return ("transforms", path / "transforms.json") \
            if _has_frames(path / "transforms.json") else None
    if (path / "transforms_train.json").is_file():
        return "nerf_synthetic", path
    return None


def save_transforms(root: Path, images: np.ndarray, sils: np.ndarray | None, cameras,
                    bit_depth: int, overwrite: bool, background: np.ndarray | None) -> Path:
    """``transforms.json`` and RGBA PNGs ``images/r_000.png`` (alpha = the silhouette; RGB
    without silhouettes), with the ``background`` colour when known."""
    target = _target(root / "transforms.json", overwrite)
    (root / "images").mkdir(exist_ok=True)
    N, H, W = images.shape[:3]
    c2w, K = opengl_from_cameras(cameras, (H, W))
    shared = bool(np.all(K == K[:1]))
    frames = []
    for i in range(N):  # one file per view
        rel = f"images/r_{i:03d}.png"
        _write_image(root / rel, images[i] if sils is None else
                     np.concatenate([images[i], sils[i][..., None]], axis=2), bit_depth)
        fr = {"file_path": rel, "transform_matrix": c2w[i].tolist()}
        if not shared:
            fr.update(_nerf_intrinsics(K[i], H, W))
        frames.append(fr)
    data = _nerf_intrinsics(K[0], H, W) if shared else {"w": W, "h": H}
    if background is not None:
        data["background"] = np.asarray(background, dtype=np.float64).tolist()
    data["frames"] = frames
    write_text(target, json.dumps(data, indent=1) + "\n")
    return target


def _nerf_intrinsics(K: np.ndarray, H: int, W: int) -> dict:
    fx, fy = float(K[0, 0]), float(K[1, 1])
    return {"camera_angle_x": 2.0 * math.atan(0.5 * W / fx),
            "camera_angle_y": 2.0 * math.atan(0.5 * H / fy), "fl_x": fx, "fl_y": fy,
            "cx": float(K[0, 2]), "cy": float(K[1, 2]), "w": W, "h": H}


_loaders = {"transforms": load_transforms, "nerf_synthetic": load_nerf_synthetic}
_savers = {"transforms": save_transforms}
