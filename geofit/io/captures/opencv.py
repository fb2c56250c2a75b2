"""geofit's own OpenCV layout: ``cameras.json`` with K, R, t (and distortion) per view.

``{"convention": "opencv", "views": [{"image": "images/000.png", "mask": "masks/000.png",
"K": 3x3, "R": 3x3, "t": 3, "dist": [k1, k2, p1, p2(, k3(, k4, k5, k6))]}, ...]}`` with OpenCV's
world-to-camera ``x = R X + t`` and pixel ``K x / x_z`` (``"mask"`` and ``"dist"`` optional;
``"dist"`` is OpenCV's ``distCoeffs``, undistorted with OpenCV, same ``K``). A top-level
``"background": [r, g, b]`` names the colour behind the object (see :func:`geofit.io.load_views`).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..._atomic import write_text
from ...cameras.conversions import cameras_from_opencv_projection, opencv_from_cameras_projection
from ._common import ReadOptions, _json_entries, _matrix, _read_json, _rotation, _target
from ._common import _write_image, build_dataset, metadata_background
from ._files import _find_image


def _dist(value, where: str) -> np.ndarray:
    """OpenCV's 4, 5 or 8 ``distCoeffs`` as 8 numbers."""
    n = len(value) if isinstance(value, list) else -1
    if n not in (4, 5, 8):
        raise ValueError(f"{where}: expected OpenCV's 4, 5 or 8 distortion coefficients (k1, k2, "
                         f"p1, p2[, k3[, k4, k5, k6]]), got {str(value)[:60]!r}")
    return np.concatenate([_matrix(value, (n,), where), np.zeros(8 - n)])


def load_opencv(file: Path, options: ReadOptions):
    """Read ``cameras.json`` (see the module notes)."""
    data, entries = _json_entries(file, "views")
    root = file.parent
    views, K, R, t, dist = [], [], [], [], []
    for where, e in entries:  # one entry per view
        for key in ("image", "K", "R", "t"):
            if key not in e:
                raise ValueError(f"{where}.{key}: missing")
        image = _find_image(root, e["image"], f"{where}.image", options.allow_outside)
        mask = None
        if e.get("mask") is not None:
            mask = _find_image(root, e["mask"], f"{where}.mask", options.allow_outside)
        k = _matrix(e["K"], (3, 3), f"{where}.K")
        if k[0, 0] <= 0 or k[1, 1] <= 0 or k[0, 1] != 0 or k[1, 0] != 0 \
                or np.any(k[2] != [0.0, 0.0, 1.0]):
            raise ValueError(f"{where}.K: expected [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] with "
                             f"fx, fy > 0, got {k.tolist()}")
        K.append(k)
        R.append(_rotation(_matrix(e["R"], (3, 3), f"{where}.R"), f"{where}.R"))
        t.append(_matrix(e["t"], (3,), f"{where}.t"))
        dist.append(np.zeros(8) if e.get("dist") is None else _dist(e["dist"], f"{where}.dist"))
        views.append({"image": image, "mask": mask, "where": where})
    return build_dataset(views, file, np.stack(K), (np.stack(R), np.stack(t)),
                         cameras_from_opencv_projection, options, root,
                         distortion=np.stack(dist),
                         background=metadata_background(data, str(file)))


def detect(path: Path):
    """``("opencv", file)`` for ``cameras.json`` (or a .json with ``views``), else None."""
    if path.is_file():
        if path.suffix.lower() == ".json" and "frames" not in _read_json(path):
            return "opencv", path
        return None
    if (path / "cameras.json").is_file():
        return "opencv", path / "cameras.json"
    return None


def save_opencv(root: Path, images: np.ndarray, sils: np.ndarray | None, cameras,
                bit_depth: int, overwrite: bool, background: np.ndarray | None) -> Path:
    """``cameras.json``, ``images/000.png`` and ``masks/000.png`` (none without
    silhouettes), with the ``background`` colour when known."""
    target = _target(root / "cameras.json", overwrite)
    N, H, W = images.shape[:3]
    names = [f"{i:03d}.png" for i in range(N)]
    write_masks = sils is not None
    (root / "images").mkdir(exist_ok=True)
    if write_masks:
        (root / "masks").mkdir(exist_ok=True)
    for i in range(N):  # one file per view
        _write_image(root / "images" / names[i], images[i], bit_depth)
        if write_masks:
            _write_image(root / "masks" / names[i], sils[i], bit_depth)
    R, t, K = opencv_from_cameras_projection(cameras, (H, W))
    views = [{"image": f"images/{names[i]}", "K": K[i].tolist(), "R": R[i].tolist(),
              "t": t[i].tolist()} for i in range(N)]
    if write_masks:
        for i, v in enumerate(views):
            v["mask"] = f"masks/{names[i]}"
    data = {"convention": "opencv", "pixel_origin": "top-left corner of the top-left pixel",
            "width": W, "height": H, "views": views}
    if background is not None:
        data["background"] = np.asarray(background, dtype=np.float64).tolist()
    write_text(target, json.dumps(data, indent=1) + "\n")
    return target


_loaders = {"opencv": load_opencv}
_savers = {"opencv": save_opencv}
