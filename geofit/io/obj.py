"""Wavefront OBJ/MTL reading and writing with PyTorch3D's ``load_obj`` semantics.

The reader keeps the file's vertex order and its per-corner texture-coordinate indices exactly
(no vertex merging or splitting, unlike general-purpose mesh loaders), fan-triangulates polygons
as ``(v0, vi, vi+1)``, and raises on anything it cannot load instead of returning a partial mesh.

Why one module of ~850 lines: the OBJ reader, its MTL and texture reading and the path policy
for the files an OBJ names (``mtllib``, ``map_Kd`` stay inside the OBJ's folder unless
``allow_outside=True``) are one chain of checks on one untrusted input, read top to bottom; the
general mesh formats (PLY, STL, OFF, glTF) live in :mod:`geofit.io.mesh`.
"""
from __future__ import annotations

import os
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np

from .._atomic import write_bytes, write_text
from .._memory import check_allocation
from .._validate import MAX_COORD, as_array, as_faces, as_points
from ._formats import EXTENSIONS, not_obj_error, sniff
from ._images import as_max_pixels, open_image
from ._paths import PathPolicy, check_input_file
from .._foreign import foreign_kind
from ..structures.mesh import Mesh, Meshes, as_mesh
from ..structures.textures import TexturesUV

__all__ = [
    "Material",
    "ObjData",
    "load_obj",
    "load_objs_as_meshes",
    "save_obj",
]

PathLike = str | os.PathLike


@dataclass
class Material:
    """One ``newmtl`` block of an MTL file (the keys PyTorch3D reads).

    Attributes
    ----------
    name : str
        The material name (``newmtl``).
    Ka, Kd, Ks : (3,) float64 or None
        Ambient, diffuse and specular RGB reflectivity; None where the MTL does not set them.
    Ns : float or None
        Specular exponent (shininess).
    map_Kd : str or None
        Absolute path of the diffuse texture image, resolved against the MTL's folder.
    """

    name: str
    Ka: np.ndarray | None = None
    Kd: np.ndarray | None = None
    Ks: np.ndarray | None = None
    Ns: float | None = None
    map_Kd: str | None = None
    extra: dict = field(default_factory=dict, repr=False)


class ObjData(NamedTuple):
    """Everything :func:`load_obj` reads from an OBJ file (and its MTL and textures).

    Attributes
    ----------
    verts : (V, 3) float64
        Vertex positions in file order.
    faces : (F, 3) int64
        Triangles as 0-based vertex indices (polygons fan-triangulated).
    faces_uvs : (F, 3) int64
        Per-corner index into ``verts_uvs``; -1 for faces written without ``vt`` indices.
    verts_uvs : (T, 2) float64
        Texture coordinates (``vt``) in file order; (0, 2) when there are none.
    faces_normals_idx : (F, 3) int64
        Per-corner index into ``normals``; -1 for faces written without ``vn`` indices.
    normals : (N, 3) float64
        Normals (``vn``) in file order; (0, 3) when there are none.
    materials : dict of str to Material
        The materials used by the OBJ (``usemtl``) and defined in its MTL, in order of first use.
        Empty when ``load_textures`` is False (the MTL is not read).
    face_materials : (F,) int64
        Index of each face's material in ``material_names``; -1 before any ``usemtl``.
    texture_images : dict of str to (H, W, 3) float64
        Diffuse texture (``map_Kd``) of each used material that has one, RGB, row 0 at the
        top of the image; in order of first use. Values are scaled by the pixel type: 8-bit
        images (any mode PIL converts to RGB, as PyTorch3D does) / 255, 16-bit greyscale
        / 65535, 32-bit integer (PIL mode ``I``) / 65535 when the values fit in 16 bits (or
        the file is a PNG) and / (2^32 - 1) otherwise; float (TIFF) pixels are kept as they
        are.
    material_names : list of str
        Material names in order of first ``usemtl`` (what ``face_materials`` indexes).
    """

    verts: np.ndarray
    faces: np.ndarray
    faces_uvs: np.ndarray
    verts_uvs: np.ndarray
    faces_normals_idx: np.ndarray
    normals: np.ndarray
    materials: dict
    face_materials: np.ndarray
    texture_images: dict
    material_names: list


# --------------------------------------------------------------------------- parsing helpers
def _read_text(path: Path) -> str:
    """The file's text: UTF-8 (a byte-order mark is dropped) or else Latin-1."""
    try:
        data = path.read_bytes()
    except OSError as exc:  # permission denied, a directory, I/O errors
        raise ValueError(f"{path}: cannot read the file ({exc.strerror or exc})") from None
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return data.decode("latin-1")


def _lines(text: str) -> list:
    """Lines split at \\n, \\r\\n or \\r only (not at the form feeds, vertical tabs, \\x1c-\\x1e and
    Unicode separators that ``str.splitlines`` also breaks at)."""
    return text.replace("\r\n", "\n").replace("\r", "\n").split("\n")


def _strip_comment(line: str) -> str:
    h = line.find("#")
    return line if h < 0 else line[:h]


_WS = np.zeros(256, dtype=bool)
_WS[[9, 10, 11, 12, 13, 32]] = True  # \t \n \v \f \r and space
_NUMERIC_OK = _WS.copy()  # bytes allowed in v/vt/vn lines: printable ASCII and whitespace
_NUMERIC_OK[32:127] = True
_POW10 = 10 ** np.arange(19, dtype=np.int64)
_SLOT_NAMES = ("vertex", "texture coordinate", "normal")


def _tokens_per_line(blob: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Byte-level tokeniser. ``blob`` holds uint8 text whose every line ends in a newline.

    Returns (positions of the newlines, positions of the token starts, tokens per line).
    """
    ws = _WS[blob]
    start = ~ws
    start[1:] &= ws[:-1]
    nlpos = np.flatnonzero(blob == 10)
    spos = np.flatnonzero(start)
    counts = np.bincount(np.searchsorted(nlpos, spos), minlength=len(nlpos))
    return nlpos, spos, counts


def _parse_float_lines(bodies: list, lines: list, ncol: int, what: str, path: Path) -> np.ndarray:
    """Parse lines of >= ``ncol`` numbers (extra ones ignored) into an (n, ncol) float64 array."""
    if not bodies:
        return np.zeros((0, ncol))
    joined = "\n".join(bodies)
    blob = np.frombuffer((joined + "\n").encode("utf-8", "replace"), dtype=np.uint8)
    bad_byte = ~_NUMERIC_OK[blob]
    if bad_byte.any():  # control or non-ASCII characters: str.split and the tokeniser disagree
        i = int(np.count_nonzero(blob[:int(np.flatnonzero(bad_byte)[0])] == 10))
        raise ValueError(f"{path}: line {lines[i]}: {what} line has a control or non-ASCII "
                         f"character (only printable ASCII, spaces and tabs are allowed)")
    counts = _tokens_per_line(blob)[2]
    short = counts < ncol
    if short.any():
        i = int(np.flatnonzero(short)[0])
        need = f"{ncol} coordinates" if what == "vertex" else f"{ncol} values"
        raise ValueError(f"{path}: line {lines[i]}: {what} needs {need}, got "
                         f"{bodies[i].strip()!r}")
    if np.all(counts == ncol):
        tokens = joined.split()
    else:  # some lines carry extra values (v x y z r g b, vt u v w): keep the first ncol
        tokens = [t for b in bodies for t in b.split()[:ncol]]
    try:
        arr = np.array(tokens, dtype=np.float64).reshape(-1, ncol)
    except ValueError:
        for body, ln in zip(bodies, lines):  # error path only: find the offending line
            row = body.split()[:ncol]
            try:
                [float(t) for t in row]
            except ValueError:
                raise ValueError(
                    f"{path}: line {ln}: {what} has a non-numeric value in {' '.join(row)!r}"
                ) from None
        raise  # pragma: no cover - the loop above always finds the bad row
    bad = ~np.isfinite(arr).all(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"{path}: line {lines[i]}: {what} is not finite "
                         f"({' '.join(bodies[i].split()[:ncol])!r}); {int(bad.sum())} such line(s)")
    return arr


def _face_line_error(body: str, ln: int, path: Path) -> ValueError:
    """The error for a face line the vectorised parser rejected (run on that one line only)."""
    for tok in body.split():
        parts = tok.split("/")
        if len(parts) > 3:
            return ValueError(f"{path}: line {ln}: face corner {tok!r} has more than 3 "
                              f"'/'-separated indices")
        if parts[0] == "":
            return ValueError(f"{path}: line {ln}: face corner {tok!r} has no vertex index")
        for slot, part in enumerate(parts):
            body_digits = part[1:] if part[:1] in "+-" else part
            if part and not (body_digits.isascii() and body_digits.isdigit()):
                return ValueError(f"{path}: line {ln}: face has a non-integer {_SLOT_NAMES[slot]} "
                                  f"index {part!r}")
            if len(body_digits) > 18:
                return ValueError(f"{path}: line {ln}: face index {part!r} is too large")
    return ValueError(f"{path}: line {ln}: malformed face {body.strip()!r}")  # pragma: no cover


def _parse_faces(bodies: list, lines: np.ndarray, path: Path):
    """Vectorised parse of face corners ``v``, ``v/vt``, ``v//vn``, ``v/vt/vn``.

    Returns ``(corners per face (F,), raw indices (C, 3) int64, present (C, 3) bool)`` where
    column 0/1/2 is the vertex / texture / normal index as written (1-based or negative).
    """
    blob = np.frombuffer(("\n".join(bodies) + "\n").encode("utf-8", "replace"), dtype=np.uint8)
    nlpos, cpos, counts = _tokens_per_line(blob)
    few = counts < 3
    if few.any():
        i = int(np.flatnonzero(few)[0])
        raise ValueError(f"{path}: line {lines[i]}: face needs at least 3 vertices, got "
                         f"{int(counts[i])} ({('f ' + bodies[i]).strip()!r})")
    digit = (blob >= 48) & (blob <= 57)
    sign = (blob == 45) | (blob == 43)
    slash = blob == 47
    num = digit | sign
    nstart = num.copy()
    nstart[1:] &= ~num[:-1]
    nend = num.copy()
    nend[:-1] &= ~num[1:]
    sign_ok = np.zeros_like(sign)
    sign_ok[:-1] = nstart[:-1] & digit[1:]  # a sign only at the start of a number, before a digit
    bad_pos = np.flatnonzero(~(_WS[blob] | slash | num) | (sign & ~sign_ok))
    # sparse positions; the corner of a position p is the last corner start <= p
    npos = np.flatnonzero(nstart)
    epos = np.flatnonzero(nend)
    spos = np.flatnonzero(slash)
    n_corners = len(cpos)
    n_corner = np.searchsorted(cpos, npos, side="right") - 1
    nslot = np.searchsorted(spos, npos) - np.searchsorted(spos, cpos)[n_corner]
    nslash = np.bincount(np.searchsorted(cpos, spos, side="right") - 1, minlength=n_corners)
    has = np.zeros((n_corners, 3), dtype=bool)
    ok_slot = nslot <= 2
    has[n_corner[ok_slot], nslot[ok_slot]] = True
    bad_corner = np.flatnonzero((nslash > 2) | ~has[:, 0])
    run_len = epos - npos + 1
    too_long = np.flatnonzero(run_len - sign[npos] > 18)
    if len(bad_pos) or len(bad_corner) or len(too_long):
        cand = [p[0] for p in (bad_pos, cpos[bad_corner], npos[too_long]) if len(p)]
        i = int(np.searchsorted(nlpos, min(cand)))
        raise _face_line_error(bodies[i], int(lines[i]), path)
    # number values: sum of digit * 10^place over each run of number bytes
    numpos = np.flatnonzero(num)  # every corner has a vertex number, so this is not empty
    place = np.repeat(epos, run_len) - numpos
    contrib = np.where(digit[numpos], (blob[numpos].astype(np.int64) - 48) * _POW10[place], 0)
    values = np.add.reduceat(contrib, np.concatenate([[0], np.cumsum(run_len)[:-1]]))
    values = np.where(blob[npos] == 45, -values, values)
    raw = np.zeros((n_corners, 3), dtype=np.int64)
    raw[n_corner, nslot] = values
    return counts, raw, has


def _resolve_indices(raw: np.ndarray, count_at: np.ndarray, total: int, what: str,
                     corner_lines: np.ndarray, path: Path) -> np.ndarray:
    """1-based / negative (relative) OBJ indices -> 0-based, checked against ``total``."""
    idx = np.where(raw > 0, raw - 1, count_at + raw)
    bad = (raw == 0) | (idx < 0) | (idx >= total)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        r = int(raw[i])
        if r == 0:
            why = "index 0 is invalid (OBJ indices start at 1)"
        elif r > 0:
            why = f"index {r} is out of range (the file has {total} {what} entries)"
        else:
            why = (f"relative index {r} points before the first {what} "
                   f"({int(count_at[i])} defined before this line)")
        raise ValueError(f"{path}: line {int(corner_lines[i])}: face {what} {why}; "
                         f"{int(bad.sum())} bad {what} index/indices in total")
    return idx


def _parse_mtl(path: Path) -> dict:
    """Read the MTL keys PyTorch3D uses (newmtl, Ka, Kd, Ks, Ns, map_Kd) -> name -> Material.

    Error messages name the file, the line number and the key, never the line's content (the
    file may be one the user did not mean to expose). ``map_Kd`` is joined to the MTL's folder
    here; the path policy is applied by :func:`load_obj` when the texture is read.
    """
    mats: dict[str, Material] = {}
    cur: Material | None = None
    for ln, raw_line in enumerate(_lines(_read_text(path)), 1):
        line = _strip_comment(raw_line).strip()
        if not line:
            continue
        tokens = line.split()
        key = tokens[0]
        if key == "newmtl":
            if len(tokens) < 2:
                raise ValueError(f"{path}: line {ln}: newmtl without a material name")
            cur = Material(name=line[len(key):].strip())
            mats[cur.name] = cur
            continue
        if key not in ("Ka", "Kd", "Ks", "Ns", "map_Kd"):
            continue
        if cur is None:
            raise ValueError(f"{path}: line {ln}: {key} before any newmtl")
        if key == "map_Kd":
            rest = line[len(key):].strip()
            if not rest:
                raise ValueError(f"{path}: line {ln}: map_Kd without a file name")
            if rest.startswith("-"):  # options such as "-s 1 1 1 file.png": the file comes last
                rest = rest.split()[-1]
            rest = rest.replace("\\", "/")
            p = Path(rest)
            cur.map_Kd = str(p if p.is_absolute() else (path.parent / p))
            cur.extra["map_Kd_source"] = (str(path), ln, rest)
            continue
        try:
            if not all(t.isascii() for t in tokens[1:4]):
                raise ValueError
            vals = [float(t) for t in tokens[1:4]]
        except ValueError:
            raise ValueError(f"{path}: line {ln}: {key} has a non-numeric value") from None
        if not all(np.isfinite(vals)) or any(v < 0 for v in vals):
            raise ValueError(f"{path}: line {ln}: {key} values must be finite and non-negative")
        if key == "Ns":
            if len(vals) < 1:
                raise ValueError(f"{path}: line {ln}: Ns needs a value")
            cur.Ns = vals[0]
        else:
            if len(vals) == 1:  # "Kd 0.5" means grey
                vals = vals * 3
            if len(vals) != 3:
                raise ValueError(f"{path}: line {ln}: {key} needs 3 values, got {len(vals)}")
            setattr(cur, key, np.array(vals, dtype=np.float64))
    return mats


def _image_to_float(im, path) -> np.ndarray:
    """A PIL image -> (H, W, 3) float64, scaled by the pixel type's range (not clipped to 8 bit)."""
    mode = im.mode
    if mode.startswith("I;16"):  # 16-bit greyscale
        a = np.asarray(im).astype(np.float64) / 65535.0
    elif mode == "I":  # 32-bit integer pixels; PNG gives this mode for 16-bit greyscale
        a = np.asarray(im)
        if a.size and a.min() < 0:
            raise ValueError(f"{path}: the image has negative pixel values")
        bits = 16 if im.format == "PNG" or (a.size and a.max() <= 65535) else 32
        a = a.astype(np.float64) / float(2**bits - 1)
    elif mode == "F":  # float pixels (TIFF): the values as they are
        a = np.asarray(im).astype(np.float64)
        if not np.isfinite(a).all():
            raise ValueError(f"{path}: the float image has NaN or infinite pixels")
    elif mode == "1":
        a = np.asarray(im).astype(np.float64)
    else:  # 8-bit modes (L, P, RGB, RGBA, LA, CMYK, YCbCr, ...): PyTorch3D's convert("RGB")
        return np.asarray(im.convert("RGB")).astype(np.float64) / 255.0
    return np.repeat(a[:, :, None], 3, axis=2)


def _read_image(path: str, memory_limit=None, max_pixels=None) -> np.ndarray:
    """A texture image as (H, W, 3) float64; its pixel count and decoded size are checked from
    the header first (:func:`geofit.io._images.open_image`)."""
    try:
        with warnings.catch_warnings():
            # PIL's warnings (corrupt EXIF, truncated data) refuse the image
            warnings.simplefilter("error")
            with open_image(path, str(path), max_pixels) as im:
                w, h = im.size
                bands = len(im.getbands())
                check_allocation(w * h * (bands * 4 + 3 * 8 * 2), setting=str(path),
                                 what=f"decoding this {w}x{h} image", limit=memory_limit)
                im.load()
                return _image_to_float(im, path)
    except ValueError as exc:
        if str(exc).startswith(str(path)):
            raise
        raise ValueError(f"{path}: not a readable image ({str(exc)[:200]})") from None
    except FileNotFoundError:
        raise
    except MemoryError:
        raise ValueError(f"{path}: not enough memory to decode the image") from None
    except Exception as exc:  # noqa: BLE001 - PIL raises OSError, SyntaxError, EOFError,
        # zlib.error, struct.error, DecompressionBombError, ... for damaged files
        raise ValueError(f"{path}: not a readable image ({type(exc).__name__}: "
                         f"{str(exc)[:200]})") from None


# --------------------------------------------------------------------------- public API
def load_obj(path: PathLike, load_textures: bool = True, *, allow_outside: bool = False,
             memory_limit=None, max_pixels: int | None = None) -> ObjData:
    """Read a Wavefront OBJ file, its MTL materials and its texture images.

    Follows ``pytorch3d.io.load_obj``: vertices, texture coordinates and normals are kept in
    file order; polygons are fan-triangulated as ``(v0, vi, vi+1)`` (assumed convex and
    counter-clockwise); faces may use the ``v``, ``v/vt``, ``v//vn`` and ``v/vt/vn`` forms.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.obj`` file.
    load_textures : bool
        Read the ``mtllib`` files and the ``map_Kd`` images they name. When False, neither is
        read (``materials`` and ``texture_images`` are empty), as in PyTorch3D.
    allow_outside : bool
        Follow ``mtllib`` and ``map_Kd`` paths that are absolute or resolve (through ``..`` or
        a symlink) outside the folder of the file naming them. By default such paths raise
        ValueError, so a downloaded mesh cannot make geofit read any file on the machine.
    memory_limit : int or str, optional
        Bytes a texture image may take once decoded (checked from its header before decoding);
        default ``GEOFIT_MEMORY_LIMIT`` or half of the available memory.
    max_pixels : int, optional
        Most pixels (width x height) a texture image may have, checked from its header before
        decoding; default :data:`geofit.io.DEFAULT_MAX_PIXELS` (2**24, a 4096 x 4096 image).

    Returns
    -------
    ObjData
        ``verts (V, 3) float64``, ``faces (F, 3) int64``, ``faces_uvs (F, 3) int64`` (-1 where a
        face has no ``vt``), ``verts_uvs (T, 2) float64``, ``faces_normals_idx (F, 3) int64``,
        ``normals (N, 3) float64``, ``materials``, ``face_materials (F,) int64``,
        ``texture_images`` (name -> (H, W, 3) float64 in [0, 1]) and ``material_names``.

    Raises
    ------
    FileNotFoundError
        If the OBJ file, or (with ``load_textures``) a texture image named by its MTL, does not
        exist. The message names the missing file. (A missing MTL file is only a warning.)
    ValueError
        Naming the file: a file that cannot be read, a texture that is not a readable image or
        would exceed the memory limit or the pixel cap, an MTL or texture path outside the folder
        (see ``allow_outside``), an MTL colour that is not finite and non-negative. Naming the file
        and line: a control or non-ASCII character in a ``v``/``vt``/``vn`` line, a coordinate
        beyond 1e38 in absolute value, a non-numeric or non-finite coordinate, a ``v``/``vn`` line
        with fewer than 3 values or a ``vt`` line with fewer than 2, a face with fewer than 3
        corners, a face mixing corners with and without ``vt`` (or ``vn``), an index that is 0
        or out of range, or a file without any face. A PLY, GLB or OFF file (recognised by its
        first bytes or its extension) is refused with a message naming its format and
        :func:`geofit.io.load_mesh`.

    Notes
    -----
    * Negative indices are relative, as the OBJ specification defines them: ``-1`` is the last
      ``v`` (``vt``, ``vn``) defined *before the face's line*. PyTorch3D counts from the end of
      the whole file instead; the two agree whenever every vertex precedes the faces (as in
      the tutorial files) and differ only for files interleaving ``v`` and ``f`` lines.
    * Positive indices may refer to vertices defined later in the file (as PyTorch3D allows).
    * Extra values are ignored: ``v x y z w`` or ``v x y z r g b`` use the first three,
      ``vt u v w`` the first two. Comments (``#`` to the end of a line) are ignored.
    * Where PyTorch3D warns and continues (indices out of range, missing texture file), this
      function raises, so nothing half-loaded is ever returned.
    * ``usemtl`` names that the MTL does not define are kept in ``material_names`` but have no
      entry in ``materials``. A ``usemtl`` without any ``mtllib`` is ignored likewise.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> from geofit.io import load_obj
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "quad.obj"
    >>> _ = p.write_text("v 0 0 0\\nv 1 0 0\\nv 1 1 0\\nv 0 1 0\\nf 1 2 3 4\\n")
    >>> load_obj(p).faces
    array([[0, 1, 2],
           [0, 2, 3]])
    """
    path = check_input_file(path, "OBJ file")
    max_pixels = as_max_pixels(max_pixels)
    if sniff(path) not in (None, "OBJ"):
        raise not_obj_error(path, sniff(path), reader=True)
    lines = _lines(_read_text(path))

    # One pass over the lines sorts them by keyword; the numbers are parsed afterwards in bulk.
    # keyword -> (the text after it, its line number) of every v / vt / vn / f line
    records: dict = {key: ([], []) for key in ("v", "vt", "vn", "f")}
    mat_lines: list = []  # (line, material index) of every usemtl
    mtllibs: list = []
    material_names: list = []
    mat_index: dict = {}
    for ln, line in enumerate(lines, 1):  # the line loop of the parser
        if "#" in line:
            line = _strip_comment(line)
        parts = line.split(None, 1)
        if not parts:
            continue
        key = parts[0]
        rest = parts[1] if len(parts) > 1 else ""
        record = records.get(key)
        if record is not None:
            record[0].append(rest)
            record[1].append(ln)
        elif key == "usemtl":
            name = rest.strip()
            if not name:
                raise ValueError(f"{path}: line {ln}: usemtl without a material name")
            if name not in mat_index:
                mat_index[name] = len(material_names)
                material_names.append(name)
            mat_lines.append((ln, mat_index[name]))
        elif key == "mtllib":
            if not rest.strip():
                raise ValueError(f"{path}: line {ln}: mtllib without a file name")
            mtllibs.append((rest.strip(), ln))
    (vb, vl), (tb, tl), (nb, nl), (fb, fl) = (records[k] for k in ("v", "vt", "vn", "f"))

    verts = _parse_float_lines(vb, vl, 3, "vertex", path)
    verts_uvs = _parse_float_lines(tb, tl, 2, "texture coordinate", path)
    normals = _parse_float_lines(nb, nl, 3, "normal", path)
    big = np.abs(verts).max(axis=1, initial=0.0) > MAX_COORD
    if big.any():
        i = int(np.flatnonzero(big)[0])
        raise ValueError(f"{path}: line {vl[i]}: vertex coordinate beyond {MAX_COORD:g} in "
                         f"absolute value (areas, normals and float32 rendering would overflow); "
                         f"{int(big.sum())} such line(s)")
    if not fb:
        raise ValueError(f"{path}: the file has no faces (empty mesh; {len(verts)} vertices)")

    f_line = np.asarray(fl, dtype=np.int64)
    f_len, raw, has = _parse_faces(fb, f_line, path)
    n_faces = len(f_len)
    starts = np.concatenate([[0], np.cumsum(f_len)[:-1]])
    corner_face = np.repeat(np.arange(n_faces), f_len)
    corner_lines = f_line[corner_face]
    # entries defined before each face's line, for relative indices
    before = [np.searchsorted(np.asarray(x, dtype=np.int64), f_line)[corner_face]
              for x in (vl, tl, nl)]
    totals = (len(verts), len(verts_uvs), len(normals))
    idx = np.full(raw.shape, -1, dtype=np.int64)
    idx[:, 0] = _resolve_indices(raw[:, 0], before[0], totals[0], "vertex", corner_lines, path)
    for col in (1, 2):  # texture coordinates, normals
        h = has[:, col]
        per_face = np.add.reduceat(h.astype(np.int64), starts)
        mixed = (per_face != 0) & (per_face != f_len)
        if mixed.any():
            i = int(np.flatnonzero(mixed)[0])
            raise ValueError(f"{path}: line {fl[i]}: face mixes corners with and without "
                             f"{_SLOT_NAMES[col]} indices")
        if h.any():
            idx[h, col] = _resolve_indices(raw[h, col], before[col][h], totals[col],
                                           _SLOT_NAMES[col], corner_lines[h], path)

    # ---- fan triangulation (c0, ci, ci+1) for i = 1 .. k-2
    n_tri = f_len - 2
    tri_face = np.repeat(np.arange(n_faces), n_tri)
    local = np.arange(len(tri_face)) - np.repeat(np.cumsum(n_tri) - n_tri, n_tri) + 1
    base = starts[tri_face]
    c = np.stack([base, base + local, base + local + 1], axis=1)
    faces = idx[c, 0]
    faces_uvs = idx[c, 1]
    faces_normals_idx = idx[c, 2]
    if mat_lines:
        ml = np.asarray(mat_lines, dtype=np.int64)
        k = np.searchsorted(ml[:, 0], f_line) - 1  # last usemtl before each face
        face_mat = np.where(k >= 0, ml[np.maximum(k, 0), 1], -1)
    else:
        face_mat = np.full(n_faces, -1, dtype=np.int64)
    face_materials = face_mat[tri_face]

    materials: dict = {}
    texture_images: dict = {}
    if load_textures and mtllibs:
        defined: dict = {}
        obj_policy = PathPolicy(path.parent, allow_outside=allow_outside)
        for name, ln in mtllibs:  # one per mtllib statement
            mp = obj_policy.resolve(name, f"{path}: line {ln}: mtllib", required=False)
            if mp is None:
                warnings.warn(f"{path}: line {ln}: material library not found: "
                              f"{path.parent / name.replace(chr(92), '/')}; loading the geometry "
                              f"without its materials", UserWarning, stacklevel=2)
                continue
            defined.update(_parse_mtl(mp))
        cache: dict = {}
        for name in material_names:  # only the materials the OBJ uses, in order of first use
            if name not in defined:
                continue
            m = defined[name]
            materials[name] = m
            if m.map_Kd is not None:
                src, src_line, ref = m.extra["map_Kd_source"]
                tex = PathPolicy(Path(src).parent, allow_outside=allow_outside).resolve(
                    ref, f"{src}: line {src_line}: map_Kd texture", required=False)
                if tex is None:
                    raise FileNotFoundError(
                        f"{path}: texture image of material {name!r} not found: {m.map_Kd}")
                m.map_Kd = str(tex)
                if m.map_Kd not in cache:
                    cache[m.map_Kd] = _read_image(m.map_Kd, memory_limit, max_pixels)
                texture_images[name] = cache[m.map_Kd]

    return ObjData(verts, faces, faces_uvs, verts_uvs, faces_normals_idx, normals, materials,
                   face_materials, texture_images, material_names)


def _obj_to_mesh(path: Path, load_textures: bool, allow_outside: bool = False,
                 max_pixels=None) -> Mesh:
    d = load_obj(path, load_textures=load_textures, allow_outside=allow_outside,
                 max_pixels=max_pixels)
    tex = None
    if d.texture_images:
        if len(d.verts_uvs) == 0:
            raise ValueError(f"{path}: the material has a texture image but the file has no "
                             f"texture coordinates (vt); load with load_textures=False")
        # PyTorch3D indexes faces_uvs == -1 as the last UV (torch negative indexing); do the same.
        fuv = np.where(d.faces_uvs < 0, len(d.verts_uvs) - 1, d.faces_uvs)
        tex = TexturesUV(next(iter(d.texture_images.values())), fuv, d.verts_uvs)
    return Mesh(d.verts, d.faces, tex)


def load_objs_as_meshes(files: PathLike | Sequence[PathLike], load_textures: bool = True, *,
                        allow_outside: bool = False, max_pixels: int | None = None) -> Meshes:
    """Load OBJ files into a :class:`~geofit.structures.Meshes` batch (PyTorch3D semantics).

    Parameters
    ----------
    files : str, os.PathLike or sequence of them
        The ``.obj`` files, one mesh each.
    load_textures : bool
        Attach a :class:`~geofit.structures.TexturesUV` to meshes whose materials have a
        texture image.
    allow_outside : bool
        Follow MTL and texture paths outside each OBJ's folder (see :func:`load_obj`).
    max_pixels : int, optional
        Pixel cap of the texture images (see :func:`load_obj`).

    Returns
    -------
    Meshes
        One mesh per file. A textured mesh gets ``TexturesUV(maps=<first texture image>,
        faces_uvs, verts_uvs)``, like ``pytorch3d.io.load_objs_as_meshes``: only the first
        texture image (in order of ``usemtl``) is used, and MTL colours (Ka, Kd, Ks, Ns) are not
        applied. Meshes without a texture image have ``textures=None``.

    Raises
    ------
    FileNotFoundError, ValueError
        As :func:`load_obj`; also ValueError when a texture image exists but the file has no
        ``vt`` coordinates.

    Notes
    -----
    Faces without ``vt`` indices in a textured file use the last texture coordinate, which is
    what PyTorch3D's indexing with -1 does.
    """
    if isinstance(files, (str, os.PathLike)):
        files = [files]
    return Meshes([_obj_to_mesh(Path(f), load_textures, allow_outside, max_pixels)
                   for f in files])


def _fmt_floats(arr: np.ndarray, decimal_places: int | None) -> tuple:
    vals = arr.ravel().tolist()
    if decimal_places is None:
        return tuple(map(repr, vals))  # shortest string that round-trips exactly
    f = f"%.{decimal_places}f"
    return tuple(f % x for x in vals)


def save_obj(path: PathLike, mesh_or_verts, faces=None, *, verts_uvs=None, faces_uvs=None,
             texture_map=None, decimal_places: int | None = None) -> None:
    """Write a triangle mesh as an OBJ file (with an MTL and a PNG texture when textured).

    Parameters
    ----------
    path : str or os.PathLike
        The ``.obj`` file to write. A texture is written next to it as ``<stem>.mtl`` and
        ``<stem>.png``.
    mesh_or_verts : Mesh or (V, 3) float64
        A :class:`~geofit.structures.Mesh` or a trimesh / Open3D mesh (its TexturesUV, if any,
        is written; vertex colours are not, OBJ has no standard place for them: use
        :func:`geofit.io.save_mesh` with ``.ply`` or ``.glb``), or vertex positions.
    faces : (F, 3) int64, optional
        Triangles; required with vertex positions, not allowed with a Mesh.
    verts_uvs : (T, 2) float64, optional
        Texture coordinates (with vertex positions only), written as ``vt`` lines.
    faces_uvs : (F, 3) int64, optional
        Per-corner indices into ``verts_uvs``; faces are then written as ``f v/vt``.
    texture_map : (H, W, C) float64, optional
        Texture image with values in [0, 1], C in {1, 3, 4}; written as an 8-bit PNG
        (``round(255 * value)``) named by an MTL ``map_Kd``. Needs UVs.
    decimal_places : int, optional
        Write coordinates with this many decimals. By default every float is written with its
        shortest exact representation (``repr``), so loading gives back the same float64 values.

    Raises
    ------
    ValueError
        For inconsistent arguments, shapes or index ranges, non-finite values, a mesh without
        faces, or texture values outside [0, 1]; for a path whose extension names another
        format (``.ply``, ``.stl``, ...: use :func:`geofit.io.save_mesh`).

    Notes
    -----
    The round trip ``load_obj(save_obj(...))`` returns identical vertices, faces and UVs by
    default; the texture comes back quantised to multiples of 1/255 (exact when the map already
    holds such values, as any map read from an 8-bit image does).
    """
    path = Path(path)
    if EXTENSIONS.get(path.suffix.lower(), "OBJ") != "OBJ":
        raise not_obj_error(path, EXTENSIONS[path.suffix.lower()], reader=False)
    if foreign_kind(mesh_or_verts) is not None:
        mesh_or_verts = as_mesh(mesh_or_verts, "mesh_or_verts")  # a trimesh or Open3D mesh
    if isinstance(mesh_or_verts, Mesh):
        if faces is not None or verts_uvs is not None or faces_uvs is not None \
                or texture_map is not None:
            raise ValueError("faces, verts_uvs, faces_uvs, texture_map: give them only with a "
                             "vertex array, not with a Mesh (the Mesh carries its own)")
        verts = mesh_or_verts.verts
        faces = mesh_or_verts.faces
        tex = mesh_or_verts.textures
        if isinstance(tex, TexturesUV):
            verts_uvs, faces_uvs, texture_map = tex.verts_uvs, tex.faces_uvs, tex.maps
    else:
        verts = as_points(mesh_or_verts, "verts")
        if faces is None:
            raise ValueError("faces: required when mesh_or_verts is a vertex array")
    faces = as_faces(faces, "faces", len(verts), allow_empty=False)
    if (verts_uvs is None) != (faces_uvs is None):
        raise ValueError("verts_uvs, faces_uvs: give both or neither")
    if verts_uvs is not None:
        verts_uvs = as_array(verts_uvs, "verts_uvs", (None, 2))
        faces_uvs = as_faces(faces_uvs, "faces_uvs", len(verts_uvs))
        if len(faces_uvs) != len(faces):
            raise ValueError(f"faces_uvs: expected shape ({len(faces)}, 3), got {faces_uvs.shape}")
    if texture_map is not None:
        if verts_uvs is None:
            raise ValueError("texture_map: needs verts_uvs and faces_uvs")
        tm = np.asarray(texture_map)
        if tm.ndim == 2:
            tm = tm[:, :, None]
        tm = as_array(tm, "texture_map", (None, None, None))
        if tm.shape[2] not in (1, 3, 4) or tm.shape[0] < 1 or tm.shape[1] < 1:
            raise ValueError(f"texture_map: expected shape (H, W, C) with C in (1, 3, 4), "
                             f"got {tm.shape}")
        if tm.min() < 0.0 or tm.max() > 1.0:
            raise ValueError(f"texture_map: expected values in [0, 1], got range "
                             f"[{tm.min():.6g}, {tm.max():.6g}]")
        texture_map = tm
    if decimal_places is not None and (not isinstance(decimal_places, (int, np.integer))
                                       or isinstance(decimal_places, bool)
                                       or not 0 <= decimal_places <= 30):
        raise ValueError(f"decimal_places: expected None or an integer in [0, 30], "
                         f"got {decimal_places!r}")

    parts = ["# written by geofit\n"]
    if texture_map is not None:
        parts.append(f"mtllib {path.stem}.mtl\nusemtl mesh\n")
    parts.append(("v %s %s %s\n" * len(verts)) % _fmt_floats(verts, decimal_places))
    if verts_uvs is not None:
        parts.append(("vt %s %s\n" * len(verts_uvs)) % _fmt_floats(verts_uvs, decimal_places))
        fv = np.stack([faces + 1, faces_uvs + 1], axis=2)  # (F, 3, 2): v/vt per corner
        parts.append(("f %d/%d %d/%d %d/%d\n" * len(faces)) % tuple(fv.ravel().tolist()))
    else:
        parts.append(("f %d %d %d\n" * len(faces)) % tuple((faces + 1).ravel().tolist()))
    if texture_map is not None:  # the texture and MTL first: the OBJ never names a missing file
        import io

        from PIL import Image

        img = np.round(texture_map * 255.0).astype(np.uint8)
        buf = io.BytesIO()
        Image.fromarray(img[:, :, 0] if img.shape[2] == 1 else img).save(buf, format="PNG")
        write_bytes(path.with_suffix(".png"), buf.getbuffer())
        write_text(path.with_suffix(".mtl"),
                   "# written by geofit\nnewmtl mesh\n"
                   f"map_Kd {path.stem}.png\n"
                   "Ka 1.0 1.0 1.0\nKd 1.0 1.0 1.0\nKs 0.0 0.0 0.0\nNs 0.0\n")
    write_text(path, "".join(parts))
