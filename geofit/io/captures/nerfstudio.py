"""nerfstudio's ``transforms.json``: the NeRF layout with a ``camera_model``.

The same frames as :mod:`.transforms` (``file_path``, ``mask_path``, ``transform_matrix``,
intrinsics at the top level or per frame) and a ``camera_model``: ``OPENCV`` (also ``PINHOLE``,
``SIMPLE_PINHOLE``) with ``k1 k2 k3 p1 p2``, or ``OPENCV_FISHEYE`` with ``k1..k4``; the images
and masks are undistorted with OpenCV (same ``K``); ``k4`` of a perspective camera (an ``r^8``
term OpenCV lacks) and other models (``EQUIRECTANGULAR``) are refused with a message.
"""
from __future__ import annotations

from pathlib import Path

from ._common import _read_json
from .transforms import load_transforms


def _is_nerfstudio(file: Path) -> bool:
    data = _read_json(file)
    return "frames" in data and "camera_model" in data


def detect(path: Path):
    """``("nerfstudio", file)`` for a transforms.json naming a ``camera_model``, else None."""
    file = path / "transforms.json" if path.is_dir() else path
    if file.is_file() and file.suffix.lower() == ".json" and _is_nerfstudio(file):
        return "nerfstudio", file
    return None


_loaders = {"nerfstudio": load_transforms}
