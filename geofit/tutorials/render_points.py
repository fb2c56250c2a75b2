"""Step 3, render_colored_points: :class:`geofit.render.PointsRenderer` with both
compositors, and the stability cases."""
from __future__ import annotations

import time

import numpy as np

from ..data import find
from ..io import load_pointcloud
from ..ops import sample_points_from_meshes
from ..render import AlphaCompositor
from ..render.points import PointsRasterizationSettings, PointsRasterizer, PointsRenderer
from ..structures import PointCloud
from ..viz import image_panel, plot_accuracy_vs_time, save_png
from .shared import (
    GEOFIT_COLUMN,
    P3D_COLUMN,
    StepResult,
    begin_textured_step,
    look_at_cameras,
    mask_iou,
    method_record,
    method_series,
    pick_size,
    progress_bar,
    run_cases,
)

__all__ = ["step_render_points"]


# --------------------------------------------------------------------------------------------
# 3. render coloured point clouds
# --------------------------------------------------------------------------------------------


#: The point-cloud tutorial's own cloud, relative to the data folder (:func:`geofit.data.find`).
BRIDGE_FILE = "PittsburghBridge/pointcloud.npz"


def _points_stability(cloud, cameras, size: str) -> list[dict]:
    s = pick_size(size, 32, 128, 256)

    def render(c, cams=cameras, radius=0.003, K=10):
        out = PointsRenderer(PointsRasterizer(cams, PointsRasterizationSettings(
            image_size=s, radius=radius, points_per_pixel=K)), AlphaCompositor()).render(c)
        return (f"ok: {100 * float(out.fragments.mask.mean()):.1f}% covered, "
                f"finite={bool(np.isfinite(out.images).all())}")

    P, C = cloud.points, cloud.features
    nan_p = P.copy()
    nan_p[0] = np.nan
    cases = {
        "NaN point": lambda: render(PointCloud(nan_p, C)),
        "empty cloud": lambda: render(PointCloud(np.zeros((0, 3)), np.zeros((0, 3)))),
        "all points behind the camera": lambda: render(
            PointCloud(P + np.array([0.0, 0.0, 50.0]), C), look_at_cameras(2.7, 0.0, 0.0)),
        "all points at one place": lambda: render(PointCloud(np.zeros_like(P), C)),
        "radius 0": lambda: render(cloud, radius=0.0),
        "radius 0.5 (huge splats)": lambda: render(cloud, radius=0.5, K=2),
        "points_per_pixel 0": lambda: render(cloud, K=0),
    }
    return run_cases(cases)


def step_render_points(out, size: str = "default", *, progress: bool = True, seed: int = 0
                       ) -> StepResult:
    """Render a coloured point cloud as the tutorial does; point count and radius against accuracy.

    The cloud is sampled from the textured mesh with its texture colours, so the mesh's own
    (unlit) render from the same camera is the target the point renders should reproduce.

    Sizes: Cloud of 5 000 / 100 000 / 500 000 points, images of 64 / 256 / 512 pixels. Progress:
    a progress bar over the renders; seed: sampling seed. Writes into ``out/render_points``; the
    signature and the StepResult are :func:`run_step`'s.
    """
    from ..render import (
        AlphaCompositor, AmbientLights, BlendParams, HardPhongShader, MeshRasterizer,
        MeshRenderer, NormWeightedCompositor, PointsRasterizationSettings, PointsRasterizer,
        PointsRenderer, RasterizationSettings,
    )
    res, d, t0, data, mesh = begin_textured_step(out, "render_points", size)
    N = pick_size(size, 5_000, 100_000, 500_000)
    S = pick_size(size, 64, 256, 512)
    res.config = {"cloud": f"{N} samples of the {data.name} with texture colours",
                  "image size": S, "radius (NDC)": 0.003, "points per pixel": 10,
                  "camera": "FoVOrthographicCameras(znear=0.01), look_at(20, 10, 180)"}
    res.description = (
        "The tutorial's three renders of a coloured cloud (alpha compositing, the same on a "
        "blue background, normalised weighted sum on red), from its orthographic camera. The "
        "cloud samples the textured mesh, so the mesh's unlit render from the same camera is "
        "the target: the chart measures how the point count and radius trade render time "
        "against coverage (silhouette IoU) and colour error.")
    cams = look_at_cameras(20.0, 10.0, 180.0, ortho=True, znear=0.01)
    bar = progress_bar(progress, 4, "render_points")
    sample = sample_points_from_meshes(mesh, N, seed=seed, return_textures=True)
    cloud = PointCloud(sample.points, sample.textures[:, :3])
    settings = PointsRasterizationSettings(image_size=S, radius=0.003, points_per_pixel=10)
    rast = PointsRasterizer(cams, settings)
    timings = {}
    imgs = {}
    for key, comp in (("alpha", AlphaCompositor()),
                      ("alpha, blue background", AlphaCompositor(background_color=(0, 0, 1))),
                      ("normalised weighted, red background",
                       NormWeightedCompositor(background_color=(1, 0, 0)))):
        r = PointsRenderer(rast, comp)
        t = time.perf_counter()
        imgs[key] = r(cloud)[0, ..., :3]
        timings[key] = time.perf_counter() - t
    bar.update(1)
    target = MeshRenderer(
        MeshRasterizer(cams, RasterizationSettings(image_size=S)),
        HardPhongShader(lights=AmbientLights(), blend_params=BlendParams(
            background_color=(0.0, 0.0, 0.0))))(mesh)[0]
    target_rgb, target_mask = target[..., :3].astype(np.float64), target[..., 3] > 0
    bar.update(1)
    for i, (k, v) in enumerate(imgs.items()):
        res.images[k] = save_png(v, d / f"points_{i}.png")
    res.targets["mesh, unlit (target)"] = save_png(target_rgb, d / "target_mesh.png")
    rows = [[target_rgb] + list(imgs.values())]
    row_labels = [f"{data.name}\n{N:,} points"]
    bridge_path = find(BRIDGE_FILE)
    if bridge_path is not None:  # the tutorial's own cloud and camera, when it is available
        bridge = load_pointcloud(bridge_path)
        bcams = look_at_cameras(20.0, 10.0, 0.0, ortho=True, znear=0.01)
        brast = PointsRasterizer(bcams, settings)
        row = [None]
        for i, comp in enumerate((AlphaCompositor(), AlphaCompositor(background_color=(0, 0, 1)),
                                  NormWeightedCompositor(background_color=(1, 0, 0)))):
            t = time.perf_counter()
            img_b = PointsRenderer(brast, comp)(bridge)[0, ..., :3]
            timings[f"PittsburghBridge ({len(bridge):,} points), render {i + 1}"] = \
                time.perf_counter() - t
            res.images[f"PittsburghBridge render {i + 1}"] = save_png(img_b,
                                                                      d / f"bridge_{i}.png")
            row.append(img_b)
        rows.append(row)
        row_labels.append(f"PittsburghBridge\n{len(bridge):,} points")
        res.notes.append(f"The tutorial's PittsburghBridge cloud was found ({bridge_path}) and "
                         "rendered with the tutorial's camera (second row).")
    res.comparison = image_panel(rows, d / "comparison.png",
                                 col_labels=["target: the mesh\n(unlit texture)", "alpha",
                                             "alpha\nblue background",
                                             "norm. weighted\nred background"],
                                 row_labels=row_labels)
    res.comparison_caption = (f"The mesh the cloud was sampled from, and the tutorial's three "
                              f"point renders (radius 0.003, {S} px).")

    counts = pick_size(size, (1_000, 5_000), (12_500, 25_000, 50_000, 100_000, 200_000),
                   (50_000, 100_000, 200_000, 500_000, 1_000_000))
    radii = (0.003, 0.006) if size != "tiny" else (0.01, 0.02)
    big = sample_points_from_meshes(mesh, counts[-1], seed=seed + 1, return_textures=True)
    methods = []
    for radius in radii:  # radii
        secs, iou, err = [], [], []
        r = PointsRenderer(PointsRasterizer(cams, PointsRasterizationSettings(
            image_size=S, radius=radius, points_per_pixel=10)), AlphaCompositor())
        for n in counts:  # cloud sizes
            c = PointCloud(big.points[:n], big.textures[:n, :3])
            t = time.perf_counter()
            o = r.render(c)
            secs.append(time.perf_counter() - t)
            iou.append(mask_iou(o.fragments.mask[0], target_mask))
            err.append(float(np.abs(o.images[0, ..., :3] - target_rgb).mean()))
        methods.append(method_record(
            f"r{radius:g}", f"radius {radius:g}, {counts[0]:,}..{counts[-1]:,} points",
            seconds=secs, curve={"iou": iou, "mean_abs_error": err},
            final={"points": list(counts)}, status="ok"))
        res.metrics += [{"points": n, "radius": radius, "seconds": round(secs[i], 4),
                         "silhouette IoU vs mesh": iou[i], "mean |RGB - mesh|": err[i]}
                        for i, n in enumerate(counts)]
    bar.update(1)
    res.methods = methods
    res.metrics += [{"points": N, "radius": 0.003, "render": k, "seconds": round(v, 4)}
                    for k, v in timings.items()]
    res.charts["Speed and accuracy: point count and radius against coverage and colour "
               "error"] = plot_accuracy_vs_time(
        method_series(methods),
        [{"metric": "iou", "label": "silhouette IoU against the mesh"},
         {"metric": "mean_abs_error", "label": "mean |RGB - mesh render| (log)", "logy": True}],
        d / "speed_accuracy.png", xlabel="render wall time (s, log)",
        title=f"render_points: {data.name} samples, {S} px ({size} size)")
    res.param_counts = [{"model": "cloud: points", "count": N},
                        {"model": "cloud: colour values", "count": 3 * N}]
    res.stability = _points_stability(cloud, cams, size)
    bar.update(1)
    bar.close()
    res.headline = {P3D_COLUMN: f"{N:,} points at {S} px, K=10: {timings['alpha']:.3f} s",
                    GEOFIT_COLUMN: f"{counts[-1]:,} points, radius {radii[-1]:g}: IoU "
                         f"{methods[-1]['curve']['iou'][-1]:.3f} vs the mesh in "
                         f"{methods[-1]['curve']['seconds'][-1]:.3f} s"}
    res.notes.append(f"The measured cloud is sampled from the {data.name} with its texture "
                     "colours, so the mesh's own render is a target to compare with"
                     + ("." if bridge_path is not None else
                        f"; the tutorial's {BRIDGE_FILE} was not found in the data folder "
                        "(GEOFIT_DATA)."))
    res.seconds = time.perf_counter() - t0
    return res
