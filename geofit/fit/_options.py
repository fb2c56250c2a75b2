"""One vocabulary for the four fits: method names, recipes, deprecated spellings, checks.

Methods name the solver (:data:`METHODS`); recipes name complete settings (:data:`RECIPE_NAMES`),
e.g. ``"tutorial"`` is PyTorch3D's recipe of each tutorial and never a method. The spellings of
the previous release (``"scipy-lbfgs"``, ``"nlopt-lbfgs"``, ``method="tutorial"``,
``preset=...``) are translated here with a :class:`DeprecationWarning`.
"""
from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Mapping

import numpy as np

from .._validate import check_int  # the one integer check, re-exported for the fits

__all__ = ["METHODS", "RECIPE_NAMES", "Recipes", "check_int", "check_weights", "dataset_argument", "merge_options",
           "method_name", "recipe_name", "warn_deprecated"]

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
    "default": "geofit's own settings for the workflow",
    "tutorial": "PyTorch3D's tutorial recipe, exactly",
    "coarse-to-fine": "fit_mesh: L-BFGS, large steps, ico-sphere 2 -> 3 -> 4 as needed",
    "contour": "fit_mesh_to_views: hard-silhouette contour gradients with Adam",
}

#: Former method spellings -> the current ones.
_OLD_METHODS = {"scipy-lbfgs": "lbfgs", "nlopt-lbfgs": "lbfgs-nlopt"}


def warn_deprecated(old: str, new: str, stacklevel: int = 3) -> None:
    """Emit the DeprecationWarning of a renamed call form (removed in the next release)."""
    warnings.warn(f"{old} is deprecated and will be removed in the next release; use {new}",
                  DeprecationWarning, stacklevel=stacklevel)


def method_name(method, name: str, allowed, *, fit: str, stacklevel: int = 4) -> str:
    """``method`` in the current vocabulary (former spellings warn), checked against
    ``allowed``."""
    if isinstance(method, str) and method in _OLD_METHODS:
        new = _OLD_METHODS[method]
        warn_deprecated(f"{fit}({name}={method!r})", f"{name}={new!r}", stacklevel)
        method = new
    if method not in allowed:
        raise ValueError(f"{name}: expected one of {tuple(allowed)}, got {method!r}")
    return method


def recipe_name(recipe, recipes: Mapping, *, fit: str) -> str:
    """Check ``recipe`` against a fit's ``RECIPES``."""
    if recipe not in recipes:
        raise ValueError(f"recipe: expected one of {tuple(recipes)} for {fit}, got {recipe!r}")
    return recipe


class Recipes(dict):
    """A fit's named settings; the former names resolve with a DeprecationWarning."""

    def __init__(self, recipes: Mapping, deprecated: Mapping | None = None, *, fit: str):
        super().__init__(recipes)
        self._deprecated = dict(deprecated or {})
        self._fit = fit

    def __missing__(self, key):
        if key in self._deprecated:
            warn_deprecated(f"{self._fit} recipe {key!r}", "the recipe= and method= options "
                            f"(see geofit.fit): {self._deprecated[key]}")
            return dict(self._deprecated[key])
        raise KeyError(key)


def dataset_argument(dataset, args: tuple, *, fit: str, images_required: bool = True):
    """The :class:`~geofit.datasets.MultiViewDataset` of a multi-view fit, from the current call
    form ``fit(dataset, ...)`` or the former ``fit(images, silhouettes, cameras, ...)`` (with a
    DeprecationWarning; the images and silhouettes are clipped to [0, 1] as the former fits
    did)."""
    from ..datasets import MultiViewDataset

    if args:
        if len(args) != 2:
            raise TypeError(f"{fit}: expected fit(dataset, ...) or the former "
                            f"fit(images, silhouettes, cameras, ...), got {1 + len(args)} "
                            "positional arguments")
        warn_deprecated(f"{fit}(images, silhouettes, cameras, ...)",
                        f"{fit}(MultiViewDataset(images=..., silhouettes=..., cameras=...), ...)",
                        4)
        from .._validate import as_unit_images

        images, silhouettes, cameras = dataset, args[0], args[1]
        images = np.clip(as_unit_images(images, "images", (None, None, None, 3)), 0.0, 1.0)
        dataset = MultiViewDataset(images=images,
                                   silhouettes=_clip01(silhouettes, "silhouettes"),
                                   cameras=cameras)
    if not isinstance(dataset, MultiViewDataset):
        raise TypeError(f"dataset: expected a geofit.datasets.MultiViewDataset, got "
                        f"{type(dataset)!r}")
    if images_required and dataset.images is None:
        raise ValueError(f"dataset: {fit} needs RGB images (dataset.images is None)")
    return dataset


def _clip01(a, name: str):
    try:
        a = np.asarray(a, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: could not convert to a float array") from None
    return np.clip(a, 0.0, 1.0)


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


def check_weights(weights, defaults: Mapping[str, float], name: str, *,
                  required: str | None = None) -> dict[str, float]:
    """Term weights: ``defaults`` updated by ``weights`` (None: the defaults), every value a
    number >= 0 and every name one of ``defaults``; ``required`` must weigh more than 0."""
    from .._validate import check_positive

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
