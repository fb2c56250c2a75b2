"""Issue 24 item 4 and the views fit's time: fits of one shape at a time, and the cost of one
soft-silhouette evaluation at the default's remeshing.

``fit SHAPE [--options JSON] [--tag T]``: ``fit_mesh_to_views(train, options=...)`` on a shape
of ``benchmarks/fit_views.py --shapes`` (or ``box``: geofit's procedural box, untuned),
normalised and vertex-coloured like that table, 20 views of 128 px and 16 held-out views;
appends one row (held-out IoU, F@0.01, chamfer-L2 from ``ViewsEvaluator`` with 100 000
samples, PSNR, wall and process CPU seconds, 1-minute load at start and end, vertices,
genus, parts, stage seconds) to ``--rows`` (JSON lines).

``entries SHAPE...``: the shape's visual hull remeshed as the default's last level remeshes
it (3 px edges, at least ``geofit.fit.init.shortest_edge``; ``--faces-only``: the
face cap alone, as before), and one soft-silhouette evaluation (rasterize, blend, vjp; one
thread) at 128 px: faces, soft-rasterizer entries per view (independent of the load) and CPU
seconds; appends rows.

``write``: the rows as ``results/fit_views_thin.json`` and ``.md``.

    GEOFIT_DATA=/work/shared/data python benchmarks/fit_views_thin.py fit open_cylinder
    GEOFIT_DATA=/work/shared/data python benchmarks/fit_views_thin.py entries box cow
    python benchmarks/fit_views_thin.py write
"""
from __future__ import annotations

import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROWS = HERE / "results" / "fit_views_thin_rows.jsonl"


def dataset(name: str):
    """(target mesh, dataset with 16 held-out views) of a shape of the fit_views table."""
    from fit_views import shape_factories, vertex_coloured

    from geofit.datasets import tutorial_views

    if name == "box":
        from geofit.shapes import box

        target = vertex_coloured(box())
    else:
        target = vertex_coloured(shape_factories([name])[name]())
    return target, tutorial_views(4, mesh=target, num_views=20, image_size=128,
                                  num_held_out=16, name=name)


def fit_row(name: str, options: dict, tag: str) -> dict:
    from geofit.fit.views import ViewsEvaluator, ViewsFitOptions, fit_mesh_to_views
    from geofit.ops import topology

    target, ds = dataset(name)
    load0 = os.getloadavg()[0]
    c0, t0 = time.process_time(), time.perf_counter()
    fit = fit_mesh_to_views(ds, options=ViewsFitOptions(**options), progress=False)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    m = ViewsEvaluator(ds.held_out, target, n_samples=100_000, taus=(0.01,))(fit.mesh,
                                                                             fit.colors)
    t = topology(fit.mesh)
    return dict(kind="fit", tag=tag, shape=name, options=options, wall=wall, cpu=cpu,
                load0=load0, load1=os.getloadavg()[0], nv=fit.mesh.n_verts, genus=t.genus,
                parts=t.n_components, stages=[(s["name"], round(s["seconds"], 2))
                                              for s in fit.stages],
                init=fit.history.events[0]["message"] if fit.history.events else "",
                **{k: float(v) for k, v in m.items() if np.ndim(v) == 0})


def entries_row(name: str, faces_only: bool) -> dict:
    import geofit
    from geofit.fit.init import MAX_FACES, shortest_edge, visual_hull_mesh
    from geofit.ops import remesh
    from geofit.render.soft import SoftRasterizationSettings, rasterize_soft
    from geofit.render.soft.blending import sigmoid_alpha_blend, sigmoid_alpha_blend_vjp

    geofit.set_num_threads(1)
    _, ds = dataset(name)
    hull = visual_hull_mesh(ds.silhouettes, ds.cameras, edge_px=6.0)
    px, area = hull.pixel_size, float(hull.mesh.face_areas.sum())
    s = SoftRasterizationSettings.tutorial(128, faces_per_pixel=50, dtype=np.float64)
    floor = (math.sqrt(area / (0.433 * MAX_FACES)) if faces_only else
             shortest_edge(area, px, 1, (128, 128), s.blur_radius))
    mesh = remesh(hull.mesh, max(3.0 * px, floor), n_passes=3).mesh  # as the fit remeshes
    cpu = []
    for _ in range(3):  # repeats: the median
        c0 = time.process_time()
        fr = rasterize_soft(mesh, ds.cameras, s)
        S = sigmoid_alpha_blend(fr, 1e-4)
        fr.vjp(grad_dists=sigmoid_alpha_blend_vjp(fr, S - ds.silhouettes, 1e-4, S))
        cpu.append(time.process_time() - c0)
    return dict(kind="entries", tag="faces only" if faces_only else "shortest_edge",
                shape=name, area_px2=area / px ** 2, edge_px=max(3.0 * px, floor) / px,
                faces=mesh.n_faces, entries_per_view=len(fr) / len(ds),
                cpu_per_evaluation=float(np.median(cpu)), load0=os.getloadavg()[0])


def write(rows_path: Path, out: Path) -> None:
    from _harness import machine_info

    rows = [json.loads(x) for x in rows_path.read_text().splitlines() if x.strip()]
    stem = "fit_views_thin"
    doc = {"benchmark": stem, "command": "python benchmarks/fit_views_thin.py write",
           "machine": machine_info(), "load": [r["load0"] for r in rows], "rows": rows}
    (out / f"{stem}.json").write_text(json.dumps(doc, indent=1))
    lines = ["| tag | shape | options | IoU | F@0.01 | chamfer-L2 | PSNR | vertices | genus / "
             "parts | CPU s | wall s | load start / end |", "|" + "---|" * 12]
    for r in rows:
        if r["kind"] == "fit":
            lines.append(f"| {r['tag']} | {r['shape']} | {json.dumps(r['options'])} | "
                         f"{r['iou']:.4f} | {r['fscore@0.01']:.3f} | {r['chamfer_l2']:.2e} | "
                         f"{r['psnr']:.2f} | {r['nv']} | {r['genus']} / {r['parts']} | "
                         f"{r['cpu']:.1f} | {r['wall']:.0f} | {r['load0']:.1f} / "
                         f"{r['load1']:.1f} |")
    lines += ["", "| sizing | shape | surface px^2 | edge px | faces | entries per view | "
              "CPU s per evaluation (1 thread) | load |", "|" + "---|" * 8]
    for r in rows:
        if r["kind"] == "entries":
            lines.append(f"| {r['tag']} | {r['shape']} | {r['area_px2']:.0f} | "
                         f"{r['edge_px']:.2f} | {r['faces']} | {r['entries_per_view']:.0f} | "
                         f"{r['cpu_per_evaluation']:.2f} | {r['load0']:.1f} |")
    (out / f"{stem}_rows.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def main(argv=None) -> int:
    sys.path.insert(0, str(HERE))
    from _harness import append_row, rows_parser

    ap = rows_parser(__doc__.split("\n")[0], ("fit", "entries", "write"), ROWS)
    ap.add_argument("--faces-only", action="store_true")
    a = ap.parse_args(argv)
    if a.mode == "write":
        write(a.rows, HERE / "results")
        return 0
    for name in a.shapes:  # shapes
        row = (fit_row(name, json.loads(a.options), a.tag) if a.mode == "fit" else
               entries_row(name, a.faces_only))
        print(json.dumps(row), flush=True)
        append_row(a.rows, row)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
