"""Step 5, fit_textured_volume: :func:`geofit.fit.volume.fit_volume`, PyTorch3D's recipe
next to geofit's method, and the stability cases."""
from __future__ import annotations


import numpy as np

from .._atomic import atomic_write
from ..fit.volume import VolumeFitOptions, fit_volume
from ..metrics import psnr
from . import shared
from .shared import pick_size

__all__ = ["step_fit_volume"]


# --------------------------------------------------------------------------------------------
# 5. fit a voxel volume
# --------------------------------------------------------------------------------------------


def _volume_settings(size: str) -> dict:
    budget = pick_size(size, None, 30.0, None)
    return {
        "n_views": pick_size(size, 6, 20, 40), "image_size": pick_size(size, 32, 64, 128),
        "n_heldout": pick_size(size, 2, 4, 8), "volume_size": pick_size(size, 16, 64, 128),
        "n_pts_per_ray": pick_size(size, 32, 75, 150),
        "tutorial": {"recipe": "tutorial", "n_iter": pick_size(size, 4, 300, 300),
                     "batch_size": pick_size(size, 2, 10, 10), "time_budget": budget},
        "lbfgs": {"method": "lbfgs", "levels": pick_size(size, (8, 16), (32, 64), (32, 64, 128)),
                  "iterations": pick_size(size, (4, 4), (60, 40), None), "time_budget": budget},
        "eval_every": pick_size(size, None, 10, 30),  # steps
    }


def step_fit_volume(out, size: str = "default", *, progress: bool = True, seed: int = 0
                    ) -> shared.StepResult:
    """Fit a voxel volume to posed renders: the tutorial's dense Adam and geofit's sparse L-BFGS.

    Sizes: ``"full"``: 40 views of 128 px, a 128^3 grid, 150 samples per ray, 300 Adam steps as
    the tutorial; ``"default"``: 20 views of 64 px, 64^3, 75 samples, each method stopped after
    30 s of solver time. Progress: a progress bar over the fits; seed: the tutorial recipe's
    random view batches. Writes into ``out/fit_volume``; the signature and the StepResult are
    :func:`run_step`'s.
    """
    res, d, t0 = shared.begin_step(out, "fit_volume", size)
    cfg = _volume_settings(size)
    full_iters = _volume_settings("full")["tutorial"]["n_iter"]  # the tutorial's own run length
    S, n_pts, img = cfg["volume_size"], cfg["n_pts_per_ray"], cfg["image_size"]
    train, test, name = shared.cow_views(cfg["n_views"], img, cfg["n_heldout"], img)
    res.config = shared.views_config(name, cfg["n_views"], cfg["n_heldout"], img, cfg["tutorial"],
                                     cfg["lbfgs"], grid=f"{S}^3", **{"samples per ray": n_pts})
    res.description = (
        "A grid of densities and colours is fitted to the renders (black background) with "
        "the emission-absorption raymarcher. Accuracy: PSNR of the RGB and IoU of the "
        "silhouette on held-out views (azimuths half-way between the training views, elevations "
        "0 and 20 degrees). "
        "Model size: the densities and colours the solver optimises.")
    labels = {"tutorial": "PyTorch3D recipe: dense grid, Adam, 10 random views per step",
              "lbfgs": "geofit: visual hull, coarse-to-fine, pruning, L-BFGS on all rays"}

    def monitor(volume):
        out_ = shared.render_volume_views(volume, test.cameras, img, n_pts)
        return {"psnr": float(psnr(out_[..., :3], test.images)),
                "iou": float(np.mean([shared.mask_iou(out_[i, ..., 3], test.silhouettes[i])
                                      for i in range(len(test.images))]))}

    bar = shared.progress_bar(progress, len(labels), "fit_volume")
    fits, renders = {}, {}
    for key, label in labels.items():  # methods
        kw = dict(cfg[key])
        recipe, budget = kw.pop("recipe", "default"), kw.pop("time_budget")
        fit = fit_volume(train, recipe=recipe, options=VolumeFitOptions(
            volume_size=S, n_pts_per_ray=n_pts, **kw), time_budget=budget, seed=seed,
            evaluator=monitor, eval_every=cfg["eval_every"])
        fits[key] = fit
        renders[key] = shared.render_volume_views(fit.volume, test.cameras, img, n_pts)
        final = monitor(fit.volume)
        shared.record_fit(res, d, key, label, fit, ("psnr", "iou"),
                          final={"seconds": fit.seconds, **final, "n_params": fit.n_params},
                          config={k: repr(v) for k, v in kw.items()})
        vol = fit.volume
        atomic_write(d / f"{key}_volume.npz", lambda p: np.savez_compressed(
            p, densities=vol.densities, features=vol.features, voxel_size=vol.voxel_size,
            volume_translation=vol.volume_translation))
        res.files[f"{key} volume"] = d / f"{key}_volume.npz"
        cut = shared.recipe_cut(fit.n_iterations, full_iters) if key == "tutorial" else ""
        res.metrics.append({"method": label + cut, "status": fit.status,
                            "seconds": round(fit.seconds, 2), "held-out PSNR (dB)": final["psnr"],
                            "held-out IoU": final["iou"],
                            "samples per ray": round(fit.samples_per_ray, 1)})
        res.param_counts.append({"method": label, "grid": f"{S}^3",
                                 "dense grid values": 4 * S ** 3,
                                 "optimised densities": fit.n_active_voxels,
                                 "optimised colours": 3 * fit.n_colour_voxels,
                                 "free parameters": fit.n_params})
        bar.update(1)
    bar.close()
    return shared.close_psnr_step(
        res, d, t0, test.images[:3], renders, fits, subject=name, fitted="volumes",
        full_iters=full_iters, params="free parameters", chart="held-out PSNR and IoU",
        panels=[{"metric": "psnr", "label": "held-out PSNR (dB)"},
                {"metric": "iou", "label": "held-out silhouette IoU"}],
        title=f"fit_volume on the {name} ({size} size)",
        stability=_volume_stability(train, S, n_pts, size, seed))


def _volume_stability(train, S: int, n_pts: int, size: str, seed: int) -> list[dict]:
    from ..fit.volume import VolumeFitOptions, fit_volume

    small = max(8, S // 4)
    cases = shared.broken_views(train)
    cases["silhouettes of the wrong size"] = (train.images, train.silhouettes[:, :-1],
                                              train.cameras)
    rows = []
    for method, kw in (("tutorial", {"recipe": "tutorial", "n_iter": pick_size(size, 2, 10, 30),
                                     "batch_size": 1}),
                       ("lbfgs", {"method": "lbfgs", "levels": (small,),
                                  "iterations": pick_size(size, 2, 10, 30)})):
        for case, (i_, s_, c_) in cases.items():  # failure cases
            opts = {k: v for k, v in kw.items() if k != "recipe"}
            rows.append(shared.fit_row(method, case, lambda: fit_volume(
                shared.stability_views(i_, s_, c_), recipe=kw.get("recipe", "default"), seed=seed,
                options=VolumeFitOptions(volume_size=small, n_pts_per_ray=max(16, n_pts // 4),
                                         **opts)), lambda f: {
                "NaN in volume": bool(np.isnan(f.volume.densities).any()),
                "occupied voxels": int(f.n_occupied_voxels),
                "seconds": round(f.seconds, 2)}))
    return rows
