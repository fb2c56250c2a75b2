"""Peak memory of a soft Phong render and its vjp, float32 against float64 storage.

The fit_textured_mesh tutorial's setting: an ico-sphere of level 4 (2562 vertices, 5120 faces)
seen by 20 cameras at distance 2.7 around it, 128 px, blur radius 9.21e-4, 50 faces per pixel
(about 3 million fragment entries). Peak memory is Python's traced allocations
(``tracemalloc``: every numpy array), forward pass and forward + vjp, with
``SoftRasterizationSettings(dtype=...)`` float32 (the default) and float64.

Run from the repository root: ``python benchmarks/soft_render_memory.py [--quick]`` (quick: 32 px).
"""
from __future__ import annotations

import os
import time
import tracemalloc

import numpy as np

from _harness import BenchmarkReport, MethodRun, parser, print_machine, record_load, result_paths
from geofit import FoVPerspectiveCameras, ico_sphere, look_at_view_transform
from geofit.render.lighting import PointLights
from geofit.render.soft import SoftPhongRenderer, SoftRasterizationSettings


def measure(dtype, image_size: int = 128, num_views: int = 20, level: int = 4) -> dict:
    """Entries, forward and forward + vjp peaks (bytes, traced) and seconds of one pass."""
    mesh = ico_sphere(level)
    R, T = look_at_view_transform(2.7, np.zeros(num_views), np.linspace(-180, 180, num_views))
    ren = SoftPhongRenderer(FoVPerspectiveCameras(R=R, T=T),
                            lights=PointLights(location=[[0.0, 0.0, -3.0]]),
                            raster_settings=SoftRasterizationSettings.tutorial(image_size,
                                                                               dtype=dtype))
    colors = np.full((mesh.n_verts, 3), 0.5)
    tracemalloc.start()
    try:
        t = time.perf_counter()
        out = ren(mesh, colors)
        forward = tracemalloc.get_traced_memory()[1]
        out.vjp(np.ones(out.images.shape))
        total = tracemalloc.get_traced_memory()[1]
        seconds = time.perf_counter() - t
    finally:
        tracemalloc.stop()
    return {"entries": len(out.fragments), "image_dtype": str(out.images.dtype),
            "forward_peak_bytes": forward, "forward_vjp_peak_bytes": total, "seconds": seconds}


def main() -> None:
    args = parser(__doc__.splitlines()[0]).parse_args()
    size = 32 if args.quick else 128
    load_before = os.getloadavg()
    report = BenchmarkReport("soft_render_memory", config={"image_size": size, "num_views": 20,
                                                           "mesh": "ico_sphere(4)",
                                                           "faces_per_pixel": 50})
    report.notes.append("peak = tracemalloc's traced peak (numpy arrays), not the RSS; seconds "
                        "include tracemalloc's overhead and are not a speed figure")
    for dt in (np.float32, np.float64):
        r = measure(dt, size)
        run = report.add(MethodRun(np.dtype(dt).name, f"{np.dtype(dt).name} storage"))
        run.final.update(r)
        run.status = "ok"
        print(f"{np.dtype(dt).name}: {r['entries']} entries, forward peak "
              f"{r['forward_peak_bytes'] / 1e6:.0f} MB, forward + vjp peak "
              f"{r['forward_vjp_peak_bytes'] / 1e6:.0f} MB")
    load_after = record_load(report, load_before)
    path, _ = result_paths(args.out, "soft_render_memory", args.quick)
    report.write(path)
    print_machine(load_before, load_after)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
