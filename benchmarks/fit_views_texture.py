"""Issue 24 item 3: the UV texture against the vertex colours on held-out views, per shape.

The data of ``benchmarks/fit_views.py --shapes`` (each shape normalised and vertex-coloured, the
cow textured; 20 training and 16 held-out views of 128 px, lit as the dataset says). The
geometry is the default ``fit_mesh_to_views(train)``'s (run once with ``texture="vertex"``,
which stops before the texture stage, and saved to ``--geometry DIR`` as ``fit_<shape>.npz``;
a saved one is reused). On it the texture stage alone is solved: least squares
(``fit_texture(robust=None)``, the previous default) and Cauchy-robust (the default), and the
held-out PSNR of each is set beside the vertex colours'. ``--true`` also solves both on the
exact geometry. "outline share": the part of the squared error on pixels where the fitted and
true silhouettes disagree.

    GEOFIT_DATA=/work/shared/data python benchmarks/fit_views_texture.py --geometry /tmp/geo
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
from _harness import BenchmarkReport, markdown_table
from fit_views import shape_factories, vertex_coloured

from geofit.datasets import tutorial_views
from geofit.fit import render_mesh_at_views
from geofit.fit.texture import fit_texture
from geofit.fit.views import ViewsFitOptions, fit_mesh_to_views
from geofit.metrics import psnr
from geofit.report import load_average
from geofit.render import MeshRasterizer, RasterizationSettings
from geofit.structures import Mesh

TRUE_SHAPES = ("cow", "fandisk", "torus", "two_spheres", "double_torus")


def geometry(name, ds, folder: Path):
    """The default fit's geometry and vertex colours (saved / reused)."""
    path = folder / f"fit_{name}.npz"
    if not path.exists():
        t0 = time.perf_counter()
        fit = fit_mesh_to_views(ds, options=ViewsFitOptions(texture="vertex"), seed=0)
        np.savez(path, verts=fit.mesh.verts, faces=fit.mesh.faces, colors=fit.colors,
                 wall=time.perf_counter() - t0)
    z = np.load(path)
    return Mesh(z["verts"], z["faces"]), z["colors"]


def true_colours(mesh, ds):
    """The default's vertex colours (its textured stage's least squares) on ``mesh`` as it is."""
    opts = ViewsFitOptions(init=mesh, silhouette_method="none", texture="vertex")
    return fit_mesh_to_views(ds, options=opts, seed=0, progress=False).colors


def heldout(mesh, ds, colors=None) -> tuple[float, float]:
    """Held-out PSNR and the outline share of its squared error."""
    h = ds.held_out
    pred = render_mesh_at_views(mesh, h, colors)
    ras = MeshRasterizer(h.cameras, RasterizationSettings(image_size=h.image_size))
    dis = ras(Mesh(mesh.verts, mesh.faces)).mask.astype(bool) ^ (h.silhouettes > 0.5)
    e = ((pred - h.images) ** 2).sum(-1)
    return float(psnr(pred, h.images)), float(e[dis].sum() / max(e.sum(), 1e-300))


def solve(mesh, colors, ds, **kw):
    t0 = time.perf_counter()
    base = Mesh(mesh.verts, mesh.faces)
    tex = fit_texture(base, ds.cameras, ds.images, lights=ds.lights, background=ds.background,
                      prior=colors, **kw)
    return Mesh(base.verts, base.faces, tex), time.perf_counter() - t0


def row(name, label, mesh, colors, ds) -> dict:
    pv, sv = heldout(mesh, ds, colors)
    ls, t_ls = solve(mesh, colors, ds, robust=None)
    rob, t_rob = solve(mesh, colors, ds)
    pl, sl = heldout(ls, ds)
    pr, sr = heldout(rob, ds)
    return {"shape": name, "geometry": label, "n_verts": mesh.n_verts,
            "psnr_vertex": pv, "psnr_uv_lstsq": pl, "psnr_uv_robust": pr,
            "outline_share_vertex": sv, "outline_share_uv_lstsq": sl,
            "outline_share_uv_robust": sr, "seconds_lstsq": t_ls, "seconds_robust": t_rob,
            "texture_size": list(rob.textures.maps.shape[:2]), "load": os.getloadavg()[0]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shapes", default="all")
    ap.add_argument("--geometry", required=True, help="folder of the saved fitted geometries")
    ap.add_argument("--true", default=",".join(TRUE_SHAPES),
                    help="shapes also solved on the exact geometry ('' for none)")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results"))
    args = ap.parse_args(argv)
    names = None if args.shapes == "all" else args.shapes.split(",")
    true_shapes = [s for s in args.true.split(",") if s]
    folder = Path(args.geometry)
    folder.mkdir(parents=True, exist_ok=True)
    report = BenchmarkReport("fit_views_texture", config={
        "views": 20, "image_size": 128, "heldout_views": 16, "geometry": "the default "
        "fit_mesh_to_views(train) (texture='vertex'), seed 0",
        "uv_lstsq": "fit_texture(robust=None)", "uv_robust": "fit_texture(), the default (Cauchy, "
        "robust=2, robust_rounds=4, kept if a 2-fold leave-views-out check prefers it to least "
        "squares)"})
    rows = []
    for name, make in shape_factories(names).items():  # shapes
        target = vertex_coloured(make())
        ds = tutorial_views(4, mesh=target, num_views=20, image_size=128, num_held_out=16,
                            name=name)
        mesh, colors = geometry(name, ds, folder)
        rows.append(row(name, "fitted", mesh, colors, ds))
        print(rows[-1], flush=True)
        if name in true_shapes:
            true = Mesh(target.verts, target.faces)
            rows.append(row(name, "true", true, true_colours(true, ds), ds))
            print(rows[-1], flush=True)
        report.tables["rows"] = rows
        report.write(Path(args.out) / "fit_views_texture.json")
    table = markdown_table(
        ["shape", "geometry", "vertex colours", "UV least squares (before)",
         "UV default (robust, checked)", "outline share v / ls / robust", "s ls / robust (load)"],
        [[r["shape"], r["geometry"], f"{r['psnr_vertex']:.2f}", f"{r['psnr_uv_lstsq']:.2f}",
          f"{r['psnr_uv_robust']:.2f}",
          f"{r['outline_share_vertex']:.2f} / {r['outline_share_uv_lstsq']:.2f} / "
          f"{r['outline_share_uv_robust']:.2f}",
          f"{r['seconds_lstsq']:.1f} / {r['seconds_robust']:.1f} ({r['load']:.0f})"]
         for r in rows])
    print(table)
    print("load", load_average())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
