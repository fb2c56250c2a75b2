"""Multi-view captures in and out: NeRF/Blender ``transforms.json``, COLMAP text models, OpenCV K/R/t.

:func:`load_views` reads a capture folder (or its camera file) into a
:class:`geofit.datasets.MultiViewDataset`; :func:`save_views` writes a dataset back out in any of
the three layouts, so a fitted scene and its cameras can be opened by other tools.

Layouts
-------
``"transforms"`` (NeRF/Blender, also instant-ngp and nerfstudio)
    ``transforms.json`` with ``frames``, each with ``file_path`` (relative to the json, with or
    without extension) and ``transform_matrix``, the OpenGL camera-to-world 4x4 (x right, y up,
    looking down -z). Intrinsics from ``fl_x``/``fl_y``/``cx``/``cy``/``w``/``h`` or
    ``camera_angle_x`` (horizontal field of view, radians; ``camera_angle_y`` likewise), at the
    top level or per frame (a frame's value wins). Defaults: ``fl_y = fl_x``, principal point at
    the image centre. Silhouettes are the images' alpha channel (RGBA PNGs).
``"colmap"``
    ``cameras.txt`` and ``images.txt`` (COLMAP's text model; in the folder itself, ``sparse/0``
    or ``sparse``), images under ``images/`` by the name in ``images.txt`` and silhouettes under
    ``masks/`` (``masks/NAME``, ``masks/NAME.png`` or ``masks/STEM.png``). Camera models
    ``PINHOLE fx fy cx cy`` and ``SIMPLE_PINHOLE f cx cy``. Poses are world-to-camera quaternions
    ``QW QX QY QZ`` and translations ``TX TY TZ`` in OpenCV's camera frame.
``"opencv"``
    ``cameras.json``: ``{"convention": "opencv", "views": [{"image": "images/000.png",
    "mask": "masks/000.png", "K": 3x3, "R": 3x3, "t": 3}, ...]}`` with OpenCV's world-to-camera
    ``x = R X + t`` and pixel ``K x / x_z`` (``"mask"`` optional).

Pixel coordinates are those of :mod:`geofit.cameras.conversions` (and COLMAP's, nerfstudio's):
(0, 0) is the top-left corner of the top-left pixel, pixel centres at ``i + 0.5``.

Images are read with pillow (8-bit: value / 255; 16-bit greyscale: value / 65535); 16-bit colour
PNGs, which pillow reduces to 8 bits, are read and written with pypng so they keep their values. Without a mask file or an alpha channel a view's silhouette is all ones (the whole image
is the object). Referenced files must lie inside the capture folder: an absolute path or one
that leaves it (``../``) is refused unless ``allow_outside=True``.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from .._atomic import write_text

__all__ = ["VIEW_FORMATS", "load_views", "save_views"]

#: The layouts :func:`load_views` reads and :func:`save_views` writes.
VIEW_FORMATS = ("transforms", "colmap", "opencv")

_IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".PNG", ".JPG", ".JPEG", ".tif", ".tiff", ".bmp",
               ".webp")
_ROTATION_TOL = 1e-4
_COLMAP_MODELS = {"PINHOLE": 4, "SIMPLE_PINHOLE": 3}


# --------------------------------------------------------------------------------------------
# The dataset (one place builds it)
# --------------------------------------------------------------------------------------------


def _make_dataset(images: np.ndarray, silhouettes: np.ndarray, cameras, name: str):
    """The one place a loaded capture becomes a :class:`geofit.datasets.MultiViewDataset`.

    ``MultiViewDataset(images=, silhouettes=, cameras=, name=)`` with the cameras' azimuth and
    elevation (degrees, about the origin) computed from the camera centres.
    """
    from ..datasets import MultiViewDataset

    C = cameras.get_camera_center()
    r = np.linalg.norm(C, axis=1)
    elev = np.degrees(np.arcsin(np.clip(C[:, 1] / np.maximum(r, 1e-300), -1.0, 1.0)))
    azim = np.degrees(np.arctan2(C[:, 0], C[:, 2]))
    return MultiViewDataset(images=images, silhouettes=silhouettes, cameras=cameras, name=name,
                            azim=azim, elev=elev)


# --------------------------------------------------------------------------------------------
# Files: paths and images
# --------------------------------------------------------------------------------------------


def _find_image(root: Path, ref, where: str, allow_outside: bool, *,
                extensions=_IMAGE_EXTS, required: bool = True) -> Path | None:
    """The checked path of image ``ref`` under ``root`` (or ``ref`` plus an image extension,
    for a ``file_path`` without one): every candidate goes through the one path policy
    (:class:`geofit.io._paths.PathPolicy`: a regular file inside ``root`` after symlinks)."""
    from ._paths import PathPolicy

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

    from ._images import check_pixels, open_image

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
    ``(N, H, W)``.
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
            sil = np.ones(rgb.shape[:2])
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
        images.append(rgb)
        sils.append(sil)
    return np.ascontiguousarray(np.stack(images)), np.ascontiguousarray(np.stack(sils))


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


def _read_json(path: Path) -> dict:
    from ._jsonread import parse_json

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
# Loading
# --------------------------------------------------------------------------------------------


def _detect(path: Path) -> tuple[str, Path]:
    """``(format, camera file)`` of a capture folder or camera file."""
    if path.is_file():
        if path.name == "cameras.txt":
            return "colmap", path
        if path.suffix.lower() == ".json":
            data = _read_json(path)
            return ("transforms" if "frames" in data else "opencv"), path
        raise ValueError(f"{path}: not a capture file (expected transforms.json, cameras.json "
                         "or COLMAP's cameras.txt)")
    if not path.is_dir():
        raise FileNotFoundError(f"path: no such file or folder {str(path)!r}")
    if (path / "transforms.json").is_file():
        return "transforms", path / "transforms.json"
    for sub in (".", "sparse/0", "sparse"):
        if (path / sub / "cameras.txt").is_file():
            return "colmap", path / sub / "cameras.txt"
    if (path / "cameras.json").is_file():
        return "opencv", path / "cameras.json"
    raise ValueError(f"{path}: no capture found (expected transforms.json, cameras.txt and "
                     "images.txt (also under sparse/0), or cameras.json)")


def load_views(path, *, allow_outside: bool = False, background=None, znear: float = 1.0,
               zfar: float = 100.0, name: str | None = None, max_pixels: int | None = None):
    """Load a multi-view capture: images, silhouettes and cameras.

    Parameters
    ----------
    path : str or Path
        A capture folder (holding ``transforms.json``; ``cameras.txt`` + ``images.txt``, also
        under ``sparse/0``; or ``cameras.json``) or one of those files (e.g. a
        ``transforms_test.json``). See the module notes for the layouts.
    allow_outside : bool
        Allow image and mask paths that are absolute or lead out of the capture folder.
    background : (3,) float64, optional
        Composite RGBA images over this colour (``rgb * alpha + background * (1 - alpha)``);
        by default the stored RGB is kept as it is.
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
        the image centre, else :class:`~geofit.cameras.PerspectiveCameras`.

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
    fmt, file = _detect(path)
    if background is not None:
        from .._validate import as_array

        background = as_array(background, "background", (3,))
        if background.min() < 0 or background.max() > 1:
            raise ValueError(f"background: expected RGB in [0, 1], got {background.tolist()}")
    if not isinstance(allow_outside, bool):
        raise TypeError(f"allow_outside: expected True or False, got {allow_outside!r}")
    reader = {"transforms": _load_transforms, "colmap": _load_colmap, "opencv": _load_opencv}
    views, K, pose, root = reader[fmt](file, allow_outside)
    images, sils = _gather(views, str(file), background, max_pixels)
    H, W = images.shape[1:3]
    from ..cameras import conversions

    if fmt == "transforms":
        K = np.stack([_intrinsics_nerf(v["intrinsics"], H, W, v["where"]) for v in views])
    convert = {"transforms": conversions.cameras_from_opengl,
               "colmap": conversions.cameras_from_colmap,
               "opencv": conversions.cameras_from_opencv_projection}[fmt]
    cameras = convert(*pose, K, (H, W), znear=znear, zfar=zfar)
    folder = file.parent if fmt != "colmap" else root
    return _make_dataset(images, sils, cameras, name or folder.resolve().name)


_NERF_KEYS = ("fl_x", "fl_y", "cx", "cy", "w", "h", "camera_angle_x", "camera_angle_y")


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


def _load_transforms(file: Path, allow_outside: bool):
    data, entries = _json_entries(file, "frames")
    root = file.parent
    top = {k: data[k] for k in _NERF_KEYS if k in data}
    views, c2w = [], []
    for where, fr in entries:  # one entry per view
        for key in ("file_path", "transform_matrix"):
            if key not in fr:
                raise ValueError(f"{where}.{key}: missing")
        image = _find_image(root, fr["file_path"], f"{where}.file_path", allow_outside)
        mask = None
        if "mask_path" in fr:
            mask = _find_image(root, fr["mask_path"], f"{where}.mask_path", allow_outside)
        M = _matrix(fr["transform_matrix"], (4, 4), f"{where}.transform_matrix")
        if np.abs(M[3] - [0.0, 0.0, 0.0, 1.0]).max() > _ROTATION_TOL:
            raise ValueError(f"{where}.transform_matrix: expected a bottom row (0, 0, 0, 1), "
                             f"got {M[3].tolist()}")
        M[:3, :3] = _rotation(M[:3, :3], f"{where}.transform_matrix")
        M[3] = [0.0, 0.0, 0.0, 1.0]
        c2w.append(M)
        views.append({"image": image, "mask": mask, "where": where,
                      "intrinsics": {**top, **{k: fr[k] for k in _NERF_KEYS if k in fr}}})
    return views, None, (np.stack(c2w),), root


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


def _load_colmap(cameras_txt: Path, allow_outside: bool):
    model_dir = cameras_txt.parent
    images_txt = model_dir / "images.txt"
    if not images_txt.is_file():
        raise ValueError(f"{images_txt}: missing (a COLMAP text model has cameras.txt and "
                         "images.txt side by side)")
    root = model_dir
    if model_dir.name == "sparse":
        root = model_dir.parent
    elif model_dir.parent.name == "sparse":
        root = model_dir.parent.parent
    cams = {}
    for where, f in _colmap_records(cameras_txt, 4, "CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]"):
        cid = _int(f[0], where, "CAMERA_ID")
        model = f[1]
        if model not in _COLMAP_MODELS:
            raise ValueError(f"{where}: MODEL: camera model {model!r} is not supported "
                             f"(supported: {', '.join(_COLMAP_MODELS)}; undistort the images "
                             "first, e.g. colmap image_undistorter)")
        w, h = _int(f[2], where, "WIDTH"), _int(f[3], where, "HEIGHT")
        params = f[4:]
        if len(params) != _COLMAP_MODELS[model]:
            raise ValueError(f"{where}: PARAMS: {model} takes {_COLMAP_MODELS[model]} "
                             f"parameters, got {len(params)}")
        if model == "PINHOLE":
            fx, fy, cx, cy = _floats(params, where, ("fx", "fy", "cx", "cy"))
        else:
            fx, cx, cy = _floats(params, where, ("f", "cx", "cy"))
            fy = fx
        if fx <= 0 or fy <= 0 or w < 1 or h < 1:
            raise ValueError(f"{where}: expected positive focal lengths and image size")
        cams[cid] = (np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]), (h, w))
    if not cams:
        raise ValueError(f"{cameras_txt}: no cameras")
    images_dir, masks_dir = root / "images", root / "masks"
    views, K, q, t = [], [], [], []
    for where, f in _colmap_records(images_txt, 10,
                                    "IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME",
                                    points_lines=True):
        _int(f[0], where, "IMAGE_ID")
        vals = _floats(f[1:8], where, ("QW", "QX", "QY", "QZ", "TX", "TY", "TZ"))
        qv = np.array(vals[:4])
        if abs(np.linalg.norm(qv) - 1.0) > 1e-3:
            raise ValueError(f"{where}: QW QX QY QZ: expected a unit quaternion, got norm "
                             f"{np.linalg.norm(qv):.6g}")
        cid = _int(f[8], where, "CAMERA_ID")
        if cid not in cams:
            raise ValueError(f"{where}: CAMERA_ID: camera {cid} is not in {cameras_txt.name}")
        name = " ".join(f[9:])
        image = _find_image(images_dir, name, f"{where}: NAME", allow_outside)
        mask = None
        if masks_dir.is_dir():
            for cand in (name, name + ".png", str(Path(name).with_suffix(".png"))):
                mask = _find_image(masks_dir, cand, f"{where}: NAME", allow_outside,
                                   extensions=(), required=False)
                if mask is not None:
                    break
            if mask is None:
                raise ValueError(f"{where}: NAME: no mask for {name!r} in {masks_dir} (tried "
                                 f"{name}, {name}.png, {Path(name).with_suffix('.png')})")
        K.append(cams[cid][0])
        q.append(qv / np.linalg.norm(qv))
        t.append(vals[4:])
        views.append({"image": image, "mask": mask, "where": where, "size": cams[cid][1]})
    if not views:
        raise ValueError(f"{images_txt}: no images")
    return views, np.stack(K), (np.stack(q), np.array(t)), root


def _load_opencv(file: Path, allow_outside: bool):
    _, entries = _json_entries(file, "views")
    root = file.parent
    views, K, R, t = [], [], [], []
    for where, e in entries:  # one entry per view
        for key in ("image", "K", "R", "t"):
            if key not in e:
                raise ValueError(f"{where}.{key}: missing")
        image = _find_image(root, e["image"], f"{where}.image", allow_outside)
        mask = None
        if e.get("mask") is not None:
            mask = _find_image(root, e["mask"], f"{where}.mask", allow_outside)
        k = _matrix(e["K"], (3, 3), f"{where}.K")
        if k[0, 0] <= 0 or k[1, 1] <= 0 or k[0, 1] != 0 or k[1, 0] != 0 \
                or np.any(k[2] != [0.0, 0.0, 1.0]):
            raise ValueError(f"{where}.K: expected [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] with "
                             f"fx, fy > 0, got {k.tolist()}")
        K.append(k)
        R.append(_rotation(_matrix(e["R"], (3, 3), f"{where}.R"), f"{where}.R"))
        t.append(_matrix(e["t"], (3,), f"{where}.t"))
        views.append({"image": image, "mask": mask, "where": where})
    return views, np.stack(K), (np.stack(R), np.stack(t)), root


# --------------------------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------------------------


def _check_dataset(dataset):
    for key in ("images", "silhouettes", "cameras"):
        if not hasattr(dataset, key):
            raise TypeError(f"dataset: expected a MultiViewDataset (images, silhouettes, "
                            f"cameras), got {type(dataset).__name__} without {key!r}")
    from .._validate import as_array

    images = as_array(dataset.images, "dataset.images")
    sils = as_array(dataset.silhouettes, "dataset.silhouettes")
    if images.ndim != 4 or images.shape[3] != 3 or images.shape[0] == 0:
        raise ValueError(f"dataset.images: expected shape (N, H, W, 3), got {images.shape}")
    if sils.shape != images.shape[:3]:
        raise ValueError(f"dataset.silhouettes: expected shape {images.shape[:3]}, got "
                         f"{sils.shape}")
    for nm, a in (("images", images), ("silhouettes", sils)):
        if a.min() < 0 or a.max() > 1:
            raise ValueError(f"dataset.{nm}: expected values in [0, 1], got range "
                             f"[{a.min():g}, {a.max():g}]")
    if len(dataset.cameras) != images.shape[0]:
        raise ValueError(f"dataset.cameras: expected {images.shape[0]} cameras, got "
                         f"{len(dataset.cameras)}")
    return images, sils, dataset.cameras


def _write_image(path: Path, a: np.ndarray, bit_depth: int) -> None:
    """Write ``(H, W)`` grey, ``(H, W, 3)`` RGB or ``(H, W, 4)`` RGBA in [0, 1] as a PNG."""
    import io

    from PIL import Image

    from .._atomic import write_bytes

    buf = io.BytesIO()  # encoded in memory, then written atomically
    if bit_depth == 8:
        Image.fromarray(np.round(a * 255.0).astype(np.uint8)).save(buf, format="PNG")
        write_bytes(path, buf.getbuffer())
        return
    b = np.round(a * 65535.0).astype(np.uint16)
    if b.ndim == 2:
        Image.fromarray(b).save(buf, format="PNG")  # pillow writes 16-bit greyscale (I;16)
        write_bytes(path, buf.getbuffer())
        return
    import png  # pypng: pillow cannot write 16-bit colour

    mode = "RGBA;16" if b.shape[2] == 4 else "RGB;16"
    png.from_array(b.reshape(b.shape[0], -1), mode).write(buf)
    write_bytes(path, buf.getbuffer())


def save_views(path, dataset, format: str = "transforms", *, bit_depth: int = 8,
               overwrite: bool = False) -> Path:
    """Write a multi-view dataset (images, silhouettes, cameras) as a capture folder.

    Parameters
    ----------
    path : str or Path
        Folder to write (created if needed).
    dataset : MultiViewDataset
        Anything with ``images (N, H, W, 3)``, ``silhouettes (N, H, W)`` in [0, 1] and
        ``N`` perspective ``cameras``.
    format : {"transforms", "colmap", "opencv"}
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
    N, H, W = sils.shape
    from ..cameras.conversions import (
        colmap_from_cameras,
        opencv_from_cameras_projection,
        opengl_from_cameras,
    )

    root = Path(path)
    target = {"transforms": root / "transforms.json", "colmap": root / "sparse/0/cameras.txt",
              "opencv": root / "cameras.json"}[format]
    if target.exists() and not overwrite:
        raise ValueError(f"path: {str(target)!r} exists (pass overwrite=True to replace it)")
    target.parent.mkdir(parents=True, exist_ok=True)
    (root / "images").mkdir(exist_ok=True)
    names = [f"{i:03d}.png" for i in range(N)]
    if format == "transforms":
        c2w, K = opengl_from_cameras(cameras, (H, W))
        shared = bool(np.all(K == K[:1]))
        frames = []
        for i in range(N):  # one file per view
            rel = f"images/r_{names[i]}"
            _write_image(root / rel, np.concatenate([images[i], sils[i][..., None]], axis=2),
                         bit_depth)
            fr = {"file_path": rel, "transform_matrix": c2w[i].tolist()}
            if not shared:
                fr.update(_nerf_intrinsics(K[i], H, W))
            frames.append(fr)
        data = _nerf_intrinsics(K[0], H, W) if shared else {"w": W, "h": H}
        data["frames"] = frames
        write_text(target, json.dumps(data, indent=1) + "\n")
        return target
    (root / "masks").mkdir(exist_ok=True)
    for i in range(N):  # one file per view
        _write_image(root / "images" / names[i], images[i], bit_depth)
        _write_image(root / "masks" / names[i], sils[i], bit_depth)
    if format == "opencv":
        R, t, K = opencv_from_cameras_projection(cameras, (H, W))
        views = [{"image": f"images/{names[i]}", "mask": f"masks/{names[i]}",
                  "K": K[i].tolist(), "R": R[i].tolist(), "t": t[i].tolist()} for i in range(N)]
        data = {"convention": "opencv", "pixel_origin": "top-left corner of the top-left pixel",
                "width": W, "height": H, "views": views}
        write_text(target, json.dumps(data, indent=1) + "\n")
        return target
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


def _nerf_intrinsics(K: np.ndarray, H: int, W: int) -> dict:
    fx, fy = float(K[0, 0]), float(K[1, 1])
    return {"camera_angle_x": 2.0 * math.atan(0.5 * W / fx),
            "camera_angle_y": 2.0 * math.atan(0.5 * H / fy), "fl_x": fx, "fl_y": fy,
            "cx": float(K[0, 2]), "cy": float(K[1, 2]), "w": W, "h": H}
