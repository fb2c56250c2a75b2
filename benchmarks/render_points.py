"""Point cloud rendering speed (and PyTorch3D parity) on the CPU.

The issue's setting: a 500k-point cloud sampled from the textured cow with texture colours
(``sample_points_from_meshes(..., return_textures=True)`` on the tutorial-normalised cow),
rendered at 512 x 512 with radius 0.003 (NDC) and 10 points per pixel, by
``PointsRenderer(PointsRasterizer, AlphaCompositor)`` from the tutorial's orthographic camera
(``look_at_view_transform(20, 10, 0)``, znear 0.01) and from a perspective camera
(``look_at_view_transform(2.7, 10, 180)``). Times are the best of ``--repeat`` runs of the whole
render (projection, rasterization, compositing), then of the rasterizer alone.

If the PyTorch3D reference file is found (``--reference``, default
``../shared/reference/pytorch3d/render_points.npz`` next to the repository), the script also
reports full-image parity for both cameras, both radii and the three compositor settings.

The load average (``os.getloadavg``) is recorded before and after: other jobs on the 2 cores
slow the timings down.

Run from the repository root::

    GEOFIT_DATA=/path/to/data python benchmarks/render_points.py [--quick]

Writes ``benchmarks/results/render_points.json`` and ``render_points.png``.
"""
from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
from _harness import (
    BenchmarkReport, MethodRun, chart_with_images, markdown_table, parse_args, parser,
    print_machine, print_parity, record_load, result_paths, time_call,
)

from geofit import PointCloud
from geofit.cameras import FoVOrthographicCameras, FoVPerspectiveCameras, look_at_view_transform
from geofit.data import load_textured_mesh
from geofit.ops import sample_points_from_meshes
from geofit.render.points.compositing import AlphaCompositor, NormWeightedCompositor
from geofit.render.points import PointsRasterizationSettings, PointsRasterizer, PointsRenderer

REPO = Path(__file__).resolve().parent.parent
DEFAULT_REFERENCE = REPO.parent / "shared" / "reference" / "pytorch3d" / "render_points.npz"
# Quoted in the issue (measured by the author with PyTorch3D 0.7.9 on the 2-core machine,
# not by this script): PyTorch3D's CPU point renderer on the same 500k-point setting.
PYTORCH3D_SECONDS = 174.0
TARGET_SECONDS = PYTORCH3D_SECONDS / 50


def parity(reference: Path) -> tuple[list, dict]:
    """Full-image agreement with PyTorch3D for every stored setting."""
    d = np.load(reference)
    cloud = PointCloud(d["points"], d["colours"])
    cams = {"ortho": FoVOrthographicCameras(R=d["ortho_R"], T=d["ortho_T"], znear=0.01),
            "persp": FoVPerspectiveCameras(R=d["persp_R"], T=d["persp_T"])}
    comps = {"alpha": AlphaCompositor(),
             "alpha_blue": AlphaCompositor(background_color=(0, 0, 1)),
             "normw_red": NormWeightedCompositor(background_color=(1, 0, 0))}
    rows, worst = [], {"idx_agree_min": 1.0, "image_mean_abs_max": 0.0, "image_max_abs_max": 0.0}
    for cam, camera in cams.items():
        for rk, r in (("r010", 0.01), ("r003", 0.003)):
            s = PointsRasterizationSettings(image_size=128, radius=r, points_per_pixel=10)
            f = PointsRasterizer(camera, s)(cloud)
            p = f"{cam}_{rk}_"
            agree = float(np.mean(f.idx == d[p + "idx"]))
            worst["idx_agree_min"] = min(worst["idx_agree_min"], agree)
            for name, comp in comps.items():
                img = PointsRenderer(PointsRasterizer(camera, s), comp)(cloud)
                err = np.abs(img - d[p + name])
                worst["image_mean_abs_max"] = max(worst["image_mean_abs_max"], float(err.mean()))
                worst["image_max_abs_max"] = max(worst["image_max_abs_max"], float(err.max()))
                rows.append([cam, r, name, f"{agree:.6f}", f"{err.mean():.2e}", f"{err.max():.2e}"])
    return rows, worst


def main() -> None:
    p = parser(__doc__.split("\n\n")[0], reference=DEFAULT_REFERENCE)
    p.add_argument("--points", type=int, default=500_000, help="cloud size (default 500000)")
    args = parse_args(p, points=50_000, image_size=128, repeat=2)
    n_points, size, repeat = args.points, args.image_size, args.repeat
    load_before = os.getloadavg()

    data = load_textured_mesh()
    mesh = data.mesh.normalize().mesh
    t0 = time.perf_counter()
    s = sample_points_from_meshes(mesh, n_points, seed=0, return_textures=True)
    t_sample = time.perf_counter() - t0
    cloud = PointCloud(s.points, s.textures[:, :3])
    settings = PointsRasterizationSettings(image_size=size, radius=0.003, points_per_pixel=10)

    report = BenchmarkReport(
        "render_points",
        config={"points": n_points, "image_size": size, "radius": 0.003, "points_per_pixel": 10,
                "repeat": repeat, "mesh": data.name, "sampling_seconds": t_sample,
                "quick": bool(args.quick)},
        notes=[("seconds: best of `repeat` runs, wall time, whole render (projection, "
                "rasterization, alpha compositing) unless the method says rasterizer only"),
               "the PyTorch3D time is quoted from the issue, not measured by this script"],
        reference={"pytorch3d_cpu_seconds": PYTORCH3D_SECONDS,
                   "source": "issue 5 (PyTorch3D 0.7.9 CPU PointsRenderer, same setting)",
                   "target_seconds": TARGET_SECONDS})
    R0, T0 = look_at_view_transform(20.0, 10.0, 0.0)
    R1, T1 = look_at_view_transform(2.7, 10.0, 180.0)
    views = {"ortho": FoVOrthographicCameras(R=R0, T=T0, znear=0.01),
             "persp": FoVPerspectiveCameras(R=R1, T=T1)}
    rows, images = [], {}
    for name, cam in views.items():
        renderer = PointsRenderer(PointsRasterizer(cam, settings), AlphaCompositor())
        out, t_render = time_call(lambda r=renderer: r.render(cloud), repeat=repeat)
        _, t_raster = time_call(lambda r=renderer: r.rasterizer(cloud), repeat=repeat)
        covered = float(out.fragments.mask.mean())
        hits = int(np.sum(out.fragments.idx >= 0))
        images[name] = out.images[0]
        run = report.add(MethodRun(name, f"geofit {name}", status="ok",
                                   config={"camera": type(cam).__name__}))
        run.final = {"render_seconds": t_render, "rasterize_seconds": t_raster,
                     "covered_fraction": covered, "fragment_hits": hits,
                     "speedup_vs_pytorch3d": PYTORCH3D_SECONDS / t_render}
        rows.append([name, f"{t_render:.3f}", f"{t_raster:.3f}", f"{100 * covered:.1f}%",
                     f"{PYTORCH3D_SECONDS / t_render:.0f}x"])
    load_after = record_load(report, load_before)

    header = ["camera", "render s", "rasterize s", "covered", "vs PyTorch3D 174 s"]
    report.tables["speed"] = markdown_table(header, rows)
    if args.reference.is_file():
        prow, worst = parity(args.reference)
        report.tables["parity"] = markdown_table(
            ["camera", "radius", "compositor", "idx agree", "image mean |d|", "image max |d|"],
            prow)
        report.tables["parity_worst"] = worst
    else:
        report.notes.append(f"parity skipped: {args.reference} not found")

    json_path, png_path = result_paths(args.out, "render_points", args.quick)
    report.write(json_path)
    _plot(report, images, png_path)
    print_machine(load_before, load_after)
    print(f"cloud: {n_points} points sampled from {data.name} in {t_sample:.2f} s; "
          f"{size}x{size}, radius 0.003, 10 points per pixel, best of {repeat}")
    print(report.tables["speed"], end="")
    print(f"target: < {TARGET_SECONDS:.2f} s (1/50 of PyTorch3D's quoted {PYTORCH3D_SECONDS:g} s)")
    print_parity(report, "parity with PyTorch3D (128x128, 20000 points, K = 10):")
    print(f"wrote {json_path} and {png_path}")


def _plot(report: BenchmarkReport, images: dict, path: Path) -> Path:
    labels = [m.label for m in report.methods] + ["PyTorch3D (quoted)"]
    secs = [m.final["render_seconds"] for m in report.methods] + [PYTORCH3D_SECONDS]
    cfg = report.config

    def chart(ax):
        ax.barh(labels, secs, color=["tab:blue"] * len(report.methods) + ["tab:gray"])
        ax.axvline(TARGET_SECONDS, color="crimson", ls="--", lw=0.8,
                   label=f"target {TARGET_SECONDS:g} s")
        ax.set_xscale("log")
        ax.set_xlabel("render wall time (s, log)")
        for i, s in enumerate(secs):
            ax.text(s, i, f" {s:.2f} s", va="center", fontsize=8)
        ax.legend(fontsize=8, frameon=False)
        ax.set_title(f"{cfg['points']} points, {cfg['image_size']}^2, K = 10", fontsize=9)

    return chart_with_images(path, chart, images)


if __name__ == "__main__":
    main()
