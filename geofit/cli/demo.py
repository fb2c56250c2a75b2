"""``geofit demo``: fit a mesh and its colours to rendered views of the cow (tutorial 4).

What a newcomer should see first. On the cow that ships with geofit (Keenan Crane's Spot, public
domain; ``GEOFIT_DATA`` or the user cache take precedence), the demo

1. renders the fit_textured_mesh tutorial's views: ``--views`` cameras around the cow at
   ``--size`` pixels (RGB and soft silhouettes), plus ``--heldout`` views kept for evaluation;
2. fits a mesh and its colours to the training views with
   ``geofit.fit_mesh_to_views`` with its defaults (the visual hull of the silhouettes
   deformed to them by L-BFGS with remeshing, within a ``--time-budget`` in seconds, then
   vertex colours and a UV texture, each by one least-squares solve);
3. writes ``out/demo.png`` (held-out targets above the fit seen from the same cameras, with
   its vertex colours and with its texture, the held-out silhouette IoU and PSNRs, the
   chamfer-L2 and F-score against the true cow, and the seconds), ``out/fit.obj`` (with
   ``fit.mtl`` and the texture image ``fit.png``) and ``out/fit.ply`` (the vertex colours):
   open them in any viewer, or ``geofit.io.load_mesh``, trimesh, Open3D, MeshLab, Blender.

``render_views`` (below) is the quick Embree render of a mesh from a ring of views.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import NamedTuple

from .._atomic import atomic_write
from ._common import check_out

__all__ = ["register", "run", "render_views", "DemoImages", "DemoResult", "run_demo"]


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
    import numpy as np

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


class DemoResult(NamedTuple):
    """Result of :func:`run_demo`."""

    name: str  # which mesh: "cow" (or the procedural stand-in's name)
    metrics: dict  # held-out iou, psnr; chamfer_l2, fscore@0.01 against the true mesh
    seconds: dict  # "data", "fit", "total" wall seconds
    mesh: "object"  # the fitted Mesh with its TexturesUV (fit.obj)
    status: str
    picture: Path
    mesh_file: Path  # fit.ply: the vertex colours
    textured_file: Path  # fit.obj (+ fit.mtl, fit.png): the UV texture


def _fit(train, time_budget: float, progress: bool):
    """The one call of the fit: the plain default of tutorial 4 (geofit's best: the visual
    hull, L-BFGS with large steps at half then full resolution, remeshing; the vertices
    refined against the RGB images; least-squares colours), the whole fit bounded by
    ``time_budget`` wall-clock seconds."""
    from ..fit import fit_mesh_to_views

    return fit_mesh_to_views(train, time_budget=time_budget, progress=progress)


def _label(img, text: str, xy, size: int, fill=(0, 0, 0)) -> None:
    from PIL import ImageDraw, ImageFont

    try:
        font = ImageFont.load_default(size=size)
    except (TypeError, OSError):  # Pillow without FreeType: the small bitmap font
        font = ImageFont.load_default()
    ImageDraw.Draw(img).text(xy, text, fill=fill, font=font)


def _picture(path: Path, rows: dict, lines: list[str]) -> None:
    """Rows of images (name -> (k, H, W, 3) in [0, 1]; the targets first), one above the other,
    scaled to >= 160 px, under a caption."""
    import numpy as np

    from PIL import Image

    k, H, W, _ = next(iter(rows.values())).shape
    scale = max(1, -(-160 // H))
    names = list(rows)
    rows = [np.concatenate(list(r), axis=1) for r in rows.values()]
    grid = np.concatenate(rows, axis=0).repeat(scale, 0).repeat(scale, 1)
    gh, gw = grid.shape[:2]
    font = max(12, min(18, gw // 48))
    head = (font + 6) * len(lines) + 8
    canvas = Image.new("RGB", (max(gw, 40 * font), head + gh), (255, 255, 255))
    canvas.paste(Image.fromarray((np.clip(grid, 0, 1) * 255 + 0.5).astype(np.uint8)), (0, head))
    for i, line in enumerate(lines):
        _label(canvas, line, (6, 4 + i * (font + 6)), font)
    for r, name in enumerate(names):
        for j in range(k):
            _label(canvas, name, (j * W * scale + 4, head + r * H * scale + 2), max(10, font - 4),
                   (90, 90, 90))
    atomic_write(path, canvas.save)


def run_demo(out, *, views: int = 20, size: int = 128, heldout: int = 8,
             time_budget: float = 60.0, verbose: bool = True) -> DemoResult:
    """Render views of the cow, fit a mesh and its colours to them, write the picture, the
    textured OBJ and the vertex-coloured PLY.

    Parameters
    ----------
    out : str or os.PathLike
        Output folder (created): ``demo.png``, ``fit.obj`` (+ ``fit.mtl``, ``fit.png``) and
        ``fit.ply`` are written there.
    views : int
        Training views (>= 2).
    size : int
        Image side in pixels (even, >= 16).
    heldout : int
        Held-out views (>= 1); the picture shows up to four of them.
    time_budget : float
        Wall-clock seconds for the whole fit (default 60: the default fit of these views needs
        about 46 s on 2 cores, so the budget is a bound, not a cut).
    verbose : bool
        Print what is done.

    Returns
    -------
    DemoResult
    """
    import numpy as np

    from ..data import load_textured_mesh
    from ..datasets import tutorial_views
    from ..structures import Mesh, TexturesUV, TexturesVertex
    from ..fit.views import ViewsEvaluator, render_mesh_at_views
    from ..io import save_mesh
    from ..metrics import psnr

    for val, nm, lo in ((views, "views", 2), (size, "size", 16), (heldout, "heldout", 1)):
        if not isinstance(val, (int, np.integer)) or isinstance(val, bool) or val < lo:
            raise ValueError(f"{nm}: expected an integer >= {lo}, got {val!r}")
    if size % 2:
        raise ValueError(f"size: expected an even number of pixels (the fit starts at half "
                         f"resolution), got {size}")
    if not (isinstance(time_budget, (int, float)) and time_budget > 0):
        raise ValueError(f"time_budget: expected a number of seconds > 0, got {time_budget!r}")
    say = print if verbose else (lambda *a, **k: None)
    t0 = time.perf_counter()
    loaded = load_textured_mesh()
    mesh = loaded.mesh.normalize().mesh
    where = f"from {loaded.path}" if loaded.path else "(procedural stand-in: the cow is missing)"
    say(f"geofit demo: {loaded.name} ({mesh.n_verts} vertices, {mesh.n_faces} faces) {where}")
    train = tutorial_views(4, mesh=mesh, num_views=views, image_size=size,
                           num_held_out=heldout, name=loaded.name)
    t_data = time.perf_counter() - t0
    say(f"geofit demo: rendered {views} training and {heldout} held-out views of {size} px "
        f"in {t_data:.1f} s; fitting (a time budget of {time_budget:g} s) ...")
    t1 = time.perf_counter()
    fit = _fit(train, float(time_budget), verbose)
    t_fit = time.perf_counter() - t1
    fitted = fit.textured_mesh
    h = train.held_out
    metrics = ViewsEvaluator(h, mesh, n_samples=20000, taus=(0.01,))(fitted)
    vertex = render_mesh_at_views(fit.mesh, h, fit.colors)
    metrics["psnr_vertex"] = psnr(vertex, h.images)
    k = min(4, len(h))
    preds = fit.render(h, n_views=k)
    dest = Path(out)
    dest.mkdir(parents=True, exist_ok=True)
    mesh_file, textured_file = dest / "fit.ply", dest / "fit.obj"
    save_mesh(mesh_file, fit.mesh if fit.colors is None else Mesh(
        fit.mesh.verts, fit.mesh.faces, TexturesVertex(np.clip(fit.colors, 0.0, 1.0))))
    save_mesh(textured_file, fitted)
    total = time.perf_counter() - t0
    what = (f"{fitted.textures.maps.shape[1]} x {fitted.textures.maps.shape[0]} texel texture"
            if isinstance(fitted.textures, TexturesUV) else "vertex colours")
    lines = [f"geofit demo: a mesh fitted to {views} views ({size} px) of the {loaded.name}: "
             f"{fit.mesh.n_verts} vertices, a {what}",
             f"held-out views: silhouette IoU {metrics['iou']:.3f}, PSNR {metrics['psnr']:.1f} "
             f"dB (vertex colours {metrics['psnr_vertex']:.1f} dB); surface: chamfer-L2 "
             f"{metrics['chamfer_l2']:.2g}, F-score@0.01 {metrics['fscore@0.01']:.2f}",
             f"fit {t_fit:.1f} s (time budget {time_budget:g} s: silhouettes, the RGB "
             f"images, then colours), {total:.1f} s in all"
             + ("" if fit.status in ("time_budget", "converged", "max_iter")
                else f"; status {fit.status}")]
    picture = dest / "demo.png"
    _picture(picture, {"target (held-out view)": h.images[:k],
                       "fit: vertex colours": vertex[:k], "fit: texture": preds}, lines)
    for line in lines[1:]:
        say(f"geofit demo: {line}")
    say(f"geofit demo: wrote {picture}, {textured_file} and {mesh_file}")
    return DemoResult(loaded.name, metrics, {"data": t_data, "fit": t_fit,
                                             "total": time.perf_counter() - t0},
                      fitted, fit.status, picture, mesh_file, textured_file)


def run(args: argparse.Namespace) -> int:
    """Run the sub-command; returns the exit code (0 unless the fit failed)."""
    res = run_demo(args.out, views=args.views, size=args.size, heldout=args.heldout,
                   time_budget=args.time_budget)
    return 0 if res.status not in ("nonfinite", "failed", "diverged") else 1


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "demo", help="fit a mesh and its colours to rendered views of the cow "
                     "(out/demo.png, out/fit.obj, out/fit.ply)",
        description=__doc__.split("\n\n", 1)[1].rsplit("\n\n", 1)[0].replace("``", "")
        if __doc__ else None, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--views", type=int, default=20, help="training views (default 20)")
    p.add_argument("--size", type=int, default=128, help="image size in pixels (default 128)")
    p.add_argument("--heldout", type=int, default=8, help="held-out views (default 8)")
    p.add_argument("--time-budget", type=float, default=60.0,
                   help="wall-clock seconds for the whole fit (default 60: the budget tutorial 4's "
                        "default is measured against)")
    p.add_argument("--out", default="out", help="output folder (default ./out)")
    p.set_defaults(func=run, check=check_out)
