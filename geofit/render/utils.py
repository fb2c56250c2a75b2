"""Showing renders and textures: image grids and the UV layout over a texture image."""
from __future__ import annotations

import math

import numpy as np

from .._validate import as_array, as_rng
from ..structures import TexturesUV

__all__ = ["image_grid", "make_grid", "plot_texture_uv", "texturesuv_image_matplotlib"]


def _grid_shape(n: int, rows, cols) -> tuple[int, int]:
    for name, v in (("rows", rows), ("cols", cols)):
        if v is not None and (not isinstance(v, (int, np.integer)) or isinstance(v, bool)
                              or v < 1):
            raise ValueError(f"{name}: expected None or an integer >= 1, got {v!r}")
    if rows is None and cols is None:
        cols = math.ceil(math.sqrt(n))
        rows = math.ceil(n / cols)
    elif rows is None:
        rows = math.ceil(n / cols)
    elif cols is None:
        cols = math.ceil(n / rows)
    if rows * cols < n:
        raise ValueError(f"rows, cols: a {rows} x {cols} grid cannot hold {n} images")
    return int(rows), int(cols)


def _images(images) -> np.ndarray:
    a = as_array(images, "images", dtype=np.float32, finite=False)
    if a.ndim == 3:
        a = a[..., None]
    if a.ndim != 4 or a.shape[0] == 0:
        raise ValueError(f"images: expected shape (N, H, W, C) with N >= 1, got {a.shape}")
    return a


def make_grid(images, rows: int | None = None, cols: int | None = None, *, rgb: bool = True,
              pad: int = 0, background: float = 1.0) -> np.ndarray:
    """Tile a batch of images into one image (for saving or a single ``imshow``).

    Parameters
    ----------
    images : (N, H, W, C) or (N, H, W) float
        The batch; with ``rgb`` the first three channels are used, otherwise the last one
        (the alpha of RGBA renders).
    rows, cols : int, optional
        Grid shape; by default a near-square grid (``cols = ceil(sqrt(N))``).
    rgb : bool
        RGB channels (True) or the last channel (False).
    pad : int
        Pixels between tiles.
    background : float
        Value of the padding and of empty cells.

    Returns
    -------
    grid : (rows * H + (rows - 1) * pad, cols * W + (cols - 1) * pad, C') float32
        ``C' = 3`` (or 1 with ``rgb=False``); image ``i`` sits in row ``i // cols``, column
        ``i % cols``.

    Raises
    ------
    ValueError
        For a bad shape or a grid too small for the batch.

    Examples
    --------
    >>> make_grid(np.zeros((5, 2, 3, 4)), pad=1).shape
    (5, 11, 3)
    """
    a = _images(images)
    N, H, W, C = a.shape
    rows, cols = _grid_shape(N, rows, cols)
    if not isinstance(pad, (int, np.integer)) or pad < 0:
        raise ValueError(f"pad: expected an integer >= 0, got {pad!r}")
    a = a[..., :3] if (rgb and C >= 3) else a[..., -1:]
    c = a.shape[3]
    out = np.full((rows * H + (rows - 1) * pad, cols * W + (cols - 1) * pad, c), background,
                  dtype=np.float32)
    for i in range(N):  # loop over images of the batch
        r, q = divmod(i, cols)
        out[r * (H + pad):r * (H + pad) + H, q * (W + pad):q * (W + pad) + W] = a[i]
    return out


def image_grid(images, rows: int | None = None, cols: int | None = None, fill: bool = True,
               show_axes: bool = False, rgb: bool = True, *, titles=None, figsize=None):
    """Show a batch of images in a matplotlib grid (PyTorch3D's tutorial ``image_grid``).

    Parameters
    ----------
    images : (N, H, W, C) float
        RGBA renders (or any images).
    rows, cols : int, optional
        Grid shape; by default near-square (PyTorch3D's default is one column).
    fill : bool
        No space between the tiles.
    show_axes : bool
        Keep the axes' ticks and frames.
    rgb : bool
        Show the RGB channels (True) or the last channel, e.g. alpha (False).
    titles : sequence of str, optional
        One title per image.
    figsize : (float, float), optional
        Matplotlib figure size in inches (default: 3 inches per tile).

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib.pyplot as plt  # kept local: matplotlib, loaded only when used (start-up)

    a = _images(images)
    N = a.shape[0]
    rows, cols = _grid_shape(N, rows, cols)
    if titles is not None and len(titles) != N:
        raise ValueError(f"titles: expected {N} titles, got {len(titles)}")
    gridspec_kw = {"wspace": 0.0, "hspace": 0.0} if fill else {}
    fig, axes = plt.subplots(rows, cols, gridspec_kw=gridspec_kw, squeeze=False,
                             figsize=figsize or (3.0 * cols, 3.0 * rows))
    for i, ax in enumerate(axes.ravel()):  # loop over tiles
        if i < N:
            im = a[i, ..., :3] if (rgb and a.shape[3] >= 3) else a[i, ..., -1]
            ax.imshow(np.clip(im, 0.0, 1.0), cmap=None if im.ndim == 3 else "gray",
                      vmin=0.0, vmax=1.0)
            if titles is not None:
                ax.set_title(str(titles[i]))
        if not show_axes or i >= N:
            ax.set_axis_off()
    return fig


def _check_uv(textures) -> TexturesUV:
    if not isinstance(textures, TexturesUV):
        raise TypeError(f"textures: expected TexturesUV, got {type(textures)!r}")
    return textures


def _texture_axes(textures, ax, *, cmap_gray: bool = False, interpolation=None):
    """The checked TexturesUV and the axes (new 7x7 figure if None) with its map drawn on
    the unit UV square."""
    import matplotlib.pyplot as plt  # kept local: matplotlib, loaded only when used (start-up)

    tex = _check_uv(textures)
    if ax is None:
        _, ax = plt.subplots(figsize=(7, 7))
    maps = tex.maps
    img = maps[..., :3] if maps.shape[2] >= 3 else maps[..., 0]
    extra = {"interpolation": interpolation} if interpolation else {}
    if cmap_gray:
        extra["cmap"] = None if img.ndim == 3 else "gray"
    ax.imshow(np.clip(img, 0, 1), extent=(0.0, 1.0, 0.0, 1.0), origin="upper", **extra)
    return tex, ax


def plot_texture_uv(textures, ax=None, *, color=(1.0, 0.0, 0.0), linewidth: float = 0.3,
                    alpha: float = 0.8):
    """Show a texture image with the mesh's UV layout (the triangles in UV space) drawn over it.

    The image is drawn on ``[0, 1]^2`` with u to the right and v up (row 0 of the image at
    v = 1), which is where PyTorch3D's sampling convention puts it: every drawn triangle covers
    exactly the texels its face samples.

    Parameters
    ----------
    textures : TexturesUV
    ax : matplotlib Axes, optional
        Where to draw (default: a new figure).
    color : colour
        Colour of the triangle edges.
    linewidth, alpha : float
        Line width and opacity of the edges.

    Returns
    -------
    matplotlib.axes.Axes
    """
    from matplotlib.collections import LineCollection  # kept local: start-up

    tex, ax = _texture_axes(textures, ax, cmap_gray=True, interpolation="bilinear")
    uv = tex.face_uvs()                                      # (F, 3, 2)
    segs = np.stack([uv, np.roll(uv, -1, axis=1)], axis=2).reshape(-1, 2, 2)
    ax.add_collection(LineCollection(segs, colors=[color], linewidths=linewidth, alpha=alpha))
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.set_xlabel("u")
    ax.set_ylabel("v")
    return ax


def texturesuv_image_matplotlib(textures, *, subsample: int | None = 10000, ax=None,
                                color=(1.0, 0.0, 0.0), radius: float = 0.01, seed=0):
    """PyTorch3D's ``texturesuv_image_matplotlib``: the texture with the UV points as dots.

    Parameters
    ----------
    textures : TexturesUV
    subsample : int or None
        Draw a random subset of this many UV points (None: all).
    ax : matplotlib Axes, optional
    color : colour
    radius : float
        Dot radius in UV units.
    seed : int or numpy.random.Generator
        For the subset.

    Returns
    -------
    matplotlib.axes.Axes
    """
    from matplotlib.collections import EllipseCollection  # kept local: start-up

    tex, ax = _texture_axes(textures, ax)
    uv = tex.verts_uvs
    if subsample is not None and len(uv) > subsample:
        uv = uv[as_rng(seed).choice(len(uv), int(subsample), replace=False)]
    d = np.full(len(uv), 2 * radius)
    ax.add_collection(EllipseCollection(d, d, np.zeros(len(uv)), units="xy", offsets=uv,
                                        transOffset=ax.transData, facecolors=[color]))
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    return ax
