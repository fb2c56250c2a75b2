"""The RGB stage of ``fit_mesh_to_views`` (issue 24 items 1-2): variants against the default.

For each shape of ``benchmarks/fit_views.py --shapes`` (normalised, vertex-coloured, the cow
textured; the tutorial's 20 views of 128 px, 16 held-out views) the default fit runs once
(``before``: held-out IoU, F@0.01 with 100 000 samples a side, PSNR of its UV texture and of
its vertex colours). Every variant then continues from that fit's silhouette-stage mesh (the
stages before the RGB stage are deterministic and the same): ``fit_mesh_to_views`` with
``init=`` that mesh, ``silhouette_method="none"`` and the variant's options runs the RGB stage,
then the default's colour and UV-texture stages, scored alike (the regularisers' pixel size is
then taken at the given mesh's centre, not from the visual hull). No time budget, so the
figures do not depend on the load (the seconds do).

Rows are appended to ``--cache``/rows.jsonl (with the silhouette meshes kept there), so a
shared machine's run can be resumed; the JSON and the markdown table are written from all rows
of the cache.

    GEOFIT_DATA=/work/shared/data python benchmarks/fit_views_rgb.py --shapes cow,fandisk \\
        --variants '{"sil1": {"rgb_iters": 10, "rgb_silhouette": 1, "rgb_large_steps": 1}}'
"""
from __future__ import annotations

import argparse
import json
import os
import pickle
import time
from pathlib import Path

from _harness import BenchmarkReport
from fit_views import shape_factories, vertex_coloured

from geofit.datasets import tutorial_views
from geofit.fit.views import ViewsEvaluator, ViewsFitOptions, fit_mesh_to_views
from geofit.structures import Mesh


def _data(shape: str):
    target = vertex_coloured(shape_factories([shape])[shape]())
    ds = tutorial_views(4, mesh=target, num_views=20, image_size=128, num_held_out=16,
                        name=shape)
    return ds, ViewsEvaluator(ds.held_out, target, n_samples=100_000, taus=(0.01,))


def _before(shape: str, ds, ev, cache: Path) -> dict:
    """The default fit (cached: its silhouette mesh and its row)."""
    path = cache / f"{shape}.pkl"
    if path.exists():
        return pickle.loads(path.read_bytes())
    t0, load = time.time(), os.getloadavg()[0]
    r = fit_mesh_to_views(ds, progress=False)
    m, mv = ev(r.mesh), ev(r.mesh, r.colors, surface=False)
    row = dict(shape=shape, iou=m["iou"], f=m["fscore@0.01"], psnr_uv=m["psnr"],
               psnr_v=mv["psnr"], sec=time.time() - t0, load=load, cpu=r.cpu_seconds,
               fit_wall=r.seconds, stages={st["name"]: round(st["seconds"], 1)
                                           for st in r.stages})
    out = dict(sil=(r.silhouette_mesh.verts, r.silhouette_mesh.faces), row=row)
    path.write_bytes(pickle.dumps(out))
    return out


def _variant(shape: str, ds, ev, sil: Mesh, opts: dict) -> dict:
    """The RGB stage (``opts``) and the default's colour and texture stages from ``sil`` (the
    public call with ``init=sil, silhouette_method="none"``)."""
    load = os.getloadavg()[0]
    r = fit_mesh_to_views(ds, options=ViewsFitOptions(init=sil, silhouette_method="none",
                                                      **opts), progress=False)
    rgb = next(st for st in r.stages if st["name"] == "rgb")
    m, mv = ev(r.mesh), ev(r.mesh, r.colors, surface=False)
    return dict(iou=round(m["iou"], 4), f=round(m["fscore@0.01"], 3),
                psnr_uv=round(m["psnr"], 2), psnr_v=round(mv["psnr"], 2),
                rgb_wall=round(rgb["seconds"], 1), rgb_cpu=None, load=round(load, 1))


def _full(shape: str, ds, ev, opts: dict) -> dict:
    """The public call from scratch: ``fit_mesh_to_views(ds, options=ViewsFitOptions(**opts))``
    (the whole default with the variant's options: hull, silhouette stage, RGB stage, colours,
    UV texture)."""
    load = os.getloadavg()[0]
    r = fit_mesh_to_views(ds, options=ViewsFitOptions(**opts), progress=False)
    st = {s_["name"]: round(s_["seconds"], 1) for s_ in r.stages}
    m, mv = ev(r.mesh), ev(r.mesh, r.colors, surface=False)
    return dict(iou=round(m["iou"], 4), f=round(m["fscore@0.01"], 3),
                psnr_uv=round(m["psnr"], 2), psnr_v=round(mv["psnr"], 2),
                rgb_wall=st.get("rgb", 0.0), rgb_cpu=None, fit_wall=round(r.seconds, 1),
                cpu=round(r.cpu_seconds, 1), stages=st, load=round(load, 1),
                load_end=round(os.getloadavg()[0], 1))


def _full_cached(shape: str, ds, ev, opts: dict, sil: Mesh) -> dict:
    """:func:`_full` with the silhouette stage's result taken from the default's cached fit.

    The public call ``fit_mesh_to_views(ds, options=ViewsFitOptions(**opts))`` runs as it is
    (the visual hull and the plan it gives, the RGB stage, the colours, the UV texture), except
    that the silhouette stage returns the silhouette mesh of the default's fit of the same data
    (the fit is deterministic without a time budget, and the options change nothing before the
    RGB stage; checked on the cow against the call from scratch). On a machine shared at load
    30-45 this saves ~70 % of every row. The RGB stage's CPU seconds are measured around it."""
    from geofit.fit import views as fv

    real_sil, real_rgb = fv._silhouette_stage, fv._rgb_stage
    cpu = {}

    def cached(plan, run):
        run.stages.append({"name": "silhouette", "method": plan.silhouette_method,
                           "status": "max_iter", "seconds": 0.0,
                           "message": "the default's silhouette stage (cached)"})
        return Mesh(sil.verts.copy(), sil.faces.copy())

    def timed(plan, run, mesh):
        c0 = time.process_time()
        out = real_rgb(plan, run, mesh)
        cpu["rgb"] = time.process_time() - c0
        return out

    fv._silhouette_stage, fv._rgb_stage = cached, timed
    try:
        row = _full(shape, ds, ev, opts)
    finally:
        fv._silhouette_stage, fv._rgb_stage = real_sil, real_rgb
    row.update(rgb_cpu=round(cpu.get("rgb", 0.0), 1), cached_silhouette=True)
    return row


def markdown(rows: list) -> str:
    """One line per shape and variant: before -> after."""
    lines = ["| shape | variant | IoU before -> after | F@0.01 before -> after | "
             "PSNR UV (dB) before -> after | PSNR vertex (dB) before -> after | "
             "RGB stage s wall / CPU (load) |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        b = r["base"]
        lines.append(f"| {r['shape']} | {r['tag']} | {b['iou']:.4f} -> {r['iou']:.4f} | "
                     f"{b['f']:.3f} -> {r['f']:.3f} | {b['psnr_uv']:.2f} -> {r['psnr_uv']:.2f} | "
                     f"{b['psnr_v']:.2f} -> {r['psnr_v']:.2f} | {r['rgb_wall']:.0f} / "
                     f"{r['rgb_cpu'] if r['rgb_cpu'] is not None else '-'} ({r['load']:.0f}) |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--shapes", default="cow,fandisk,suzanne,thin_plate",
                    help="comma-separated, or 'all' (the 11 of fit_views.py --shapes all)")
    ap.add_argument("--before-only", action="store_true",
                    help="run (and cache) the default fits only")
    ap.add_argument("--cached-silhouette", action="store_true",
                    help="with --full: the silhouette stage's result from the default's cached "
                         "fit (see _full_cached); waits for it if another process runs it")
    ap.add_argument("--after-only", action="store_true",
                    help="with --full: run the variants only (the default's rows are joined "
                         "from the cache when the report is written; another process may be "
                         "running them)")
    ap.add_argument("--variants", default='{"sil1": {"rgb_iters": 10, "rgb_silhouette": 1, '
                                          '"rgb_large_steps": 1}}')
    ap.add_argument("--cache", default=str(Path(os.environ.get("TMPDIR", "/tmp"))
                                           / "fit_views_rgb"))
    ap.add_argument("--full", action="store_true",
                    help="each variant is the whole public call from scratch "
                         "(fit_mesh_to_views(ds, options=ViewsFitOptions(**variant))), not a "
                         "continuation from the default's silhouette mesh")
    ap.add_argument("--report-only", action="store_true",
                    help="write the JSON and table from the cache's rows, fit nothing")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results"))
    ap.add_argument("--name", default="fit_views_rgbstage")
    ap.add_argument("--notes", help="a JSON file of notes (a list) to keep in the report, "
                                    "e.g. rows of a diagnosis run")
    args = ap.parse_args(argv)
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    rows_path = cache / "rows.jsonl"
    variants = json.loads(args.variants)
    shapes = (list(shape_factories()) if args.shapes == "all" else args.shapes.split(","))
    report = BenchmarkReport(args.name, config={
        "shapes": shapes, "variants": variants, "views": 20, "image_size": 128,
        "heldout_views": 16, "fscore_samples": 100_000, "time_budget": None,
        "full": args.full})
    if not args.report_only:
        for shape in shapes:  # shapes
            ds, ev = _data(shape)
            if args.cached_silhouette and args.full:
                while not (cache / f"{shape}.pkl").exists():  # the default's fit, elsewhere
                    time.sleep(20)
                time.sleep(2)
                c = pickle.loads((cache / f"{shape}.pkl").read_bytes())
            elif args.after_only and args.full:
                c = {"row": None}
            else:
                c = _before(shape, ds, ev, cache)
                print(shape, "before", json.dumps(c["row"]), flush=True)
            if args.before_only:
                continue
            for tag, opts in variants.items():  # variants
                if args.full and args.cached_silhouette:
                    run = _full_cached(shape, ds, ev, opts, Mesh(*c["sil"]))
                elif args.full:
                    run = _full(shape, ds, ev, opts)
                else:
                    run = _variant(shape, ds, ev, Mesh(*c["sil"]), opts)
                row = dict(shape=shape, tag=tag, opts=opts, base=c["row"], full=args.full,
                           **run)
                print(json.dumps(row), flush=True)
                with open(rows_path, "a", encoding="utf-8") as fh:
                    fh.write(json.dumps(row) + "\n")
    rows = [json.loads(x) for x in rows_path.read_text().splitlines() if x.strip()]
    for r in rows:  # rows run with --after-only: the default's row from the cache
        if r.get("base") is None and (cache / f"{r['shape']}.pkl").exists():
            r["base"] = pickle.loads((cache / f"{r['shape']}.pkl").read_bytes())["row"]
    rows = [r for r in rows if r.get("base") is not None]
    report.tables["rows"] = rows
    if args.notes:
        report.notes.extend(json.loads(Path(args.notes).read_text()))
    out = Path(args.out)
    report.write(out / f"{args.name}.json")
    (out / f"{args.name}_table.md").write_text(markdown(rows), encoding="utf-8")
    print(markdown(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
