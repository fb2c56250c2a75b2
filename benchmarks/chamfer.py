"""Exact nearest neighbours for chamfer: Open3D's search structures against scipy's cKDTree.

A chamfer distance needs, in both directions, the exact nearest point of one cloud for every
point of the other. This benchmark times that search (tree builds included, both directions)
for three scenes and three sizes (10k, 100k and 1M points a side):

* ``overlap``: two independent samplings of the normalised dolphin (the tutorial's target) --
  the end of a fit, every query has a neighbour one sample spacing away;
* ``tutorial``: samples of ``ico_sphere(4)`` against the normalised dolphin -- the start of the
  mesh-fitting tutorial: the dolphin sits inside the unit sphere, so a dolphin point near the
  centre is almost equally far from every sphere point;
* ``apart``: the same sphere shifted by (3, 0, 0), clear of the dolphin -- two disjoint clouds.

Methods: ``scipy.spatial.cKDTree`` (geofit's settings ``balanced_tree=False,
compact_nodes=False``, with ``workers=-1`` and ``workers=1``; and scipy's default balanced,
compact tree), both again with the tree points and the queries sorted along a Z-order curve
(:func:`geofit.loss.chamfer.morton_order`, sorting timed), Open3D's
``core.nns.NearestNeighborSearch`` (``knn_index``/``knn_search`` and
``hybrid_index``/``hybrid_search`` with a radius of 3 sample spacings, the misses then searched
with knn), ``open3d.geometry.KDTreeFlann`` (one Python call per query point: up to 100k only),
and :func:`geofit.chamfer_distance` end to end with each backend. Every method's neighbours are
checked against scipy's: the distances must be equal (exact search; ties may pick another index).

Up to 10k points a side each figure is the median of ``--repeat`` runs (3); from 100k one run
(the far scenes take minutes on a shared machine), and at 1M
only the methods that were not already slower at 100k than the plain search of their library
(scipy's balanced tree, the hybrid search, KDTreeFlann and the per-backend chamfer runs are
skipped there; the table says so). The times of the two directions are also stored apart:
far scenes are hard in one direction (a query almost equally far from many points).

The acceptance figure is the default's (``chamfer_auto``) time on far clouds over its time on
overlapping ones at 1M points a side: ``tables.default_ratios`` in the JSON (apart/overlap and
tutorial/overlap per size, with the load), also printed on the chart.

Run from the repository root::

    GEOFIT_DATA=/path/to/data python benchmarks/chamfer.py [--quick]

Writes ``benchmarks/results/chamfer.json`` and ``chamfer.png``. To re-measure only the default
(``geofit.chamfer_distance``, ``backend="auto"``) on the three scenes, median of ``--repeat``
runs at every size, and update those rows, the ratios and the chart in the existing JSON (the
other rows are kept, and the JSON records both commands)::

    GEOFIT_DATA=/path/to/data python benchmarks/chamfer.py --default-only [--sizes 1000000]
"""
from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np
from _harness import BenchmarkReport, machine_info, markdown_table, parser, record_load

import geofit
from geofit.data import load_target_mesh
from geofit.loss.chamfer import morton_order
from geofit.ops import sample_points_from_meshes


def scenes(n: int) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The three (x, y) pairs of n points a side."""
    dolphin = load_target_mesh().mesh.normalize().mesh
    sphere = geofit.ico_sphere(4)
    y = sample_points_from_meshes(dolphin, n, seed=0)
    return {
        "overlap": (sample_points_from_meshes(dolphin, n, seed=1), y),
        "tutorial": (sample_points_from_meshes(sphere, n, seed=1), y),
        "apart": (sample_points_from_meshes(sphere, n, seed=1) + [3.0, 0.0, 0.0], y),
    }


# ------------------------------------------------------------------------- one direction each
def scipy_nn(workers: int, balanced: bool):
    from scipy.spatial import cKDTree

    def nn(tree_points, q):
        tree = cKDTree(tree_points, balanced_tree=balanced, compact_nodes=balanced)
        return tree.query(q, k=1, workers=workers)[1]

    return nn


def open3d_knn(tree_points, q):
    import open3d as o3d

    nns = o3d.core.nns.NearestNeighborSearch(o3d.core.Tensor(tree_points))
    nns.knn_index()
    idx, _ = nns.knn_search(o3d.core.Tensor(q), 1)
    return idx.numpy()[:, 0]


def z_order(nn):
    """``nn`` on a tree over Z-ordered points queried in Z-order (sorting timed too)."""
    def run(tree_points, q):
        ot, oq = morton_order(tree_points), morton_order(q)
        idx = nn(np.ascontiguousarray(tree_points[ot]), np.ascontiguousarray(q[oq]))
        out = np.empty(len(q), np.int64)
        out[oq] = ot[idx]
        return out

    return run


def open3d_hybrid(tree_points, q):
    """Fixed-radius search (3 sample spacings), then knn for the queries with no hit."""
    import open3d as o3d

    lo, hi = tree_points.min(0), tree_points.max(0)
    spacing = float(np.sqrt(np.prod(np.sort(hi - lo)[1:]) / len(tree_points)))
    radius = 3.0 * spacing
    nns = o3d.core.nns.NearestNeighborSearch(o3d.core.Tensor(tree_points))
    nns.hybrid_index(radius)
    idx, _, _ = nns.hybrid_search(o3d.core.Tensor(q), radius, 1)
    idx = idx.numpy()[:, 0].astype(np.int64)
    miss = idx < 0
    if miss.any():
        nns.knn_index()
        idx[miss] = nns.knn_search(o3d.core.Tensor(q[miss]), 1)[0].numpy()[:, 0]
    return idx


def open3d_flann(tree_points, q):
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(tree_points))
    tree = o3d.geometry.KDTreeFlann(pc)
    return np.array([tree.search_knn_vector_3d(p, 1)[1][0] for p in q])  # one call per query


def geofit_chamfer(backend: str):
    def run(x, y):
        return geofit.chamfer_distance(x, y, backend=backend).loss

    return run


NN_METHODS = {
    "scipy": ("scipy cKDTree, workers=-1 (geofit's settings)", scipy_nn(-1, False)),
    "scipy_1": ("scipy cKDTree, workers=1", scipy_nn(1, False)),
    "scipy_balanced": ("scipy cKDTree, balanced + compact (scipy default)", scipy_nn(-1, True)),
    "open3d_knn": ("Open3D core.nns knn", open3d_knn),
    "scipy_morton": ("scipy cKDTree, workers=-1, points and queries in Z-order",
                     z_order(scipy_nn(-1, False))),
    "open3d_morton": ("Open3D core.nns knn, points and queries in Z-order", z_order(open3d_knn)),
    "open3d_hybrid": ("Open3D core.nns hybrid (3 spacings) + knn for misses", open3d_hybrid),
    "open3d_flann": ("Open3D KDTreeFlann (a Python call per point)", open3d_flann),
}
CHAMFER_METHODS = {
    "chamfer_scipy": ("geofit.chamfer_distance(backend='scipy')", geofit_chamfer("scipy")),
    "chamfer_open3d": ("geofit.chamfer_distance(backend='open3d')", geofit_chamfer("open3d")),
    "chamfer_auto": ("geofit.chamfer_distance(backend='auto')", geofit_chamfer("auto")),
}
FLANN_MAX = 100_000
LARGE = 1_000_000  # from this size only the methods below
ONE_RUN = 100_000  # from this size one run per figure
LARGE_METHODS = ("scipy", "scipy_1", "open3d_knn", "scipy_morton", "open3d_morton",
                 "chamfer_auto")


def _sqdist(a, b, idx):
    d = a - b[idx]
    return np.einsum("ij,ij->i", d, d)


def main() -> None:
    p = parser(__doc__.splitlines()[0])
    p.add_argument("--sizes", type=int, nargs="+",
                   help="points a side (default 10000 100000 1000000; 1000000 with "
                        "--default-only)")
    p.add_argument("--repeat", type=int, default=3, help="runs per figure below 100k (median)")
    p.add_argument("--replot", type=Path, help="only redraw the PNG of this JSON")
    p.add_argument("--timeout", type=float, default=150.0,
                   help="seconds after which one measurement is stopped and reported as such")
    p.add_argument("--default-only", action="store_true",
                   help="re-measure only geofit.chamfer_distance(backend='auto') (median of "
                        "--repeat runs at every size; --sizes defaults to 1000000 here) and "
                        "update its rows, the ratios and the chart in the existing chamfer.json")
    args = p.parse_args()
    if args.replot:
        replot(args.replot)
        return
    if args.default_only:
        rerun_default(args)
        return
    sizes = [2_000, 20_000] if args.quick else args.sizes or [10_000, 100_000, 1_000_000]
    load_before = os.getloadavg()
    import open3d as o3d  # imported before the timings (its import takes seconds)

    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    report = BenchmarkReport("chamfer", config={"sizes": sizes, "quick": bool(args.quick),
                                                "repeat": args.repeat, "large": LARGE,
                                                "timeout": args.timeout,
                                                "large_methods": list(LARGE_METHODS)})
    report.notes += [
        "seconds: wall time, both directions (x -> y and y -> x), tree builds included; median "
        "of `repeat` runs below 100k points, one run from 100k; the machine's other jobs add "
        "noise, see loadavg_before/after and the per-row load; cpu_seconds: the CPU time of "
        "the measuring process in that run (all its threads), less sensitive to the load",
        "check: every method's squared distances equal scipy's exactly (an exact search)",
        "scenes: overlap = two samplings of the normalised dolphin; tutorial = ico_sphere(4) "
        "samples against the dolphin inside it (the fit's start); apart = the sphere shifted "
        "by (3, 0, 0)",
    ]
    rows = []
    stem = "chamfer_quick" if args.quick else "chamfer"
    for n in sizes:
        repeat = 1 if n >= ONE_RUN else max(args.repeat, 1)
        for scene, (x, y) in scenes(n).items():
            ref = None
            for key, (label, fn) in {**NN_METHODS, **CHAMFER_METHODS}.items():
                why = None
                if key == "open3d_flann" and n > FLANN_MAX:
                    why = f"a Python call per point: run up to {FLANN_MAX} points"
                elif n >= LARGE and key not in LARGE_METHODS:
                    why = "slower than its library's plain search at 100k: not run at 1M"
                row = {"method": key, "label": label, "scene": scene, "n": n, "seconds": None}
                if why:
                    rows.append({**row, "status": f"skipped: {why}"})
                    continue
                out = _measure(key, fn, x, y, repeat, args.timeout)
                if out is None:  # did not finish: a lower bound, not a time
                    row.update(status=f"timeout: not finished after {args.timeout:g} s",
                               seconds_at_least=args.timeout, load_1min=os.getloadavg()[0])
                    rows.append(row)
                    print(f"{n:>8} {scene:9s} {key:15s} > {args.timeout:g} s (timeout)",
                          flush=True)
                    _write(report, rows, sizes, args.out, stem, load_before, partial=True)
                    continue
                times, dirs, result, cpus = out
                k = int(np.argsort(times)[len(times) // 2])  # the median run
                status = "ok"
                if key in NN_METHODS:
                    if ref is None:
                        ref = result
                    elif not (np.array_equal(result[0], ref[0])
                              and np.array_equal(result[1], ref[1])):
                        status = "MISMATCH"
                elif ref is not None and not np.isclose(result, ref[0].mean() + ref[1].mean(),
                                                        rtol=1e-12):
                    status = "MISMATCH"
                row.update(seconds=times[k], runs=times, status=status, cpu_seconds=cpus[k],
                           load_1min=os.getloadavg()[0])
                if key == "chamfer_auto":
                    row["ref_loss"] = _ref_loss(ref)
                if key in NN_METHODS:
                    row["seconds_x_to_y"], row["seconds_y_to_x"] = dirs[k]
                rows.append(row)
                extra = (f" (x->y {dirs[k][0]:.3f}, y->x {dirs[k][1]:.3f})"
                         if key in NN_METHODS else "")
                print(f"{n:>8} {scene:9s} {key:15s} {times[k]:9.3f} s{extra}  {status}  "
                      f"load {row['load_1min']:.1f}", flush=True)
                _write(report, rows, sizes, args.out, stem, load_before, partial=True)
    _write(report, rows, sizes, args.out, stem, load_before, partial=False)
    print(report.tables["markdown"])
    plot(rows, sizes, args.out / f"{stem}.png", machine_info())
    print(json.dumps(report.tables["default_ratios"], indent=1))
    print("wrote", args.out / f"{stem}.json")


def _child(key, fn, x, y, repeat, conn) -> None:
    """Run one measurement (in a forked process) and send (times, directions, result, CPU
    seconds of the process: its own work, whatever the machine's other jobs)."""
    times, dirs, cpus = [], [], []
    for _ in range(repeat):  # repetitions of one measurement
        c0 = time.process_time()
        t0 = time.perf_counter()
        if key in CHAMFER_METHODS:
            out = fn(x, y)
            t1 = t0
        else:  # x -> y queries a tree over y, and back
            out0 = fn(y, x)
            t1 = time.perf_counter()
            out = (out0, fn(x, y))
        t2 = time.perf_counter()
        cpus.append(time.process_time() - c0)
        times.append(t2 - t0)
        dirs.append((t1 - t0, t2 - t1))
    result = out if key in CHAMFER_METHODS else (_sqdist(x, y, out[0]), _sqdist(y, x, out[1]))
    conn.send((times, dirs, result, cpus))
    conn.close()


def _measure(key, fn, x, y, repeat, timeout):
    """(times, per-direction times, result, CPU times) of one measurement, or None after
    ``timeout`` s."""
    import multiprocessing as mp

    ctx = mp.get_context("fork")  # the child shares x and y; Open3D was imported before
    recv, send = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_child, args=(key, fn, x, y, repeat, send))
    proc.start()
    send.close()
    got = recv.recv() if recv.poll(timeout) else None
    if got is None:
        proc.kill()
    proc.join()
    return got


def _write(report, rows, sizes, out_dir, stem, load_before, *, partial: bool) -> None:
    """Tables and the JSON from the rows so far (rewritten after every row)."""
    report.config["partial"] = partial
    record_load(report, load_before)
    report.tables["runs"] = rows
    by = {(r["method"], r["scene"], r["n"]): r["seconds"] for r in rows}
    status = {(r["method"], r["scene"], r["n"]): r["status"] for r in rows}
    ratio = {}
    for key in {**NN_METHODS, **CHAMFER_METHODS}:
        for n in sizes:
            o = by.get((key, "overlap", n))
            for scene in ("tutorial", "apart"):
                f = by.get((key, scene, n))
                if o and f:
                    ratio[f"{key} {scene}/overlap n={n}"] = f / o
    report.tables["far_over_overlap"] = ratio
    report.tables["default_ratios"] = default_ratios(rows)
    header = ["method"] + [f"{s} {n // 1000}k" for n in sizes
                           for s in ("overlap", "tutorial", "apart")]
    md = []
    for key, (label, _) in {**NN_METHODS, **CHAMFER_METHODS}.items():
        cells = [label]
        for n in sizes:
            for s in ("overlap", "tutorial", "apart"):
                v, st = by.get((key, s, n)), status.get((key, s, n), "")
                cells.append(f"{v:.3g}" if v is not None else
                             f"> {st.split('after ')[1]}" if st.startswith("timeout") else
                             "skipped" if st.startswith("skipped") else "")
        md.append(cells)
    report.tables["markdown"] = markdown_table(header, md)
    report.write(out_dir / f"{stem}.json")


def default_ratios(rows) -> dict:
    """The default's far/overlap ratios per size: the acceptance figure (apart <= 2x)."""
    out = {}
    auto = {(r["scene"], r["n"]): r for r in rows if r["method"] == "chamfer_auto"}
    for n in sorted({n for _, n in auto}):
        o = auto.get(("overlap", n))
        if not o or not o.get("seconds"):
            continue
        entry = {"overlap_seconds": o["seconds"], "load_1min": {"overlap": o.get("load_1min")}}
        for scene in ("apart", "tutorial"):
            r = auto.get((scene, n))
            if not r:
                continue
            entry["load_1min"][scene] = r.get("load_1min")
            if r.get("seconds"):
                entry[f"{scene}_seconds"] = r["seconds"]
                entry[f"{scene}/overlap"] = r["seconds"] / o["seconds"]
                if r.get("cpu_seconds") and o.get("cpu_seconds"):
                    entry[f"{scene}/overlap_cpu"] = r["cpu_seconds"] / o["cpu_seconds"]
            elif r.get("seconds_at_least"):  # stopped at the timeout: a lower bound
                entry[f"{scene}_seconds_at_least"] = r["seconds_at_least"]
                entry[f"{scene}/overlap_at_least"] = r["seconds_at_least"] / o["seconds"]
        if "apart/overlap" in entry:
            entry["apart_within_2x"] = entry["apart/overlap"] <= 2.0
        out[f"n={n}"] = entry
    return out


def _ratio_text(ratios: dict) -> str:
    """One line per size for the chart: the default's far/overlap ratios."""
    lines = []
    for key, e in ratios.items():
        parts = []
        for scene in ("apart", "tutorial"):
            if f"{scene}/overlap" in e:
                parts.append(f"{scene}/overlap {e[f'{scene}/overlap']:.2f}")
            elif f"{scene}/overlap_at_least" in e:
                parts.append(f"{scene}/overlap > {e[f'{scene}/overlap_at_least']:.2f}")
        load = max(v for v in e["load_1min"].values() if v is not None)
        cpu = e.get("apart/overlap_cpu")
        cpu = f"; CPU time apart/overlap {cpu:.2f}" if cpu else ""
        lines.append(f"default, {key}: " + ", ".join(parts) + f" (wall, load <= {load:.1f}){cpu}")
    return "\n".join(lines)


def _ref_loss(ref):
    """The chamfer loss from the exact reference distances (None when no reference ran)."""
    return None if ref is None else float(ref[0].mean() + ref[1].mean())


def rerun_default(args) -> None:
    """``--default-only``: re-measure the default on the three scenes, update chamfer.json."""
    sizes = args.sizes or [1_000_000]
    path = args.out / "chamfer.json"
    old = json.loads(path.read_text(encoding="utf-8")) if path.exists() else None
    rows = old["tables"]["runs"] if old else []
    ref_loss = {(r["scene"], r["n"]): r["ref_loss"] for r in rows if r.get("ref_loss")}
    rows = [r for r in rows if not (r["method"] == "chamfer_auto" and r["n"] in sizes)]
    load_before = os.getloadavg()
    import open3d as o3d  # imported before the timings (its import takes seconds)

    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    label, fn = CHAMFER_METHODS["chamfer_auto"]
    new_rows = []
    for n in sizes:
        for scene, (x, y) in scenes(n).items():
            row = {"method": "chamfer_auto", "label": label, "scene": scene, "n": n,
                   "seconds": None}
            out = _measure("chamfer_auto", fn, x, y, max(args.repeat, 1), args.timeout)
            if out is None:
                row.update(status=f"timeout: not finished after {args.timeout:g} s",
                           seconds_at_least=args.timeout, load_1min=os.getloadavg()[0])
                print(f"{n:>8} {scene:9s} default > {args.timeout:g} s (timeout)", flush=True)
            else:
                times, _, loss, cpus = out
                k = int(np.argsort(times)[len(times) // 2])  # the median run
                want = ref_loss.get((scene, n))  # the exact loss of an earlier full run
                status = ("unchecked: no reference loss stored" if want is None else
                          "ok" if np.isclose(loss, want, rtol=1e-12) else "MISMATCH")
                row.update(seconds=times[k], runs=times, cpu_seconds=cpus[k], status=status,
                           load_1min=os.getloadavg()[0])
                if want is not None:
                    row["ref_loss"] = want
                print(f"{n:>8} {scene:9s} default {row['seconds']:9.3f} s  (runs "
                      f"{', '.join(f'{t:.2f}' for t in times)})  {status}  "
                      f"load {row['load_1min']:.1f}", flush=True)
            new_rows.append(row)
    rows += new_rows
    all_sizes = sorted({r["n"] for r in rows})
    report = BenchmarkReport("chamfer", config=dict(old["config"]) if old else {})
    report.notes = list(old["notes"]) if old else []
    report.config["sizes"] = all_sizes
    report.config["default_rerun"] = {
        "command": report.command, "sizes": sizes, "repeat": args.repeat,
        "note": "rows of chamfer_auto at these sizes: median of `repeat` runs, measured by "
                "this command; the other rows come from `previous_run`"}
    if old:
        report.config.setdefault("previous_run", {"command": old["command"],
                                                  "created": old["created"],
                                                  "load_average_1_5_15min":
                                                  old["machine"]["load_average_1_5_15min"]})
    _write(report, rows, all_sizes, args.out, "chamfer", load_before, partial=False)
    report.config["default_rerun"].update(loadavg_before=list(load_before),
                                          loadavg_after=list(os.getloadavg()))
    report.write(path)
    plot(rows, all_sizes, args.out / "chamfer.png", machine_info(),
         report.tables["default_ratios"])
    print(json.dumps(report.tables["default_ratios"], indent=1))
    print("wrote", path)


def plot(rows, sizes, path, mi, ratios=None) -> None:
    """Seconds against points a side, one panel per scene; a run stopped at the timeout is an
    open triangle at the timeout (a lower bound)."""
    import matplotlib.pyplot as plt

    from geofit.viz import chart_style

    methods = {**NN_METHODS, **CHAMFER_METHODS}
    with chart_style():
        fig, axes = plt.subplots(1, 3, figsize=(13, 6.0), sharey=True)
        for ax, scene in zip(axes, ("overlap", "tutorial", "apart")):
            for i, (key, (label, _)) in enumerate(methods.items()):
                color = f"C{i}"
                pts = [(r["n"], r["seconds"]) for r in rows
                       if r["method"] == key and r["scene"] == scene and r["seconds"]]
                if pts:
                    nn, ss = zip(*pts)
                    ax.loglog(nn, ss, "o-" if key in NN_METHODS else "s--", color=color,
                              label=label if scene == "overlap" else None)
                late = [(r["n"], r["seconds_at_least"]) for r in rows
                        if r["method"] == key and r["scene"] == scene
                        and r.get("seconds_at_least")]
                if late:
                    nn, ss = zip(*late)
                    ax.loglog(nn, ss, "^", color=color, markerfacecolor="none", markersize=9)
            ax.set_title(scene)
            ax.set_xlabel("points a side")
            ax.grid(True, which="both", alpha=0.3)
        axes[0].set_ylabel("seconds, both directions (builds included)")
        fig.legend(loc="lower center", ncol=3, fontsize=8, frameon=False,
                   bbox_to_anchor=(0.5, 0.075))
        fig.suptitle(f"Exact nearest neighbours for chamfer: {mi['cpu']}, "
                     f"{mi['cpu_affinity']} cores (open triangle: stopped at the timeout)")
        ratios = default_ratios(rows) if ratios is None else ratios
        if ratios:
            fig.text(0.01, 0.01, _ratio_text(ratios), fontsize=8, va="bottom")
        fig.tight_layout(rect=(0, 0.2, 1, 1))
        fig.savefig(path, dpi=110)
        plt.close(fig)


def replot(path) -> None:
    """Redraw the PNG next to a written JSON (``--replot``)."""
    d = json.loads(Path(path).read_text(encoding="utf-8"))
    plot(d["tables"]["runs"], d["config"]["sizes"], Path(path).with_suffix(".png"), d["machine"])


if __name__ == "__main__":
    main()
