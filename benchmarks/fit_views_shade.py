"""Issue 24 items 1-2 (viewsshade): can the RGB images move the views fit's geometry?

``scan SHAPE...``: the hard image loss (:class:`geofit.render.mesh.HardImageLoss`, the
dataset's light, one ray a pixel as the targets were rendered) on the pixels 2 px or more inside
the true silhouettes (no outline: what the silhouettes do not say), with the TRUE vertex
colours and with least-squares colours (what the RGB stage solves), for the true mesh and the true surface remeshed to about 6000 and 1500 vertices (the
fit's size), each moved along its vertex normals by -0.005, 0, +0.005 (0.2 px): is the truth
the minimum of the image term at the fit's tessellation?

``stage SHAPE... --options JSON``: the default's RGB stage (options merged over the default's
``rgb_*``) from the default's silhouette-stage mesh of the shape (``rgb_iters=0``; cached in
``--cache``, deterministic without a time budget), then the default's colours and texture:
held-out IoU, F@0.01 (100 000 samples), PSNR, the CPU seconds of the call. ``{}`` reproduces the
default (Suzanne 0.9764 / 0.643 as in fit_views_shapes_session9).

    GEOFIT_DATA=/work/shared/data python benchmarks/fit_views_shade.py scan suzanne
    python benchmarks/fit_views_shade.py stage fandisk --options '{"rgb_color_smooth": 1e-4}'
"""
from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROWS = HERE / "results" / "fit_views_shade_rows.jsonl"
OFFSETS = (-0.005, 0.0, 0.005)


def true_colours(verts: np.ndarray) -> np.ndarray:
    """The benchmark's vertex colours (``fit_views.vertex_coloured``) at ``verts``."""
    return 0.5 + 0.4 * np.sin(3.0 * verts + np.array([0.5, 1.5, 2.5]))


def lsq_loss(loss, mesh) -> float:
    """The image loss with the vertex colours solved by least squares (a 1e-9 ridge)."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    A, y = loss.color_operator(mesh)
    n = y.shape[0] / loss.supersample ** 2
    out = 0.0
    for c in range(3):  # channels
        x = spla.spsolve((A[c].T @ A[c] + 1e-9 * sp.identity(mesh.n_verts)).tocsc(),
                         A[c].T @ y[:, c])
        out += float(np.sum((A[c] @ x - y[:, c]) ** 2)) / n
    return out


def scan(name: str) -> list[dict]:
    from fit_views_session9_geom import remesh_to_count
    from fit_views_thin import dataset
    from scipy.ndimage import binary_erosion

    from geofit import Mesh
    from geofit.render.mesh import HardImageLoss

    target, ds = dataset(name)
    truth = Mesh(target.verts, target.faces)
    inner = np.stack([binary_erosion(s > 0.5, iterations=2) for s in ds.silhouettes])
    loss = HardImageLoss(ds.cameras, ds.images, lights=ds.lights, masks=inner.astype(float),
                         background=ds.background if ds.background is not None else (1, 1, 1))
    area = float(truth.face_areas.sum())
    rows = []
    for n in (None, 6000, 1500):  # tessellations
        m = truth if n is None else remesh_to_count(
            truth, float(np.sqrt(2.0 * area / (n * np.sqrt(3.0)))), n)
        C = true_colours(m.verts)
        moved = [Mesh(m.verts + d * m.verts_normals, m.faces) for d in OFFSETS]  # offsets
        rows.append(dict(kind="scan", shape=name, n_verts=m.n_verts, offsets=OFFSETS,
                         inner_loss=[float(loss(mm, C)[0]) for mm in moved],
                         inner_loss_lsq=[lsq_loss(loss, mm) for mm in moved]))
        print(json.dumps(rows[-1]), flush=True)
    return rows


def stage(name: str, options: dict, cache: Path) -> dict:
    from fit_views_thin import dataset

    from geofit import Mesh
    from geofit.fit.views import ViewsEvaluator, ViewsFitOptions, fit_mesh_to_views

    target, ds = dataset(name)
    path = cache / f"sil_{name}.npz"
    if not path.exists():
        res = fit_mesh_to_views(ds, options=ViewsFitOptions(rgb_iters=0), progress=False)
        np.savez(path, verts=res.mesh.verts, faces=res.mesh.faces)
    z = np.load(path)
    opts = dict(rgb_iters=5, rgb_silhouette=1.0, rgb_large_steps=1.0, rgb_weight=0.3)
    opts.update(options)
    c0 = time.process_time()
    res = fit_mesh_to_views(ds, options=ViewsFitOptions(
        init=Mesh(z["verts"], z["faces"]), silhouette_method="none", **opts), progress=False)
    cpu = time.process_time() - c0
    m = ViewsEvaluator(ds.held_out, target, n_samples=100_000, taus=(0.01,))(res.mesh,
                                                                             res.colors)
    row = dict(kind="stage", shape=name, options=options, iou=m["iou"],
               fscore=m["fscore@0.01"], psnr=m.get("psnr"), cpu=cpu, load=os.getloadavg()[0],
               stages=[(s["name"], s["status"], round(s["seconds"], 1)) for s in res.stages])
    print(json.dumps(row), flush=True)
    return row


def main(argv=None) -> int:
    sys.path.insert(0, str(HERE))
    from _harness import append_row, rows_parser

    ap = rows_parser(__doc__.split("\n")[0], ("scan", "stage"), ROWS)
    ap.add_argument("--cache", type=Path, default=Path("/tmp/fit_views_shade"))
    a = ap.parse_args(argv)
    a.cache.mkdir(parents=True, exist_ok=True)
    for name in a.shapes:  # shapes
        rows = scan(name) if a.mode == "scan" else [stage(name, json.loads(a.options), a.cache)]
        for r in rows:
            append_row(a.rows, {**r, "tag": a.tag})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
