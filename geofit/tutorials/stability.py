"""The fit_mesh stability scenarios, in one place for the tutorials' report and benchmarks/.

Each scenario perturbs one input of :func:`geofit.fit.fit_mesh` the way real data or a careless
setting would: a noisy or holed or NaN target, a genus-1 target, a degenerate start, a first step
100 times too large. :func:`fit_mesh_scenario` returns the inputs of that run; the caller fits,
scores against ``reference`` and reports the outcome (``benchmarks/fit_mesh.py`` writes the
stability table, :func:`geofit.tutorials.step_fit_mesh` a row per case in its report).

The volume and NeRF stability tables (``benchmarks/fit_volume.py`` and ``benchmarks/fit_nerf.py``
with ``--stability``) also run on shapes no one tuned for: :func:`stability_shape` gives a
normalised, vertex-coloured test shape (a procedural one of :data:`geofit.shapes.TEST_SHAPES`, or
a file of ``$GEOFIT_DATA/shapes/``) and :func:`shape_views` its multi-view renders.
"""
from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import numpy as np

from ..data import find
from ..datasets import tutorial_views
from ..fit import FINE_WEIGHTS, TUTORIAL_WEIGHTS, CoarseToFine
from ..io import load_mesh
from ..shapes import TEST_SHAPES, ico_sphere, torus
from ..structures import Mesh, TexturesVertex

__all__ = ["MESH_MODES", "STABILITY_SHAPES", "MeshScenario", "collapse_edges",
           "fit_mesh_scenario", "mesh_fit_arguments", "shape_views", "stability_shape"]

#: Scenario key -> what it does (the stability table's legend).
MESH_MODES = {
    "noise": "target vertices + Gaussian noise, sigma 0.01 (normalised frame); scored against "
             "the clean target",
    "holes": "target with 4 holes (faces within 0.15 of 4 random vertices removed, open "
             "boundary); scored against the full target",
    "torus": "genus-1 target (geofit.torus()) from a genus-0 sphere",
    "degenerate_start": "source with every 7th edge collapsed (zero-area triangles)",
    "step_x100": "SGD/Adam: lr x100; L-BFGS: objective x100 (all weights), i.e. the first "
                 "gradient step 100 times too large, which the line search must absorb",
    "nan_target": "one target coordinate set to NaN",
}


class MeshScenario(NamedTuple):
    """Inputs of one stability run of :func:`geofit.fit.fit_mesh`.

    Attributes
    ----------
    source : Mesh or None
        The start (None: fit_mesh's default sphere).
    target : Mesh or (verts, faces)
        What to fit (may hold a NaN on purpose).
    kwargs : dict
        The method's settings (a modified copy): ``recipe`` and :class:`geofit.fit.MeshFitOptions`
        fields (see :func:`mesh_fit_arguments`).
    reference : Mesh
        What to score the result against (the clean target).
    """

    source: Mesh | None
    target: Any
    kwargs: dict
    reference: Mesh


def collapse_edges(mesh: Mesh, every: int = 7) -> Mesh:
    """``mesh`` with every ``every``-th edge collapsed onto its second end (zero-area faces)."""
    v = mesh.verts.copy()
    e = mesh.edges[::every]
    v[e[:, 0]] = v[e[:, 1]]
    return mesh.update_verts(v)


def mesh_fit_arguments(settings: dict, init=None) -> dict:
    """``fit_mesh`` keyword arguments (``recipe``, ``options``) from a flat dict of settings:
    ``recipe`` and :class:`geofit.fit.MeshFitOptions` fields (``init`` set when given)."""
    from ..fit import MeshFitOptions

    kw = dict(settings)
    recipe = kw.pop("recipe", "sphere")
    if init is not None:
        kw["init"] = init
    return {"recipe": recipe, "options": MeshFitOptions(**kw)}


def fit_mesh_scenario(mode: str, target: Mesh, kwargs: dict, *, source_level: int | None = None,
                      seed: int = 7) -> MeshScenario:
    """The inputs of the stability run ``mode`` for a method's fit_mesh ``kwargs``.

    Parameters
    ----------
    mode : str
        A key of :data:`MESH_MODES`.
    target : Mesh
        The clean target.
    kwargs : dict
        The method's settings: ``recipe`` and :class:`geofit.fit.MeshFitOptions` fields (not
        modified).
    source_level : int, optional
        Ico-sphere level of the start when the method has no coarse-to-fine schedule
        (default 4, the tutorial's).
    seed : int
        Seed of the noise and of the hole centres (a fresh generator per scenario).

    Returns
    -------
    MeshScenario

    Raises
    ------
    ValueError
        If ``mode`` is not a key of :data:`MESH_MODES`.
    """
    if mode not in MESH_MODES:
        raise ValueError(f"mode: expected one of {sorted(MESH_MODES)}, got {mode!r}")
    kw = dict(kwargs)
    rng = np.random.default_rng(seed)
    norm = target.normalize()
    source, tin, reference = None, target, target
    if mode == "noise":
        tin = target.update_verts(target.verts + rng.normal(scale=0.01 * norm.scale,
                                                            size=target.verts.shape))
    elif mode == "holes":
        tn = norm.mesh
        centres = tn.verts[rng.choice(tn.n_verts, 4, replace=False)]
        d = np.linalg.norm(tn.verts[tn.faces].mean(1)[:, None, :] - centres[None], axis=2).min(1)
        tin = Mesh(target.verts, target.faces[d > 0.15])
    elif mode == "torus":
        tin = reference = torus()
    elif mode == "degenerate_start":
        c2f = kw.get("refine")
        if isinstance(c2f, CoarseToFine):
            level = c2f.start_level
        else:
            level = 2 if kw.get("recipe") == "coarse-to-fine" else (source_level or 4)
        source = collapse_edges(ico_sphere(level))
    elif mode == "step_x100":
        if kw["method"] == "sgd":
            kw["lr"] = 100.0 * kw.get("lr", 1.0)
        elif kw["method"] == "adam":
            kw["lr"] = 100.0 * kw.get("lr", 0.01)
        else:
            x100 = {k: 100 * v for k, v in TUTORIAL_WEIGHTS.items()}
            kw["weights"] = [x100, {k: 100 * v for k, v in FINE_WEIGHTS.items()}]
            c2f = kw.get("refine")
            if c2f is not None or kw.get("recipe") == "coarse-to-fine":
                c2f = c2f if isinstance(c2f, CoarseToFine) else CoarseToFine()
                kw["refine"] = dataclasses.replace(c2f, coarse_weights=x100)
    elif mode == "nan_target":
        v = target.verts.copy()
        v[0, 0] = np.nan
        tin = (v, target.faces)
    return MeshScenario(source, tin, kw, reference)


#: The shapes the volume and NeRF stability tables add to the cow: genus 1 and open (procedural,
#: :data:`geofit.shapes.TEST_SHAPES`) and a file of ``$GEOFIT_DATA/shapes/`` (skipped when absent).
STABILITY_SHAPES = ("torus", "open_cylinder", "suzanne")

#: Shapes turned about the x axis (degrees) before normalising: the torus lies in the xz plane,
#: where the training views at elevation 0 would only see it edge-on and never through its hole.
_TILT_X = {"torus": 60.0, "double_torus": 60.0}


def stability_shape(name: str) -> Mesh:
    """A test shape, normalised as the tutorials' cow and coloured by position.

    Parameters
    ----------
    name : str
        A key of :data:`geofit.shapes.TEST_SHAPES` (``"torus"``, ``"open_cylinder"``, ...) or the
        stem of an OBJ file in ``$GEOFIT_DATA/shapes/`` (``"suzanne"``, ``"fandisk"``, ...).

    Returns
    -------
    Mesh
        The torus and double torus turned 60 degrees about x (seen through the hole from
        elevation 0); centred on its vertex mean, largest absolute coordinate 1 (:meth:`Mesh.normalize`), with a
        :class:`~geofit.structures.TexturesVertex` colour ``0.15 + 0.35 (v + 1)`` per vertex
        (a smooth field in [0.15, 0.85] that differs on every side of the shape).

    Raises
    ------
    ValueError
        If ``name`` is neither a procedural shape nor a file in the data folder's ``shapes/``.
    """
    if not isinstance(name, str):
        raise ValueError(f"name: expected a shape name (str), got {name!r}")
    if name in TEST_SHAPES:
        mesh = TEST_SHAPES[name]()
    else:
        path = find(f"shapes/{name}.obj") if name.isidentifier() else None
        if path is None:
            raise ValueError(f"name: expected one of {sorted(TEST_SHAPES)} or a file "
                             f"shapes/{name}.obj in the data folder (GEOFIT_DATA), got {name!r}")
        mesh = load_mesh(path, load_textures=False)
    if name in _TILT_X:
        a = np.radians(_TILT_X[name])
        rot = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(a), -np.sin(a)],
                        [0.0, np.sin(a), np.cos(a)]])
        mesh = mesh.update_verts(mesh.verts @ rot.T)
    norm = mesh.normalize().mesh
    colours = 0.15 + 0.35 * (norm.verts + 1.0)
    return Mesh(norm.verts, norm.faces, textures=TexturesVertex(colours))


def shape_views(name: str, *, num_views: int = 20, image_size: int = 64,
                num_held_out: int = 8):
    """Tutorial 5/6-style renders of :func:`stability_shape` ``(name)``.

    Parameters
    ----------
    name : str
        As :func:`stability_shape`.
    num_views : int
        Training views at elevation 0 around the shape (:func:`geofit.datasets.tutorial_views`).
    image_size : int
        Square image size in pixels.
    num_held_out : int
        Held-out views (even: half at elevation 0, half at 20, between the training azimuths).

    Returns
    -------
    MultiViewDataset
        Black background, thresholded silhouettes, ``held_out`` attached, ``name`` set.

    Examples
    --------
    >>> data = shape_views("torus", num_views=4, image_size=16, num_held_out=2)
    >>> data.images.shape, data.name, len(data.held_out)
    ((4, 16, 16, 3), 'torus', 2)
    """
    return tutorial_views(5, mesh=stability_shape(name), num_views=num_views,
                          image_size=image_size, num_held_out=num_held_out, name=name)
