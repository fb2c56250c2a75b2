"""Issue 24 (viewsgeom): where the views fit's surface is farther than F@0.01's threshold.

``diag SHAPE... [--options JSON] [--tag T] [--compare]``: on a shape of
``benchmarks/fit_views.py --shapes`` (normalised and vertex-coloured like that table, 20 views of
128 px, 16 held-out views), fit ``fit_mesh_to_views(train, options=...)`` and split the
surface error at tau = 0.01 (F@0.01's threshold; a pixel is about 0.024 at the object) by where
it is on the true surface:

- ``hidden``: a concavity no silhouette can see: the true point moved tau along its normal is
  still inside the silhouette of every one of 200 cameras spread over the sphere (tested by
  casting the camera rays through it against the true mesh, no pixels involved);
- ``edge``: else within 0.02 of a feature edge of the true mesh (dihedral angle > 30 degrees);
- ``face``: the rest (flat or smoothly curved faces).

For the precision side (samples of the fit farther than tau from the truth) each sample takes
the class of its closest true point; for the recall side (true samples farther than tau from
the fit) its own. Also the signed offset of the fit's samples (outward positive, by the true
face's normal): median over all samples and per class, and the F-score the fit would have
were it moved inward by its median offset (a systematic inflation); ``--init-true`` starts
the fit from the true mesh (e.g. with ``--options '{"levels": [[0, 1]]}'``: the 128 px level
alone). ``unpinned``: the misses
whose true point the 20 training views do not pin (moved tau along its normal it is still
inside all 20 silhouettes): there only the regularisers decide where the surface is. ``--compare`` adds the
rows of what is possible: the true mesh remeshed to about the fit's vertex count, the visual
hull the fit starts from, and the fit started from the true mesh.

Rows (JSON lines) go to ``--rows``; ``write`` makes ``results/fit_views_session9_geom.json``
and ``.md``.

    GEOFIT_DATA=/work/shared/data python benchmarks/fit_views_session9_geom.py diag fandisk --compare
    python benchmarks/fit_views_session9_geom.py write
"""
from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROWS = HERE / "results" / "fit_views_session9_geom_rows.jsonl"
TAU = 0.01
EDGE_R = 0.02
DIHEDRAL = 30.0
N_SAMPLES = 50_000
CLASSES = ("hidden", "edge", "face")


def feature_points(mesh, angle_deg: float = DIHEDRAL, step: float = 0.002) -> np.ndarray:
    """Points every ``step`` along the edges whose dihedral angle exceeds ``angle_deg``
    (and along boundary edges)."""
    F = mesh.faces
    e = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    fid = np.tile(np.arange(len(F)), 3)
    key = np.sort(e, axis=1)
    order = np.lexsort((key[:, 1], key[:, 0]))
    key, fid = key[order], fid[order]
    same = np.all(key[1:] == key[:-1], axis=1)
    n = mesh.face_normals
    pair = np.flatnonzero(same)
    cosang = np.einsum("ij,ij->i", n[fid[pair]], n[fid[pair + 1]])
    sharp = key[pair[cosang < np.cos(np.radians(angle_deg))]]
    counts = np.bincount(np.unique(key, axis=0, return_inverse=True)[1].ravel())
    uk = np.unique(key, axis=0)
    bnd = uk[counts == 1]
    edges = np.concatenate([sharp, bnd])
    if len(edges) == 0:
        return np.empty((0, 3))
    a, b = mesh.verts[edges[:, 0]], mesh.verts[edges[:, 1]]
    length = np.linalg.norm(b - a, axis=1)
    k = np.maximum(np.ceil(length / step).astype(int), 1)
    seg = np.repeat(np.arange(len(edges)), k + 1)
    t = np.concatenate([np.linspace(0.0, 1.0, kk + 1) for kk in k])
    return a[seg] + t[:, None] * (b - a)[seg]


def carved(points, normals, target, centers, delta: float = TAU) -> np.ndarray:
    """(k,) bool: ``points + delta normals`` is outside the silhouette of ``target`` seen from
    at least one of the camera ``centers`` (the ray from the centre through it misses)."""
    from geofit.raycast import RayCaster

    rc = RayCaster(target)
    q = points + delta * normals
    out = np.zeros(len(points), bool)
    for c in centers:  # cameras
        out |= ~rc.cast(np.broadcast_to(c, q.shape), q - c).hit
    return out


def fibonacci_centers(n: int = 200, dist: float = 2.7) -> np.ndarray:
    """``n`` camera centres spread evenly over the sphere of radius ``dist``."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    phi = np.pi * (1.0 + 5 ** 0.5) * i
    r = np.sqrt(1.0 - z * z)
    return dist * np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def classify(target, cameras):
    """Samples of the true surface, their class index (0 hidden, 1 edge, 2 face) and whether
    the training views pin them (carved at tau)."""
    from scipy.spatial import cKDTree

    from geofit.ops import sample_points_from_meshes

    s = sample_points_from_meshes(target, N_SAMPLES, seed=np.random.default_rng(1),
                                  return_normals=True)
    pinned = carved(s.points, s.normals, target, cameras.get_camera_center())
    visible = pinned | carved(s.points, s.normals, target, fibonacci_centers())
    fp = feature_points(target)
    d_edge = cKDTree(fp).query(s.points)[0] if len(fp) else np.full(len(s.points), np.inf)
    cls = np.where(~visible, 0, np.where(d_edge < EDGE_R, 1, 2))
    return s.points, cls, pinned


def breakdown(pred, target, t_points, t_cls, t_pinned) -> dict:
    """F@tau split by class (see the module docstring)."""
    from scipy.spatial import cKDTree

    from geofit.ops import sample_points_from_meshes
    from geofit.raycast import PointToMeshDistance

    p = sample_points_from_meshes(pred, N_SAMPLES, seed=np.random.default_rng(2))
    ct = PointToMeshDistance(target).query(p)
    d_pt = ct.distances
    signed = np.einsum("ij,ij->i", p - ct.points, target.face_normals[ct.face_ids])
    nearest = cKDTree(t_points).query(ct.points)[1]
    p_cls, p_pinned = t_cls[nearest], t_pinned[nearest]
    d_tp = PointToMeshDistance(pred).query(t_points).distances
    prec, rec = float(np.mean(d_pt < TAU)), float(np.mean(d_tp < TAU))
    f = 2 * prec * rec / max(prec + rec, 1e-12)
    med = float(np.median(signed))
    # moved inward by the median offset (the fit's samples only; recall is approximated
    # by the same shift of the distances of the true samples' closest fit points)
    prec_s = float(np.mean(np.abs(signed - med) < TAU))
    out = {"fscore": f, "precision": prec, "recall": rec, "median_offset": med,
           "fscore_offset_removed": 2 * prec_s * rec / max(prec_s + rec, 1e-12)}
    for k, name in enumerate(CLASSES):  # classes
        pm, tm = p_cls == k, t_cls == k
        out[name] = {
            "share_true": float(tm.mean()),
            "prec_miss": float(np.mean((d_pt >= TAU) & pm)),   # of all pred samples
            "rec_miss": float(np.mean((d_tp >= TAU) & tm)),    # of all true samples
            "prec_miss_unpinned": float(np.mean((d_pt >= TAU) & pm & ~p_pinned)),
            "rec_miss_unpinned": float(np.mean((d_tp >= TAU) & tm & ~t_pinned)),
            "median_offset": float(np.median(signed[pm])) if pm.any() else 0.0,
            "p90_abs_offset": float(np.percentile(np.abs(signed[pm]), 90)) if pm.any() else 0.0,
        }
    return out


def remesh_to_count(mesh, edge: float, n_verts: int):
    """``mesh`` remeshed towards ``edge`` (5 passes at a time, at most 6 times) until it has
    fewer than 1.3 ``n_verts`` vertices (a fine mesh coarsens only a little per pass)."""
    from geofit.ops import remesh

    for _ in range(6):  # rounds of passes
        mesh = remesh(mesh, edge, n_passes=5).mesh
        if mesh.n_verts < 1.3 * n_verts:
            break
    return mesh


def run(name: str, options: dict, tag: str, compare: bool, init_true: bool = False
        ) -> list[dict]:
    from fit_views_thin import dataset

    from geofit import Mesh
    from geofit.fit.views import ViewsEvaluator, ViewsFitOptions, fit_mesh_to_views
    target, ds = dataset(name)
    geom = Mesh(target.verts, target.faces)
    t_points, t_cls, t_pinned = classify(geom, ds.cameras)
    ev = ViewsEvaluator(ds.held_out, target, n_samples=N_SAMPLES, taus=(TAU,))
    rows = []

    def row(label, mesh, wall=None, cpu=None, extra=None):
        np.savez(f"/tmp/viewsgeom/{name}_{tag}_{label.split()[0]}_{label.split()[-1]}.npz",
                 verts=mesh.verts, faces=mesh.faces)
        m = ev(mesh, surface=False)
        r = dict(kind="diag", tag=tag, shape=name, mesh=label, options=options,
                 iou=m["iou"], n_verts=mesh.n_verts,
                 mean_edge=float(mesh.edge_lengths.mean()), wall=wall, cpu=cpu,
                 load=os.getloadavg()[0], pinned_share=float(np.mean(t_pinned)),
                 **breakdown(Mesh(mesh.verts, mesh.faces), geom, t_points, t_cls, t_pinned),
                 **(extra or {}))
        print(json.dumps(r), flush=True)
        rows.append(r)

    def fit(opts):
        c0, t0 = time.process_time(), time.perf_counter()
        res = fit_mesh_to_views(ds, options=ViewsFitOptions(**opts), progress=False)
        return res, time.perf_counter() - t0, time.process_time() - c0

    res, wall, cpu = fit({**options, "init": geom} if init_true else options)
    row("fit from the true mesh" if init_true else "fit", res.mesh, wall, cpu)
    if compare:
        edge = float(res.mesh.edge_lengths.mean())
        row("true mesh remeshed to about the fit's vertex count",
            remesh_to_count(geom, edge, res.mesh.n_verts))
        row("visual hull (the fit's start)", res.init_mesh)
        res2, w2, c2 = fit({**options, "init": geom})
        row("fit from the true mesh", res2.mesh, w2, c2)
    return rows


def write(rows_path: Path, out: Path) -> None:
    from _harness import machine_info, markdown_table

    rows = [json.loads(x) for x in rows_path.read_text().splitlines() if x.strip()]
    stem = "fit_views_session9_geom"
    doc = {"benchmark": stem, "command": "python benchmarks/fit_views_session9_geom.py write",
           "tau": TAU, "edge_radius": EDGE_R, "dihedral_deg": DIHEDRAL,
           "machine": machine_info(), "rows": rows}
    (out / f"{stem}.json").write_text(json.dumps(doc, indent=1))
    header = ["shape", "mesh", "options", "IoU", "F@0.01", "precision / recall",
              "recall misses: hidden / edge / face (unpinned)",
              "precision misses: hidden / edge / face (unpinned)",
              "median offset: all (hidden / edge / face)", "F offset removed", "verts",
              "CPU s (load)"]
    table = []
    for r in rows:
        h, e, f = (r[c] for c in CLASSES)
        opt = json.dumps(r["options"].get("silhouette_weights", r["options"])) \
            if r["options"] else "default"
        table.append([
            r["shape"], r["mesh"], opt, f"{r['iou']:.4f}", f"{r['fscore']:.3f}",
            f"{r['precision']:.3f} / {r['recall']:.3f}",
            "{:.3f} / {:.3f} ({:.3f}) / {:.3f} ({:.3f})".format(
                h["rec_miss"], e["rec_miss"], e["rec_miss_unpinned"], f["rec_miss"],
                f["rec_miss_unpinned"]),
            "{:.3f} / {:.3f} ({:.3f}) / {:.3f} ({:.3f})".format(
                h["prec_miss"], e["prec_miss"], e["prec_miss_unpinned"], f["prec_miss"],
                f["prec_miss_unpinned"]),
            "{:+.4f} ({:+.4f} / {:+.4f} / {:+.4f})".format(
                r["median_offset"], h["median_offset"], e["median_offset"], f["median_offset"]),
            f"{r['fscore_offset_removed']:.3f}", r["n_verts"],
            f"{r['cpu']:.0f} ({r['load']:.0f})" if r.get("cpu") else "-"])
    lines = markdown_table(header, table).splitlines()
    (out / f"{stem}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def main(argv=None) -> int:
    sys.path.insert(0, str(HERE))
    from _harness import append_row, rows_parser

    ap = rows_parser(__doc__.split("\n")[0], ("diag", "write"), ROWS)
    ap.add_argument("--compare", action="store_true")
    ap.add_argument("--init-true", action="store_true", help="start from the true mesh")
    a = ap.parse_args(argv)
    if a.mode == "write":
        write(a.rows, HERE / "results")
        return 0
    for name in a.shapes:  # shapes
        for r in run(name, json.loads(a.options), a.tag, a.compare, a.init_true):
            append_row(a.rows, r)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
