"""``geofit render [MESH]``: render a textured mesh by ray casting (PyTorch3D's tutorial 2).

With a mesh file (``.obj`` with its MTL and texture, or ``.ply``/``.stl``/``.off``) that mesh is
rendered; without one, geofit's default textured mesh (the cow when the tutorial data is found,
else the procedural stand-in). The camera looks at the origin from ``--dist`` at ``--elev`` /
``--azim`` (the tutorial's view of the cow by default); ``--views N`` renders the tutorial's batch
of N views instead (elevations 0..180, azimuths -180..180) as one grid. A point light sits at
``--light``; Phong shading with PyTorch3D's defaults.

Writes ``render.png`` (the image, or a grid of the views), ``render_depth.png`` (near = bright),
``render_normals.png`` and, with ``--open3d``, ``render_open3d.png`` (geofit and Open3D side by
side) into ``--out``.
"""
from __future__ import annotations

import argparse
import time

from .._atomic import atomic_write
from ._common import add_command, out_dir, wrote

__all__ = ["register", "run"]


def _to_uint8(img: np.ndarray) -> np.ndarray:
    import numpy as np

    return (np.clip(img, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def _depth_to_unit(depth: np.ndarray) -> np.ndarray:
    """View depth (N, H, W), inf on the background -> brightness in [0, 1] (near = bright)."""
    import numpy as np

    out = np.zeros(depth.shape)
    hit = np.isfinite(depth)
    if hit.any():
        lo, hi = depth[hit].min(), depth[hit].max()
        out[hit] = 0.2 + 0.8 * ((hi - depth[hit]) / (hi - lo) if hi > lo else 1.0)
    return out


def run(args: argparse.Namespace) -> int:
    """Run the sub-command; returns the exit code."""
    import numpy as np
    from PIL import Image

    from ..cameras import FoVPerspectiveCameras, look_at_view_transform
    from ..render import (
        HardPhongShader,
        MeshRasterizer,
        MeshRendererWithFragments,
        PointLights,
        RasterizationSettings,
        SoftPhongShader,
        make_grid,
    )

    t0 = time.perf_counter()
    if args.mesh is None:
        from ..data import load_textured_mesh

        data = load_textured_mesh()
        mesh, source = data.mesh, data.name
    else:
        from ..io import load_mesh

        mesh, source = load_mesh(args.mesh), str(args.mesh)
    if mesh.n_faces == 0:
        raise ValueError(f"{source}: the mesh has no faces")
    if args.normalize:
        mesh = mesh.normalize().mesh
    t_load = time.perf_counter() - t0

    if args.views < 1 or args.image_size < 1 or args.supersample < 1:
        raise ValueError("--views, --image-size and --supersample must be >= 1")
    if args.views == 1:
        R, T = look_at_view_transform(args.dist, args.elev, args.azim)
    else:
        R, T = look_at_view_transform(args.dist, np.linspace(0.0, 180.0, args.views),
                                      np.linspace(-180.0, 180.0, args.views))
    cameras = FoVPerspectiveCameras(R=R, T=T)
    settings = RasterizationSettings(image_size=args.image_size, supersample=args.supersample)
    shader_cls = HardPhongShader if args.hard else SoftPhongShader
    shader = shader_cls(lights=PointLights(location=[args.light]), shadows=args.shadows)
    renderer = MeshRendererWithFragments(MeshRasterizer(cameras, settings), shader)
    batch = mesh.extend(args.views) if args.views > 1 else mesh
    t1 = time.perf_counter()
    images, fragments = renderer(batch)
    t_render = time.perf_counter() - t1

    dest = out_dir(args)
    paths = [dest / "render.png", dest / "render_depth.png", dest / "render_normals.png"]
    atomic_write(paths[0], Image.fromarray(_to_uint8(make_grid(images))).save)
    depth = _depth_to_unit(fragments.depth_image(np.inf))[..., None]
    atomic_write(paths[1], Image.fromarray(
        _to_uint8(make_grid(depth, rgb=False, background=0.0)[..., 0])).save)
    atomic_write(paths[2], Image.fromarray(
        _to_uint8(make_grid(fragments.normal_image(), background=0.0))).save)
    rays = fragments.n_views * fragments.image_size[0] * fragments.image_size[1]
    print(f"mesh: {source} ({mesh.n_verts} vertices, {mesh.n_faces} faces, loaded in "
          f"{t_load:.2f} s)")
    print(f"{args.views} view(s) at {args.image_size}x{args.image_size}"
          f"{f' x{args.supersample} supersampled' if args.supersample > 1 else ''}, dist "
          f"{args.dist:g}, light at {tuple(args.light)}"
          f"{', shadows' if args.shadows else ''}")
    print(f"rendered in {t_render:.3f} s ({rays / max(t_render, 1e-9) / 1e6:.1f} M pixels/s); "
          f"{100.0 * fragments.n_hits / rays:.1f}% of the pixels see the mesh")
    if args.open3d:
        from ..render.open3d import render_open3d

        o3d = render_open3d(batch, cameras, args.image_size)
        side = np.concatenate([images[..., :3], o3d.images], axis=2)
        paths.append(dest / "render_open3d.png")
        atomic_write(paths[-1], Image.fromarray(_to_uint8(make_grid(side, pad=4))).save)
        mask = fragments.mask if args.supersample == 1 else None
        if mask is not None:
            iou = (mask & o3d.mask).sum() / max((mask | o3d.mask).sum(), 1)
            print(f"Open3D: silhouette IoU {iou:.4f} (left geofit, right Open3D)")
    return wrote(*paths)


def register(subparsers) -> None:
    """Add the ``render`` sub-command."""
    p = add_command(subparsers, "render", __doc__, run,
                    input=("mesh", ".obj (with MTL and texture), .ply, .stl, .off or .glb; "
                                   "default: the textured default mesh (the cow if found)"))
    p.add_argument("--image-size", type=int, default=512, help="pixels per side (default 512)")
    p.add_argument("--views", type=int, default=1,
                   help="number of views; >1 renders the tutorial's batch (default 1)")
    p.add_argument("--dist", type=float, default=2.7, help="camera distance (default 2.7)")
    p.add_argument("--elev", type=float, default=0.0, help="elevation in degrees (default 0)")
    p.add_argument("--azim", type=float, default=180.0,
                   help="azimuth in degrees (default 180: the cow's front)")
    p.add_argument("--light", type=float, nargs=3, metavar=("X", "Y", "Z"),
                   default=[0.0, 0.0, -3.0], help="point light position (default 0 0 -3)")
    p.add_argument("--supersample", type=int, default=1,
                   help="antialiasing: rays per pixel side (default 1, PyTorch3D's image)")
    p.add_argument("--shadows", action="store_true", help="hard shadows by shadow rays")
    p.add_argument("--hard", action="store_true",
                   help="HardPhongShader (alpha = coverage) instead of SoftPhongShader")
    p.add_argument("--normalize", action="store_true",
                   help="centre the mesh and scale its largest coordinate to 1 first")
    p.add_argument("--open3d", action="store_true",
                   help="also render with Open3D and write the two side by side")
