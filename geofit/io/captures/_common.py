"""What every capture layout shares: parsing checks, the read options, and the one place a
layout's views become a :class:`geofit.structures.MultiViewDataset` (private to geofit.io)."""
from __future__ import annotations

import io
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import png  # pypng: pillow cannot write 16-bit colour PNGs
from PIL import Image

from ..._atomic import write_bytes
from ...structures import MultiViewDataset
from .._jsonread import parse_json
from ._files import _gather
from ._undistort import undistort

_ROTATION_TOL = 1e-4


@dataclass(frozen=True)
class ReadOptions:
    """The options of :func:`geofit.io.load_views` every layout's loader receives."""

    allow_outside: bool = False
    background: np.ndarray | None = None
    znear: float = 1.0
    zfar: float = 100.0
    name: str | None = None
    max_pixels: int | None = None


# --------------------------------------------------------------------------------------------
# Parsing
# --------------------------------------------------------------------------------------------


def _matrix(value, shape: tuple, where: str) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: expected a {_shape_text(shape)} array of numbers, got "
                         f"{str(value)[:60]!r}") from None
    if a.shape != shape:
        raise ValueError(f"{where}: expected shape {_shape_text(shape)}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{where}: expected finite numbers")
    return a


def _shape_text(shape: tuple) -> str:
    return "x".join(str(s) for s in shape)


def _rotation(R: np.ndarray, where: str) -> np.ndarray:
    """Check ``R`` is a rotation (to 1e-4) and return the nearest exact one."""
    err = np.abs(R @ R.T - np.eye(3)).max()
    det = np.linalg.det(R)
    if err > _ROTATION_TOL or abs(det - 1.0) > _ROTATION_TOL:
        raise ValueError(f"{where}: not a rotation (max|R R^T - I| = {err:.3g}, det {det:.6g}); "
                         "expected an orthonormal matrix with determinant +1, no scale")
    U, _, Vt = np.linalg.svd(R)
    return U @ Vt


def _number(d: dict, key: str, where: str, positive: bool = True) -> float:
    v = d[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
            or (positive and v <= 0):
        kind = "a positive number" if positive else "a finite number"
        raise ValueError(f"{where}.{key}: expected {kind}, got {v!r}")
    return float(v)


def _colour(value, where: str) -> np.ndarray:
    """An RGB colour in [0, 1] from a capture's metadata."""
    c = _matrix(value, (3,), where)
    if c.min() < 0 or c.max() > 1:
        raise ValueError(f"{where}: expected RGB values in [0, 1], got {c.tolist()}")
    return c


def _read_json(path: Path) -> dict:
    try:
        with open(path, "rb") as f:
            text = f.read()
    except OSError as exc:
        raise ValueError(f"{path}: cannot read JSON: {exc}") from None
    data = parse_json(text, str(path))  # nesting, huge integers: ValueError naming the file
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a JSON object at the top level, got "
                         f"{type(data).__name__}")
    return data


def _json_entries(file: Path, key: str):
    """The JSON object of ``file`` and ``(where, entry)`` for each object in its list ``key``."""
    data = _read_json(file)
    entries = data.get(key)
    if not isinstance(entries, list) or not entries:
        raise ValueError(f"{file}: {key}: expected a non-empty list of {key}")
    for i, e in enumerate(entries):
        if not isinstance(e, dict):
            raise ValueError(f"{file}: {key}[{i}]: expected an object, got {type(e).__name__}")
    return data, [(f"{file}: {key}[{i}]", e) for i, e in enumerate(entries)]


# --------------------------------------------------------------------------------------------
# The one place a capture becomes a dataset
# --------------------------------------------------------------------------------------------


def build_dataset(views: list, file: Path, K, pose: tuple, convert: Callable,
                  options: ReadOptions, folder: Path, *, distortion: np.ndarray | None = None,
                  fisheye: bool = False, background: np.ndarray | None = None
                  ) -> MultiViewDataset:
    """Read the views' images (and masks) and build the dataset.

    Parameters
    ----------
    views : list of dict
        ``image`` (Path), ``where`` (str), optional ``mask`` (Path) and ``size`` ((H, W)).
    file : Path
        The camera file (for messages).
    K : (N, 3, 3) float64 or callable
        Pixel intrinsics (corner convention), or ``K(H, W)`` when they depend on the image size.
    pose : tuple
        The leading arguments of ``convert`` (e.g. ``(R, t)``).
    convert : callable
        A :mod:`geofit.cameras.conversions` function ``convert(*pose, K, (H, W), znear=,
        zfar=)``.
    options : ReadOptions
        From :func:`geofit.io.load_views`.
    folder : Path
        The capture folder (its name is the dataset's default name).
    distortion : (N, 8) or (N, 4) float64, optional
        OpenCV's distortion coefficients of each view (see :mod:`._undistort`): the images and
        masks are undistorted to the pinhole camera with the same ``K``.
    fisheye : bool
        ``distortion`` holds OpenCV's fisheye coefficients.
    background : (3,) float64, optional
        The background colour the capture's metadata names.

    Notes
    -----
    The dataset's ``background``: ``options.background`` (the caller's; RGBA images are
    composited over it), else the metadata's (it names the colour already in the pixels, as
    :func:`geofit.io.save_views` writes it), else the colour of the pixels outside every
    silhouette when they are uniform (99% within 2/255 of their median), else None (unknown).
    Silhouettes are None (unknown) when no view has a mask or an alpha channel. ``lights``
    stay None: a capture's lighting is in its pixels.
    """
    images, sils = _gather(views, str(file), options.background, options.max_pixels)
    bg = options.background if options.background is not None else background
    H, W = images.shape[1:3]
    K = K(H, W) if callable(K) else K
    if distortion is not None and np.any(distortion != 0):
        images, sils = undistort(images, sils, K, distortion, fisheye)
    if bg is None and sils is not None:
        bg = _uniform_background(images, sils)
    cameras = convert(*pose, K, (H, W), znear=options.znear, zfar=options.zfar)
    C = cameras.get_camera_center()
    r = np.linalg.norm(C, axis=1)
    elev = np.degrees(np.arcsin(np.clip(C[:, 1] / np.maximum(r, 1e-300), -1.0, 1.0)))
    azim = np.degrees(np.arctan2(C[:, 0], C[:, 2]))
    return MultiViewDataset(images=images, silhouettes=sils, cameras=cameras, background=bg,
                            name=options.name or folder.resolve().name, azim=azim, elev=elev)


def _uniform_background(images: np.ndarray, sils: np.ndarray) -> np.ndarray | None:
    """The median colour of the pixels outside every silhouette when 99% of them lie within
    2/255 of it (a rendered or keyed background), else None."""
    px = images[sils == 0.0]
    if len(px) < 16:
        return None
    med = np.median(px, axis=0)
    if np.quantile(np.abs(px - med).max(axis=1), 0.99) > 2.0 / 255.0:
        return None
    return med


def metadata_background(data: dict, where: str) -> np.ndarray | None:
    """``data["background"]`` (RGB in [0, 1]) of a capture's JSON, or None."""
    if data.get("background") is None:
        return None
    return _colour(data["background"], f"{where}.background")


# --------------------------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------------------------


def _write_image(path: Path, a: np.ndarray, bit_depth: int) -> None:
    """Write ``(H, W)`` grey, ``(H, W, 3)`` RGB or ``(H, W, 4)`` RGBA in [0, 1] as a PNG
    (encoded in memory, then written atomically by :func:`geofit._atomic.write_bytes`)."""
    buf = io.BytesIO()
    if bit_depth == 8:
        Image.fromarray(np.round(a * 255.0).astype(np.uint8)).save(buf, format="PNG")
    else:
        b = np.round(a * 65535.0).astype(np.uint16)
        if b.ndim == 2:
            Image.fromarray(b).save(buf, format="PNG")  # pillow writes 16-bit greyscale (I;16)
        else:
            mode = "RGBA;16" if b.shape[2] == 4 else "RGB;16"
            png.from_array(b.reshape(b.shape[0], -1), mode).write(buf)
    write_bytes(path, buf.getbuffer())


def _target(file: Path, overwrite: bool) -> Path:
    """``file``, refused if it exists without ``overwrite``; its folder created."""
    if file.exists() and not overwrite:
        raise ValueError(f"path: {str(file)!r} exists (pass overwrite=True to replace it)")
    file.parent.mkdir(parents=True, exist_ok=True)
    return file
