"""One vocabulary for the four fits: method and recipe names, option presets, checks.

Methods name the solver (:data:`METHODS`); recipes name complete settings (:data:`RECIPE_NAMES`):
each fit's ``RECIPES`` maps a name to a preset of its options object (a frozen dataclass:
:class:`~geofit.fit.MeshFitOptions`, :class:`~geofit.fit.ViewsFitOptions`,
:class:`~geofit.fit.VolumeFitOptions`, :class:`~geofit.fit.NerfConfig`), and
:func:`merge_options` lays the user's options over the preset.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import replace

import numpy as np

from .._validate import check_int, check_positive  # the one integer check, re-exported
from ..structures import MultiViewDataset

__all__ = ["METHODS", "RECIPE_NAMES", "as_dataset", "check_int", "check_weights",
           "merge_options", "recipe_name"]

#: Every method (solver) name a geofit fit accepts, and what it is.
METHODS: dict[str, str] = {
    "lbfgs": "scipy's L-BFGS-B over all the data (deterministic objective)",
    "lbfgs-nlopt": "nlopt's LD_LBFGS over all the data (deterministic objective)",
    "adam": "Adam (geofit.fit.solvers.adam or geofit.nn.optim.Adam)",
    "sgd": "SGD with momentum (PyTorch3D's tutorials 1 and 4)",
    "lstsq": "one sparse linear least-squares solve (vertex colours of fit_mesh_to_views)",
}

#: Recipe names shared by the fits (each fit accepts those of its own ``RECIPES``).
RECIPE_NAMES: dict[str, str] = {
    "default": "geofit's own settings for the workflow (its best)",
    "tutorial": "PyTorch3D's tutorial recipe, exactly",
    "sphere": "fit_mesh: L-BFGS with large steps from the tutorial's ico-sphere",
    "coarse-to-fine": "fit_mesh: L-BFGS, large steps, ico-sphere 2 -> 3 -> 4 as needed",
    "sphere-lbfgs": "fit_mesh_to_views: L-BFGS on all views from the ico-sphere",
    "contour": "fit_mesh_to_views: hard-silhouette contour gradients with Adam",
}


def recipe_name(recipe, recipes: Mapping, *, fit: str) -> str:
    """Check ``recipe`` against a fit's ``RECIPES``."""
    if not isinstance(recipe, str) or recipe not in recipes:
        raise ValueError(f"recipe: expected one of {tuple(recipes)} for {fit}, got {recipe!r}")
    return recipe


def merge_options(preset, options, cls, name: str = "options"):
    """The options of a fit: the recipe's ``preset`` with every field that ``options`` sets
    (not None) replaced by the user's value. ``options`` is None or an instance of ``cls``."""
    if options is None:
        return preset
    if not isinstance(options, cls):
        raise TypeError(f"{name}: expected a {cls.__name__} or None, got {type(options)!r}")
    changes = {f.name: getattr(options, f.name) for f in dataclasses.fields(cls)
               if getattr(options, f.name) is not None}
    return dataclasses.replace(preset, **changes)


def as_dataset(dataset, *, fit: str, images_required: bool = True,
               silhouettes: str = "required") -> MultiViewDataset:
    """The training views of a multi-view fit, checked once at the door.

    ``silhouettes="required"`` refuses a dataset whose silhouettes are unknown (a capture
    without masks; the message says how to make them); ``"full"`` fits without them: unknown
    silhouettes (of the views and of ``held_out``) become ones, every pixel shows the scene.
    """
    if not isinstance(dataset, MultiViewDataset):
        raise TypeError(f"dataset: expected a geofit.structures.MultiViewDataset, got "
                        f"{type(dataset)!r}")
    if images_required and dataset.images is None:
        raise ValueError(f"dataset: {fit} needs RGB images (dataset.images is None)")
    if silhouettes == "required":
        dataset.require_silhouettes(fit)
        return dataset
    held = dataset.held_out
    if held is not None and held.silhouettes is None and held.images is not None:
        held = replace(held, silhouettes=np.ones(held.images.shape[:3]))
    sil = dataset.silhouettes
    if sil is None:
        sil = np.ones(dataset.images.shape[:3])
    if sil is dataset.silhouettes and held is dataset.held_out:
        return dataset
    return replace(dataset, silhouettes=sil, held_out=held)


def check_weights(weights, defaults: Mapping[str, float], name: str, *,
                  required: str | None = None) -> dict[str, float]:
    """Term weights: ``defaults`` updated by ``weights`` (None: the defaults), every value a
    number >= 0 and every name one of ``defaults``; ``required`` must weigh more than 0."""
    if weights is None:
        out = dict(defaults)
    elif not isinstance(weights, Mapping):
        raise TypeError(f"{name}: expected a dict of term weights, got {type(weights)!r}")
    else:
        unknown = set(weights) - set(defaults)
        if unknown:
            raise ValueError(f"{name}: unknown terms {sorted(unknown)}; expected some of "
                             f"{tuple(defaults)}")
        out = dict(defaults)
        for k, v in weights.items():
            out[k] = check_positive(v, f"{name}[{k!r}]", strict=False)
    if required is not None and not out[required] > 0.0:
        raise ValueError(f"{name}: the data term {required!r} needs a weight > 0")
    return out
