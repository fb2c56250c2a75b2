"""The decoded-pixel cap for every image geofit reads (issue 28 point 2).

Textures (OBJ ``map_Kd``), capture images and masks, and the images inside GLB/glTF files are
checked from their headers before a pixel is decoded: PIL opens lazily, so ``im.size`` is known
after ``Image.open`` and before ``im.load()``. An image of more than ``max_pixels`` pixels is
refused with a ValueError naming the file and its size. A 140 KB PNG can declare 12000 x 12000
pixels (1.7 GB once decoded as float64): the cap is what keeps such a file harmless.

The default, :data:`DEFAULT_MAX_PIXELS` = 2**24 (a 4096 x 4096 texture), keeps the float64
copy a loader makes below about 0.5 GB; a caller raises it with ``max_pixels=``.

PIL's own guard (``DecompressionBombWarning`` above ``Image.MAX_IMAGE_PIXELS``, an error above
twice that) is replaced by this cap, not silenced: the warning is ignored only while the header
is read, the cap is applied right after, and a caller's ``max_pixels`` above PIL's limit is
honoured (PIL's limit is lifted to it for that one open, under a lock).
"""
from __future__ import annotations

import contextlib
import io
import threading
import warnings

__all__ = ["DEFAULT_MAX_PIXELS", "as_max_pixels", "check_pixels", "check_image_bytes",
           "open_image"]

#: Default cap on the decoded pixels (width x height) of one image: a 4096 x 4096 texture.
DEFAULT_MAX_PIXELS = 1 << 24

_PIL_LIMIT_LOCK = threading.Lock()


def as_max_pixels(max_pixels, name: str = "max_pixels") -> int:
    """Check a ``max_pixels`` argument: None (the default cap) or a positive integer."""
    if max_pixels is None:
        return DEFAULT_MAX_PIXELS
    if isinstance(max_pixels, bool) or not isinstance(max_pixels, int):
        try:
            import numpy as np

            if isinstance(max_pixels, np.integer):
                max_pixels = int(max_pixels)
            else:
                raise TypeError
        except TypeError:
            raise TypeError(f"{name}: expected None or a positive integer, got "
                            f"{type(max_pixels).__name__} {max_pixels!r:.40}") from None
    if max_pixels < 1:
        raise ValueError(f"{name}: expected None or a positive integer, got {max_pixels}")
    return max_pixels


def check_pixels(width: int, height: int, where: str, max_pixels) -> None:
    """Refuse an image of ``width x height`` pixels above ``max_pixels`` (ValueError)."""
    cap = as_max_pixels(max_pixels)
    if width * height > cap:
        raise ValueError(f"{where}: the image is {width}x{height} = {width * height:,} pixels, "
                         f"over the decoded-pixel cap of {cap:,} (checked from its header "
                         f"before decoding; pass max_pixels= to raise the cap)")


@contextlib.contextmanager
def open_image(source, where: str, max_pixels=None):
    """``PIL.Image.open(source)`` with the size checked against the cap before any decoding.

    ``source`` is a path or a binary file object. Yields the lazily opened image (call
    ``load()``, ``np.asarray`` or ``convert`` on it); errors while opening become ValueError
    naming ``where``.
    """
    from PIL import Image

    cap = as_max_pixels(max_pixels)
    pil_limit = Image.MAX_IMAGE_PIXELS
    try:
        if pil_limit is not None and cap > 2 * pil_limit:  # the caller raised the cap past PIL
            with _PIL_LIMIT_LOCK:
                Image.MAX_IMAGE_PIXELS = cap
                try:
                    im = _open_quiet(Image, source)
                finally:
                    Image.MAX_IMAGE_PIXELS = pil_limit
        else:
            im = _open_quiet(Image, source)
    except Image.DecompressionBombError as exc:  # over twice PIL's limit and over the cap
        raise ValueError(f"{where}: the image is over the decoded-pixel cap ({exc})") from None
    except (OSError, SyntaxError, EOFError, ValueError) as exc:
        raise ValueError(f"{where}: not a readable image ({type(exc).__name__}: "
                         f"{str(exc)[:200]})") from None
    with im:
        w, h = im.size
        check_pixels(w, h, where, cap)
        yield im


def _open_quiet(Image, source):
    with warnings.catch_warnings():
        # the cap is checked by the caller right after the header is read, before decoding
        warnings.simplefilter("ignore", Image.DecompressionBombWarning)
        return Image.open(source)


def check_image_bytes(data: bytes, where: str, max_pixels=None) -> None:
    """Check an encoded image held in memory (a GLB image) against the cap, from its header."""
    with open_image(io.BytesIO(data), where, max_pixels):
        pass
