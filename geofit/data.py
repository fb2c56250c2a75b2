"""Tutorial data: find or download PyTorch3D's tutorial meshes, or build procedural stand-ins.

Where the files are looked for, in order:

1. the folder named by the environment variable ``GEOFIT_DATA`` (holding ``dolphin/dolphin.obj``,
   ``cow_mesh/cow.obj``, ``cow_mesh/cow.mtl``, ``cow_mesh/cow_texture.png``);
2. the user cache, ``$XDG_CACHE_HOME/geofit`` or ``~/.cache/geofit``, where :func:`download`
   writes;
3. the data installed with geofit (:func:`shipped_dir`): the cow (Keenan Crane's "Spot", public
   domain), so the rendering tutorials and ``geofit demo`` use the real cow on any machine.

The dolphin (licence unknown) is not shipped: without ``GEOFIT_DATA``, a cached download or
network, :func:`load_target_mesh` falls back to a deterministic procedural stand-in (and
:func:`load_textured_mesh` to a procedural textured mesh should the shipped cow be missing),
and says which mesh it returned.
"""
from __future__ import annotations

import hashlib
import os
import tempfile
import urllib.error
import urllib.request
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import NamedTuple

import numpy as np

from .io import load_mesh, load_objs_as_meshes
from .shapes import ico_sphere
from .structures.mesh import Mesh
from .structures.textures import TexturesUV

__all__ = [
    "DEFAULT_URL",
    "FILES",
    "GROUPS",
    "DataMesh",
    "DataUnavailableError",
    "cache_dir",
    "data_dir",
    "download",
    "find",
    "shipped_dir",
    "load_target_mesh",
    "load_textured_mesh",
    "procedural_target",
    "procedural_textured_mesh",
]

#: Where PyTorch3D's tutorials download their data from.
DEFAULT_URL = "https://dl.fbaipublicfiles.com/pytorch3d/data"

#: Known tutorial files: relative path -> (size in bytes, sha256). The checksums are those of the
#: files committed in PyTorch3D's repository (cow, ``docs/tutorials/data/cow_mesh``) and of the
#: dolphin the ``deform_source_mesh_to_target_mesh`` tutorial downloads.
FILES: dict[str, tuple[int, str]] = {
    "dolphin/dolphin.obj": (
        156763, "eb47d91c9da39d84185bd54bf66df8253561a31ec488aa893725c17cc2a425ba"),
    "cow_mesh/cow.obj": (
        330659, "62337f06b4aa4f2eaa95f854553a02039d853365a78b0a581c26ece5691a6d99"),
    "cow_mesh/cow.mtl": (
        155, "ce6398d52486f81f2c329b1683ad4fedce970471aa36e589e05c5177432db6cb"),
    "cow_mesh/cow_texture.png": (
        78699, "cddabbae52a666173e7953e238b88340d285044dc20b36f8ed3f1a41db534fa5"),
}

#: Shorthand names accepted by :func:`download`.
GROUPS: dict[str, tuple[str, ...]] = {
    "dolphin": ("dolphin/dolphin.obj",),
    "cow": ("cow_mesh/cow.obj", "cow_mesh/cow.mtl", "cow_mesh/cow_texture.png"),
}

_CHUNK = 1 << 16


class DataUnavailableError(RuntimeError):
    """The tutorial data could not be fetched (no network, server error, missing file)."""


class DataMesh(NamedTuple):
    """A mesh together with what it is.

    Attributes
    ----------
    mesh : Mesh
        The mesh.
    name : str
        ``"dolphin"`` / ``"cow"`` for the tutorial files, ``"procedural_target"`` /
        ``"procedural_textured"`` for the stand-ins.
    path : Path or None
        The file it was read from; None for a procedural mesh.
    """

    mesh: Mesh
    name: str
    path: Path | None


# --------------------------------------------------------------------------- locations
def cache_dir() -> Path:
    """The user cache folder, ``$XDG_CACHE_HOME/geofit`` or ``~/.cache/geofit`` (not created)."""
    xdg = os.environ.get("XDG_CACHE_HOME", "").strip()
    base = Path(xdg).expanduser() if xdg else Path.home() / ".cache"
    return base / "geofit"


def data_dir() -> Path:
    """The folder tutorial data is read from first.

    Returns
    -------
    Path
        ``$GEOFIT_DATA`` when that variable is set (and not empty), else :func:`cache_dir`.
        The folder may not exist; :func:`find` checks each file.
    """
    env = os.environ.get("GEOFIT_DATA", "").strip()
    return Path(env).expanduser() if env else cache_dir()


def shipped_dir() -> Path | None:
    """The folder of data installed with geofit (the cow), or None if it is missing.

    Returns
    -------
    Path or None
        ``geofit/_data`` inside the installed package (package data of a regular or editable
        install; in a source checkout a link to the top-level ``data/`` folder), or the
        checkout's ``data/`` folder itself where the link is not available. None when the
        environment variable ``GEOFIT_SHIPPED_DATA`` is ``0`` (the tests use this to exercise
        the procedural fallbacks).
    """
    if os.environ.get("GEOFIT_SHIPPED_DATA", "").strip().lower() in ("0", "false", "no", "off"):
        return None
    pkg = Path(__file__).resolve().parent
    for d in (pkg / "_data", pkg.parent / "data"):
        if (d / "cow_mesh" / "cow.obj").is_file():
            return d
    return None


def _search_dirs() -> list[Path]:
    dirs = [data_dir()]
    if cache_dir() not in dirs:
        dirs.append(cache_dir())
    shipped = shipped_dir()
    if shipped is not None:
        dirs.append(shipped)
    return dirs


def _check_name(name: str) -> str:
    if not isinstance(name, str) or not name:
        raise ValueError(f"name: expected a relative file path such as 'cow_mesh/cow.obj', "
                         f"got {name!r}")
    p = Path(name)
    if p.is_absolute() or ".." in p.parts:
        raise ValueError(f"name: expected a relative path inside the data folder, got {name!r}")
    return p.as_posix()


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(_CHUNK), b""):
            h.update(block)
    return h.hexdigest()


def find(name: str, *, verify: bool = False) -> Path | None:
    """The path of a tutorial file, or None when it is not available.

    Parameters
    ----------
    name : str
        Path relative to the data folder, e.g. ``"dolphin/dolphin.obj"`` or
        ``"cow_mesh/cow.obj"``.
    verify : bool
        Also require the file's sha256 to match :data:`FILES` (for the files listed there).

    Returns
    -------
    Path or None
        The first existing ``<folder>/<name>`` over ``$GEOFIT_DATA``, the user cache, then the
        data shipped with geofit (:func:`shipped_dir`).

    Raises
    ------
    ValueError
        If ``name`` is absolute or leaves the data folder.
    """
    name = _check_name(name)
    for d in _search_dirs():
        p = d / name
        if p.is_file():
            if verify and name in FILES and _sha256(p) != FILES[name][1]:
                continue
            return p
    return None


# --------------------------------------------------------------------------- download
def _help_text(names: Iterable[str], dest: Path) -> str:
    lines = []
    for n in names:
        size, sha = FILES.get(n, (None, None))
        extra = f" ({size} bytes, sha256 {sha})" if size is not None else ""
        lines.append(f"  {n}{extra}")
    return ("To provide the tutorial data without network access, set the environment variable "
            "GEOFIT_DATA to a folder holding\n" + "\n".join(lines) +
            f"\nor copy those files into {dest} (same relative paths).")


def _resolve_files(files) -> dict[str, str]:
    if files is None:
        return {n: FILES[n][1] for n in FILES}
    if isinstance(files, Mapping):
        out = {}
        for n, sha in files.items():
            n = _check_name(n)
            if not (isinstance(sha, str) and len(sha) == 64
                    and all(c in "0123456789abcdef" for c in sha.lower())):
                raise ValueError(f"files[{n!r}]: expected a 64-digit hex sha256, got {sha!r}")
            out[n] = sha.lower()
        return out
    if isinstance(files, str):
        files = [files]
    out = {}
    for n in files:
        if n in GROUPS:
            out.update({m: FILES[m][1] for m in GROUPS[n]})
        elif n in FILES:
            out[n] = FILES[n][1]
        else:
            raise ValueError(f"files: unknown tutorial file {n!r}; expected one of "
                             f"{sorted(GROUPS) + sorted(FILES)}, or a mapping name -> sha256")
    return out


def _fetch(url: str, target: Path, sha: str, timeout: float, help_text: str) -> None:
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".part", dir=target.parent)
    try:
        h = hashlib.sha256()
        with os.fdopen(fd, "wb") as out:
            try:
                with urllib.request.urlopen(url, timeout=timeout) as resp:
                    for block in iter(lambda: resp.read(_CHUNK), b""):
                        h.update(block)
                        out.write(block)
            except urllib.error.HTTPError as exc:
                raise DataUnavailableError(
                    f"could not download {url}: HTTP {exc.code} {exc.reason}.\n{help_text}"
                ) from None
            except (urllib.error.URLError, OSError, ValueError) as exc:
                reason = getattr(exc, "reason", exc)
                raise DataUnavailableError(
                    f"could not download {url}: {reason}.\n{help_text}") from None
        got = h.hexdigest()
        if got != sha:
            raise ValueError(f"{url}: sha256 mismatch, expected {sha}, got {got}; "
                             f"the file was not saved")
        with open(tmp, "rb") as fh:  # durable before it takes the target's name
            os.fsync(fh.fileno())
        os.replace(tmp, target)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def download(dest: str | os.PathLike | None = None, *, base_url: str = DEFAULT_URL,
             files=None, force: bool = False, timeout: float = 30.0) -> dict[str, Path]:
    """Fetch the tutorial files, check their sha256 and store them atomically.

    Parameters
    ----------
    dest : str or os.PathLike, optional
        Folder to write into; by default the user cache :func:`cache_dir`, which :func:`find`
        searches.
    base_url : str
        URL prefix; file ``name`` is fetched from ``base_url + "/" + name``. Any scheme urllib
        handles (``https://``, ``http://``, ``file://``) works, so a local mirror can be used.
    files : None, str, sequence of str, or mapping of str to str
        Which files: None for all of :data:`FILES`; names from :data:`FILES` or :data:`GROUPS`
        (``"dolphin"``, ``"cow"``); or a mapping ``relative name -> sha256`` (hex) for files
        that are not in the registry.
    force : bool
        Download even when a file with the right checksum is already there.
    timeout : float
        Seconds to wait for the server (per request).

    Returns
    -------
    dict of str to Path
        Where each requested file now is.

    Raises
    ------
    DataUnavailableError
        If a file cannot be fetched (no network, unreachable host, HTTP error, missing local
        file). The message says how to provide the files by hand.
    ValueError
        If a downloaded file's sha256 differs from the expected one (nothing is written for
        it), or for unknown names.

    Notes
    -----
    Each file is streamed into a temporary file next to its destination and renamed into place
    only after its checksum matched, so an interrupted or corrupt download never leaves a
    partial file under the final name. An existing file with a wrong checksum is replaced.
    """
    wanted = _resolve_files(files)
    dest = cache_dir() if dest is None else Path(dest)
    if not isinstance(base_url, str) or not base_url:
        raise ValueError(f"base_url: expected a URL string, got {base_url!r}")
    out: dict[str, Path] = {}
    help_text = _help_text(wanted, dest)
    for name, sha in wanted.items():  # one request per file
        target = dest / name
        if not force and target.is_file() and _sha256(target) == sha:
            out[name] = target
            continue
        _fetch(f"{base_url.rstrip('/')}/{name}", target, sha, timeout, help_text)
        out[name] = target
    return out


# --------------------------------------------------------------------------- procedural shapes
def _bump(d: np.ndarray, centre, widths) -> np.ndarray:
    """Smooth bump on the unit sphere: exp(-sum(((d - c) / w)^2)) per direction d (n, 3)."""
    c = np.asarray(centre, dtype=np.float64)
    c = c / np.linalg.norm(c)
    w = np.asarray(widths, dtype=np.float64)
    return np.exp(-np.sum(((d - c) / w) ** 2, axis=1))


def procedural_target() -> Mesh:
    """A deterministic dolphin-like stand-in for the deform tutorial's ``dolphin.obj``.

    Returns
    -------
    Mesh
        2562 vertices and 5120 faces (``ico_sphere(4)``'s topology, like the real dolphin),
        closed, genus 0 (Euler characteristic 2), counter-clockwise seen from outside,
        non-convex, in the tutorial frame: centred on the vertex mean and scaled so the
        largest absolute coordinate is 1.

    Notes
    -----
    Each unit direction ``d`` of ``ico_sphere(4)`` is moved to ``r(d) d`` with
    ``r(d) = e(d) (1 + sum_i a_i b_i(d))``: ``e`` is the radius of an ellipsoid with semi-axes
    (0.32, 0.38, 1.0) (long axis z, the snout at +z, the tail at -z) and ``b_i`` are smooth
    anisotropic Gaussian bumps ``exp(-sum(((d - c_i) / w_i)^2))``: a dorsal fin (+y), two
    pectoral flippers, a beak, two tail flukes, and three dents (a waist before the tail and
    two eye sockets) that make the surface non-convex. Since ``r > 0`` everywhere, the surface
    is a radial graph over the sphere and cannot intersect itself.
    """
    ico = ico_sphere(4)
    d = ico.verts
    ax = np.array([0.32, 0.38, 1.0])
    e = 1.0 / np.sqrt(np.sum((d / ax) ** 2, axis=1))
    field = (
        1.3 * _bump(d, (0.0, 1.0, -0.25), (0.14, 0.6, 0.25))      # dorsal fin
        + 0.7 * _bump(d, (0.9, -0.6, 0.35), (0.25, 0.2, 0.12))    # right flipper
        + 0.7 * _bump(d, (-0.9, -0.6, 0.35), (0.25, 0.2, 0.12))   # left flipper
        + 0.12 * _bump(d, (0.0, -0.1, 1.0), (0.08, 0.08, 0.2))    # beak
        + 0.6 * _bump(d, (0.35, 0.0, -1.0), (0.2, 0.08, 0.12))    # right fluke
        + 0.6 * _bump(d, (-0.35, 0.0, -1.0), (0.2, 0.08, 0.12))   # left fluke
        - 0.35 * _bump(d, (0.0, 0.0, -1.0), (0.5, 0.5, 0.05))     # waist (tail stock)
        - 0.25 * _bump(d, (1.0, 0.15, 0.6), (0.2, 0.12, 0.06))    # right eye socket
        - 0.25 * _bump(d, (-1.0, 0.15, 0.6), (0.2, 0.12, 0.06))   # left eye socket
    )
    verts = d * (e * (1.0 + field))[:, None]
    return Mesh(verts, ico.faces).normalize().mesh


def _uv_sphere(n_lat: int, n_lon: int):
    """Indices of a latitude-longitude sphere: 3-D faces (closed) and seam-split UV faces."""
    R = n_lat - 1  # rings between the poles
    def ring(i, j):  # vertex of ring i, column j (the seam column wraps to column 0)
        return 1 + i * n_lon + (j % n_lon)

    def uvring(i, j):  # UV of ring i, column j (the seam column n_lon is its own UV)
        return i * (n_lon + 1) + j

    north, south = 0, 1 + R * n_lon
    j = np.arange(n_lon)
    n_uv_grid = R * (n_lon + 1)
    # north cap
    cap_n = np.stack([np.full(n_lon, north), ring(0, j), ring(0, j + 1)], 1)
    cap_n_uv = np.stack([n_uv_grid + j, uvring(0, j), uvring(0, j + 1)], 1)
    # bands between ring i and i + 1
    i, jj = np.meshgrid(np.arange(R - 1), j, indexing="ij")
    i, jj = i.ravel(), jj.ravel()
    a, b, c, dd = ring(i, jj), ring(i + 1, jj), ring(i + 1, jj + 1), ring(i, jj + 1)
    ua, ub, uc, ud = uvring(i, jj), uvring(i + 1, jj), uvring(i + 1, jj + 1), uvring(i, jj + 1)
    band = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, dd], 1)])
    band_uv = np.concatenate([np.stack([ua, ub, uc], 1), np.stack([ua, uc, ud], 1)])
    # south cap
    cap_s = np.stack([np.full(n_lon, south), ring(R - 1, j + 1), ring(R - 1, j)], 1)
    cap_s_uv = np.stack([n_uv_grid + n_lon + j, uvring(R - 1, j + 1), uvring(R - 1, j)], 1)
    faces = np.concatenate([cap_n, band, cap_s]).astype(np.int64)
    faces_uvs = np.concatenate([cap_n_uv, band_uv, cap_s_uv]).astype(np.int64)
    # 3-D directions
    theta = np.pi * np.arange(1, n_lat) / n_lat
    phi = 2 * np.pi * np.arange(n_lon) / n_lon
    T, P = np.meshgrid(theta, phi, indexing="ij")
    body = np.stack([np.sin(T) * np.sin(P), np.cos(T), np.sin(T) * np.cos(P)], -1).reshape(-1, 3)
    dirs = np.concatenate([[[0.0, 1.0, 0.0]], body, [[0.0, -1.0, 0.0]]])
    # UVs: u = phi / 2 pi (seam column u = 1 duplicated), v = 1 at the north pole
    u = np.arange(n_lon + 1) / n_lon
    v = 1.0 - np.arange(1, n_lat) / n_lat
    U, Vv = np.meshgrid(u, v)
    grid = np.stack([U.ravel(), Vv.ravel()], 1)
    pole_u = (np.arange(n_lon) + 0.5) / n_lon
    poles = np.concatenate([np.stack([pole_u, np.ones(n_lon)], 1),
                            np.stack([pole_u, np.zeros(n_lon)], 1)])
    verts_uvs = np.concatenate([grid, poles])
    return dirs, faces, faces_uvs, verts_uvs


def _procedural_texture(size: int) -> np.ndarray:
    """(size, size, 3) float64 in [0, 1]: a 16 x 16 checker over a hue (u) and shade (v) gradient."""
    t = np.arange(size) / (size - 1)
    u = t[None, :]                 # column -> u (align_corners convention)
    v = 1.0 - t[:, None]           # row 0 is the top of the image, v = 1
    hue = 2 * np.pi * u
    rgb = np.stack([0.5 + 0.5 * np.cos(hue), 0.5 + 0.5 * np.cos(hue - 2 * np.pi / 3),
                    0.5 + 0.5 * np.cos(hue + 2 * np.pi / 3)], -1)
    shade = 0.35 + 0.65 * v
    checker = ((np.floor(u * 16) + np.floor(v * 16)) % 2)[..., None]
    img = rgb * shade[..., None] * (0.55 + 0.45 * checker)
    return np.clip(img, 0.0, 1.0)


def procedural_textured_mesh(n_lat: int = 32, n_lon: int = 64, texture_size: int = 512) -> Mesh:
    """A deterministic textured stand-in for the tutorials' cow: a UV-mapped ellipsoid.

    Parameters
    ----------
    n_lat : int
        Latitude bands (>= 3); the mesh has ``(n_lat - 1) n_lon + 2`` vertices and
        ``2 (n_lat - 1) n_lon`` faces.
    n_lon : int
        Longitude segments (>= 3).
    texture_size : int
        Side of the square texture image in pixels (>= 16).

    Returns
    -------
    Mesh
        A closed genus-0 ellipsoid (semi-axes 0.9 in x, 0.65 in y, 0.75 in z, with a gentle
        bulge), faces counter-clockwise seen from outside, with a ``TexturesUV``: ``maps``
        ``(texture_size, texture_size, 3)`` float64 in [0, 1], a 16 x 16 checkerboard over a
        hue gradient in u and a shade gradient in v.

    Notes
    -----
    The UV layout is latitude-longitude and seam-aware: the 3-D vertices on the seam (u = 0 and
    u = 1) and at the poles are shared, so the surface is watertight, while each face corner has
    its own UV index (``faces_uvs`` differs from ``faces``): the seam column appears twice in
    ``verts_uvs`` and each pole triangle has its own pole UV at the middle of its column, so no
    triangle's UVs wrap around the image.
    """
    for val, nm, lo in ((n_lat, "n_lat", 3), (n_lon, "n_lon", 3), (texture_size, "texture_size", 16)):
        if not isinstance(val, (int, np.integer)) or isinstance(val, bool) or val < lo:
            raise ValueError(f"{nm}: expected an integer >= {lo}, got {val!r}")
    dirs, faces, faces_uvs, verts_uvs = _uv_sphere(int(n_lat), int(n_lon))
    bulge = 1.0 + 0.08 * np.exp(-np.sum((dirs - [0.0, 0.0, 1.0]) ** 2, axis=1) / 0.3)
    verts = dirs * np.array([0.9, 0.65, 0.75]) * bulge[:, None]
    tex = TexturesUV(_procedural_texture(int(texture_size)), faces_uvs, verts_uvs)
    return Mesh(verts, faces, tex)


# --------------------------------------------------------------------------- loaders
def load_target_mesh() -> DataMesh:
    """The deform tutorial's target: ``dolphin/dolphin.obj`` if found, else the stand-in.

    Returns
    -------
    DataMesh
        ``(mesh, "dolphin", path)`` with the file's raw coordinates (the tutorial normalises it
        afterwards), or ``(procedural_target(), "procedural_target", None)``.
    """
    p = find("dolphin/dolphin.obj")
    if p is not None:
        return DataMesh(load_mesh(p, load_textures=False), "dolphin", p)
    return DataMesh(procedural_target(), "procedural_target", None)


def load_textured_mesh() -> DataMesh:
    """The rendering tutorials' textured mesh: the cow (shipped with geofit), else a stand-in.

    Returns
    -------
    DataMesh
        ``(mesh, "cow", path)`` (from ``$GEOFIT_DATA``, the cache or the copy installed with
        geofit, in that order) read with :func:`geofit.io.load_objs_as_meshes` (TexturesUV
        from ``cow_texture.png``, raw coordinates), or
        ``(procedural_textured_mesh(), "procedural_textured", None)``.
    """
    p = find("cow_mesh/cow.obj")
    if p is not None:
        return DataMesh(load_objs_as_meshes([p])[0], "cow", p)
    return DataMesh(procedural_textured_mesh(), "procedural_textured", None)
