"""Multi-view captures in and out: :func:`load_views` and :func:`save_views`.

:func:`load_views` reads a capture folder (or its camera file) into a
:class:`geofit.structures.MultiViewDataset`; :func:`save_views` writes a dataset back out, so a
fitted scene and its cameras can be opened by other tools. The layouts live in
:mod:`geofit.io.captures`, one module per layout, merged in one table through which
:func:`load_views` detects the layout:

``transforms`` (NeRF/Blender, instant-ngp)
    ``transforms.json``; ``nerf_synthetic``: the Blender dataset's folder with
    ``transforms_train.json`` and ``transforms_test.json`` / ``transforms_val.json`` (the test
    views become ``held_out``).
``nerfstudio``
    ``transforms.json`` with a ``camera_model`` and ``k1..k4``, ``p1``, ``p2`` distortion.
``colmap``
    ``cameras.txt`` + ``images.txt`` or ``cameras.bin`` + ``images.bin`` (in the folder,
    ``sparse/0`` or ``sparse``), ``images/`` and optional ``masks/``.
``opencv``
    geofit's own ``cameras.json`` with OpenCV's ``K``, ``R``, ``t`` (and ``dist``) per view.

Lens distortion is undistorted with OpenCV (images and masks resampled to the pinhole camera
with the same ``K``) or refused with a message, never ignored.

Pixel coordinates are those of :mod:`geofit.cameras.conversions` (and COLMAP's, nerfstudio's):
(0, 0) is the top-left corner of the top-left pixel, pixel centres at ``i + 0.5``.

Images are read with pillow (8-bit: value / 255; 16-bit greyscale: value / 65535); 16-bit colour
PNGs, which pillow reduces to 8 bits, are read and written with pypng so they keep their values.
Without mask files or an alpha channel the silhouettes are unknown (None). Referenced files must lie inside the capture folder: an absolute path or one that
leaves it (``../``) is refused unless ``allow_outside=True``.
"""
from __future__ import annotations

from pathlib import Path


from .._validate import as_array
from .captures import LOADERS, SAVERS, detect
from .captures._common import ReadOptions

__all__ = ["VIEW_FORMATS", "load_views", "save_views"]

#: The layouts :func:`save_views` writes (:func:`load_views` reads these and more).
VIEW_FORMATS = tuple(SAVERS)


def load_views(path, *, allow_outside: bool = False, background=None, znear: float = 1.0,
               zfar: float = 100.0, name: str | None = None, max_pixels: int | None = None):
    """Load a multi-view capture: images, silhouettes and cameras.

    Parameters
    ----------
    path : str or Path
        A capture folder or its camera file (e.g. a ``transforms_test.json``), in any layout
        of :mod:`geofit.io.captures` (found by :func:`geofit.io.captures.detect`).
    allow_outside : bool
        Allow image and mask paths that are absolute or lead out of the capture folder.
    background : (3,) float64, optional
        Composite RGBA images over this colour (``rgb * alpha + background * (1 - alpha)``);
        by default the stored RGB is kept as it is. The dataset's ``background`` is this
        colour, else the one the capture's metadata names (``"background"`` in
        ``transforms.json`` or ``cameras.json``, as :func:`save_views` writes it), else the
        uniform colour of the pixels outside every silhouette, else None (unknown).
    znear, zfar : float
        Clipping planes of the cameras (captures do not store them).
    name : str, optional
        The dataset's name (default: the capture folder's name).
    max_pixels : int, optional
        Most pixels (width x height) one image or mask may have, checked from its header before
        decoding; default 2**24 (see :mod:`geofit.io._images`).

    Returns
    -------
    MultiViewDataset
        ``images (N, H, W, 3)`` and ``silhouettes (N, H, W)`` float64 in [0, 1] and ``N``
        cameras: :class:`~geofit.cameras.FoVPerspectiveCameras` when every principal point is
        the image centre, else :class:`~geofit.cameras.PerspectiveCameras`. Silhouettes are
        the masks, else the alpha channel, else None (unknown; see
        :data:`geofit.structures.views.UNKNOWN_SILHOUETTES`). ``lights`` is None: a capture's
        lighting is in its pixels, and the fits that shade fit unlit colour. The
        NeRF-synthetic split folder gives its test views as ``held_out``.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    ValueError
        For bad input, naming the file and the field: a missing or unreadable image, a
        ``transform_matrix`` or ``R`` that is not a rotation, an unsupported COLMAP camera
        model, a malformed line, images of different sizes, a path outside the folder.

    Examples
    --------
    >>> import tempfile
    >>> from geofit.datasets import held_out_views
    >>> data = held_out_views(num_views=4, image_size=16, n_azimuths=3, elevations=(0.0,))
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     _ = save_views(tmp, data, format="transforms")
    ...     back = load_views(tmp)
    >>> back.images.shape, back.silhouettes.shape, len(back.cameras)
    ((3, 16, 16, 3), (3, 16, 16), 3)
    """
    path = Path(path)
    layout, file = detect(path)
    if background is not None:
        background = as_array(background, "background", (3,))
        if background.min() < 0 or background.max() > 1:
            raise ValueError(f"background: expected RGB in [0, 1], got {background.tolist()}")
    if not isinstance(allow_outside, bool):
        raise TypeError(f"allow_outside: expected True or False, got {allow_outside!r}")
    from ._images import as_max_pixels

    options = ReadOptions(allow_outside=allow_outside, background=background, znear=znear,
                          zfar=zfar, name=name, max_pixels=as_max_pixels(max_pixels))
    return LOADERS[layout](file, options)


def _check_dataset(dataset):
    for key in ("images", "silhouettes", "cameras"):
        if not hasattr(dataset, key):
            raise TypeError(f"dataset: expected a MultiViewDataset (images, silhouettes, "
                            f"cameras), got {type(dataset).__name__} without {key!r}")
    images = as_array(dataset.images, "dataset.images")
    if images.ndim != 4 or images.shape[3] != 3 or images.shape[0] == 0:
        raise ValueError(f"dataset.images: expected shape (N, H, W, 3), got {images.shape}")
    sils = None  # silhouettes unknown: no masks, no alpha
    if dataset.silhouettes is not None:
        sils = as_array(dataset.silhouettes, "dataset.silhouettes")
        if sils.shape != images.shape[:3]:
            raise ValueError(f"dataset.silhouettes: expected shape {images.shape[:3]}, got "
                             f"{sils.shape}")
    for nm, a in (("images", images), ("silhouettes", sils)):
        if a is not None and (a.min() < 0 or a.max() > 1):
            raise ValueError(f"dataset.{nm}: expected values in [0, 1], got range "
                             f"[{a.min():g}, {a.max():g}]")
    if len(dataset.cameras) != images.shape[0]:
        raise ValueError(f"dataset.cameras: expected {images.shape[0]} cameras, got "
                         f"{len(dataset.cameras)}")
    return images, sils, dataset.cameras


def save_views(path, dataset, format: str = "transforms", *, bit_depth: int = 8,
               overwrite: bool = False) -> Path:
    """Write a multi-view dataset (images, silhouettes, cameras) as a capture folder.

    Parameters
    ----------
    path : str or Path
        Folder to write (created if needed).
    dataset : MultiViewDataset
        Anything with ``images (N, H, W, 3)``, ``silhouettes (N, H, W)`` in [0, 1] (or None:
        no masks written) and ``N`` perspective ``cameras``; its ``background`` colour, when
        set, is written to the camera file of the JSON layouts.
    format : {"transforms", "colmap", "opencv"}
        One of :data:`VIEW_FORMATS`:
        ``"transforms"``: ``transforms.json`` and RGBA PNGs ``images/r_000.png`` (alpha = the
        silhouette); ``"colmap"``: ``sparse/0/{cameras,images,points3D}.txt`` (one PINHOLE
        camera per view), ``images/000.png`` (RGB) and ``masks/000.png``; ``"opencv"``:
        ``cameras.json``, ``images/000.png`` and ``masks/000.png``.
    bit_depth : {8, 16}
        PNG bits per channel.
    overwrite : bool
        Replace an existing camera file (otherwise refused).

    Returns
    -------
    Path
        The camera file written (``transforms.json``, ``sparse/0/cameras.txt`` or
        ``cameras.json``); :func:`load_views` on the folder reads the dataset back.

    Raises
    ------
    ValueError
        For an unknown ``format`` or ``bit_depth``, a malformed dataset, or an existing
        camera file without ``overwrite``.
    TypeError
        For orthographic cameras (no pinhole equivalent) or a non-dataset.
    """
    if format not in VIEW_FORMATS:
        raise ValueError(f"format: expected one of {VIEW_FORMATS}, got {format!r}")
    if bit_depth not in (8, 16) or isinstance(bit_depth, bool):
        raise ValueError(f"bit_depth: expected 8 or 16, got {bit_depth!r}")
    images, sils, cameras = _check_dataset(dataset)
    background = getattr(dataset, "background", None)
    return SAVERS[format](Path(path), images, sils, cameras, bit_depth, overwrite, background)
