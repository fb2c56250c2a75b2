"""``geofit demo``: render the default mesh from several views by Embree ray casting.

The default mesh is the tutorial cow when ``GEOFIT_DATA`` (or the cache) has it, otherwise
geofit's procedural textured mesh. All rays of all views go to Embree in one call; each hit is
coloured by its texture (or a flat grey) times a head-light Lambert term.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np

__all__ = ["register", "render_views", "DemoImages"]


class DemoImages(NamedTuple):
    """Result of :func:`render_views`."""

    images: np.ndarray  # (N, H, W, 3) float64 in [0, 1]
    face_ids: np.ndarray  # (N, H, W) int64, -1 on background
    seconds_cast: float
    seconds_shade: float


def render_views(mesh, n_views: int = 8, image_size: int = 256, dist: float = 2.7,
                 elev: float = 15.0, background=(1.0, 1.0, 1.0)) -> DemoImages:
    """Render a normalised mesh from ``n_views`` azimuths around it.

    Parameters
    ----------
    mesh : Mesh
        The mesh, already in the tutorials' normalised frame (centred, max |coord| 1).
    n_views : int
        Number of views, evenly spaced in azimuth (>= 1).
    image_size : int
        Square image side in pixels (>= 8).
    dist, elev : float
        Camera distance and elevation in degrees (PyTorch3D's look_at_view_transform).
    background : (3,) float
        Background colour.

    Returns
    -------
    DemoImages
    """
    from ..cameras import FoVPerspectiveCameras, look_at_view_transform
    from ..raycast import RayCaster

    if not isinstance(n_views, (int, np.integer)) or n_views < 1:
        raise ValueError(f"n_views: expected an integer >= 1, got {n_views!r}")
    if not isinstance(image_size, (int, np.integer)) or image_size < 8:
        raise ValueError(f"image_size: expected an integer >= 8, got {image_size!r}")
    azim = np.linspace(-180.0, 180.0, n_views, endpoint=False) + 180.0
    R, T = look_at_view_transform(dist, elev, azim)
    cameras = FoVPerspectiveCameras(R=R, T=T)
    rays = cameras.pixel_rays((image_size, image_size))
    o = rays.origins.reshape(-1, 3)
    d = rays.directions.reshape(-1, 3)

    t0 = time.perf_counter()
    hits = RayCaster(mesh).cast(o, d)
    t1 = time.perf_counter()

    hit = hits.face_id >= 0
    rgb = np.empty((len(o), 3))
    rgb[:] = background
    f = hits.face_id[hit]
    if mesh.textures is not None:
        albedo = mesh.sample_textures(f, hits.bary[hit])[:, :3]
    else:
        albedo = np.full((len(f), 3), 0.7)
    n = mesh.face_normals[f]
    view = d[hit] / np.linalg.norm(d[hit], axis=1, keepdims=True)
    lambert = np.abs(np.einsum("ij,ij->i", n, view))  # head light, two-sided
    rgb[hit] = np.clip(albedo * (0.35 + 0.65 * lambert[:, None]), 0.0, 1.0)
    t2 = time.perf_counter()

    shape = (n_views, image_size, image_size)
    return DemoImages(rgb.reshape(*shape, 3), hits.face_id.reshape(shape), t1 - t0, t2 - t1)


def _grid(images: np.ndarray, cols: int) -> np.ndarray:
    n, h, w, c = images.shape
    rows = -(-n // cols)
    out = np.ones((rows * h, cols * w, c))
    for i, img in enumerate(images):  # loop over views
        r, q = divmod(i, cols)
        out[r * h:(r + 1) * h, q * w:(q + 1) * w] = img
    return out


def run(args: argparse.Namespace) -> int:
    from PIL import Image

    from ..data import load_textured_mesh

    loaded = load_textured_mesh()
    mesh = loaded.mesh.normalize().mesh
    print(f"geofit demo: mesh '{loaded.name}' ({mesh.n_verts} vertices, {mesh.n_faces} faces)"
          + (f" from {loaded.path}" if loaded.path else " (procedural: set GEOFIT_DATA for the cow)"))
    res = render_views(mesh, args.views, args.size)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    grid = _grid(res.images, min(args.views, 4))
    path = out / "demo.png"
    Image.fromarray((grid * 255 + 0.5).astype(np.uint8)).save(path)
    n_rays = res.face_ids.size
    print(f"geofit demo: {args.views} views of {args.size}x{args.size} = {n_rays} rays in one "
          f"threaded cast: cast {res.seconds_cast:.3f} s ({n_rays / res.seconds_cast / 1e6:.1f} M rays/s), "
          f"shade {res.seconds_shade:.3f} s; coverage {np.mean(res.face_ids >= 0):.1%}")
    print(f"geofit demo: wrote {path}")
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser("demo", help="render the default mesh from several views (PNG grid)",
                              description=__doc__)
    p.add_argument("--views", type=int, default=8, help="number of views (default 8)")
    p.add_argument("--size", type=int, default=256, help="image size in pixels (default 256)")
    p.add_argument("--out", default="out", help="output folder (default ./out)")
    p.set_defaults(func=run)
