"""Step 6, fit_simple_neural_radiance_field: :func:`geofit.fit.nerf.fit_nerf`, the tutorial's
preset next to geofit's, and the stability cases."""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from .._atomic import atomic_write
from ..fit.nerf import RECIPES, fit_nerf, render_nerf
from . import shared
from .shared import pick_size

__all__ = ["step_nerf"]


# --------------------------------------------------------------------------------------------
# 6. fit a neural radiance field
# --------------------------------------------------------------------------------------------


def _nerf_settings(size: str) -> dict:
    budget = pick_size(size, None, 20.0, None)
    scene = {"recipe": "default", "n_iter": pick_size(size, 2, 20000, 20000),
             "n_pts_per_ray": pick_size(size, 8, 64, 128)}
    if size == "tiny":
        scene.update(n_rays_per_image=32, hull_resolution=24)
    return {
        "n_views": pick_size(size, 4, 20, 40), "image_size": pick_size(size, 24, 64, 128),
        "n_heldout": pick_size(size, 1, 2, 8), "heldout_size": pick_size(size, 24, 32, 128),
        "tutorial": {"recipe": "tutorial", "n_iter": pick_size(size, 2, 3000, 3000),
                     "n_rays_per_image": pick_size(size, 32, 128, 750),
                     "n_pts_per_ray": pick_size(size, 8, 64, 128)},
        "scene": scene,
        "time_budget": budget,
        "eval_every": pick_size(size, 2, None, None),  # steps (None: 1/20 of the run)
    }


def step_nerf(out, size: str = "default", *, progress: bool = True, seed: int = 0
              ) -> shared.StepResult:
    """Fit a neural radiance field: the tutorial's network and recipe, and geofit's scene-sized one.

    Sizes: ``"full"``: 40 views of 128 px, 3000 steps of the tutorial's recipe; ``"default"``:
    20 views of 64 px, 64 samples per ray (the tutorial recipe with 128 rays per view instead of
    750), each method stopped after 20 s of solver time, PSNR on held-out renders of 32 px.
    Progress: a progress bar over the fits; seed: initialisation, view and ray choices. Writes
    into ``out/nerf``; the signature and the StepResult are :func:`run_step`'s.
    """
    res, d, t0 = shared.begin_step(out, "nerf", size)
    cfg = _nerf_settings(size)
    full_iters = _nerf_settings("full")["tutorial"]["n_iter"]  # the tutorial's own run length
    img = cfg["image_size"]
    train, test, name = shared.cow_views(cfg["n_views"], img, cfg["n_heldout"], cfg["heldout_size"])
    res.config = shared.views_config(
        name, cfg["n_views"], cfg["n_heldout"], img, cfg["tutorial"], cfg["scene"],
        **{"held-out image size": cfg["heldout_size"],
           "time budget per method (s)": cfg["time_budget"]})
    res.description = (
        "A radiance field (MLP on harmonic embeddings) is fitted to the renders with the "
        "emission-absorption raymarcher. Accuracy: PSNR of full renders of held-out views "
        "(azimuths half-way between the training views, elevations 0 and 20 degrees). Model "
        "size: the network's weights.")
    labels = {"tutorial": "PyTorch3D recipe: 60 frequencies, 2 x 256 Softplus, MC rays",
              "scene": "geofit: scene-sized network, visual hull, density grid"}
    bar = shared.progress_bar(progress, len(labels), "nerf")
    fits = {}
    for key, label in labels.items():  # methods
        kw = dict(cfg[key])
        recipe = kw.pop("recipe")
        fit = fit_nerf(train, recipe=recipe, options=replace(RECIPES[recipe], **kw),
                       evaluator=test, time_budget=cfg["time_budget"],
                       eval_every=cfg["eval_every"], seed=seed)
        kw["recipe"] = recipe
        fits[key] = fit
        shared.record_fit(res, d, key, label, fit, ("psnr",),
                          final={"seconds": fit.seconds, "psnr": fit.psnr,
                                 "n_params": fit.n_params},
                          config={k: repr(v) for k, v in kw.items()})
        atomic_write(d / f"{key}_weights.npz",
                     lambda p: np.savez_compressed(p, **fit.field.params))
        res.files[f"{key} weights"] = d / f"{key}_weights.npz"
        cut = shared.recipe_cut(fit.n_iterations, full_iters) if key == "tutorial" else ""
        res.metrics.append({"method": label + cut, "status": fit.status,
                            "seconds": round(fit.seconds, 2), "iterations": fit.n_iterations,
                            "held-out PSNR (dB)": fit.psnr,
                            "samples per ray": round(fit.samples_per_ray, 1)})
        res.param_counts.append({"method": label, "network parameters": fit.n_params})
        bar.update(1)
    bar.close()
    renders = {}
    for key, fit in fits.items():
        renders[key] = fit.images if fit.images is not None else render_nerf(
            fit.field, test.cameras, cfg["heldout_size"], n_pts_per_ray=fit.config.n_pts_per_ray,
            occupancy=fit.occupancy)
    return shared.close_psnr_step(
        res, d, t0, test.images[:3], renders, fits, subject=name, fitted="fields",
        full_iters=full_iters, params="network parameters", chart="held-out PSNR",
        panels=[{"metric": "psnr", "label": "held-out PSNR (dB)"}],
        title=f"fit_nerf on the {name} ({size} size)", stability=_nerf_stability(train, size, seed))


def _nerf_stability(train, size: str, seed: int) -> list[dict]:
    from ..fit.nerf import RECIPES, fit_nerf

    n_iter = pick_size(size, 2, 4, 50)
    cases = {case: (*arrays, {}) for case, arrays in shared.broken_views(train).items()}
    cases["learning rate x1000"] = (train.images, train.silhouettes, train.cameras,
                                    {"lr_x": 1000.0})
    rows = []
    for method in ("tutorial", "scene"):
        for case, (i_, s_, c_, extra) in cases.items():  # failure cases
            kw = {"recipe": "default" if method == "scene" else method, "n_iter": n_iter,
                  "n_pts_per_ray": 16,
                  "n_rays_per_image": 64}
            if "lr_x" in extra:
                kw["lr"] = (1e-3 if method == "tutorial" else 5e-3) * extra["lr_x"]
            recipe = kw.pop("recipe")
            rows.append(shared.fit_row(method, case, lambda: fit_nerf(
                shared.stability_views(i_, s_, c_), recipe=recipe, seed=seed,
                options=replace(RECIPES[recipe], **kw)), lambda f: {
                "NaN weights": bool(np.isnan(f.field.get_flat()).any()),
                "seconds": round(f.seconds, 2)}))
    return rows
