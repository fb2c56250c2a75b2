"""``geofit render-points [CLOUD]``: render a coloured point cloud (PyTorch3D's tutorial 3).

With a ``.npz`` (``verts`` and ``rgb``, as the tutorial's PittsburghBridge file) or ``.ply`` file,
that cloud is rendered. Without one: the tutorial's ``PittsburghBridge/pointcloud.npz`` if it is in
the data folder (``$GEOFIT_DATA`` or the user cache), else geofit's default cloud: points sampled
uniformly on the default textured mesh (the cow when the tutorial data is found, else the
procedural stand-in), normalised as in the tutorials, each coloured by the texture at its
surface point.
Writes ``render_points.png`` (the composited image) and ``render_points_depth.png`` (the depth of
the nearest point, near = bright, background black) into ``--out``.
"""
from __future__ import annotations

import argparse
import time

from .._atomic import atomic_write
from ._common import add_command, out_dir, wrote

__all__ = ["BRIDGE", "default_cloud", "register", "run"]

#: The tutorial's cloud, relative to the data folder (``geofit.data.find``).
BRIDGE = "PittsburghBridge/pointcloud.npz"


def default_cloud(n_points: int = 300_000, seed=0):
    """geofit's default coloured cloud: samples of the textured default mesh with texture colours.

    Parameters
    ----------
    n_points : int
        Number of samples, >= 1.
    seed : int or numpy.random.Generator
        Sampling randomness (reproducible).

    Returns
    -------
    cloud : PointCloud
        ``points (n_points, 3)`` on the mesh normalised as in the tutorials (centred on the
        vertex mean, largest absolute coordinate 1) and ``features (n_points, 3)`` RGB in [0, 1].
    name : str
        ``"cow"`` or ``"procedural_textured"``.
    """
    from ..data import load_textured_mesh
    from ..ops import sample_points_from_meshes
    from ..structures.pointcloud import PointCloud

    data = load_textured_mesh()
    mesh = data.mesh.normalize().mesh
    s = sample_points_from_meshes(mesh, n_points, seed=seed, return_textures=True)
    return PointCloud(s.points, s.textures[:, :3]), data.name


def _to_uint8(img: np.ndarray) -> np.ndarray:
    import numpy as np

    return (np.clip(img, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def _depth_to_uint8(depth: np.ndarray) -> np.ndarray:
    import numpy as np

    out = np.zeros(depth.shape, dtype=np.uint8)
    hit = depth >= 0
    if hit.any():
        lo, hi = depth[hit].min(), depth[hit].max()
        t = (hi - depth[hit]) / (hi - lo) if hi > lo else np.ones(int(hit.sum()))
        out[hit] = (55 + 200 * t + 0.5).astype(np.uint8)
    return out


def run(args: argparse.Namespace) -> int:
    """Run the sub-command; returns the exit code."""
    from PIL import Image

    from ..cameras import FoVOrthographicCameras, FoVPerspectiveCameras, look_at_view_transform
    from ..data import find
    from ..io import load_pointcloud
    from ..render.points.compositing import AlphaCompositor, NormWeightedCompositor
    from ..render.points import (
        PointsRasterizationSettings,
        PointsRasterizer,
        PointsRenderer,
    )

    t0 = time.perf_counter()
    if args.cloud is None:
        args.cloud = find(BRIDGE)
    if args.cloud is None:
        cloud, source = default_cloud(args.n_points, args.seed)
        azim = 180.0 if args.azim is None else args.azim   # the cow faces -Z: look at its front
    else:
        cloud = load_pointcloud(args.cloud)
        source = str(args.cloud)
        azim = 0.0 if args.azim is None else args.azim
    if cloud.features is None:
        raise ValueError(f"{source}: the cloud has no colours to render")
    t_load = time.perf_counter() - t0
    dist = args.dist if args.dist is not None else (20.0 if args.camera == "ortho" else 2.7)
    R, T = look_at_view_transform(dist, args.elev, azim)
    if args.camera == "ortho":
        cameras = FoVOrthographicCameras(R=R, T=T, znear=0.01)
    else:
        cameras = FoVPerspectiveCameras(R=R, T=T)
    settings = PointsRasterizationSettings(image_size=args.image_size, radius=args.radius,
                                           points_per_pixel=args.points_per_pixel,
                                           radius_units=args.radius_units)
    bg = None if args.background is None else tuple(args.background)
    comp = (AlphaCompositor(background_color=bg) if args.compositor == "alpha"
            else NormWeightedCompositor(background_color=bg))
    renderer = PointsRenderer(PointsRasterizer(cameras, settings), comp)
    t1 = time.perf_counter()
    out = renderer.render(cloud)
    t_render = time.perf_counter() - t1

    dest = out_dir(args)
    img_path = dest / "render_points.png"
    depth_path = dest / "render_points_depth.png"
    atomic_write(img_path, Image.fromarray(_to_uint8(out.images[0, ..., :3])).save)
    atomic_write(depth_path, Image.fromarray(_depth_to_uint8(out.depth[0])).save)
    covered = float(out.fragments.mask.mean())
    print(f"cloud: {source} ({len(cloud)} points, loaded in {t_load:.2f} s)")
    print(f"camera: {args.camera}, dist {dist:g}, elev {args.elev:g}, azim {azim:g}; "
          f"image {settings.hw[0]}x{settings.hw[1]}, radius {args.radius:g} "
          f"({args.radius_units}), {args.points_per_pixel} points per pixel, "
          f"{args.compositor} compositor")
    print(f"rendered in {t_render:.3f} s; {100 * covered:.1f}% of the pixels covered")
    return wrote(img_path, depth_path)


def register(subparsers) -> None:
    """Add the ``render-points`` sub-command."""
    p = add_command(subparsers, "render-points", __doc__, run,
                    input=("cloud", ".npz (verts, rgb) or .ply point cloud; default: the "
                                    f"tutorial's {BRIDGE} if in the data folder, else samples "
                                    "of the textured default mesh (the cow if found)"))
    p.add_argument("--image-size", type=int, default=512)
    p.add_argument("--radius", type=float, default=0.003,
                   help="point radius (NDC units unless --radius-units world; default 0.003)")
    p.add_argument("--radius-units", choices=("ndc", "world"), default="ndc")
    p.add_argument("--points-per-pixel", type=int, default=10)
    p.add_argument("--compositor", choices=("alpha", "norm"), default="alpha",
                   help="alpha (front-to-back) or norm (normalised weighted sum)")
    p.add_argument("--background", type=float, nargs=3, metavar=("R", "G", "B"), default=None,
                   help="background colour of pixels no point covers (default: black, 0)")
    p.add_argument("--camera", choices=("ortho", "persp"), default="ortho")
    p.add_argument("--dist", type=float, default=None,
                   help="camera distance (default 20 for ortho as in the tutorial, 2.7 persp)")
    p.add_argument("--elev", type=float, default=10.0, help="elevation in degrees (default 10)")
    p.add_argument("--azim", type=float, default=None,
                   help="azimuth in degrees (default 0 for a file, as in the tutorial; 180 for "
                        "the default cow, to face it)")
    p.add_argument("--n-points", type=int, default=300_000,
                   help="samples in the default cloud (default 300000)")
    p.add_argument("--seed", type=int, default=0, help="sampling seed of the default cloud")
