"""Capture files: paths inside the capture folder, images, masks (private to geofit.io).

The helpers every capture layout shares to find and read its image and mask files (moved here
from ``geofit/io/views.py``): every path through :class:`geofit.io._paths.PathPolicy`, every
image's pixel count checked from its header (:mod:`geofit.io._images`, ``max_pixels``).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

_IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".PNG", ".JPG", ".JPEG", ".tif", ".tiff", ".bmp",
               ".webp")


# --------------------------------------------------------------------------------------------
# Files: paths and images
# --------------------------------------------------------------------------------------------


def _find_image(root: Path, ref, where: str, allow_outside: bool, *,
                extensions=_IMAGE_EXTS, required: bool = True) -> Path | None:
    """The checked path of image ``ref`` under ``root`` (or ``ref`` plus an image extension,
    for a ``file_path`` without one): every candidate goes through the one path policy
    (:class:`geofit.io._paths.PathPolicy`: a regular file inside ``root`` after symlinks)."""
    from .._paths import PathPolicy

    try:
        return PathPolicy(root, allow_outside=allow_outside, folder_name="capture folder").resolve(
            ref, where, extensions=extensions, required=required)
    except FileNotFoundError:
        raise ValueError(f"{where}: image {str(Path(root) / ref)!r} not found (also tried the "
                         f"extensions {', '.join(_IMAGE_EXTS[:3])}, ...)") from None


def _is_png16_colour(path: Path) -> bool:
    with open(path, "rb") as f:
        head = f.read(26)
    return (len(head) == 26 and head[:8] == b"\x89PNG\r\n\x1a\n" and head[24] == 16
            and head[25] in (2, 4, 6))


def _read_image(path: Path, where: str, max_pixels=None) -> np.ndarray:
    """An image file as ``(H, W, C)`` float64 in [0, 1], ``C`` in 1..4 (grey, grey+alpha, RGB,
    RGBA); errors become ValueError naming the file. The pixel count is checked against
    ``max_pixels`` from the header, before decoding (:mod:`geofit.io._images`)."""
    from PIL import Image

    from .._images import check_pixels, open_image

    try:
        if _is_png16_colour(path):
            import png  # pypng: pillow reduces 16-bit colour PNGs to 8 bits

            with open(path, "rb") as f:
                reader = png.Reader(file=f)
                reader.preamble()
                check_pixels(reader.width, reader.height,
                             f"{where}: cannot read image {str(path)!r}", max_pixels)
                w, h, flat, info = reader.read_flat()
            a = np.asarray(flat, dtype=np.uint16).reshape(h, w, info["planes"])
            a = a.astype(np.float64) / 65535.0
        else:
            with open_image(path, f"{where}: cannot read image {str(path)!r}", max_pixels) as im:
                mode = im.mode
                if mode in ("I;16", "I;16B", "I;16L", "I"):
                    a = np.asarray(im, dtype=np.float64) / 65535.0
                elif mode == "F":
                    a = np.asarray(im, dtype=np.float64)
                else:
                    if mode not in ("L", "LA", "RGB", "RGBA"):
                        alpha = "A" in im.getbands() or "transparency" in im.info
                        im = im.convert("RGBA" if alpha else "RGB")
                    a = np.asarray(im, dtype=np.float64) / 255.0
    except (OSError, ValueError, SyntaxError, EOFError, Image.DecompressionBombError,
            _png_error()) as exc:
        if isinstance(exc, ValueError) and str(exc).startswith(where):  # already names it
            raise
        raise ValueError(f"{where}: cannot read image {str(path)!r}: {exc}") from None
    if a.ndim == 2:
        a = a[..., None]
    if a.ndim != 3 or a.shape[2] not in (1, 2, 3, 4) or a.shape[0] == 0 or a.shape[1] == 0:
        raise ValueError(f"{where}: image {str(path)!r} has unsupported shape {a.shape}")
    if not np.all(np.isfinite(a)) or a.min() < 0.0 or a.max() > 1.0:
        raise ValueError(f"{where}: image {str(path)!r} has values outside [0, 1]")
    return a


def _png_error():
    import png

    return png.Error


def _split_rgba(a: np.ndarray):
    """RGB ``(H, W, 3)`` and alpha ``(H, W)`` (None without alpha) of a read image."""
    c = a.shape[2]
    rgb = np.repeat(a[..., :1], 3, axis=2) if c in (1, 2) else a[..., :3]
    alpha = a[..., -1] if c in (2, 4) else None
    return rgb, alpha


def _mask_values(a: np.ndarray) -> np.ndarray:
    """A mask image as ``(H, W)``: grey value, or the mean of RGB."""
    return a[..., 0] if a.shape[2] in (1, 2) else a[..., :3].mean(axis=2)


def _gather(views: list, where_file: str, background, max_pixels=None):
    """Read every view's image (and mask); check one common size.

    ``views`` holds dicts with ``image`` (Path), ``where`` and optional ``mask`` (Path) and
    ``size`` ((H, W) declared by the camera file). Returns images ``(N, H, W, 3)``, silhouettes
    ``(N, H, W)`` (None when no view has a mask or alpha: silhouettes unknown).
    """
    images, sils, size0 = [], [], None
    for v in views:  # one file per view
        a = _read_image(v["image"], v["where"], max_pixels)
        rgb, alpha = _split_rgba(a)
        if v.get("mask") is not None:
            sil = _mask_values(_read_image(v["mask"], v["where"], max_pixels))
            if sil.shape != rgb.shape[:2]:
                raise ValueError(f"{v['where']}: mask {str(v['mask'])!r} is {sil.shape[0]}x"
                                 f"{sil.shape[1]}, its image {rgb.shape[0]}x{rgb.shape[1]}")
        elif alpha is not None:
            sil = alpha
        else:
            sil = None
        if background is not None and alpha is not None:
            rgb = rgb * alpha[..., None] + background * (1.0 - alpha[..., None])
        hw = rgb.shape[:2]
        if v.get("size") is not None and tuple(v["size"]) != hw:
            raise ValueError(f"{v['where']}: image {str(v['image'])!r} is {hw[0]}x{hw[1]} "
                             f"(HxW), the camera says {v['size'][0]}x{v['size'][1]}")
        if size0 is None:
            size0 = hw
        elif hw != size0:
            raise ValueError(f"{v['where']}: image {str(v['image'])!r} is {hw[0]}x{hw[1]}, "
                             f"the first view's {size0[0]}x{size0[1]}: every view of "
                             f"{where_file} must have the same size")
        if sils and (sil is None) != (sils[0] is None):
            raise ValueError(f"{v['where']}: image {str(v['image'])!r} "
                             f"{'has no' if sil is None else 'has a'} mask or alpha channel, "
                             f"the first view's {'has' if sil is None else 'has none'}: give "
                             "every view a mask, or none")
        images.append(rgb)
        sils.append(sil)
    if sils[0] is None:
        return np.ascontiguousarray(np.stack(images)), None
    return np.ascontiguousarray(np.stack(images)), np.ascontiguousarray(np.stack(sils))
