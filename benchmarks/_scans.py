"""The ``scans`` part of ``benchmarks/fit_mesh.py``: fit_mesh on noisy scans with strays (issue 25).

Point clouds sampled from shapes no one tuned on (the normalised true mesh; noise is isotropic
Gaussian in units of the unit box; strays uniform in the noisy cloud's bounding box, *added*
to the points), fitted by geofit's default ``fit_mesh(points)`` and by Open3D's screened
Poisson (depth 8, normals from 30 neighbours oriented by
``orient_normals_consistent_tangent_plane``, the 2% lowest-density vertices trimmed), full
size and decimated to geofit's face count (quadric decimation). Accuracy against the **true**
surface (:mod:`geofit.metrics`, 50 000 seeded samples a side): chamfer-L2 and F@0.01; wall and
CPU seconds (the machine's load average is recorded: timings under load are not the quiet
machine's).

Run on its own to compare two versions of geofit (``PYTHONPATH`` picks which):

    PYTHONPATH=/path/to/old GEOFIT_DATA=/work/shared/data python benchmarks/_scans.py --label before
    GEOFIT_DATA=/work/shared/data python benchmarks/_scans.py --label after --table

Writes ``fit_mesh_scans_<label>.json``; ``--table`` merges every label found into
``fit_mesh_scans.md`` and ``fit_mesh_scans.png``.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from geofit._atomic import write_json
from geofit.report import machine_summary

#: (name, points, noise, stray fraction)
CONDITIONS = [("20k, noise 0.005, 1% strays", 20_000, 0.005, 0.01),
              ("50k, noise 0.002, clean", 50_000, 0.002, 0.0)]
SHAPES = ["fandisk", "suzanne", "teapot", "torus"]


def true_mesh(name: str):
    """The normalised true surface of a shape (file shapes from ``$GEOFIT_DATA/shapes``)."""
    from geofit import load_mesh
    from geofit.shapes import torus

    if name == "torus":
        m = torus(1.0, 0.35, 96, 48)
    else:
        m = load_mesh(Path(os.environ.get("GEOFIT_DATA", "/work/shared/data")) / "shapes"
                      / f"{name}.obj")
    return m.normalize().mesh


def scan(m, n: int, noise: float, strays: float, seed: int = 0) -> np.ndarray:
    """``n`` noisy surface samples plus ``strays * n`` uniform strays."""
    from geofit.ops import sample_points_from_meshes

    rng = np.random.default_rng(seed)
    P = sample_points_from_meshes(m, n, seed=seed) + rng.normal(0.0, noise, (n, 3))
    O = rng.uniform(P.min(0), P.max(0), (int(round(strays * n)), 3))
    return np.r_[P, O]


def poisson(P: np.ndarray):
    """Open3D's screened Poisson as a user would run it; (verts, faces), seconds, cpu."""
    import open3d as o3d

    t, c = time.perf_counter(), time.process_time()
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P))
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(30))
    pcd.orient_normals_consistent_tangent_plane(30)
    m, dens = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(pcd, depth=8)
    dens = np.asarray(dens)
    m.remove_vertices_by_mask(dens < np.quantile(dens, 0.02))
    return m, time.perf_counter() - t, time.process_time() - c


def o3d_to_mesh(m):
    from geofit import Mesh

    return Mesh(np.asarray(m.vertices, dtype=np.float64), np.asarray(m.triangles, dtype=np.int64))


def run(label: str, out: Path, shapes=SHAPES, with_poisson: bool = True,
        time_budget: float | None = None) -> list[dict]:
    """Every shape and condition: geofit's default (and Poisson); rows written as JSON."""
    from geofit.fit import fit_mesh
    from geofit.metrics import MeshEvaluator

    rows = []
    for sname in shapes:
        m = true_mesh(sname)
        ev = MeshEvaluator(m, n_samples=50_000, taus=0.01, seed=0)
        for cname, n, noise, strays in CONDITIONS:
            P = scan(m, n, noise, strays)
            load = os.getloadavg()[0]
            t, c = time.perf_counter(), time.process_time()
            res = fit_mesh(P, seed=0, progress=False, time_budget=time_budget)
            wall, cpu = time.perf_counter() - t, time.process_time() - c
            met = ev.evaluate(res.mesh)
            row = {"shape": sname, "condition": cname, "n_points": len(P), "label": label,
                   "method": f"geofit ({label})", "faces": res.mesh.n_faces,
                   "chamfer_l2": met.chamfer_l2, "fscore": met.fscore[0.01], "seconds": wall,
                   "cpu_seconds": cpu, "load": load, "status": res.status,
                   "time_budget": time_budget}
            rep = getattr(res, "data_report", None)
            if rep is not None:
                row["data_report"] = rep.as_dict()
            rows.append(row)
            print(json.dumps(row), flush=True)
            if not with_poisson:
                continue
            pm, pw, pc = poisson(P)
            full = o3d_to_mesh(pm)
            met = ev.evaluate(full)
            rows.append({"shape": sname, "condition": cname, "n_points": len(P),
                         "label": label, "method": "Poisson (full)", "faces": full.n_faces,
                         "chamfer_l2": met.chamfer_l2, "fscore": met.fscore[0.01],
                         "seconds": pw, "cpu_seconds": pc, "load": os.getloadavg()[0]})
            t, c = time.perf_counter(), time.process_time()
            small = o3d_to_mesh(pm.simplify_quadric_decimation(int(res.mesh.n_faces)))
            dw, dc = time.perf_counter() - t, time.process_time() - c
            met = ev.evaluate(small)
            rows.append({"shape": sname, "condition": cname, "n_points": len(P),
                         "label": label, "method": f"Poisson (same size as {label})",
                         "faces": small.n_faces, "chamfer_l2": met.chamfer_l2,
                         "fscore": met.fscore[0.01], "seconds": pw + dw,
                         "cpu_seconds": pc + dc, "load": os.getloadavg()[0]})
            print(json.dumps(rows[-2]), "\n", json.dumps(rows[-1]), flush=True)
    out.mkdir(parents=True, exist_ok=True)
    name = f"fit_mesh_scans_{label}"
    loads = [r["load"] for r in rows]
    doc = {"benchmark": name, "command": "python " + " ".join(
               [str(Path(__file__).relative_to(Path(__file__).parents[1]))] + sys.argv[1:]),
           "machine": machine_summary(), "load": [min(loads), max(loads)] if loads else None,
           "rows": rows}
    write_json(out / f"{name}.json", doc)
    return rows


def table(out: Path) -> str:
    """Merge every ``fit_mesh_scans_*.json`` into a markdown table and a chart."""
    import matplotlib.pyplot as plt

    rows = []
    for p in sorted(out.glob("fit_mesh_scans_*.json")):
        rows += json.loads(p.read_text())["rows"]
    lines = ["| shape | condition | method | faces | chamfer-L2 | F@0.01 | wall s | CPU s "
             "| load |", "|" + "---|" * 9]
    key = sorted({(r["condition"], r["shape"]) for r in rows})
    for cond, shape in key:
        for r in rows:
            if (r["condition"], r["shape"]) == (cond, shape):
                lines.append(f"| {shape} | {cond} | {r['method']} | {r['faces']} | "
                             f"{r['chamfer_l2']:.3g} | {r['fscore']:.4f} | {r['seconds']:.1f} | "
                             f"{r['cpu_seconds']:.1f} | {r['load']:.1f} |")
    md = "\n".join(lines) + "\n"
    (out / "fit_mesh_scans.md").write_text(
        "Written by `benchmarks/fit_mesh.py --parts scans` (see benchmarks/_scans.py). "
        "Accuracy against the true surface; timings under the recorded load.\n\n" + md)
    conds = sorted({r["condition"] for r in rows})
    fig, axes = plt.subplots(1, len(conds), figsize=(6 * len(conds), 4.5), squeeze=False)
    for ax, cond in zip(axes[0], conds):
        for meth in sorted({r["method"] for r in rows}):
            sel = [r for r in rows if r["condition"] == cond and r["method"] == meth]
            if sel:
                ax.scatter([r["faces"] for r in sel], [r["chamfer_l2"] for r in sel],
                           label=meth)
                for r in sel:
                    ax.annotate(r["shape"], (r["faces"], r["chamfer_l2"]), fontsize=7)
        ax.set(xscale="log", yscale="log", xlabel="faces", ylabel="chamfer-L2 (true surface)",
               title=cond)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "fit_mesh_scans.png", dpi=110)
    plt.close(fig)
    return md


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--label", default="after")
    p.add_argument("--out", default=str(Path(__file__).parent / "results"))
    p.add_argument("--shapes", default=",".join(SHAPES))
    p.add_argument("--no-poisson", action="store_true")
    p.add_argument("--time-budget", type=float, default=None,
                   help="geofit's wall-clock budget (default: the fit's own 10 s); on a loaded "
                        "machine give more so the fit gets the CPU a quiet machine gives")
    p.add_argument("--table", action="store_true", help="merge the labels' JSON into a table")
    a = p.parse_args(argv)
    out = Path(a.out)
    run(a.label, out, [s for s in a.shapes.split(",") if s], not a.no_poisson, a.time_budget)
    if a.table:
        print(table(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
