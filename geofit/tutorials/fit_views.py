"""Step 4, fit_textured_mesh: :func:`geofit.fit.views.fit_mesh_to_views`, PyTorch3D's recipe
next to geofit's methods, and the stability cases."""
from __future__ import annotations


import numpy as np

from ..datasets import tutorial_views
from ..fit.views import ViewsEvaluator, ViewsFitOptions, fit_mesh_to_views
from ..io import save_obj
from ..shapes import ico_sphere
from ..structures import MultiViewDataset
from . import shared
from .shared import pick_size

__all__ = ["step_fit_views"]


# --------------------------------------------------------------------------------------------
# 4. fit a mesh to multi-view images
# --------------------------------------------------------------------------------------------


def _views_settings(size: str) -> dict:
    return {
        "num_views": pick_size(size, 4, 20, 20),
        "image_size": pick_size(size, 32, 64, 128),
        "num_heldout": pick_size(size, 2, 8, 16),
        # PyTorch3D's recipe (fit_textured_mesh): SGD on 2 random views, then the textured
        # stage from the sphere
        "tutorial": {"silhouette_method": "sgd", "textured_method": "sgd",
                     "textured_init": "sphere", "texture": "vertex",
                     "silhouette_iters": pick_size(size, 4, 150, 2000),
                     "textured_iters": pick_size(size, 4, 150, 2000)},
        # geofit's best (benchmarks/fit_views.py "best"): L-BFGS on all views, large steps,
        # coarse-to-fine; least-squares colours, then joint L-BFGS
        "geofit": {"silhouette_method": "lbfgs", "textured_method": "lbfgs",
                   "large_steps": 10.0, "texture": "vertex",
                   "levels": pick_size(size, [(0, 1)], [(0, 2), (1, 1)], [(0, 2), (1, 1)]),
                   "silhouette_iters": pick_size(size, 4, 60, 2000),
                   "textured_iters": pick_size(size, 4, 30, 200)},
        "init_level": pick_size(size, 2, 4, 4),
        "eval_every": pick_size(size, 10 ** 9, 20, 100),  # steps
    }


def step_fit_views(out, size: str = "default", *, progress: bool = True, seed: int = 0
                   ) -> shared.StepResult:
    """Fit a mesh and vertex colours to multi-view images: the tutorial's SGD and geofit's solvers.

    Sizes: ``"full"``: 20 views of 128 px, 2000 SGD steps per stage as the tutorial;
    ``"default"``: 20 views of 64 px, 150 SGD steps per stage. Progress: a progress bar over the
    stages; seed: random view choices of the SGD recipe. Writes into ``out/fit_views``; the
    signature and the StepResult are :func:`run_step`'s.
    """
    res, d, t0 = shared.begin_step(out, "fit_views", size)
    cfg = _views_settings(size)
    ds = tutorial_views(4, num_views=cfg["num_views"], image_size=cfg["image_size"],
                        num_held_out=cfg["num_heldout"])
    res.config = shared.views_config(ds.name, cfg["num_views"], cfg["num_heldout"],
                                     cfg["image_size"], cfg["tutorial"], cfg["geofit"])
    res.description = (
        "A sphere is deformed to match the soft silhouettes of the training views, then its "
        "vertex colours (and positions) are fitted to the RGB images. Accuracy on held-out "
        "views: silhouette IoU and RGB PSNR (hard renders), and chamfer-L2 / F-score at 0.01 "
        "against the true mesh. Times are solver times (the clock is paused at checkpoints).")
    ev = ViewsEvaluator(ds.held_out, ds.mesh, n_samples=pick_size(size, 2000, 10_000, 20_000),
                        taus=(0.01,))
    labels = {"tutorial": "PyTorch3D recipe: SGD, 2 random views per step",
              "geofit": "geofit: L-BFGS on all views, large steps, coarse-to-fine; "
                        "least-squares then L-BFGS colours"}

    def evaluate(mesh, colors):
        # the silhouette stage has no colours yet: score its shape in a uniform grey, so that
        # every checkpoint has the same metrics (PSNR then rises in the textured stage)
        if colors is None:
            colors = np.full((mesh.n_verts, 3), 0.5)
        return ev(mesh, colors)

    bar = shared.progress_bar(progress, len(labels), "fit_views")
    fits = {}
    for name, label in labels.items():  # methods
        kw = dict(cfg[name])
        kw["init"] = ico_sphere(cfg["init_level"] - (1 if len(kw.get("levels", ())) > 1
                                                     else 0))
        fit = fit_mesh_to_views(ds, options=ViewsFitOptions(**kw), evaluator=evaluate,
                                eval_every=cfg["eval_every"], seed=seed)
        kw.pop("init")
        fits[name] = fit
        final = ev(fit.mesh, fit.colors)
        n_colors = 0 if fit.colors is None else int(np.size(fit.colors))
        res.files[f"{name} mesh"] = d / f"{name}.obj"
        save_obj(res.files[f"{name} mesh"], fit.mesh)
        shared.record_fit(res, d, name, label, fit, ("iou", "chamfer_l2", "psnr"),
                          final={"seconds": fit.seconds, **final,
                                 "n_params": 3 * fit.mesh.n_verts + n_colors}, config=kw)
        cut = ""
        if name == "tutorial":
            full = _views_settings("full")["tutorial"]
            cut = shared.recipe_cut(kw["silhouette_iters"] + kw["textured_iters"],
                                    full["silhouette_iters"] + full["textured_iters"])
        res.metrics.append({"method": label + cut, "status": fit.status,
                            "seconds": round(fit.seconds, 2), **final})
        res.param_counts.append({"method": label, "vertices": fit.mesh.n_verts,
                                 "position parameters": 3 * fit.mesh.n_verts,
                                 "colour parameters": n_colors,
                                 "free parameters": 3 * fit.mesh.n_verts + n_colors})
        bar.update(1)
    bar.close()

    # held-out renders of each result next to the held-out targets
    h = ds.held_out
    k = min(3, len(h))
    renders = {name: fit.render(h, n_views=k) for name, fit in fits.items()}
    shared.heldout_comparison(res, d, h.images[:k], renders, fits,
                              f"Held-out views of the {ds.name} (never trained on) and the fitted "
                              "meshes rendered from them.")
    panels = [{"metric": "iou", "label": "held-out silhouette IoU"}]
    if any("chamfer_l2" in m["curve"] for m in res.methods):
        panels.append({"metric": "chamfer_l2", "label": "chamfer-L2 vs true mesh (log)",
                       "logy": True})
    return shared.close_comparison(
        res, d, t0, chart="held-out IoU and chamfer-L2", panels=panels,
        title=f"fit_mesh_to_views on the {ds.name} ({size} size)",
        stability=_views_stability(ds, size, seed),
        headline=lambda m, i: (f"IoU {m.get('iou', float('nan')):.3f}, PSNR "
                               f"{m.get('psnr', float('nan')):.1f} dB in {m['seconds']:.1f} s"
                               + (m["method"][len(labels["tutorial"]):] if i == 0 else "")))


def _views_stability(ds, size: str, seed: int) -> list[dict]:
    from ..fit.views import ViewsFitOptions, fit_mesh_to_views
    from ..shapes import ico_sphere

    tr = ds
    iters = pick_size(size, 2, 10, 40)
    nan_sil = tr.silhouettes.copy()
    nan_sil[0, 0, 0] = np.nan
    rng = np.random.default_rng(seed + 3)
    cases = {
        "one view only": lambda: MultiViewDataset(
            images=tr.images[:1], silhouettes=tr.silhouettes[:1],
            cameras=tr.cameras[[0]], lights=tr.lights),
        "empty silhouettes": lambda: MultiViewDataset(
            images=tr.images, silhouettes=np.zeros_like(tr.silhouettes),
            cameras=tr.cameras, lights=tr.lights),
        "noisy silhouettes (20% pixels flipped)": lambda: MultiViewDataset(
            images=tr.images, silhouettes=np.where(rng.random(tr.silhouettes.shape) < 0.2,
                                                   1.0 - tr.silhouettes, tr.silhouettes),
            cameras=tr.cameras, lights=tr.lights),
        "NaN in a silhouette": lambda: MultiViewDataset(
            images=tr.images, silhouettes=nan_sil, cameras=tr.cameras, lights=tr.lights),
    }
    rows = []
    for method, kw in (("tutorial", {"silhouette_method": "sgd",
                                     "textured_method": "none"}),
                       ("geofit", {"silhouette_method": "lbfgs", "textured_method": "none",
                                   "large_steps": 10.0})):
        for case, make in cases.items():  # failure cases
            def run(make=make, kw=kw):
                views = make()
                vps = min(2, len(views))
                return fit_mesh_to_views(views, options=ViewsFitOptions(
                    init=ico_sphere(2), silhouette_iters=iters, views_per_step=vps, **kw),
                    seed=seed)
            rows.append(shared.fit_row(method, case, run, lambda f: {
                "NaN vertices": bool(np.isnan(f.mesh.verts).any()),
                "seconds": round(f.seconds, 2)}))
    return rows
