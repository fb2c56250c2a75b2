"""The ``scans`` part of ``benchmarks/fit_mesh.py``: fit_mesh on scans as they come (issue 25).

Point clouds sampled from shapes no one tuned on (the normalised true mesh; noise isotropic
Gaussian in units of the unit box; strays uniform in the noisy cloud's bounding box, *added*
to the points; one-sided scans: the samples 3 cameras see, :func:`one_sided_scan`), one factor
at a time around a base of 20,000 points, noise 0.005, 1% strays (:data:`GRID`). Each is fitted
by geofit's default ``fit_mesh(points)``, Open3D's screened Poisson (depth 8, normals from 30
neighbours oriented by ``orient_normals_consistent_tangent_plane``, the 2% lowest-density
vertices trimmed), full size and decimated to geofit's face count (quadric decimation), and
Open3D's ball pivoting. Accuracy against the **true** surface (:mod:`geofit.metrics`, 50 000
seeded samples a side; one-sided scans only where the scan has evidence, plus the invented
area: :class:`EvidenceEvaluator`); wall and CPU seconds with the machine's load average.

    GEOFIT_DATA=/work/shared/data python benchmarks/_scans.py --shapes torus,fandisk
    python benchmarks/_scans.py --table-only

writes ``results/fit_mesh_scans.json`` (after each cell), ``fit_mesh_scans.md`` (the verdict
per condition, then every row) and one chart per condition (``fit_mesh_scans_<condition>.png``:
chamfer-L2 against wall seconds and against faces).
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

#: The base condition of the grid: 20,000 points, noise 0.005, 1% strays, seen from all sides.
BASE = {"n": 20_000, "noise": 0.005, "strays": 0.01, "one_sided": False}

#: The grid: one factor at a time around :data:`BASE` (name, factor, changes).
GRID = [("base: 20k, noise 0.005, 1% strays", "base", {}),
        ("noise 0", "noise", {"noise": 0.0}),
        ("noise 0.002", "noise", {"noise": 0.002}),
        ("noise 0.01", "noise", {"noise": 0.01}),
        ("density 5k", "density", {"n": 5_000}),
        ("density 50k", "density", {"n": 50_000}),
        ("density 100k", "density", {"n": 100_000}),
        ("strays 0", "strays", {"strays": 0.0}),
        ("strays 5%", "strays", {"strays": 0.05}),
        ("one-sided (3 views)", "one-sided", {"one_sided": True})]

#: The older table's second condition, kept to check "nothing worse than today" at 50k points.
CLEAN_50K = ("50k, noise 0.002, clean", "clean 50k", {"n": 50_000, "noise": 0.002, "strays": 0.0})

SHAPES = ["torus", "fandisk", "suzanne", "teapot", "ogre", "open_cylinder"]


def true_mesh(name: str):
    """The normalised true surface of a shape (procedural :data:`geofit.shapes.TEST_SHAPES`
    with a finer torus, tutorial 1's dolphin, or a file of ``$GEOFIT_DATA/shapes``)."""
    from geofit import load_mesh
    from geofit.shapes import TEST_SHAPES, torus

    data = Path(os.environ.get("GEOFIT_DATA", "/work/shared/data"))
    if name == "torus":
        m = torus(1.0, 0.35, 96, 48)
    elif name in TEST_SHAPES:
        m = TEST_SHAPES[name]()
    elif name == "dolphin":
        m = load_mesh(data / "dolphin" / "dolphin.obj")
    else:
        m = load_mesh(data / "shapes" / f"{name}.obj")
    return m.normalize().mesh


def scan(m, n: int, noise: float, strays: float, seed: int = 0) -> np.ndarray:
    """``n`` noisy surface samples plus ``strays * n`` uniform strays."""
    from geofit.ops import sample_points_from_meshes

    rng = np.random.default_rng(seed)
    P = sample_points_from_meshes(m, n, seed=seed) + rng.normal(0.0, noise, (n, 3))
    O = rng.uniform(P.min(0), P.max(0), (int(round(strays * n)), 3))
    return np.r_[P, O]


#: Camera centres of the one-sided scans: 3 views on a ring 30 degrees above the equator
#: (y up), 120 degrees apart, at distance 3 from the normalised shape's centre.
def _view_centres() -> np.ndarray:
    az = np.deg2rad([0.0, 120.0, 240.0]) + 0.3
    el = np.deg2rad(30.0)
    return 3.0 * np.c_[np.cos(el) * np.cos(az), np.full(3, np.sin(el)), np.cos(el) * np.sin(az)]


def one_sided_scan(m, n: int, noise: float, strays: float, seed: int = 0):
    """A scan from 3 viewpoints only: ``(points, clean)``.

    ``8 n`` area-uniform samples of the true surface; a sample is seen by a camera when its
    normal faces it (cosine > 0.05) and the segment to the camera hits nothing (geofit's Embree
    :class:`~geofit.raycast.RayCaster`); ``n`` of the samples seen by at least one camera get
    Gaussian noise ``noise``, plus ``strays * n`` uniform strays in their bounding box.
    ``clean`` are the same ``n`` samples without noise: where the scan has evidence.
    """
    from geofit.ops import sample_points_from_meshes
    from geofit.raycast import RayCaster

    rng = np.random.default_rng(seed)
    P, N = sample_points_from_meshes(m, 8 * n, seed=seed, return_normals=True)
    rc = RayCaster(m)
    seen = np.zeros(len(P), dtype=bool)
    for c in _view_centres():  # 3 cameras
        d = c - P
        L = np.linalg.norm(d, axis=1)
        d /= L[:, None]
        facing = np.einsum("ij,ij->i", d, N) > 0.05
        seen |= facing & ~rc.cast(P + 1e-6 * d, d, tfar=L).hit
    idx = rng.choice(np.flatnonzero(seen), min(n, int(seen.sum())), replace=False)
    clean = P[idx]
    V = clean + rng.normal(0.0, noise, clean.shape)
    O = rng.uniform(V.min(0), V.max(0), (int(round(strays * n)), 3))
    return np.r_[V, O], clean


class EvidenceEvaluator:
    """Accuracy of a reconstruction of a one-sided scan where the scan has evidence.

    ``delta = max(0.02, 3 s)`` with ``s`` the median nearest-neighbour distance of the clean
    visible samples ``clean``. 50,000 area-uniform samples of the true surface and of the
    reconstruction; a sample is *in evidence* when it is within ``delta`` of a clean visible
    sample. Chamfer-L2 and F@0.01 are computed as :mod:`geofit.metrics` does (exact
    point-to-surface distances both ways), between the true surface's and the
    reconstruction's samples in evidence only; ``invented`` is the area fraction of the
    reconstruction outside the evidence (samples not in evidence / all samples).
    """

    def __init__(self, m, clean: np.ndarray, n_samples: int = 50_000, seed: int = 0):
        from scipy.spatial import cKDTree

        from geofit.loss import PointToSurface
        from geofit.ops import sample_points_from_meshes

        self.tree = cKDTree(clean)
        s = float(np.median(self.tree.query(clean, 2)[0][:, 1]))
        self.delta = max(0.02, 3.0 * s)
        self.n, self.seed = n_samples, seed
        T = sample_points_from_meshes(m, n_samples, seed=seed)
        self.T = T[self.tree.query(T)[0] <= self.delta]
        self.p2s = PointToSurface(m)

    def evaluate(self, pred) -> dict:
        from geofit.ops import sample_points_from_meshes
        from geofit.raycast import PointToMeshDistance

        Q = sample_points_from_meshes(pred, self.n, seed=self.seed + 1)
        inside = self.tree.query(Q)[0] <= self.delta
        d_pt = self.p2s.query(Q[inside]).distances
        d_tp = PointToMeshDistance(pred).query(self.T).distances
        prec, rec = float(np.mean(d_pt < 0.01)), float(np.mean(d_tp < 0.01))
        f = 2 * prec * rec / (prec + rec) if prec + rec > 0 else 0.0
        return {"chamfer_l2": float(np.mean(d_pt ** 2) + np.mean(d_tp ** 2)), "fscore": f,
                "invented": float(1.0 - inside.mean()), "delta": self.delta}


class _TrueEvaluator:
    """:class:`geofit.metrics.MeshEvaluator` (50,000 seeded samples a side) as a dict."""

    def __init__(self, m):
        from geofit.metrics import MeshEvaluator

        self.ev = MeshEvaluator(m, n_samples=50_000, taus=0.01, seed=0)

    def evaluate(self, pred) -> dict:
        met = self.ev.evaluate(pred)
        return {"chamfer_l2": met.chamfer_l2, "fscore": met.fscore[0.01]}


def _estimate_normals(P: np.ndarray):
    import open3d as o3d

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P))
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(30))
    return pcd


def poisson(P: np.ndarray):
    """Open3D's screened Poisson as a user would run it; (Open3D mesh, seconds, CPU seconds)."""
    import open3d as o3d

    t, c = time.perf_counter(), time.process_time()
    pcd = _estimate_normals(P)
    pcd.orient_normals_consistent_tangent_plane(30)
    m, dens = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(pcd, depth=8)
    dens = np.asarray(dens)
    m.remove_vertices_by_mask(dens < np.quantile(dens, 0.02))
    return m, time.perf_counter() - t, time.process_time() - c


def ball_pivoting(P: np.ndarray):
    """Open3D's ball pivoting as its tutorial runs it (normals from 30 neighbours, radii 3 and
    6 mean nearest-neighbour distances); (Open3D mesh, seconds, CPU seconds)."""
    import open3d as o3d

    t, c = time.perf_counter(), time.process_time()
    pcd = _estimate_normals(P)
    r = 3.0 * float(np.mean(pcd.compute_nearest_neighbor_distance()))
    m = o3d.geometry.TriangleMesh.create_from_point_cloud_ball_pivoting(
        pcd, o3d.utility.DoubleVector([r, 2.0 * r]))
    return m, time.perf_counter() - t, time.process_time() - c


def o3d_to_mesh(m):
    from geofit import Mesh

    return Mesh(np.asarray(m.vertices, dtype=np.float64), np.asarray(m.triangles, dtype=np.int64))


def conditions(names=None) -> list[tuple[str, str, dict]]:
    """The grid's conditions (all, or those whose name is in ``names``), :data:`BASE` filled in."""
    out = []
    for name, factor, change in GRID + [CLEAN_50K]:
        if (names is None and factor != "clean 50k") or (names is not None and name in names):
            out.append((name, factor, dict(BASE, **change)))
    return out


def _cached_poisson(P: np.ndarray, cache: Path | None, key: str):
    """:func:`poisson` of ``P``, or the one saved in ``cache`` under ``key`` (the same scan:
    its size and coordinate sum are checked) with the seconds it took then."""
    import open3d as o3d

    f = None if cache is None else cache / f"{key}.npz"
    stamp = np.array([len(P), float(P.sum())])
    if f is not None and f.exists():
        d = np.load(f)
        if np.array_equal(d["stamp"], stamp):
            m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(d["V"]),
                                          o3d.utility.Vector3iVector(d["F"]))
            return m, float(d["wall"]), float(d["cpu"])
    m, w, c = poisson(P)
    if f is not None:
        cache.mkdir(parents=True, exist_ok=True)
        np.savez(f, V=np.asarray(m.vertices), F=np.asarray(m.triangles), wall=w, cpu=c,
                 stamp=stamp)
    return m, w, c


def run_cell(sname: str, m, cname: str, factor: str, c: dict, *, peers: bool = True,
             time_budget: float | None = None, label: str = "geofit",
             poisson_cache: Path | None = None, ball: bool = True) -> list[dict]:
    """One shape under one condition: geofit's default, Poisson (full, same size), ball
    pivoting; one row each. ``poisson_cache``: a folder where the full Poisson mesh of each
    scan is kept between runs (its seconds are those of the run that made it)."""
    from geofit.fit import fit_mesh

    if c["one_sided"]:
        P, clean = one_sided_scan(m, c["n"], c["noise"], c["strays"])
        ev = EvidenceEvaluator(m, clean)
    else:
        P = scan(m, c["n"], c["noise"], c["strays"])
        ev = _TrueEvaluator(m)
    common = {"shape": sname, "condition": cname, "factor": factor, "n_points": len(P),
              "n_surface_points": c["n"], "noise": c["noise"], "strays": c["strays"],
              "one_sided": c["one_sided"]}
    rows = []

    def add(method, mesh, wall, cpu, load, **extra):
        rows.append(dict(common, method=method, faces=mesh.n_faces, seconds=wall,
                         cpu_seconds=cpu, load=load, **ev.evaluate(mesh), **extra))
        print(json.dumps(rows[-1]), flush=True)

    load = os.getloadavg()[0]
    t, cp = time.perf_counter(), time.process_time()
    res = fit_mesh(P, seed=0, progress=False, time_budget=time_budget)
    wall, cpu = time.perf_counter() - t, time.process_time() - cp
    rep = res.data_report
    add(label, res.mesh, wall, cpu, load, status=res.status, time_budget=time_budget,
        data_report=None if rep is None else rep.as_dict())
    if not peers:
        return rows
    load = os.getloadavg()[0]
    slug = "".join(ch if ch.isalnum() else "_" for ch in f"{sname}_{cname}")
    try:
        pm, pw, pc = _cached_poisson(P, poisson_cache, slug)
    except RuntimeError as e:  # Open3D's normal orientation fails on an exactly flat scan
        print(json.dumps(dict(common, method="Poisson (full)", error=str(e).splitlines()[0])),
              flush=True)
        return rows
    add("Poisson (full)", o3d_to_mesh(pm), pw, pc, load)
    t, cp = time.perf_counter(), time.process_time()
    small = o3d_to_mesh(pm.simplify_quadric_decimation(int(res.mesh.n_faces)))
    add("Poisson (same size)", small, pw + time.perf_counter() - t,
        pc + time.process_time() - cp, load)
    if not ball:
        return rows
    load = os.getloadavg()[0]
    bm, bw, bc = ball_pivoting(P)
    bpa = o3d_to_mesh(bm)
    if bpa.n_faces:
        add("ball pivoting", bpa, bw, bc, load)
    return rows


def run(out: Path, shapes=SHAPES, names=None, *, peers: bool = True,
        time_budget: float | None = None, name: str = "fit_mesh_scans", cells=None,
        poisson_cache: Path | None = None, ball: bool = True) -> list[dict]:
    """Every shape under every condition (or only the ``(shape, condition)`` pairs of
    ``cells``); the rows are written to ``out/<name>.json`` after each cell (a run cut short
    keeps what it measured)."""
    out.mkdir(parents=True, exist_ok=True)
    rows: list[dict] = []
    if cells is not None:
        shapes = list(dict.fromkeys(s for s, _ in cells))
        names = list(dict.fromkeys(c for _, c in cells))
    for sname in shapes:
        m = true_mesh(sname)
        for cname, factor, c in conditions(names):
            if cells is not None and (sname, cname) not in cells:
                continue
            rows += run_cell(sname, m, cname, factor, c, peers=peers, time_budget=time_budget,
                             poisson_cache=poisson_cache, ball=ball)
            loads = [r["load"] for r in rows]
            write_json(out / f"{name}.json", {
                "benchmark": name,
                "command": "python " + " ".join(
                    [str(Path(__file__).relative_to(Path(__file__).parents[1]))] + sys.argv[1:]),
                "machine": machine_summary(), "load": [min(loads), max(loads)],
                "base": BASE, "rows": rows})
    return rows


def verdicts(rows: list[dict]) -> list[dict]:
    """The acceptance per shape and condition: geofit at least as accurate as Poisson at the
    same size (chamfer-L2 and F@0.01), no more faces than points, within 10 s (wall; the
    quiet re-run's seconds where :func:`add_quiet_timings` gave them)."""
    out = []
    for key in sorted({(r["condition"], r["shape"]) for r in rows}):
        sel = {r["method"]: r for r in rows if (r["condition"], r["shape"]) == key}
        g, p = sel.get("geofit"), sel.get("Poisson (same size)")
        if g is None or p is None:
            continue
        v = {"condition": key[0], "shape": key[1], "factor": g["factor"],
             "chamfer": g["chamfer_l2"] <= p["chamfer_l2"], "fscore": g["fscore"] >= p["fscore"],
             "faces": g["faces"] <= g["n_points"],
             "time": g.get("quiet_seconds", g["seconds"]) <= 10.0}
        v["pass"] = all(v[k] for k in ("chamfer", "fscore", "faces", "time"))
        out.append(v)
    return out


def add_quiet_timings(out: Path, name: str, quiet: Path) -> int:
    """Put the wall seconds of a quiet geofit-only run (``--no-peers``, the same cells) beside
    the grid's geofit rows in ``out/<name>.json``: only where the quiet run gave the same
    result (faces, chamfer-L2 and F@0.01 equal), so the time belongs to the same fit. The
    grid's peers run in the same processes and take long, so the grid itself is timed under
    load; the verdict's 10 s then uses the quiet seconds. Returns the rows matched."""
    path = out / f"{name}.json"
    doc, q = json.loads(path.read_text()), json.loads(Path(quiet).read_text())
    qs = {(r["shape"], r["condition"]): r for r in q["rows"] if r["method"] == "geofit"}
    n = 0
    for r in doc["rows"]:
        m = qs.get((r["shape"], r["condition"])) if r["method"] == "geofit" else None
        if m is not None and all(m[k] == r[k] for k in ("faces", "chamfer_l2", "fscore")):
            r.update(quiet_seconds=m["seconds"], quiet_cpu_seconds=m["cpu_seconds"],
                     quiet_load=m["load"])
            n += 1
    doc["quiet_timings"] = {"benchmark": q["benchmark"], "command": q["command"],
                            "load": q["load"], "rows_matched": n}
    write_json(path, doc)
    return n


def table(out: Path, name: str = "fit_mesh_scans") -> str:
    """The markdown table, the verdict summary and one chart per condition from
    ``out/<name>.json``."""
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter

    from geofit._atomic import write_text

    doc = json.loads((out / f"{name}.json").read_text())
    rows = doc["rows"]
    order = [g[0] for g in GRID + [CLEAN_50K]]
    conds = sorted({r["condition"] for r in rows}, key=order.index)
    ver = verdicts(rows)
    lines = ["| condition | shapes | pass | chamfer <= Poisson same size | F >= Poisson same size "
             "| faces <= points | <= 10 s | failing cells |", "|" + "---|" * 8]
    for cond in conds:
        vs = [v for v in ver if v["condition"] == cond]
        fails = ", ".join(v["shape"] + " (" + "/".join(k for k in ("chamfer", "fscore", "faces",
                                                                     "time") if not v[k]) + ")"
                          for v in vs if not v["pass"])
        lines.append(f"| {cond} | {len(vs)} | {sum(v['pass'] for v in vs)} | "
                     + " | ".join(str(sum(v[k] for v in vs))
                                  for k in ("chamfer", "fscore", "faces", "time"))
                     + f" | {fails or '-'} |")
    lines += ["", "| shape | condition | method | faces | chamfer-L2 | F@0.01 | invented | wall s "
              "| CPU s | load | quiet wall s |", "|" + "---|" * 11]
    for cond in conds:
        for r in rows:
            if r["condition"] == cond:
                inv = f"{r['invented']:.3f}" if "invented" in r else "-"
                lines.append(f"| {r['shape']} | {cond} | {r['method']} | {r['faces']} | "
                             f"{r['chamfer_l2']:.3g} | {r['fscore']:.4f} | {inv} | "
                             f"{r['seconds']:.1f} | {r['cpu_seconds']:.1f} | {r['load']:.1f} | "
                             + (f"{r['quiet_seconds']:.1f} |" if "quiet_seconds" in r else "- |"))
    md = "\n".join(lines) + "\n"
    head = (f"Written by `benchmarks/fit_mesh.py --parts scans` (benchmarks/_scans.py; command "
            f"`{doc['command']}`, load {doc['load'][0]:.1f}-{doc['load'][1]:.1f}: timings under "
            "that load). One factor at a time around the base (20,000 surface points, Gaussian "
            "noise 0.005 of the unit box, 1% uniform strays added). geofit = the default "
            "`fit_mesh(points)` (no time budget); Poisson = Open3D screened Poisson, depth 8, "
            "normals from 30 neighbours oriented by orient_normals_consistent_tangent_plane(30), "
            "the 2% lowest-density vertices trimmed; same size = quadric decimation to geofit's "
            "face count; ball pivoting = Open3D, radii 3 and 6 mean neighbour distances. "
            "Accuracy against the true surface (50,000 samples a side); one-sided scans: only "
            "where the scan has evidence, and `invented` = area fraction of the reconstruction "
            "farther than delta = max(0.02, 3 spacings) from every clean visible sample "
            "(EvidenceEvaluator). pass = chamfer-L2 and F@0.01 at least as good as Poisson same "
            "size, faces <= points, wall <= 10 s.\n\n")
    qt = doc.get("quiet_timings")
    if qt:
        head += (f"Quiet wall s: geofit's cells re-run alone (`{qt['command']}`, load "
                 f"{qt['load'][0]:.1f}-{qt['load'][1]:.1f}), the seconds kept where the quiet "
                 f"run gave the same faces, chamfer-L2 and F@0.01 ({qt['rows_matched']} rows); "
                 "the verdict's 10 s uses them.\n\n")
    write_text(out / f"{name}.md", head + md)
    for cond in conds:
        sel = [r for r in rows if r["condition"] == cond]
        fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
        for meth in sorted({r["method"] for r in sel}):
            rs = [r for r in sel if r["method"] == meth]
            for ax, x in zip(axes, ("seconds", "faces")):
                ax.scatter([r[x] for r in rs], [r["chamfer_l2"] for r in rs], label=meth)
                for r in rs:
                    ax.annotate(r["shape"], (r[x], r["chamfer_l2"]), fontsize=7)
        for ax, x in zip(axes, ("wall seconds (under load)", "faces")):
            ax.set(xscale="log", yscale="log", xlabel=x, ylabel="chamfer-L2 (true surface)")
            ax.xaxis.set_minor_formatter(NullFormatter())
            ax.legend(fontsize=7)
        fig.suptitle(cond)
        fig.tight_layout()
        slug = "".join(ch if ch.isalnum() else "_" for ch in cond.split(":")[0]).strip("_")
        fig.savefig(out / f"{name}_{slug}.png", dpi=100)
        plt.close(fig)
    return md


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default=str(Path(__file__).parent / "results"))
    p.add_argument("--shapes", default=",".join(SHAPES))
    p.add_argument("--conditions", default=None,
                   help="';'-separated condition names (default: the grid)")
    p.add_argument("--name", default="fit_mesh_scans", help="file name of the JSON, md, PNGs")
    p.add_argument("--no-peers", action="store_true", help="geofit only")
    p.add_argument("--time-budget", type=float, default=None,
                   help="geofit's wall-clock budget (default: none)")
    p.add_argument("--table-only", action="store_true", help="only redraw from the JSON")
    p.add_argument("--cells", default=None,
                   help="';'-separated shape:condition pairs to run instead of the grid "
                        "(e.g. 'teapot:density 50k;torus:strays 5%%')")
    p.add_argument("--poisson-cache", default=None,
                   help="folder keeping each scan's full Poisson mesh between runs")
    p.add_argument("--no-ball", action="store_true", help="no ball pivoting")
    p.add_argument("--quiet-timings", default=None,
                   help="the JSON of a quiet --no-peers run of the same cells: its wall "
                        "seconds beside the grid's geofit rows where the results agree")
    a = p.parse_args(argv)
    out = Path(a.out)
    if not a.table_only:
        names = None if a.conditions is None else a.conditions.split(";")
        cells = (None if a.cells is None
                 else [tuple(c.split(":", 1)) for c in a.cells.split(";") if c])
        run(out, [s for s in a.shapes.split(",") if s], names, peers=not a.no_peers,
            time_budget=a.time_budget, name=a.name, cells=cells,
            poisson_cache=None if a.poisson_cache is None else Path(a.poisson_cache),
            ball=not a.no_ball)
    if a.quiet_timings:
        print(f"quiet timings for {add_quiet_timings(out, a.name, Path(a.quiet_timings))} rows")
    print(table(out, a.name))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
