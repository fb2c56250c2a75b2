"""Bit-identity check of the four fits across the skeleton refactor (issue 23 item 2).

Runs each fit's default call and a few alternative recipes at reduced sizes, with iteration
limits (no binding time budget), and writes losses, array hashes and the quality figures to
JSON. ``python benchmarks/_skeleton_check.py OUT.json [CASE ...]``; compare two outputs with
``python benchmarks/_skeleton_check.py --compare A.json B.json``.
"""
from __future__ import annotations

import hashlib
import json
import sys

import numpy as np

from geofit.datasets import tutorial_views
from geofit.fit import fit_mesh, fit_mesh_to_views, fit_nerf, fit_volume
from geofit.shapes import ico_sphere, torus

import geofit.fit as _fit
from geofit.fit import NerfConfig

NEW = hasattr(_fit, "MeshFitOptions")  # the skeleton's options objects (absent on main)
NEW_VIEWS = hasattr(_fit, "ViewsFitOptions")
NEW_VOLUME = hasattr(_fit, "VolumeFitOptions")
NEW_NERF = "options" in __import__("inspect").signature(fit_nerf).parameters
if NEW:
    from geofit.fit import MeshFitOptions, Remeshing
if NEW_VIEWS:
    from geofit.fit import ViewsFitOptions
if NEW_VOLUME:
    from geofit.fit import VolumeFitOptions

BIG = 1e6  # a time budget that never binds


def _h(a) -> str:
    return hashlib.sha256(np.ascontiguousarray(np.asarray(a)).tobytes()).hexdigest()[:16]


def _hist(res) -> dict:
    a = res.history.as_arrays()
    return {"loss": [float(x) for x in a["loss"]], "n_rows": int(len(res.history)),
            "status": res.status, "n_iterations": int(res.n_iterations),
            "n_evaluations": int(res.n_evaluations)}


def _mesh_out(res) -> dict:
    d = _hist(res)
    d.update(verts=_h(res.mesh.verts), faces=_h(res.mesh.faces), n_verts=int(res.mesh.n_verts))
    if res.metrics is not None:
        d["metrics"] = {k: float(v) for k, v in res.metrics.as_dict().items()
                        if isinstance(v, (int, float))}
    return d


def _target(name):
    if name == "torus":
        return torus()
    from geofit.io import load_mesh
    return load_mesh("/work/shared/data/dolphin/dolphin.obj", load_textures=False)


def _torus_views():
    from geofit.structures import Mesh, TexturesVertex
    t = torus().scale_verts(0.8)
    col = 0.5 + 0.4 * np.tanh(t.verts)
    return tutorial_views(4, mesh=Mesh(t.verts, t.faces, TexturesVertex(col)), num_views=6,
                          image_size=40, num_held_out=3)


def mesh_cases():
    dol, tor = _target("dolphin"), _target("torus")
    pts = np.random.default_rng(0).normal(size=(3000, 3))
    pts = pts / np.linalg.norm(pts, axis=1, keepdims=True)
    if NEW:
        yield "mesh_default_dolphin", lambda: fit_mesh(dol, time_budget=BIG, progress=False)
        yield "mesh_default_torus", lambda: fit_mesh(tor, time_budget=BIG, progress=False)
        yield "mesh_default_cloud", lambda: fit_mesh(pts, time_budget=BIG, progress=False)
        yield "mesh_tutorial_dolphin", lambda: fit_mesh(
            dol, recipe="tutorial", options=MeshFitOptions(n_iter=60, n_samples=1000),
            progress=False)
        yield "mesh_lbfgs_torus", lambda: fit_mesh(
            tor, recipe="sphere", options=MeshFitOptions(init=2, n_iter=20, n_stages=2),
            progress=False)
        yield "mesh_c2f_dolphin", lambda: fit_mesh(
            dol, recipe="coarse-to-fine", options=MeshFitOptions(n_iter=15), progress=False)
        yield "mesh_adam_torus", lambda: fit_mesh(
            tor, recipe="sphere", options=MeshFitOptions(method="adam", init=2, n_iter=30,
                                                         n_samples=800), progress=False)
        yield "mesh_adaptive_sphere_dolphin", lambda: fit_mesh(
            dol, options=MeshFitOptions(init="sphere", refine=Remeshing(max_rounds=2),
                                        n_iter=10), time_budget=BIG, progress=False)
    else:
        yield "mesh_default_dolphin", lambda: fit_mesh(dol, time_budget=BIG, progress=False)
        yield "mesh_default_torus", lambda: fit_mesh(tor, time_budget=BIG, progress=False)
        yield "mesh_default_cloud", lambda: fit_mesh(pts, time_budget=BIG, progress=False)
        yield "mesh_tutorial_dolphin", lambda: fit_mesh(
            dol, recipe="tutorial", n_iter=60, n_samples=1000, progress=False)
        yield "mesh_lbfgs_torus", lambda: fit_mesh(
            tor, init=2, n_iter=20, n_stages=2, progress=False)
        yield "mesh_c2f_dolphin", lambda: fit_mesh(
            dol, recipe="coarse-to-fine", n_iter=15, progress=False)
        yield "mesh_adam_torus", lambda: fit_mesh(
            tor, method="adam", init=2, n_iter=30, n_samples=800, progress=False)
        from geofit.fit import fit_mesh_adaptive
        yield "mesh_adaptive_sphere_dolphin", lambda: fit_mesh_adaptive(
            dol, init="sphere", max_rounds=2, n_iter=10, time_budget=BIG)


def views_cases():
    ds = tutorial_views(4, num_views=6, image_size=40, num_held_out=3)
    tor = _torus_views()
    if NEW_VIEWS:
        yield "views_default_cow", lambda: fit_mesh_to_views(
            ds, options=ViewsFitOptions(silhouette_iters=15), progress=False)
        yield "views_default_torus", lambda: fit_mesh_to_views(
            tor, options=ViewsFitOptions(silhouette_iters=15), progress=False)
        yield "views_tutorial_cow", lambda: fit_mesh_to_views(
            ds, recipe="tutorial", options=ViewsFitOptions(
                init=ico_sphere(2), silhouette_iters=15, textured_iters=10), progress=False)
        yield "views_contour_cow", lambda: fit_mesh_to_views(
            ds, recipe="contour", options=ViewsFitOptions(init=ico_sphere(2),
                                                          silhouette_iters=15), progress=False)
    else:
        yield "views_default_cow", lambda: fit_mesh_to_views(ds, silhouette_iters=15,
                                                             progress=False)
        yield "views_default_torus", lambda: fit_mesh_to_views(tor, silhouette_iters=15,
                                                               progress=False)
        yield "views_tutorial_cow", lambda: fit_mesh_to_views(
            ds, recipe="tutorial", init=ico_sphere(2), silhouette_iters=15, textured_iters=10,
            progress=False)
        yield "views_contour_cow", lambda: fit_mesh_to_views(
            ds, recipe="contour", init=ico_sphere(2), silhouette_iters=15, progress=False)


def _views_out(res, ds):
    from geofit.fit.views import ViewsEvaluator
    d = _hist(res)
    d.update(verts=_h(res.mesh.verts), n_verts=int(res.mesh.n_verts),
             colors=None if res.colors is None else _h(res.colors))
    ev = ViewsEvaluator(ds.held_out)(res.mesh, res.colors)
    d["heldout"] = {k: float(v) for k, v in ev.items()}
    return d


def volume_cases():
    ds = tutorial_views(5, num_views=8, image_size=32, num_held_out=2)
    if NEW_VOLUME:
        yield "volume_default_cow", lambda: fit_volume(ds, options=VolumeFitOptions(
            volume_size=16, n_pts_per_ray=32, levels=(8, 16), iterations=(15, 15)),
            progress=False)
        yield "volume_tutorial_cow", lambda: fit_volume(ds, recipe="tutorial", options=(
            VolumeFitOptions(volume_size=16, n_pts_per_ray=32, n_iter=10)), progress=False)
        yield "volume_adam_cow", lambda: fit_volume(ds, options=VolumeFitOptions(
            method="adam", volume_size=16, n_pts_per_ray=32, levels=(8, 16),
            iterations=(10, 10)), progress=False)
    else:
        yield "volume_default_cow", lambda: fit_volume(
            ds, volume_size=16, n_pts_per_ray=32, levels=(8, 16), iterations=(15, 15),
            progress=False)
        yield "volume_tutorial_cow", lambda: fit_volume(
            ds, recipe="tutorial", volume_size=16, n_pts_per_ray=32, n_iter=10, progress=False)
        yield "volume_adam_cow", lambda: fit_volume(
            ds, method="adam", volume_size=16, n_pts_per_ray=32, levels=(8, 16),
            iterations=(10, 10), progress=False)


def _volume_out(res):
    d = _hist(res)
    d.update(densities=_h(res.volume.densities), features=_h(res.volume.features),
             n_active=int(res.n_active_voxels))
    return d


def _small_nerf(**kw):
    opts = {"n_harmonic_functions": 2, "n_hidden_neurons": 12, "n_hidden_color": 8,
            "n_harmonic_functions_dir": 1, "n_pts_per_ray": 32, "n_rays_per_image": 48,
            "batch_size": 4, "hull_resolution": 24, "n_iter": 30, "density_grid_warmup": 10,
            "density_grid_every": 10, "n_threads": 1, "lr": 2e-2, "silhouette_margin": 0}
    opts.update(kw)
    return NerfConfig.scene(**opts)


def nerf_cases():
    ds = tutorial_views(6, num_views=8, image_size=24, num_held_out=2)
    yield "nerf_scene_cow", lambda: fit_nerf(ds, config=_small_nerf(), progress=False) \
        if not NEW_NERF else fit_nerf(ds, options=_small_nerf(), progress=False)
    tut = NerfConfig.tutorial(n_harmonic_functions=2, n_hidden_neurons=12, n_hidden_color=8,
                              n_harmonic_functions_dir=1, n_pts_per_ray=16,
                              n_rays_per_image=32, batch_size=2, n_iter=10)
    yield "nerf_tutorial_cow", lambda: fit_nerf(ds, config=tut, progress=False) \
        if not NEW_NERF else fit_nerf(ds, options=tut, progress=False)


def _nerf_out(res):
    d = _hist(res)
    d["params"] = _h(res.field.get_flat())
    d["psnr"] = None if res.psnr is None else float(res.psnr)
    d["images"] = None if res.images is None else _h(res.images)
    return d


def run(out_path, only=()):
    out = {}
    groups = [(mesh_cases, _mesh_out, None), (views_cases, _views_out, "views"),
              (volume_cases, _volume_out, None), (nerf_cases, _nerf_out, None)]
    for cases, fmt, kind in groups:
        if only and not any(o in cases.__name__ for o in only):
            continue
        ds4 = tutorial_views(4, num_views=6, image_size=40, num_held_out=3) if kind else None
        tor4 = _torus_views() if kind else None
        for name, call in cases():
            res = call()
            if kind:
                out[name] = fmt(res, tor4 if "torus" in name else ds4)
            else:
                out[name] = fmt(res)
            print(name, out[name]["status"], out[name]["loss"][-1] if out[name]["loss"] else None,
                  flush=True)
            with open(out_path, "w") as f:
                json.dump(out, f, indent=1)


def compare(a, b):
    A, B = json.load(open(a)), json.load(open(b))
    ok = True
    for k in A:
        if k not in B:
            print(f"{k}: missing in {b}")
            ok = False
            continue
        same = A[k] == B[k]
        ok &= same
        print(f"{k}: {'identical' if same else 'DIFFERENT'}")
        if not same:
            for f in A[k]:
                if A[k][f] != B[k].get(f):
                    print(f"   {f}: {str(A[k][f])[:80]} -> {str(B[k].get(f))[:80]}")
    return ok


if __name__ == "__main__":
    if sys.argv[1] == "--compare":
        sys.exit(0 if compare(sys.argv[2], sys.argv[3]) else 1)
    run(sys.argv[1], sys.argv[2:])
