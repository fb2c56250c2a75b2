"""COLMAP sparse models, text (``cameras.txt``, ``images.txt``) or binary (``cameras.bin``,
``images.bin``).

The model lies in the capture folder itself, in ``sparse/0`` or in ``sparse``; images under
``images/`` by the name in the model and silhouettes under ``masks/`` (``masks/NAME``,
``masks/NAME.png`` or ``masks/STEM.png``). Poses are world-to-camera quaternions ``QW QX QY QZ``
and translations ``TX TY TZ`` in OpenCV's camera frame.

Camera models: ``SIMPLE_PINHOLE f cx cy`` and ``PINHOLE fx fy cx cy`` as they are;
``SIMPLE_RADIAL``, ``RADIAL``, ``OPENCV``, ``FULL_OPENCV`` and ``OPENCV_FISHEYE`` undistorted with
OpenCV (images and masks resampled, same ``K``); the other fisheye and ``FOV`` models refused
(run ``colmap image_undistorter`` first).
"""
from __future__ import annotations

import math
import struct
from pathlib import Path

import numpy as np

from ..._atomic import write_text
from ...cameras.conversions import cameras_from_colmap, colmap_from_cameras
from ._common import ReadOptions, _target, _write_image, build_dataset
from ._files import _find_image

#: name -> (COLMAP model id, parameter names, fisheye).
_MODELS = {
    "SIMPLE_PINHOLE": (0, ("f", "cx", "cy"), False),
    "PINHOLE": (1, ("fx", "fy", "cx", "cy"), False),
    "SIMPLE_RADIAL": (2, ("f", "cx", "cy", "k1"), False),
    "RADIAL": (3, ("f", "cx", "cy", "k1", "k2"), False),
    "OPENCV": (4, ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"), False),
    "OPENCV_FISHEYE": (5, ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"), True),
    "FULL_OPENCV": (6, ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5",
                        "k6"), False),
}
#: COLMAP's other models (refused), by id: name and parameter count.
_OTHER_MODELS = {7: ("FOV", 5), 8: ("SIMPLE_RADIAL_FISHEYE", 4), 9: ("RADIAL_FISHEYE", 5),
                 10: ("THIN_PRISM_FISHEYE", 12)}
_BY_ID = {v[0]: k for k, v in _MODELS.items()}
_OPENCV_ORDER = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")


def _camera(model: str, w: int, h: int, params: list, where: str):
    """``(K, (h, w), distortion, fisheye)`` of one COLMAP camera."""
    if model not in _MODELS:
        raise ValueError(f"{where}: MODEL: camera model {model!r} is not supported "
                         f"(supported: {', '.join(_MODELS)}; undistort the images first, e.g. "
                         "colmap image_undistorter)")
    _, names, fisheye = _MODELS[model]
    if len(params) != len(names):
        raise ValueError(f"{where}: PARAMS: {model} takes {len(names)} parameters, got "
                         f"{len(params)}")
    p = dict(zip(names, _floats(params, where, names)))
    fx, fy = (p["f"], p["f"]) if "f" in p else (p["fx"], p["fy"])
    if fx <= 0 or fy <= 0 or w < 1 or h < 1:
        raise ValueError(f"{where}: expected positive focal lengths and image size")
    K = np.array([[fx, 0.0, p["cx"]], [0.0, fy, p["cy"]], [0.0, 0.0, 1.0]])
    order = ("k1", "k2", "k3", "k4") if fisheye else _OPENCV_ORDER
    return K, (h, w), np.array([p.get(k, 0.0) for k in order]), fisheye


def _colmap_records(path: Path, min_fields: int, layout: str, *, points_lines: bool = False):
    """``(where, fields)`` of each data line of a COLMAP text file (comments and blank lines
    skipped; with ``points_lines`` the POINTS2D line after each image line, possibly empty, too).
    ``where`` is ``"path:line"``; a line with fewer than ``min_fields`` fields is refused."""
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: cannot read: {exc}") from None
    n = 0
    while n < len(lines):
        s = lines[n].strip()
        n += 1
        if not s or s.startswith("#"):
            continue
        where = f"{path}:{n}"
        fields = s.split()
        if len(fields) < min_fields:
            raise ValueError(f"{where}: expected {layout}, got {s[:80]!r}")
        yield where, fields
        if points_lines:
            n += 1


def _floats(fields: list, where: str, names: tuple) -> list:
    out = []
    for f, n in zip(fields, names):
        try:
            v = float(f)
        except ValueError:
            raise ValueError(f"{where}: {n}: expected a number, got {f!r}") from None
        if not math.isfinite(v):
            raise ValueError(f"{where}: {n}: expected a finite number, got {f!r}")
        out.append(v)
    return out


def _int(field: str, where: str, name: str) -> int:
    try:
        return int(field)
    except ValueError:
        raise ValueError(f"{where}: {name}: expected an integer, got {field!r}") from None


def _text_cameras(cameras_txt: Path) -> dict:
    cams = {}
    for where, f in _colmap_records(cameras_txt, 4, "CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]"):
        cid = _int(f[0], where, "CAMERA_ID")
        w, h = _int(f[2], where, "WIDTH"), _int(f[3], where, "HEIGHT")
        cams[cid] = _camera(f[1], w, h, f[4:], where)
    return cams


def _text_images(images_txt: Path):
    """``(where, qvec, tvec, camera_id, name)`` of each image line."""
    for where, f in _colmap_records(images_txt, 10,
                                    "IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME",
                                    points_lines=True):
        _int(f[0], where, "IMAGE_ID")
        vals = _floats(f[1:8], where, ("QW", "QX", "QY", "QZ", "TX", "TY", "TZ"))
        yield where, np.array(vals[:4]), vals[4:], _int(f[8], where, "CAMERA_ID"), \
            " ".join(f[9:])


class _Reader:
    """Little-endian fields of a COLMAP binary file, with the offset in messages."""

    def __init__(self, path: Path):
        try:
            self.data = path.read_bytes()
        except OSError as exc:
            raise ValueError(f"{path}: cannot read: {exc}") from None
        self.path, self.pos = path, 0

    def take(self, fmt: str):
        size = struct.calcsize("<" + fmt)
        if self.pos + size > len(self.data):
            raise ValueError(f"{self.path}: truncated at byte {self.pos} (expected {size} more "
                             "bytes)")
        out = struct.unpack_from("<" + fmt, self.data, self.pos)
        self.pos += size
        return out

    def name(self) -> str:
        end = self.data.find(b"\0", self.pos)
        if end < 0:
            raise ValueError(f"{self.path}: truncated image name at byte {self.pos}")
        s = self.data[self.pos:end].decode("utf-8", errors="replace")
        self.pos = end + 1
        return s

    def where(self) -> str:
        return f"{self.path}@{self.pos}"


def _binary_cameras(cameras_bin: Path) -> dict:
    r = _Reader(cameras_bin)
    (n,) = r.take("Q")
    cams = {}
    for _ in range(n):  # one record per camera
        where = r.where()
        cid, model_id, w, h = r.take("iiQQ")
        if model_id in _BY_ID:
            model = _BY_ID[model_id]
            count = len(_MODELS[model][1])
        elif model_id in _OTHER_MODELS:
            model, count = _OTHER_MODELS[model_id]
        else:
            raise ValueError(f"{where}: MODEL: unknown COLMAP camera model id {model_id}")
        params = [repr(v) for v in r.take("d" * count)]
        cams[cid] = _camera(model, int(w), int(h), params, where)
    return cams


def _binary_images(images_bin: Path):
    r = _Reader(images_bin)
    (n,) = r.take("Q")
    for _ in range(n):  # one record per image
        where = r.where()
        vals = r.take("I7dI")
        name = r.name()
        (n_points,) = r.take("Q")
        r.take(f"{24 * n_points}x")  # POINTS2D (x, y, POINT3D_ID): not needed
        if not all(math.isfinite(v) for v in vals[1:8]):
            raise ValueError(f"{where}: QVEC/TVEC: expected finite numbers")
        yield where, np.array(vals[1:5]), list(vals[5:8]), vals[8], name


def load_colmap(cameras_file: Path, options: ReadOptions):
    """Read a COLMAP text or binary model (see the module notes)."""
    model_dir = cameras_file.parent
    binary = cameras_file.suffix == ".bin"
    images_file = model_dir / ("images.bin" if binary else "images.txt")
    if not images_file.is_file():
        raise ValueError(f"{images_file}: missing (a COLMAP model has {cameras_file.name} and "
                         f"{images_file.name} side by side)")
    root = model_dir
    if model_dir.name == "sparse":
        root = model_dir.parent
    elif model_dir.parent.name == "sparse":
        root = model_dir.parent.parent
    cams = (_binary_cameras if binary else _text_cameras)(cameras_file)
    if not cams:
        raise ValueError(f"{cameras_file}: no cameras")
    if len({c[3] for c in cams.values()}) > 1:
        raise ValueError(f"{cameras_file}: the cameras mix fisheye and perspective models")
    images_dir, masks_dir = root / "images", root / "masks"
    views, K, q, t, dist = [], [], [], [], []
    for where, qv, tv, cid, name in (_binary_images if binary else _text_images)(images_file):
        if abs(np.linalg.norm(qv) - 1.0) > 1e-3:
            raise ValueError(f"{where}: QW QX QY QZ: expected a unit quaternion, got norm "
                             f"{np.linalg.norm(qv):.6g}")
        if cid not in cams:
            raise ValueError(f"{where}: CAMERA_ID: camera {cid} is not in {cameras_file.name}")
        image = _find_image(images_dir, name, f"{where}: NAME", options.allow_outside)
        mask = None
        if masks_dir.is_dir():
            for cand in (name, name + ".png", str(Path(name).with_suffix(".png"))):
                mask = _find_image(masks_dir, cand, f"{where}: NAME", options.allow_outside,
                                   extensions=(), required=False)
                if mask is not None:
                    break
            if mask is None:
                raise ValueError(f"{where}: NAME: no mask for {name!r} in {masks_dir} (tried "
                                 f"{name}, {name}.png, {Path(name).with_suffix('.png')})")
        K.append(cams[cid][0])
        dist.append(cams[cid][2])
        q.append(qv / np.linalg.norm(qv))
        t.append(tv)
        views.append({"image": image, "mask": mask, "where": where, "size": cams[cid][1]})
    if not views:
        raise ValueError(f"{images_file}: no images")
    fisheye = next(iter(cams.values()))[3]
    return build_dataset(views, cameras_file, np.stack(K), (np.stack(q), np.array(t)),
                         cameras_from_colmap, options, root, distortion=np.stack(dist),
                         fisheye=fisheye)


def detect(path: Path):
    """``("colmap", cameras file)`` for a COLMAP model (the folder, ``sparse/0``, ``sparse``,
    or the cameras file itself), else None."""
    if path.is_file():
        return ("colmap", path) if path.name in ("cameras.txt", "cameras.bin") else None
    for sub in (".", "sparse/0", "sparse"):
        for name in ("cameras.txt", "cameras.bin"):
            if (path / sub / name).is_file():
                return "colmap", path / sub / name
    return None


def save_colmap(root: Path, images: np.ndarray, sils: np.ndarray | None, cameras,
                bit_depth: int, overwrite: bool, background: np.ndarray | None) -> Path:
    """``sparse/0/{cameras,images,points3D}.txt`` (one PINHOLE camera per view),
    ``images/000.png`` (RGB) and ``masks/000.png`` (none without silhouettes; COLMAP has no
    place for the ``background``)."""
    target = _target(root / "sparse/0/cameras.txt", overwrite)
    N, H, W = images.shape[:3]
    names = [f"{i:03d}.png" for i in range(N)]
    (root / "images").mkdir(exist_ok=True)
    if sils is not None:
        (root / "masks").mkdir(exist_ok=True)
    for i in range(N):  # one file per view
        _write_image(root / "images" / names[i], images[i], bit_depth)
        if sils is not None:
            _write_image(root / "masks" / names[i], sils[i], bit_depth)
    q, t, K = colmap_from_cameras(cameras, (H, W))
    cam_lines = ["# Camera list with one line of data per camera:",
                 "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]", f"# Number of cameras: {N}"]
    img_lines = ["# Image list with two lines of data per image:",
                 "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
                 "#   POINTS2D[] as (X, Y, POINT3D_ID)", f"# Number of images: {N}"]
    for i in range(N):  # one line per view
        k = K[i]
        cam_lines.append(" ".join([f"{i + 1} PINHOLE {W} {H}"]
                                  + [repr(float(v)) for v in (k[0, 0], k[1, 1], k[0, 2], k[1, 2])]))
        img_lines.append(" ".join([str(i + 1)] + [repr(float(v)) for v in q[i]]
                                  + [repr(float(v)) for v in t[i]] + [str(i + 1), names[i]]))
        img_lines.append("")
    write_text(target.parent / "images.txt", "\n".join(img_lines) + "\n")
    write_text(target.parent / "points3D.txt",
               "# 3D point list (empty: geofit writes cameras only)\n")
    write_text(target, "\n".join(cam_lines) + "\n")  # last: its presence marks a capture
    return target


_loaders = {"colmap": load_colmap}
_savers = {"colmap": save_colmap}
