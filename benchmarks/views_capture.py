"""A capture written and read back fits as well as the renders themselves (issue 16's acceptance).

The volume tutorial's training renders (40 views of the cow, 128 px) are written as a NeRF/Blender
capture with :func:`geofit.io.save_views` (cameras as OpenGL camera-to-world ``transform_matrix``,
RGBA PNGs whose alpha is the silhouette) and loaded back with :func:`geofit.io.load_views`.
``fit_volume`` with its defaults then runs on both (same seed), and each fit is scored on the
same held-out views (8 azimuths between the training views, elevations 0 and 20). Writes
``results/views_capture.json``: the two held-out PSNRs and IoUs, their difference, the solver
seconds and the time to write and load the capture.

Run from the repository root: ``python benchmarks/views_capture.py [--quick]``.
"""
from __future__ import annotations

import os
import tempfile
import time

import numpy as np
from _harness import BenchmarkReport, MethodRun, parser, print_machine, record_load, result_paths

import geofit.datasets
from geofit.datasets import held_out_views
from geofit.fit.volume import VolumeFitOptions, fit_volume, volume_metrics
from geofit.io import load_views, save_views


def _fit(ds, **kw):
    """``fit_volume(dataset, options=VolumeFitOptions(**kw))`` without a progress bar."""
    return fit_volume(ds, options=VolumeFitOptions(**kw), progress=False)


def main() -> None:
    args = parser(__doc__.splitlines()[0]).parse_args()
    views, size, volume = (10, 64, 64) if args.quick else (40, 128, 128)
    load_before = os.getloadavg()
    train = geofit.datasets.tutorial_views(5, num_views=views, image_size=size, num_held_out=0)
    test = held_out_views(num_views=views, image_size=size)
    report = BenchmarkReport("views_capture", config={
        "views": views, "image_size": size, "volume_size": volume, "method": "lbfgs",
        "held_out_views": len(test), "dataset": train.name})
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        save_views(tmp, train, format="transforms")
        t_write = time.perf_counter() - t0
        t0 = time.perf_counter()
        loaded = load_views(tmp)
        t_load = time.perf_counter() - t0
    report.config.update(write_seconds=t_write, load_seconds=t_load,
                         image_max_abs_difference=float(np.abs(loaded.images
                                                               - train.images).max()))
    psnr = {}
    for key, ds, label in (("direct", train, "renders given directly"),
                           ("capture", loaded, "transforms.json capture via load_views")):
        res = _fit(ds, volume_size=volume)
        m = volume_metrics(res.volume, test.images, test.silhouettes, test.cameras)
        run = report.add(MethodRun(key, label, status=res.status, message=res.message))
        run.add(res.seconds, psnr=m.psnr, iou=m.iou)
        run.final = {"psnr": m.psnr, "iou": m.iou, "solver_seconds": res.seconds}
        psnr[key] = m.psnr
        print(f"{label}: held-out PSNR {m.psnr:.3f} dB, IoU {m.iou:.4f}, {res.seconds:.1f} s")
    report.tables["psnr_difference_db"] = psnr["capture"] - psnr["direct"]
    report.notes.append("8-bit PNGs: the capture's images differ from the renders by at most "
                        "half a grey level (image_max_abs_difference)")
    load_after = record_load(report, load_before)
    path, _ = result_paths(args.out, "views_capture", args.quick)
    report.write(path)
    print(f"difference {psnr['capture'] - psnr['direct']:+.3f} dB; wrote {path}")
    print_machine(load_before, load_after)


if __name__ == "__main__":
    main()
