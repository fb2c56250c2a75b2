"""Fit a mesh and its vertex colours to multi-view images (PyTorch3D's fit_textured_mesh tutorial).

The tutorial renders the cow from 20 views (RGB and soft silhouettes, 128 x 128), deforms an
``ico_sphere(4)`` to match the silhouettes (SGD, two random views per step, edge / normal /
Laplacian regularisers), then fits vertex positions and per-vertex colours to the RGB images.
Here every gradient is analytic (:mod:`geofit.render.soft`), and the chain rule is composed in
plain sight in :class:`_Objective`.

* The data: a :class:`geofit.datasets.MultiViewDataset` (``geofit.datasets.tutorial_views(4)``
  renders the tutorial's, with held-out views for evaluation).
* :func:`fit_mesh_to_views` -- a silhouette stage, then a textured stage. The default
  (recipe ``"default"``) is geofit's best for any shape: it starts from the **visual hull** of
  the silhouettes (:mod:`geofit.fit._views_init`: carved at the soft silhouettes' 0.5 level,
  marching cubes, quadric decimation; the hull's genus and parts),
  then alternates L-BFGS on the soft silhouettes of all views (large steps, lambda 10 at
  64 px, 1 at 128 px) with **remeshing** (:func:`geofit.ops.remesh`) to edges of ``edge_px`` = 3 pixels
  of the level's images, and ends with least-squares colours: vertex colours, then a UV
  texture on the final geometry (:func:`geofit.fit.texture.fit_texture`; ``texture="vertex"``
  keeps the vertex colours). Every length is a number of
  pixels times the pixel's world size at the object
  (:func:`~geofit.structures.visual_hull.pixel_footprint`), so nothing depends on the object's scale. The hull is only a start:
  with 50 faces blended, a soft silhouette exceeds 0.5 up to about a pixel outside the
  outline (on the cow's 20 views 5472 such pixels against 65798 inside), so the 0.5 hull is
  inflated (held-out IoU 0.889, F@0.01 0.001 on the cow, measured); the fit matches the
  targets with the same soft model, which the true mesh fits exactly (its soft render equals
  the targets to 1e-18). ``init="sphere"`` keeps the tutorial's ico-sphere.
  Silhouette methods (:data:`SILHOUETTE_METHODS`):

  - ``"sgd"`` (recipe ``"tutorial"``): the tutorial's recipe (SGD lr 1, momentum 0.9, two
    random views per step, soft silhouettes, weights silhouette 1, edge 1, normal 0.01,
    Laplacian 1);
  - ``"lbfgs"`` / ``"lbfgs-nlopt"``: the same objective over *all* views (deterministic),
    optionally with the large-steps parameterisation and coarse-to-fine levels (image size and
    mesh level rising together);
  - ``"adam"`` with ``silhouette_loss="contour"`` (recipe ``"contour"``): geometry-first: the
    hard silhouette's loss differentiated by edge sampling along the mesh's projected contour
    (:mod:`geofit.render.soft.contour`), Adam in the large-steps parameterisation,
    coarse-to-fine.

  Textured methods (:data:`TEXTURED_METHODS`): ``"sgd"`` (the tutorial's: SGD on offsets and
  colours, two
  views per step, weights RGB 1, silhouette 1, edge 1, normal 0.01, Laplacian 1), ``"lstsq"``
  (colours by one sparse least-squares solve on the hard render of the fitted geometry: for
  fixed geometry the image is affine in the colours), ``"lbfgs"`` (``lstsq`` colours, then joint
  L-BFGS on positions and colours over all views with the soft Phong renderer). On the cow the
  joint refinement lowers the held-out PSNR (24.3 -> 23.3 dB in 120 s, measured): the soft
  Phong image (blur, 50 faces blended) is not the hard image the targets are, and the
  least-squares colours already fit the hard image optimally for the geometry.
* :class:`ViewsEvaluator` -- held-out metrics (:func:`geofit.metrics.silhouette_iou`,
  :func:`geofit.metrics.psnr`; chamfer-L2 and F-score against the true mesh via
  :mod:`geofit.metrics`).

No NaN: every map is evaluated in float64 with PyTorch3D's clamps (and the additional guards of
:mod:`geofit.render.soft`); the solvers stop with status ``"nonfinite"`` (returning the last
finite parameters) should a value or gradient ever be non-finite, and every recorded history row
is checked.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from .._validate import as_rng, check_choice, check_positive
from ..ops import topology
from ..structures import MultiViewDataset
from ..render.soft import SoftRasterizationSettings
from ..render.soft.contour import ContourSilhouetteLoss
from ..shapes import ico_sphere, subdivide
from ..structures import Mesh, TexturesUV, as_mesh
from ..structures.visual_hull import fill_grey_cores
from ._options import as_dataset, check_int, check_weights, merge_options, recipe_name
from ._progress import NoBar, advance, progress_bar
from ._rgb_refine import interior_masks, refine_rgb
from ._views_eval import ViewsEvaluator, colored_mesh, render_mesh_at_views
from ._views_adapt import remesh_adaptive
from ._views_init import initial_mesh, remesh_to_length
from ._views_objective import (
    REG_TERMS, _ContourObjective, _lstsq_colors, _Objective, dataset_background, dataset_lights,
    silhouette_pinning,
)
from .history import Clock, FitHistory, FitResult
from .init import _check_margins, shortest_edge
from .large_steps import vertex_parameterization
from .solvers import StepInfo, adam, lbfgs_nlopt, lbfgs_scipy, sgd
from .texture import fit_texture

__all__ = [
    "FINAL_STAGE_SHARE",
    "HULL_SILHOUETTE_WEIGHTS",
    "INITS",
    "LAPLACIAN_ANCHORS",
    "RECIPES",
    "SILHOUETTE_LOSSES",
    "SILHOUETTE_METHODS",
    "TEXTURED_METHODS",
    "TEXTURES",
    "TUTORIAL_SILHOUETTE_WEIGHTS",
    "TUTORIAL_TEXTURED_WEIGHTS",
    "ViewsEvaluator",
    "ViewsFitOptions",
    "ViewsFitResult",
    "fit_mesh_to_views",
    "render_mesh_at_views",
]

#: Silhouette-stage methods of :func:`fit_mesh_to_views` (``"none"`` skips the stage).
SILHOUETTE_METHODS = ("lbfgs", "lbfgs-nlopt", "sgd", "adam")
#: Silhouette losses: the soft silhouette's squared error, or the hard silhouette's contour
#: gradients (:mod:`geofit.render.soft.contour`).
SILHOUETTE_LOSSES = ("soft", "contour")
#: Textured-stage methods of :func:`fit_mesh_to_views`.
TEXTURED_METHODS = ("lstsq", "lbfgs", "sgd", "none")
#: What the fitted mesh carries after a textured stage: a UV texture (``"uv"``:
#: :func:`geofit.fit.texture.fit_texture` on the final geometry) or the vertex colours.
TEXTURES = ("uv", "vertex")

#: Weights of the default fit's silhouette stage (at the tutorial's pixel size, see
#: :data:`TUTORIAL_PIXEL`): the tutorial's normal weight, edge and Laplacian 0.3 (the
#: large-steps parameterisation already smooths the steps; the smoothing still carries the
#: shape into directions no view sees: on the cow, held-out IoU 0.976 with these against 0.972
#: with edge 0, measured).
HULL_SILHOUETTE_WEIGHTS = {"silhouette": 1.0, "edge": 0.3, "normal": 0.01, "laplacian": 0.3,
                           "normal_variation": 0.0}

#: The world size of a pixel in the tutorial's views (distance 2.7, field of view 60 degrees,
#: 128 px): the default recipe's edge and Laplacian weights are set at this pixel size and
#: scaled to the data's (squared and linearly, as the two terms scale with the edge length), so
#: that they weigh the same against the silhouettes at any object scale and image size.
TUTORIAL_PIXEL = 2.0 * 2.7 * math.tan(math.radians(30.0)) / 128

#: Solvers of the RGB stage (``options.rgb_method``).
RGB_METHODS = ("lbfgs", "adam")

#: Forms of the silhouette stage's Laplacian term (``options.laplacian_anchor``): on the
#: vertices (``"none"``, the tutorial's), on the displacement from each remesh round's start
#: (``"round"``), or so on the last coarse-to-fine level only (``"last"``) or in the last
#: solve only (``"final"``).
LAPLACIAN_ANCHORS = ("none", "round", "last", "final")

#: Per-vertex mixes of the anchored and the plain Laplacian (``options.laplacian_pin``):
#: none (the anchored term on every vertex), or weighted by the silhouettes' share of the
#: forces on each vertex (``"force"``, :func:`geofit.fit._views_objective.silhouette_pinning`).
LAPLACIAN_PINS = ("none", "force")

#: Initialisations of :func:`fit_mesh_to_views` (or a Mesh).
INITS = ("hull", "sphere")

#: The tutorial's loss weights for the silhouette stage.
TUTORIAL_SILHOUETTE_WEIGHTS = {"silhouette": 1.0, "edge": 1.0, "normal": 0.01, "laplacian": 1.0}
#: The tutorial's loss weights for the textured stage.
TUTORIAL_TEXTURED_WEIGHTS = {"rgb": 1.0, "silhouette": 1.0, "edge": 1.0, "normal": 0.01,
                             "laplacian": 1.0}


@dataclass(frozen=True)
class ViewsFitOptions:
    """The settings of :func:`fit_mesh_to_views`; None means "the recipe's".

    Attributes
    ----------
    init : {"hull", "sphere"} or Mesh
        Starting mesh. ``"hull"``: the visual hull of the silhouettes (carved at their 0.5
        level, marching cubes, decimated to edges of ``2 edge_px`` pixels;
        :mod:`geofit.fit._views_init`). ``"sphere"``: the tutorial's ``ico_sphere(4)``
        (``ico_sphere(4 - subdivisions)`` when ``levels`` subdivide). A Mesh (geofit, trimesh
        or Open3D) is used as given. The result's ``init`` says which.
    silhouette_method : {"lbfgs", "lbfgs-nlopt", "sgd", "adam", "none"}
        Solver of the silhouette stage (see the module docstring); ``"sgd"`` draws
        ``views_per_step`` random views per step, the others use all views.
    silhouette_loss : {"soft", "contour"}
        The soft silhouettes' squared error, or the hard silhouette's contour gradients
        (``"adam"`` only).
    textured_method : {"lstsq", "lbfgs", "sgd", "none"}
        Method of the textured stage.
    silhouette_weights, textured_weights : dict
        Term weights (:data:`HULL_SILHOUETTE_WEIGHTS` for ``"default"``, else the tutorial's,
        :data:`TUTORIAL_SILHOUETTE_WEIGHTS`; :data:`TUTORIAL_TEXTURED_WEIGHTS`). With
        ``recipe="default"`` the silhouette stage's edge and Laplacian weights hold at the
        tutorial's pixel size (:data:`TUTORIAL_PIXEL`) and are scaled by
        ``(TUTORIAL_PIXEL / p)**2`` and ``TUTORIAL_PIXEL / p`` for the data's pixel size ``p``.
    silhouette_iters, textured_iters : int
        Iteration budgets per stage (SGD / Adam steps or L-BFGS iterations; for coarse-to-fine
        split over the levels in proportion to their downsampling factor, then evenly over a
        level's remeshing rounds). 120 and 2000 for ``"default"``, 2000 and 2000 otherwise.
    large_steps : float
        ``lambda`` of the large-steps parameterisation (0: plain vertex positions).
    final_large_steps : float
        ``lambda`` at the last coarse-to-fine level (None: ``large_steps``). The default
        recipe's 1 (10 on the coarse level keeps the smooth start): at full resolution
        lambda 10 damps the small, local moves that put the outline on the targets' last
        pixel, and the fit stopped short (on the cow, a soft-silhouette error 6x that of the
        true surface remeshed alike, the fit 0.2-0.5 px too wide along the outline). Cow,
        measured: held-out IoU 0.9748 / 0.9781 / 0.9818 and F@0.01 0.781 / 0.783 / 0.803
        with 10 / 3 / 1, at the same cost.
    final_regularization : float
        Factor on the edge, normal, Laplacian and normal-variation weights at the last
        coarse-to-fine level (and in the RGB stage, which keeps that level's terms; 1: as on
        the other levels). 0.5 on the 11 shapes of ``benchmarks/fit_views.py --shapes all``
        (session 11's default otherwise; IoU / F@0.01 / texture PSNR 1 -> 0.5): cow 0.9827 /
        0.828 / 27.15 -> 0.9845 / 0.854 / 27.59 (the outline pixels it misses 310 -> 204),
        fandisk 0.400 -> 0.448 F, teapot 0.847 -> 0.869, Suzanne 0.643 -> 0.664 (28.54 dB),
        open cylinder 0.9882 / 0.682 -> 0.9904 / 0.787, ogre 0.8587 / 0.476 -> 0.8737 /
        0.492, torus 31.47 -> 31.94 dB, median F 0.828 -> 0.854; but woody F 0.967 -> 0.942,
        thin plate 0.378 -> 0.374, and texture PSNR double torus 29.78 -> 29.59, two spheres
        34.66 -> 34.39 dB (their too-wide outline pixels). 0.5 for ``"default"`` since
        session 12 (with the RGB stage's Adam and ``silhouette_grey_px=2``; the whole
        default's figures under ``rgb_regularization``). 0.25 on the cow:
        0.9840 / 0.861 / 27.57; 0.75: cow 0.9833 / 0.840 / 27.32, double torus 0.9802 /
        0.970 / 29.71, two spheres 0.9948 / 1.000 / 34.83 (the other 8 not run).
    levels : sequence of (int, int)
        Coarse-to-fine schedule of the L-BFGS and contour methods: per level the number of
        midpoint subdivisions to apply first and the image downsampling factor, e.g.
        ``[(0, 2), (1, 1)]`` = start mesh at half resolution, then subdivide once at full
        resolution (``[(0, 1)]``: one level at full resolution). The edge, normal and Laplacian
        weights of a level with ``s`` subdivisions still to come are multiplied by ``4**-s``.
    remesh_rounds : int
        Remesh-and-solve rounds per level (0: no remeshing). Before each solve the mesh is
        remeshed (:func:`geofit.ops.remesh`) to edges of ``edge_px`` pixels of that level's
        images (at most a fifteenth of the initial mesh's bounding-box diagonal, and long
        enough to keep about 4000 faces at full resolution, 1000 at half, and about 6
        soft-rasterizer entries per pixel of a view: a large surface, a box's or a hull's
        double wall, gets longer edges, so one evaluation's time stays bounded;
        :func:`geofit.fit.init.shortest_edge`).
    edge_px : float
        Target edge length of the remeshing in pixels (measured at the initial mesh's centre).
    textured_init : {"silhouette", "sphere"}
        Start the textured stage from the silhouette result or, as the tutorial does, from the
        initial mesh.
    views_per_step : int
        Random views per step of the SGD methods (2).
    lr, momentum : float
        SGD settings (1.0, 0.9).
    adam_lr : float
        Step size of the contour method's Adam at the first level (each level ``l`` runs three
        phases with step sizes ``a``, ``a * 0.3`` and ``a * 0.1``, ``a = adam_lr * 0.3**l``).
    faces_per_pixel : int
        K of the soft rasterizer (50).
    color_reg : float
        Weight of the Laplacian smoothness of the colours in the ``lstsq`` solve (fills
        vertices no view sees).
    texture : {"uv", "vertex"}
        What the result's mesh carries after the textured stage: ``"uv"`` (recipe
        ``"default"``) a :class:`~geofit.structures.TexturesUV` solved on the final geometry
        by :func:`geofit.fit.texture.fit_texture` (a xatlas atlas, texels by one sparse
        least-squares solve over all views, with the dataset's lights or unlit colour, the
        vertex colours filling texels no view sees); ``"vertex"`` (the other recipes) the
        vertex colours (:class:`~geofit.structures.TexturesVertex`). The vertex colours are
        in ``result.colors`` either way.
    texel_px : float
        Texel size of the ``"uv"`` atlas in pixels of the views at the object (1: about one
        texel per pixel of surface seen).
    hull_upsample : int
        Carve the visual hull at sub-pixel outlines: the soft silhouettes interpolated on a
        grid this many times finer (:func:`geofit.fit.init.visual_hull_mesh`; 1: the pixels).
    hull_close_px : float
        Close each thresholded silhouette with a disk of this radius (pixels) before carving:
        pinholes and slits narrower than twice that (cracks between the parts of a mesh, a
        sheet seen edge-on) carve no tunnel through the hull (0: none).
    hull_fill_px : float
        Fill each thresholded silhouette's pinholes before carving: background regions that
        do not reach the image's border and cover at most this many pixels
        (:func:`geofit.structures.visual_hull.signed_distance_images`; 0: none; 9 by
        default). The outline stays as it is (a closing, ``hull_close_px``, also fills
        notches of the outline). A soft rasterizer that blends the K nearest faces leaves
        such pinholes in the silhouettes of a dense mesh, and each carved a tunnel through
        the hull (the ogre's 20 views have 221 of at most 9 pixels, the fandisk's 21, the
        teapot's 56). With 9 against 0, held-out IoU / F@0.01: ogre 0.8311 / 0.405 -> 0.8348 /
        0.452, teapot 0.9787 / 0.823 -> 0.9810 / 0.845, torus 0.9927 / 0.981 -> 0.9936 /
        0.997, cow 0.9818 / 0.803 -> 0.9828 / 0.813,
        double torus 0.9761 / 0.972 -> 0.9757 / 0.955; no shape of the 11 of
        benchmarks/fit_views.py loses more than IoU 0.01 or F 0.02 (measured,
        benchmarks/results/fit_views_session9_thin.md).
    hull_grey_px : float
        Carve the hull where the soft silhouettes are known to be background: grey pixels
        (above 0.05) more than this many pixels from every pixel at or below 0.05 count as
        inside (:func:`geofit.fit.init.visual_hull_mesh`'s ``grey_px``; 0: none, the
        default). With 2 the ogre's hull keeps 1 253 true-mask pixels its soft targets lose
        (hull held-out IoU 0.46 -> 0.62) but its fit ends lower (IoU 0.8587 -> 0.8494,
        F@0.01 0.476 -> 0.433), while the thin plate's edge-on strip survives (0.9626 / 0.378
        -> 0.9824 / 0.527) and the 9 other shapes of benchmarks/fit_views.py move by at most
        IoU 0.001 / F 0.014 (measured): not the default while the ogre loses F.
    hull_margins : sequence of float
        The hull's carving vote (pixels, non-increasing;
        :func:`geofit.structures.visual_hull.hull_field`): ``(0,)`` carves what any one view
        puts outside its silhouette, ``(1, 0)`` only what one view puts more than a pixel
        outside or two views outside (a pinhole, a seam between parts or a slit at most 2
        pixels wide in one view carves no tunnel). Not the default: on the tutorial's views
        ``(1, 0)`` gives the open cylinder held-out IoU 0.981 (0.965) and genus 1 (31), the
        thin plate F@0.01 0.504 (0.309), the ogre IoU 0.821 (0.791), but the cow F@0.01 0.754
        (0.781; measured, benchmarks/results/fit_views_viewsthin.md).
    hull_vote_depth : float
        With ``hull_margins``, the vote only fills, and only where its hull is deeper than
        this many pixels (:func:`geofit.structures.visual_hull.carve_hull`): the tunnels that
        single-view seams and slits bore are filled, the outline stays the plain hull's (0:
        the vote as it is).
    hull_close_handles : float
        Close the hull's handles that no silhouette supports: nodes at most a pixel outside
        every silhouette with hull nodes on both sides within this many pixels along a
        lattice direction are filled
        (:func:`geofit.structures.visual_hull.close_unsupported_handles`), kept only if that
        lowers the hull's genus (0: none). The history's first note (its
        ``hull_handles_closed``, ``hull_filled_nodes``, ``hull_genus``) and ``result.message``
        say what was removed. The default recipe's is 4: a carving artefact's handle is a
        wrong topology the fit cannot undo (issue 24). Held-out IoU / F@0.01 / hull genus
        without -> with it, on the procedural stand-ins of public shapes
        (``benchmarks/fit_views.py --shapes unseen``): eared character 0.8627 / 0.376 / 47 ->
        0.9151 / 0.500 / 4, cartoon figure 0.9650 / 0.574 / 73 -> 0.9695 / 0.694 / 0, noisy
        scan 0.9108 / 0.166 / 41 -> 0.9156 / 0.211 / 7, beetle 0.8941 / 0.809 -> 0.9168 /
        0.805 (15 -> 3 parts), machine part (a true handle) unchanged; its cost on the table's
        shapes: open cylinder 0.9837 / 0.729 / 31 -> 0.9882 / 0.682 / 2, cow 0.9838 / 0.834
        / 1 -> 0.9827 / 0.828 / 0, teapot 0.9823 / 0.860 / 3 -> 0.9814 / 0.847 / 1; the 8
        others keep their hull (torus 1, double torus 2: filling would not lower the genus).
    hull_per_part : bool
        Decimate each connected part of the hull on its own (at least 48 faces a part), so
        that a part the carving cut off (a thin leg) keeps its shape (False: the whole hull
        at once, whose quadric decimation collapses small parts). Not the default: the
        ogre's hull keeps 50 parts (held-out IoU 0.46 -> 0.51) but its fit ends at IoU 0.7809
        / F@0.01 0.396 (0.8587 / 0.476 without; measured).
    silhouette_grey_px : float
        Raise the covered grey pixels of the target silhouettes to 1 before the fit (the
        hull is carved from them and every stage matches them): pixels at or below 0.5, above
        1e-3 and more than this many pixels from every pixel at or below 1e-3, whose RGB
        differs from the dataset's background
        (:func:`geofit.structures.visual_hull.fill_grey_cores`; 0: none). Targets without
        such pixels are left as they are. A soft rasterizer
        that keeps the K faces nearest the camera drops the covering face where more than K
        nearer faces of a dense mesh pass within its blur radius (about 2 px for the
        tutorial's): the target then reads grey, down to 0.01, inside the object, the hull
        is carved through there (the ogre's: genus 21, 50 parts) and the fit pulls the
        surface in. 2 is about the tutorial's blur radius (1.94 px at 128 px); 2 for
        ``"default"`` (session 12, with the RGB stage's Adam and ``final_regularization=0.5``;
        the whole default's figures under ``rgb_regularization``). Alone, against session 11's
        default, on the shapes of ``benchmarks/fit_views.py``: the ogre's
        held-out IoU / F@0.01 / PSNR 0.8587 / 0.476 / 22.62 -> 0.9343 / 0.656 / 25.74 (hull
        genus 21 -> 0), thin plate 0.9626 / 0.378 -> 0.9795 / 0.526, double torus 0.9807 /
        0.949 -> 0.9821 / 0.956, cow 0.9827 / 0.828 -> 0.9829 / 0.824, the unseen beetle
        0.9168 / 0.805 -> 0.9183 / 0.800, but teapot 0.9814 / 0.847 -> 0.9805 / 0.836; no
        pixel is raised on two spheres, open cylinder, Suzanne, woody (measured, CHANGELOG).
    rgb_iters : int
        Iterations (L-BFGS) or steps (Adam, ``rgb_method``) of the RGB refinement stage after
        the silhouette stage (0: none):
        the vertices against the RGB images with the hard image term
        (:class:`geofit.render.mesh.HardImageLoss`), the vertex colours solved by sparse least
        squares inside every evaluation (variable projection), so the residual moves the
        geometry (:func:`geofit.fit._rgb_refine.refine_rgb`). Needs RGB images. With
        ``silhouette_method="none"`` it refines the initial mesh (e.g. a Mesh given as
        ``init``; set explicitly: the recipe's stage runs only after a silhouette stage and
        with RGB images). 15 Adam steps for ``"default"`` (with ``rgb_method="adam",
        rgb_lr=0.1, rgb_supersample=1, rgb_weight=1, rgb_regularization=0.3,
        rgb_silhouette=1, rgb_large_steps=1``; session 12, figures under
        ``rgb_regularization``), 0 otherwise. Session 9's 5 L-BFGS iterations (``rgb_weight=0.3``)
        raised the median held-out F@0.01 and IoU on the 11 shapes of
        ``benchmarks/fit_views.py --shapes all`` for about 12-14 CPU s on the cow
        (benchmarks/results/fit_views_session9_rgb.md) but barely moved the surface.
    rgb_weight : float
        Weight of the image term in the RGB stage (1, as in ``"default"``).
    rgb_silhouette : float
        Weight of the last level's soft-silhouette term kept in the RGB stage, with that
        level's edge, normal and Laplacian regularisers (0: the image term alone, as before).
        Without it the stage moves the outline the silhouettes had right and lets the mesh
        degrade (thin plate, 10 iterations: held-out IoU 0.9620 / F@0.01 0.280 alone, 0.9694 /
        0.349 with it and ``rgb_large_steps=1``; before the stage 0.9614 / 0.377).
    rgb_large_steps : float
        ``lambda`` of the large-steps parameterisation in the RGB stage (10, 1 for
        ``"default"``; 0: plain vertex positions).
    rgb_color_reg : float
        Weight of the colours' Laplacian smoothness inside the RGB stage's variable
        projection (1e-4): larger leaves the colours fewer degrees of freedom to absorb what
        the geometry should explain.
    rgb_color_smooth : float
        Weight of the colours' Dirichlet energy ``int |grad C|^2 dA`` (cotangent stiffness of
        the stage's starting mesh) in the same solve: the same on any shape's size and vertex
        count; larger makes the shading that the world-fixed lights put on the surface
        the geometry's to explain rather than the colours' (0: none). Measured from the
        default's silhouette mesh (``benchmarks/fit_views_shade.py stage``), 1e-4: F@0.01
        Suzanne 0.643 -> 0.646, fandisk 0.400 -> 0.403, thin plate 0.378 -> 0.378 (5
        iterations); with 20 iterations Suzanne 0.656 -> 0.663, fandisk 0.412 -> 0.412, thin
        plate 0.406 -> 0.401. The least-squares colours keep ~90 % of the image term's
        curvature around the truth (``scan``), so what the colours absorb is not what holds
        the geometry back.
    rgb_inner_px : int
        The RGB stage's image term only on the pixels this many pixels or more inside the
        target silhouettes (0: on every pixel): the outline is the silhouettes' to fit.
        Measured with 2: F@0.01 Suzanne 0.643 -> 0.647, fandisk 0.400 -> 0.385, thin plate
        0.378 -> 0.380 (IoU -0.002 to -0.003).
    rgb_supersample : int
        Rays per pixel ``s x s`` of the RGB stage's image term (2; 1 for ``"default"``). The
        views' targets are hard renders at the pixel centres: at ``s = 1`` the term compares like with like (the
        true fandisk's image loss 1.2e-6, the fitted one's 2.8e-3), at ``s = 2`` the
        sub-pixel rays at outlines and creases miss the centre sample and the term has a
        floor (4.8e-3 at the truth, 5.6e-3 at the fit: almost no contrast); ``s = 1`` also
        casts a quarter of the rays (image part of an evaluation 1.0 -> 0.4 CPU s on the
        fandisk).
    rgb_method : {"lbfgs", "adam"}
        Solver of the RGB stage: L-BFGS (``rgb_iters`` iterations) or Adam (``"default"``;
        ``rgb_iters`` steps of ``rgb_lr`` pixels, one evaluation each, the evaluated point
        of least objective kept). Measured on the fandisk from the default's silhouette
        mesh: L-BFGS's first trial step (up to 3 px) raises the silhouette term tenfold, the
        line search backs off and the 5 iterations move the vertices 0.1 px (90th
        percentile along the normals); Adam's per-coordinate steps move the surface the
        silhouettes do not hold 0.5-0.7 px in 15 steps.
    rgb_lr : float
        Adam's step in pixels at the object (0.1).
    rgb_regularization : float
        Factor on the edge, normal, Laplacian and normal-variation weights kept in the RGB
        stage (1; 0.3 for ``"default"``): the image term's signal inside the outline is a few times smaller than
        theirs (fandisk: regularisers 3.2e-3 of an objective of 5.7e-3). Measured from the
        default's silhouette mesh (``benchmarks/fit_views_shade.py stage``), IoU / F@0.01 /
        vertex-colour PSNR with ``rgb_method="adam", rgb_supersample=1, rgb_iters=15,
        rgb_weight=1, rgb_regularization=0.3, rgb_lr=0.1`` against the default's RGB stage:
        fandisk 0.9838 / 0.400 / 26.8 -> 0.9857 / 0.476 / 27.8 (``rgb_lr=0.2``: F 0.496),
        Suzanne 0.9764 / 0.643 / 27.8 -> 0.9817 / 0.663 / 28.7, the unseen noisy scan 0.9156
        / 0.211 / 23.6 -> 0.9536 / 0.564 / 25.3, the cow 0.9827 / 0.829 / 26.0 -> 0.9849 /
        0.878 / 26.4, for about 5 more CPU s (15 evaluations of about 1.25 CPU s). With the default's weights Adam gives the fandisk F 0.412; L-BFGS
        with these weights and 10 iterations 0.422 (25 evaluations). The whole default fit
        with ``rgb_method="adam", rgb_supersample=1, rgb_iters=15, rgb_weight=1,
        rgb_regularization=0.3, rgb_lr=0.2`` (``benchmarks/fit_views.py --shapes``, IoU /
        F@0.01 / UV-texture PSNR, CPU s under a load of 24-40 against the quiet default's):
        cow 0.9827 / 0.828 / 27.15 -> 0.9844 / 0.880 / 27.36 (61.7 -> 74.0), fandisk 0.9838 /
        0.400 / 27.23 -> 0.9859 / 0.498 / 27.56 (62.3 -> 67.6), teapot 0.9814 / 0.847 / 30.26
        -> 0.9833 / 0.879 / 30.70 (42.6 -> 43.0), Suzanne 0.9764 / 0.643 / 27.95 -> 0.9822 /
        0.657 / 29.03 (54.6 -> 57.0), open cylinder 0.9882 / 0.682 / 25.11 -> 0.9895 / 0.748 /
        25.77 (84.3 -> 85.6), thin plate 0.9626 / 0.378 / 25.63 -> 0.9753 / 0.419 / 26.73
        (73.6 -> 75.3), woody 0.9496 / 0.967 / 29.40 -> 0.9554 / 0.993 / 30.82, the ogre
        0.8587 / 0.476 / 22.62 -> 0.9063 / 0.515 / 24.24, double torus 0.9807 / 0.949 / 29.78
        -> 0.9869 / 0.952 / 31.52, but the torus 0.9933 / 0.997 / 31.47 -> 0.9916 / 0.987 /
        30.60 (64.0 -> 73.9 CPU s), two spheres 0.9948 / 1.000 / 34.66 -> 0.9947 / 1.000 /
        34.71; medians IoU 0.9814 -> 0.9844, F@0.01 0.828 -> 0.879. Measured at the end of
        session 12 and not yet made the default (the torus's F -0.0098 is within the team's
        0.01 rule; the change is the recipe's one line).
    laplacian_anchor : {"none", "round", "last", "final"}
        What the silhouette stage's Laplacian term smooths: the vertices (``"none"``, the
        tutorial's ``mean_i |(L V)_i|``), or the displacement from the start of each
        remesh-and-solve round (``"round"``: ``mean_i |(L (V - V0))_i|``, re-anchored after
        every remeshing; the RGB stage anchors at its start), or so on the last coarse-to-fine
        level only (``"last"``: the plain term keeps the start from the hull smooth), or in the
        last remesh-and-solve round only (``"final"``). The plain term has the surface's own
        curvature as its cost, so it shrinks and rounds what the silhouettes do not pin; the
        anchored one only smooths the moves. Started from the true Suzanne (``init=`` the true
        mesh, the default otherwise), held-out F@0.01 0.639 with ``"none"``, 0.829 with
        ``"round"`` (fandisk 0.557 -> 0.870); but from the visual hull (the default's start, a
        superset of the object) the plain term's shrinkage is what moves the surface the
        silhouettes do not pin inward, and the anchored forms lose (measured, IoU / F@0.01,
        ``"none"`` -> ``"last"``: fandisk 0.9838 / 0.400 -> 0.9799 / 0.390, Suzanne 0.9764 /
        0.643 -> 0.9746 / 0.621, thin plate 0.9626 / 0.378 -> 0.9609 / 0.371, double torus
        0.9807 / 0.949 -> 0.9752 / 0.918, open cylinder 0.9837 / 0.729 -> 0.9746 / 0.678;
        ``"round"``: Suzanne 0.9702 / 0.615, torus 0.9933 / 0.997 -> 0.9874 / 0.945;
        ``"final"``: fandisk 0.9822 / 0.380, Suzanne 0.9752 / 0.639, double torus 0.9779 /
        0.954): ``"none"`` in every recipe.
    laplacian_pin : {"none", "force"}
        Where ``laplacian_anchor`` anchors the Laplacian, anchor it on every vertex
        (``"none"``) or only where the silhouettes pin the surface: per vertex the mix
        ``p_i |(L (V - V0))_i| + (1 - p_i) |(L V)_i|`` with ``p_i`` the silhouette term's share
        of the forces on the vertex at the solve's start (``"force"``), so the plain term
        still shrinks the surface no silhouette holds (concavities, faces between the rims)
        while the held surface keeps its shape. Needs ``laplacian_anchor`` other than
        ``"none"``. Measured on all 11 shapes from the visual hull (the default otherwise;
        held-out IoU / F@0.01 / texture PSNR dB, the default -> ``"force"`` with
        ``laplacian_anchor="round"``): fandisk 0.9838 / 0.400 / 27.23 -> 0.9825 / 0.422 /
        26.96, Suzanne 0.9764 / 0.643 / 27.95 -> 0.9778 / 0.655 / 28.00, cow 0.9827 / 0.828 /
        27.15 -> 0.9828 / 0.841 / 26.04, teapot 0.9814 / 0.847 / 30.26 -> 0.9800 / 0.853 /
        29.80, open cylinder 0.9882 / 0.682 / 25.11 -> 0.9846 / 0.709 / 23.11, double torus
        0.9807 / 0.949 / 29.78 -> 0.9803 / 0.957 / 28.88, ogre 0.8587 / 0.476 / 22.62 ->
        0.8647 / 0.442 / 22.80, thin plate 0.9626 / 0.378 / 25.63 -> 0.9655 / 0.324 / 25.48,
        woody 0.9496 / 0.967 / 29.40 -> 0.9428 / 0.961 / 29.16, torus 0.9933 / 0.997 / 31.47
        -> 0.9923 / 0.984 / 30.91, two spheres 0.9948 / 1.000 / 34.66 -> 0.9929 / 1.000 /
        32.65 (medians IoU 0.9814 -> 0.9803, F 0.828 -> 0.841; with ``"last"``: fandisk
        0.9822 / 0.411, Suzanne 0.9776 / 0.648, thin plate 0.9642 / 0.326). From the true
        Suzanne it keeps less of the truth than the anchored term (F 0.639 plain, 0.829
        ``"round"``, 0.681 ``"round"`` + ``"force"``). The torus's F (-0.013), the thin plate's
        F, woody's IoU and the textures' PSNR (cow -1.1 dB) lose: ``"none"`` in every recipe.
    contour_threshold : float
        The contour method compares the mesh's hard silhouette with the targets binarised at
        this level (0.9: on the tutorial's 20 views it misclassifies the fewest pixels against
        the true hard masks, 3514 of 327680, against 5478 at 0.5 and 3311 at 0.95, which loses
        interior pixels); 0: the targets as they are, compared at 0.5.
    silhouette_log_eps : float
        On pixels where the soft target is background (below this value) and the mesh covers
        more than it, compare the soft silhouettes in log-transmittance, ``-log(1 - S + e)``
        with ``e`` this value (0: ``S`` everywhere, the tutorial's; the soft method only).
        The product coverage's pull on such a pixel fades with ``1 - S`` (squared where the
        front and back faces meet at the outline); in log-transmittance it pulls as hard as
        an uncovered pixel the target fills. The true surface stays a minimum. Measured with
        0.05 on the 11 shapes of ``benchmarks/fit_views.py`` (its views and metrics, held-out
        F@0.01): Suzanne 0.643 -> 0.659, thin plate 0.378 -> 0.475, double torus 0.949 ->
        0.973, cow 0.834 -> 0.828, but the ogre 0.476 -> 0.355 (IoU 0.859 -> 0.781; 479
        true-mask pixels of its views have soft targets below 0.05, which it carves) and the open
        cylinder 0.729 -> 0.707: not the default (CHANGELOG.md has the table).
    remesh_adapt : float
        Degrees the surface may turn from one face to the next in the remeshing rounds (0:
        one edge length, ``edge_px``, everywhere): each vertex's target length is this angle
        over the turning per length the mesh shows there (the angle between neighbouring
        faces' normals over the edge's length), scaled so that the expected face count is
        that of the uniform length, between a pixel of the level and the longest edge
        (:func:`geofit.fit._views_adapt.adaptive_edge_lengths`): folds (a plate's rim, a
        tube's lip, a thin leg) finer, flat regions coarser, at about the same cost. With a
        plate's rim one vertex line (3 px edges, 3 px thick), the uniform Laplacian's minimum
        through it is the collapsed sheet and the faces cross; resolved, they stay apart.
        Held-out IoU / F@0.01 with 30 against 0 (benchmarks/fit_views.py's views and
        metrics): thin plate 0.9626 / 0.378 -> 0.9712 / 0.617, woody 0.9496 / 0.967 ->
        0.9562 / 0.999, open cylinder 0.9882 / 0.682 -> 0.9851 / 0.667, cow 0.9827 / 0.828 ->
        0.9814 / 0.803 (measured): not the default while the cow loses.
    """
    init: Any = None
    silhouette_method: str | None = None
    silhouette_loss: str | None = None
    textured_method: str | None = None
    silhouette_weights: Mapping[str, float] | None = None
    textured_weights: Mapping[str, float] | None = None
    silhouette_iters: int | None = None
    textured_iters: int | None = None
    large_steps: float | None = None
    final_large_steps: float | None = None
    final_regularization: float | None = None
    levels: Any = None
    remesh_rounds: int | None = None
    edge_px: float | None = None
    textured_init: str | None = None
    views_per_step: int | None = None
    lr: float | None = None
    momentum: float | None = None
    adam_lr: float | None = None
    faces_per_pixel: int | None = None
    color_reg: float | None = None
    contour_threshold: float | None = None
    texture: str | None = None
    texel_px: float | None = None
    hull_upsample: int | None = None
    hull_close_px: float | None = None
    hull_fill_px: float | None = None
    hull_grey_px: float | None = None
    hull_margins: Any = None
    hull_vote_depth: float | None = None
    hull_close_handles: float | None = None
    hull_per_part: bool | None = None
    silhouette_grey_px: float | None = None
    rgb_iters: int | None = None
    rgb_weight: float | None = None
    rgb_silhouette: float | None = None
    rgb_large_steps: float | None = None
    rgb_color_reg: float | None = None
    rgb_color_smooth: float | None = None
    rgb_inner_px: int | None = None
    rgb_supersample: int | None = None
    rgb_method: str | None = None
    rgb_lr: float | None = None
    rgb_regularization: float | None = None
    laplacian_anchor: str | None = None
    silhouette_log_eps: float | None = None
    laplacian_pin: str | None = None
    remesh_adapt: float | None = None


#: Settings every recipe shares unless it says otherwise.
_COMMON = dict(textured_iters=2000, edge_px=3.0, views_per_step=2, lr=1.0, momentum=0.9,
               adam_lr=0.01, faces_per_pixel=50, color_reg=1e-4, contour_threshold=0.9,
               textured_weights=TUTORIAL_TEXTURED_WEIGHTS, texel_px=1.0, hull_upsample=1,
               hull_close_px=0.0, hull_fill_px=9.0, hull_grey_px=0.0, hull_margins=(0.0,),
               hull_vote_depth=0.0, hull_close_handles=0.0, hull_per_part=False,
               silhouette_grey_px=0.0, final_regularization=1.0, rgb_iters=0, rgb_weight=1.0,
               rgb_silhouette=0.0, rgb_large_steps=10.0, rgb_color_reg=1e-4,
               rgb_color_smooth=0.0, rgb_inner_px=0, rgb_supersample=2, rgb_method="lbfgs", rgb_lr=0.1,
               rgb_regularization=1.0, laplacian_anchor="none",
               silhouette_log_eps=0.0, laplacian_pin="none", remesh_adapt=0.0)

#: Recipes of :func:`fit_mesh_to_views`: named :class:`ViewsFitOptions` presets.
#: ``"default"`` starts from the visual hull and remeshes as the surface moves;
#: ``"sphere-lbfgs"`` is L-BFGS on all views from the tutorial's ``ico_sphere(4)``;
#: ``"tutorial"`` the tutorial's SGD for both stages; ``"contour"`` Adam on the hard
#: silhouette's contour gradients.
RECIPES: dict[str, ViewsFitOptions] = {
    "default": ViewsFitOptions(
        silhouette_method="lbfgs", silhouette_loss="soft", textured_method="lstsq",
        textured_init="silhouette", large_steps=10.0, final_large_steps=1.0, init="hull",
        levels=((0, 2), (0, 1)),
        remesh_rounds=2, silhouette_iters=120, silhouette_weights=HULL_SILHOUETTE_WEIGHTS,
        texture="uv", **dict(_COMMON, rgb_iters=15, rgb_silhouette=1.0, rgb_large_steps=1.0,
                             rgb_weight=1.0, rgb_supersample=1, rgb_method="adam", rgb_lr=0.1,
                             rgb_regularization=0.3, final_regularization=0.5,
                             silhouette_grey_px=2.0, hull_close_handles=4.0)),
    "sphere-lbfgs": ViewsFitOptions(
        silhouette_method="lbfgs", silhouette_loss="soft", textured_method="lstsq",
        textured_init="silhouette", large_steps=0.0, init="sphere", levels=((0, 1),),
        remesh_rounds=0, silhouette_iters=2000,
        silhouette_weights=TUTORIAL_SILHOUETTE_WEIGHTS, texture="vertex", **_COMMON),
    "tutorial": ViewsFitOptions(
        silhouette_method="sgd", silhouette_loss="soft", textured_method="sgd",
        textured_init="sphere", large_steps=0.0, init="sphere", levels=((0, 1),),
        remesh_rounds=0, silhouette_iters=2000,
        silhouette_weights=TUTORIAL_SILHOUETTE_WEIGHTS, texture="vertex", **_COMMON),
    "contour": ViewsFitOptions(
        silhouette_method="adam", silhouette_loss="contour", textured_method="lstsq",
        textured_init="silhouette", large_steps=10.0, init="sphere", levels=((0, 1),),
        remesh_rounds=0, silhouette_iters=2000,
        silhouette_weights=TUTORIAL_SILHOUETTE_WEIGHTS, texture="vertex", **_COMMON),
}

#: Share of a time budget the silhouette stage leaves to the final stage (the colours' hard
#: render and sparse solve: about 1.5 s of a 30 s budget on the cow, measured under load).
FINAL_STAGE_SHARE = 0.1
#: The share it leaves with ``texture="uv"`` (the colours and the UV texture: on the cow's 20
#: views of 128 px the two take 3-5 s under load).
_TEXTURE_RESERVE = 0.15
#: The UV texture's wall time over the vertex colours' (the stage before it, on the same
#: views): 3.5-5.0 in five fits of the cow and the thin plate at loads 12-22 (both cast every
#: pixel ray and solve a sparse system, so both slow down alike). With a time budget the
#: texture is skipped when this times the colours' seconds does not fit in what is left.
_TEXTURE_PER_COLOURS = 5.0
_ADAM_PHASES = (1.0, 0.3, 0.1)  # lr factors of the contour method's Adam phases
_ADAM_LEVEL_DECAY = 0.3         # and per coarse-to-fine level
# the overall status of a fit is the first of these that a stage ended with
_STATUS_ORDER = ("nonfinite", "failed", "diverged", "callback", "stalled", "time_budget",
                 "max_eval", "max_iter", "converged")


# =========================================================================================
# Result
# =========================================================================================


@dataclass(kw_only=True)
class ViewsFitResult(FitResult):
    """Result of :func:`fit_mesh_to_views`.

    Attributes
    ----------
    mesh : Mesh
        The fitted mesh, after a textured stage with ``TexturesUV`` (``options.texture``
        ``"uv"``, the default recipe's) or ``TexturesVertex`` (``"vertex"``).
    colors : (V, 3) float64 or None
        Fitted vertex colours (also with a UV texture: they fill the texels no view sees).
    silhouette_mesh : Mesh
        The mesh after the silhouette stage.
    stages : list of dict
        Per stage: name, method, status, message, seconds, iterations, evaluations.
    init : str
        The initialisation used: ``"hull"`` (visual hull), ``"sphere"`` or ``"user"``.
    init_mesh : Mesh
        The starting mesh.
    topology : geofit.ops.TopologyReport or None
        Genus, boundary loops, parts, non-manifold edges and self-intersecting face pairs of
        the fitted mesh (a self-intersecting result says so in ``message``); None when the
        time budget was used up before it could be checked.
    """

    mesh: Mesh = None
    colors: np.ndarray | None = None
    silhouette_mesh: Mesh = None
    stages: list = field(default_factory=list)
    init: str = ""
    init_mesh: Mesh = None
    topology: Any = None

    @property
    def textured_mesh(self) -> Mesh:
        """The fitted mesh with its UV texture, or else its vertex colours (clipped to [0, 1];
        uniform grey 0.7 when no textured stage ran), ready to render or save."""
        if isinstance(self.mesh.textures, TexturesUV):
            return self.mesh
        return colored_mesh(self.mesh, self.colors)

    def render(self, views: MultiViewDataset, *, n_views: int | None = None) -> np.ndarray:
        """(N, H, W, 3) float64 renders of :attr:`textured_mesh` at ``views`` (e.g. the
        dataset's held-out views; :func:`render_mesh_at_views`)."""
        return render_mesh_at_views(self.textured_mesh, views, n_views=n_views)

    def summary(self) -> dict[str, Any]:
        d = super().summary()
        d["init"] = self.init
        d["n_verts"] = self.mesh.n_verts if self.mesh is not None else 0
        if self.topology is not None:
            d["topology"] = self.topology.as_dict()
        return d


# =========================================================================================
# The fit
# =========================================================================================


def _check_adapt(value) -> float:
    """``options.remesh_adapt``: degrees in [0, 180]."""
    v = check_positive(value, "options.remesh_adapt", strict=False)
    if v > 180.0:
        raise ValueError(f"options.remesh_adapt: expected degrees in [0, 180], got {value!r}")
    return float(v)


def _levels(levels, mesh_level_final: int, image_size):
    """Coarse-to-fine schedule: list of (subdivisions to apply before, downsample factor)."""
    if levels is None:
        return [(0, 1)]
    out = []
    for i, lv in enumerate(levels):
        try:
            sub, fac = int(lv[0]), int(lv[1])
        except (TypeError, ValueError, IndexError):
            raise ValueError(f"levels[{i}]: expected (subdivisions, downsample factor), got "
                             f"{lv!r}") from None
        if sub < 0 or fac < 1:
            raise ValueError(f"levels[{i}]: expected subdivisions >= 0 and factor >= 1, got "
                             f"{lv!r}")
        out.append((sub, fac))
    return out


@dataclass
class _Recorder:
    """Records history rows, checks finiteness, runs the observer's evaluation at checkpoints."""

    h: FitHistory
    clock: Clock
    evaluate: Callable | None
    eval_every: int
    callback: Callable | None
    stage: int
    step0: int
    bar: object = field(default_factory=NoBar)
    last_eval: float = -math.inf  # the step of the last checkpoint
    steps: int = 0

    def __call__(self, obj: _Objective, info, mesh_fn, colors_fn, force_eval=False) -> bool:
        self.steps += 1
        last = getattr(obj, "_cache", {}).get(np.asarray(info.x).tobytes(), obj.last)
        terms = last.get("terms", {})
        value = float(info.value)
        step = self.step0 + self.steps
        seconds = self.clock.elapsed()
        metrics = None
        if self.evaluate is not None and (force_eval or step - self.last_eval
                                          >= self.eval_every):
            with self.clock.paused(caller=True):
                metrics = self.evaluate(mesh_fn(info.x), colors_fn(info.x))
            self.last_eval = step
        if self.h.terms and set(terms) != set(self.h.terms):
            terms = {k: terms.get(k, 0.0) for k in self.h.terms}
        self.h.record(step, seconds, value, terms, metrics, n_params=len(info.x),
                      stage=self.stage)
        advance(self.bar, self.clock, dict(loss=f"{value:.4g}", stage=self.stage)
                if self.steps % 10 == 1 else None)
        if self.callback is not None:
            with self.clock.paused(caller=True):
                stop = self.callback(info._replace(stage=self.stage, terms=dict(terms),
                                                   metrics=metrics))
            return bool(stop)
        return False


def fit_mesh_to_views(dataset: MultiViewDataset, *, recipe: str = "default",
                      options: ViewsFitOptions | None = None,
                      time_budget: float | None = None, seed=0,
                      evaluator: Callable | None = None, eval_every: int | None = None,
                      callback: Callable[[StepInfo], bool | None] | None = None,
                      progress: bool = True) -> ViewsFitResult:
    """Fit a mesh to multi-view silhouettes, then its colours (tutorial 4).

    The default starts from the visual hull of the silhouettes (its genus and parts), and
    alternates L-BFGS on the soft silhouettes of all views (large steps, half then full
    resolution) with remeshing to edges of ``edge_px`` pixels, then refines the vertices
    against the RGB images (the hard image term with the colours solved inside every
    evaluation, the silhouettes kept; ``options.rgb_iters``); the vertex colours then come
    from one sparse least-squares solve, and the result's mesh carries a UV texture solved
    likewise (:func:`geofit.fit.texture.fit_texture`, ``options.texture``).

    Parameters
    ----------
    dataset : MultiViewDataset
        Training views: cameras, soft silhouettes and (for a textured stage) RGB images.
    recipe : {"default", "sphere-lbfgs", "tutorial", "contour"}
        Named settings (:data:`RECIPES`, presets of :class:`ViewsFitOptions`): ``"default"``
        the visual hull, large steps, coarse-to-fine and remeshing as above;
        ``"sphere-lbfgs"`` L-BFGS on the soft silhouettes of all views from the ico-sphere;
        ``"tutorial"`` the tutorial's SGD (two random views per step) for both stages, the
        textured one from the sphere; ``"contour"`` Adam on the hard silhouette's contour
        gradients, large steps 10.
    options : ViewsFitOptions, optional
        Settings that override the recipe's (every field left None keeps the recipe's).
    time_budget : float, optional
        Wall-clock seconds for the whole fit: the start (the visual hull, carved view by view
        with the clock checked between views), the solves (checked between view batches inside
        each evaluation), the remeshing and the final stage; not the time spent in the
        evaluator or callback you pass. The geometry leaves :data:`FINAL_STAGE_SHARE` of it
        (15 % with ``texture="uv"``) to the final stage: the colours (one sparse solve) and
        the UV texture (one sparse solve); the silhouette stage shares the rest over its
        solves and the RGB stage gets what it leaves (the silhouettes' geometry is what a
        short budget buys first; on the cow's 20 views of 128 px a 30 s budget left the RGB
        stage nothing in our runs).
        If the budget is spent before the texture, or what is left is less than the texture's
        predicted time (five times the colours' stage, as measured under load), the mesh
        keeps its vertex colours and the ``"texture"`` stage says so. A budget used up while
        carving the hull returns the unfitted ico-sphere with status ``"time_budget"`` and
        says so. None (the default): no budget; the default fit of the tutorial's 20 views of
        128 px of the cow then needs about 36 s wall and 62 CPU s on 2 cores (quiet machine,
        load 1.3; benchmarks/results/fit_views_shapes_session11.md); larger surfaces take
        longer (the thin plate 44 s, the open cylinder 51 s).
    seed : int or numpy.random.Generator
        For the random views of the stochastic recipes.
    evaluator : callable, optional
        ``evaluator(mesh, colors) -> dict`` run at checkpoints with the clock paused (e.g. a
        :class:`ViewsEvaluator` of held-out views; the last checkpoint is that of the vertex
        colours: score the UV texture with ``evaluator(result.textured_mesh)``).
    eval_every : int, optional
        Steps between checkpoints (default 10); the colours of the ``lstsq`` stage are always
        evaluated.
    callback : callable, optional
        ``callback(StepInfo) -> bool | None`` after every step; ``info.stage`` is the stage
        (the silhouette level, or 100 for the textured stage), ``info.terms`` the unweighted
        terms and ``info.metrics`` the checkpoint's metrics (or None). True stops the stage.
    progress : bool
        Show a tqdm progress bar (on stderr; one tick per iteration of either stage).

    Returns
    -------
    ViewsFitResult
        ``status`` is the most serious of the stages' statuses, in the order ``nonfinite``,
        ``failed``, ``diverged``, ``callback``, ``stalled``, ``time_budget``, ``max_eval``,
        ``max_iter``, ``converged``; ``stages`` has each stage's own status and message;
        ``textured_mesh`` the coloured result.
    """
    views = _as_dataset(dataset)
    plan = _Plan.validate(views, recipe, options, time_budget)
    run = _Solver(plan, seed=seed, evaluator=evaluator, eval_every=eval_every,
                  callback=callback, progress=progress)
    initial_mesh(plan, run)
    sil_mesh = plan.init
    # the geometry (its checks inside evaluations too) ends where the final stage's share of
    # the budget begins; the RGB stage gets what the silhouette stage leaves of it
    geometry_end = None if plan.time_budget is None else plan.time_budget - plan.reserve
    with run.clock.until(geometry_end):
        if plan.silhouette_method != "none":
            sil_mesh = _silhouette_stage(plan, run)
            if plan.rgb_iters and (not run.stages or run.stages[-1]["status"] not in
                                   ("nonfinite", "failed", "callback")):
                sil_mesh = _rgb_stage(plan, run, sil_mesh)
        elif plan.rgb_iters:  # a given mesh refined against the images alone
            sil_mesh = _rgb_stage(plan, run, sil_mesh)
    mesh, colors = sil_mesh, None
    if plan.textured_method != "none" and (not run.stages or run.stages[-1]["status"] not in
                                           ("nonfinite", "failed")):
        if run.clock.over():  # nothing left of the budget for the colours
            run.stages.append({"name": "textured", "method": plan.textured_method,
                               "status": "time_budget", "seconds": 0.0,
                               "message": f"not run: no time left of the budget of "
                                          f"{plan.time_budget:g} s (no colours)"})
        else:
            mesh, colors = _textured_stage(plan, run, sil_mesh)
    return _views_result(plan, run, mesh, colors, sil_mesh)


def _as_dataset(dataset) -> MultiViewDataset:
    """The training views, checked once at the door (silhouettes must be known)."""
    return as_dataset(dataset, fit="fit_mesh_to_views", images_required=False)


@dataclass
class _Plan:
    """The validated settings of one :func:`fit_mesh_to_views` call (recipe resolved)."""
    views: MultiViewDataset
    init: Mesh
    recipe: str
    silhouette_method: str
    silhouette_loss: str
    textured_method: str
    textured_init: str
    silhouette_weights: dict
    textured_weights: dict
    silhouette_iters: int
    textured_iters: int
    time_budget: float | None
    large_steps: float | None
    levels: list
    views_per_step: int
    lr: float
    momentum: float
    adam_lr: float
    faces_per_pixel: int
    color_reg: float
    contour_threshold: float | None
    init_name: str = "user"
    remesh_rounds: int = 0
    edge_px: float = 3.0
    init_info: dict = field(default_factory=dict)
    texture: str = "vertex"
    texel_px: float = 1.0
    reserve: float = 0.0  # seconds of the budget the geometry leaves to colours and texture
    hull_upsample: int = 1
    hull_close_px: float = 0.0
    hull_fill_px: float = 0.0
    hull_grey_px: float = 0.0
    hull_margins: tuple = (0.0,)
    hull_vote_depth: float = 0.0
    hull_close_handles: float = 0.0
    hull_per_part: bool = False
    grey_filled: int = 0  # target pixels at or below 0.5 that silhouette_grey_px raised
    rgb_iters: int = 0
    final_large_steps: float | None = None  # the last level's lambda (None: large_steps)
    final_regularization: float = 1.0  # factor on the regularisers at the last level
    rgb_weight: float = 1.0
    rgb_silhouette: float = 0.0
    rgb_large_steps: float = 10.0
    rgb_color_reg: float = 1e-4
    rgb_color_smooth: float = 0.0
    rgb_inner_px: int = 0
    rgb_supersample: int = 2
    rgb_method: str = "lbfgs"
    rgb_lr: float = 0.1
    rgb_regularization: float = 1.0
    laplacian_anchor: str = "none"
    silhouette_log_eps: float = 0.0
    laplacian_pin: str = "none"
    remesh_adapt: float = 0.0

    @classmethod
    def validate(cls, dataset: MultiViewDataset, recipe, options, time_budget) -> _Plan:
        """Check every option once and fill in the recipe's."""
        recipe = recipe_name(recipe, RECIPES, fit="fit_mesh_to_views")
        rec = RECIPES[recipe]
        o = merge_options(rec, options, ViewsFitOptions, "options")
        sm, loss, tm, ti = (o.silhouette_method, o.silhouette_loss, o.textured_method,
                            o.textured_init)
        check_choice(sm, "options.silhouette_method", SILHOUETTE_METHODS + ("none",))
        check_choice(loss, "options.silhouette_loss", SILHOUETTE_LOSSES)
        if loss == "contour" and sm not in ("adam", "none"):
            raise ValueError(f"options.silhouette_loss: 'contour' gradients are not those of a "
                             f"smooth objective; expected silhouette_method='adam', got {sm!r}")
        check_choice(tm, "options.textured_method", TEXTURED_METHODS)
        check_choice(o.laplacian_anchor, "options.laplacian_anchor", LAPLACIAN_ANCHORS)
        check_choice(o.laplacian_pin, "options.laplacian_pin", LAPLACIAN_PINS)
        if o.laplacian_pin != "none" and o.laplacian_anchor == "none":
            raise ValueError(f"options.laplacian_pin: {o.laplacian_pin!r} mixes the anchored "
                             f"Laplacian in; expected a laplacian_anchor other than 'none', got "
                             f"'none'")
        check_choice(o.rgb_method, "options.rgb_method", RGB_METHODS)
        check_choice(ti, "options.textured_init", ("silhouette", "sphere"))
        if sm == "none" and tm == "none":
            raise ValueError("options: silhouette_method and textured_method are both 'none': "
                             "nothing to fit")
        if tm != "none" and dataset.images is None:
            raise ValueError("dataset: a textured stage needs RGB images (dataset.images is "
                             "None)")
        user = options if options is not None else ViewsFitOptions()
        sw = check_weights(user.silhouette_weights, rec.silhouette_weights,
                           "options.silhouette_weights")
        tw = check_weights(user.textured_weights, rec.textured_weights,
                           "options.textured_weights")
        remesh_rounds = check_int(o.remesh_rounds, "options.remesh_rounds", 0)
        edge_px = check_positive(o.edge_px, "options.edge_px")
        for nm in ("silhouette_iters", "textured_iters", "views_per_step", "faces_per_pixel"):
            check_int(getattr(o, nm), f"options.{nm}")
        if o.views_per_step > len(dataset):
            raise ValueError(f"options.views_per_step: expected at most {len(dataset)} (the "
                             f"number of views), got {o.views_per_step}")
        large_steps = check_positive(o.large_steps, "options.large_steps", strict=False) or None
        lv = _levels(o.levels, 4, dataset.image_size)
        init = o.init
        if isinstance(init, str):
            check_choice(init, "options.init", INITS)
            init_name = init
            init = ico_sphere(max(4 - sum(s for s, _ in lv), 0)) if init == "sphere" else None
        else:
            init_name = "user"
            init = as_mesh(init, "init")  # a geofit, trimesh or Open3D mesh
        H, W = dataset.image_size
        for _, f_ in lv:
            if H % f_ or W % f_:
                raise ValueError(f"options.levels: factor {f_} does not divide the image size "
                                 f"{(H, W)}")
        if time_budget is not None:
            time_budget = check_positive(time_budget, "time_budget")
        threshold = check_positive(o.contour_threshold, "options.contour_threshold",
                                   strict=False) or None
        check_choice(o.texture, "options.texture", TEXTURES)
        texel_px = check_positive(o.texel_px, "options.texel_px")
        uv = o.texture == "uv" and tm != "none"
        reserve = 0.0 if time_budget is None or tm == "none" else \
            (_TEXTURE_RESERVE if uv else FINAL_STAGE_SHARE) * time_budget
        rgb_iters = check_int(o.rgb_iters, "options.rgb_iters", 0)
        if user.rgb_iters is None and (dataset.images is None or sm == "none"):
            # the recipe's RGB stage refines the silhouette stage's result; silhouettes alone
            # have nothing for it (rgb_iters set explicitly refines a given mesh, or refuses)
            rgb_iters = 0
        if rgb_iters and dataset.images is None:
            raise ValueError("options.rgb_iters: the RGB refinement needs RGB images "
                             "(dataset.images is None)")
        if not isinstance(o.hull_per_part, (bool, np.bool_)):
            raise TypeError(f"options.hull_per_part: expected a bool, got "
                            f"{o.hull_per_part!r}")
        grey_px = check_positive(o.silhouette_grey_px, "options.silhouette_grey_px",
                                 strict=False)
        grey_filled = 0
        if grey_px > 0:  # the targets' grey cores (a dense mesh's K-nearest cut) covered
            sil, grey_filled = fill_grey_cores(dataset.silhouettes, grey_px,
                                               images=dataset.images,
                                               background=dataset.background)
            dataset = replace(dataset, silhouettes=sil)
        return cls(dataset, init, recipe, sm, loss, tm, ti, sw, tw, o.silhouette_iters,
                   o.textured_iters, time_budget, large_steps, lv, o.views_per_step,
                   check_positive(o.lr, "options.lr"),
                   check_positive(o.momentum, "options.momentum", strict=False),
                   check_positive(o.adam_lr, "options.adam_lr"), o.faces_per_pixel,
                   check_positive(o.color_reg, "options.color_reg", strict=False), threshold,
                   init_name, remesh_rounds, edge_px, texture=o.texture, texel_px=texel_px,
                   reserve=reserve,
                   hull_upsample=check_int(o.hull_upsample, "options.hull_upsample"),
                   hull_close_px=check_positive(o.hull_close_px, "options.hull_close_px",
                                                strict=False),
                   hull_fill_px=check_positive(o.hull_fill_px, "options.hull_fill_px",
                                               strict=False),
                   hull_grey_px=check_positive(o.hull_grey_px, "options.hull_grey_px",
                                               strict=False),
                   hull_margins=_check_margins(o.hull_margins, "options.hull_margins"),
                   hull_vote_depth=check_positive(o.hull_vote_depth, "options.hull_vote_depth",
                                                  strict=False),
                   hull_close_handles=check_positive(o.hull_close_handles,
                                                     "options.hull_close_handles",
                                                     strict=False),
                   hull_per_part=bool(o.hull_per_part), grey_filled=grey_filled,
                   rgb_iters=rgb_iters,
                   rgb_weight=check_positive(o.rgb_weight, "options.rgb_weight"),
                   rgb_silhouette=check_positive(o.rgb_silhouette, "options.rgb_silhouette",
                                                 strict=False),
                   rgb_large_steps=check_positive(o.rgb_large_steps, "options.rgb_large_steps",
                                                  strict=False),
                   rgb_color_reg=check_positive(o.rgb_color_reg, "options.rgb_color_reg",
                                                strict=False),
                   rgb_color_smooth=check_positive(o.rgb_color_smooth,
                                                   "options.rgb_color_smooth", strict=False),
                   rgb_inner_px=check_int(o.rgb_inner_px, "options.rgb_inner_px", 0),
                   rgb_supersample=check_int(o.rgb_supersample, "options.rgb_supersample", 1),
                   rgb_method=o.rgb_method,
                   rgb_lr=check_positive(o.rgb_lr, "options.rgb_lr"),
                   rgb_regularization=check_positive(o.rgb_regularization,
                                                     "options.rgb_regularization",
                                                     strict=False),
                   laplacian_anchor=o.laplacian_anchor, laplacian_pin=o.laplacian_pin,
                   silhouette_log_eps=check_positive(o.silhouette_log_eps,
                                                     "options.silhouette_log_eps",
                                                     strict=False),
                   remesh_adapt=_check_adapt(o.remesh_adapt),
                   final_regularization=check_positive(
                       o.final_regularization, "options.final_regularization", strict=False),
                   final_large_steps=(large_steps if o.final_large_steps is None else
                                      check_positive(o.final_large_steps,
                                                     "options.final_large_steps",
                                                     strict=False) or None))

    def settings(self, size, persp=None) -> SoftRasterizationSettings:
        """The tutorial's soft rasterization at ``size`` with this fit's K, storing fragments
        in float64: the fit's gradients are solved by L-BFGS line searches (DESIGN: float64
        where gradients are checked and solved), and its benchmark figures were measured so."""
        return SoftRasterizationSettings.tutorial(size, faces_per_pixel=self.faces_per_pixel,
                                                  perspective_correct=persp, dtype=np.float64)

    def remaining(self, clock: Clock) -> float | None:
        """Seconds left of the time budget (None: no budget)."""
        if self.time_budget is None:
            return None
        return clock.remaining()


class _Solver:
    """The state shared by the stages of one fit: clock, history, progress bar, counters."""
    def __init__(self, plan: _Plan, *, seed, evaluator, eval_every, callback, progress):
        self.rng = as_rng(seed)
        # the fit's time budget: every stage checks it (Clock.check / Clock.remaining), the
        # visual hull between views, the objectives between view batches
        self.clock = Clock(plan.time_budget)
        self.history = FitHistory()
        if evaluator is not None and not callable(evaluator):
            raise TypeError(f"evaluator: expected a callable (mesh, colors) -> dict or None, "
                            f"got {type(evaluator)!r}")
        eval_every = 10 if eval_every is None else check_int(eval_every, "eval_every")
        self.evaluate, self.eval_every, self.callback = evaluator, eval_every, callback
        total = (plan.silhouette_iters if plan.silhouette_method != "none" else 0) + \
            (plan.textured_iters if plan.textured_method in ("sgd", "lbfgs") else 0)
        self.bar = progress_bar(progress, total, f"fit_mesh_to_views[{plan.silhouette_method}"
                                                 f"+{plan.textured_method}]")
        self.stages: list = []
        self.n_iterations = 0
        self.n_evaluations = 0
        self.step = 0

    def recorder(self, stage_index: int) -> _Recorder:
        """The per-step recorder of one solve (history, evaluation, callback, bar)."""
        return _Recorder(self.history, self.clock, self.evaluate, self.eval_every,
                         self.callback, stage_index, self.step, self.bar)

    def add(self, res, rec: _Recorder) -> None:
        """Count a finished solve's steps, iterations and evaluations."""
        self.step += rec.steps
        self.n_iterations += res.n_iterations
        self.n_evaluations += res.n_evaluations


def _silhouette_stage(plan: _Plan, run: _Solver) -> Mesh:
    """Deform the mesh to the silhouettes, level by level (remeshing before each solve when
    ``remesh_rounds``); returns the mesh."""
    t_stage = run.clock.elapsed()
    # the tutorial's SGD (random views per step) runs one level at full resolution
    sub_levels = [(0, 1)] if plan.silhouette_method == "sgd" else plan.levels
    rounds = max(plan.remesh_rounds, 1)
    n_solves = len(sub_levels) * rounds
    # iterations shared in proportion to the downsampling factor: the cheap coarse levels
    # get more of them
    total_fac = sum(f_ for _, f_ in sub_levels)
    mesh = plan.init
    status, message = "max_iter", ""
    stop = False
    if run.clock.over():  # e.g. spent carving the hull
        status, message = "time_budget", run.clock.status_words(0)
        stop = True
    for li, (sub, fac) in enumerate(sub_levels):  # coarse-to-fine levels
        if stop:
            break
        for _ in range(sub):  # subdivisions
            mesh = subdivide(mesh)
        data = plan.views.downsample(fac)
        weights = _level_weights(plan, sub_levels, li)
        for ri in range(rounds):  # remesh-and-solve rounds
            if run.clock.over():
                # the rest of the budget is the final stage's (Clock.until): no remeshing,
                # no solve
                status, message = "time_budget", run.clock.status_words(run.step)
                stop = True
                break
            if plan.remesh_rounds:
                # edge_px pixels, at most max_edge; at least the length that keeps the face
                # count and the soft rasterizer's entries bounded (a bounded time per
                # evaluation)
                floor = shortest_edge(float(mesh.face_areas.sum()),
                                      plan.init_info["pixel_size"], fac, data.image_size,
                                      plan.settings(data.image_size).blur_radius)
                length = max(min(plan.edge_px * fac * plan.init_info["pixel_size"],
                                 plan.init_info["max_edge"]), floor)
                mesh = (remesh_adaptive(mesh, length, math.radians(plan.remesh_adapt),
                                        longest=max(plan.init_info["max_edge"], length),
                                        shortest=fac * plan.init_info["pixel_size"])
                        if plan.remesh_adapt else remesh_to_length(mesh, length))
            k = li * rounds + ri
            budget = None
            if plan.time_budget is not None:
                budget = max(plan.remaining(run.clock) / (n_solves - k), 1e-3)
            lam = plan.final_large_steps if li == len(sub_levels) - 1 else plan.large_steps
            last = li == len(sub_levels) - 1
            anchored = plan.laplacian_anchor == "round" or (
                plan.laplacian_anchor == "last" and last) or (
                plan.laplacian_anchor == "final" and last and ri == rounds - 1)
            obj = _silhouette_objective(plan, run, mesh, data, weights, lam,
                                        anchor=mesh.verts if anchored else None)
            if anchored and plan.laplacian_pin != "none":
                obj.pin = silhouette_pinning(obj, mesh)
            iters = max(1, round(plan.silhouette_iters * fac / (rounds * total_fac)))
            mesh, res = _silhouette_solve(plan, run, obj, mesh, li, iters, budget)
            status, message = res.status, res.message
            run.history.note(run.step, run.clock.elapsed(),
                             f"silhouette level {li} round {ri}: {res.status}",
                             n_verts=mesh.n_verts, image_size=list(data.image_size))
            if res.status in ("nonfinite", "failed", "callback"):
                stop = True
                break
        if stop:
            break
    run.stages.append({"name": "silhouette", "method": plan.silhouette_method,
                       "status": status, "message": message,
                       "seconds": run.clock.elapsed() - t_stage})
    return mesh


def _level_weights(plan: _Plan, sub_levels, li: int) -> dict:
    """The silhouette stage's term weights at level ``li`` of ``sub_levels``."""
    # the regularisers scale with the squared edge length (1/4 per subdivision): on a
    # coarse level they get the weight that gives them their final-level magnitude
    later = sum(s_ for s_, _ in sub_levels[li + 1:])
    scale = 0.25 ** later * (plan.final_regularization if li == len(sub_levels) - 1 else 1.0)
    weights = {k: (v * scale if k in REG_TERMS else v)
               for k, v in plan.silhouette_weights.items()}
    if plan.recipe == "default":  # weights set in pixels (TUTORIAL_PIXEL)
        r = TUTORIAL_PIXEL / plan.init_info["pixel_size"]
        weights["edge"] *= r * r
        weights["laplacian"] *= r
    return weights


def _silhouette_objective(plan: _Plan, run: _Solver, mesh: Mesh,
                          data: MultiViewDataset, weights: dict, lam: float | None,
                          anchor: np.ndarray | None = None):
    """The objective of one level: soft silhouettes, or the contour term (large steps
    ``lam``); ``anchor``: the Laplacian's rest vertices (``options.laplacian_anchor``)."""
    param = vertex_parameterization(mesh, lam)
    if plan.silhouette_loss == "contour":

        closs = ContourSilhouetteLoss(data.cameras, data.silhouettes,
                                      threshold=plan.contour_threshold)
        return _ContourObjective(mesh, closs, weights, param, anchor=anchor)
    vps = plan.views_per_step if plan.silhouette_method == "sgd" else None
    obj = _Objective(mesh, data, weights, textured=False, param=param,
                     settings=plan.settings(data.image_size), views_per_step=vps, rng=run.rng,
                     anchor=anchor, log_eps=plan.silhouette_log_eps)
    obj.clock = run.clock
    return obj


def _silhouette_solve(plan: _Plan, run: _Solver, obj, mesh: Mesh, li: int,
                      iters: int, budget: float | None):
    """Run the silhouette method on one level's objective; returns the mesh and the result."""
    rec = run.recorder(li)
    x0 = obj.param.to_params(mesh.verts).ravel()

    def cb(info, obj=obj, rec=rec):
        return rec(obj, info, lambda x: obj.base.update_verts(obj.split(x)[0]), lambda x: None)

    method, clock = plan.silhouette_method, run.clock
    if method == "sgd":
        res = sgd(obj, x0, lr=plan.lr, momentum=plan.momentum, n_iter=iters,
                  time_budget=budget, callback=cb, clock=clock)
    elif method == "lbfgs":
        res = lbfgs_scipy(obj, x0, max_iter=iters, time_budget=budget, callback=cb, clock=clock)
    elif method == "lbfgs-nlopt":
        res = lbfgs_nlopt(obj, x0, max_eval=iters, time_budget=budget, callback=cb, clock=clock)
    else:
        res = _adam_phases(obj, x0, lr=plan.adam_lr, decay=_ADAM_LEVEL_DECAY ** li,
                           iters=iters, budget=budget, callback=cb, clock=clock)
    run.add(res, rec)
    return obj.base.update_verts(obj.split(res.x)[0]), res


def _rgb_stage(plan: _Plan, run: _Solver, mesh: Mesh) -> Mesh:
    """Refine the vertices against the RGB images (hard image term, variable-projection
    colours, large steps, L-BFGS; :func:`geofit.fit._rgb_refine.refine_rgb`); returns the
    mesh."""
    t_stage = run.clock.elapsed()
    if run.clock.over():  # the geometry's part of the budget is spent (e.g. on the hull)
        run.stages.append({"name": "rgb", "method": "lbfgs", "status": "time_budget",
                           "seconds": 0.0, "message": "not run: " + run.clock.status_words()})
        return mesh
    v = plan.views
    bg = dataset_background(v)
    extra = None
    if plan.rgb_silhouette:
        # the last level's silhouettes and regularisers stay in the objective: the outline
        # the silhouettes put right is kept, the mesh stays regular
        weights = _level_weights(plan, plan.levels, len(plan.levels) - 1)
        weights["silhouette"] = weights.get("silhouette", 0.0) * plan.rgb_silhouette
        weights = {k: (w * plan.rgb_regularization if k in REG_TERMS else w)
                   for k, w in weights.items()}
        obj = _silhouette_objective(plan, run, mesh, v, weights, None, anchor=(
            mesh.verts if plan.laplacian_anchor != "none" else None))
        if plan.laplacian_anchor != "none" and plan.laplacian_pin != "none":
            obj.pin = silhouette_pinning(obj, mesh)

        def extra(verts, obj=obj):
            value, g = obj(verts.ravel())
            return value, g.reshape(-1, 3)

    res = refine_rgb(mesh, v.cameras, v.images, lights=dataset_lights(v), background=bg,
                     lam=plan.rgb_large_steps, reg=plan.rgb_color_reg,
                     maxiter=plan.rgb_iters, extra=extra, image_weight=plan.rgb_weight,
                     smooth=plan.rgb_color_smooth, supersample=plan.rgb_supersample,
                     method=plan.rgb_method,
                     lr=plan.rgb_lr * plan.init_info.get("pixel_size", TUTORIAL_PIXEL),
                     masks=(interior_masks(v.silhouettes, plan.rgb_inner_px)
                            if plan.rgb_inner_px else None),
                     clock=run.clock if plan.time_budget is not None else None)
    run.n_evaluations += res.n_evaluations
    status = "time_budget" if res.stopped else "max_iter"
    gain = f", loss {res.values[0]:.4g} -> {min(res.values):.4g}" if res.values else ""
    run.history.note(run.step, run.clock.elapsed(),
                     f"rgb refinement: {res.n_evaluations} evaluations{gain}",
                     n_verts=res.mesh.n_verts)
    run.stages.append({"name": "rgb", "method": "lbfgs", "status": status,
                       "message": "vertices against the RGB images (hard image term, "
                                  "least-squares colours inside the loop)",
                       "seconds": run.clock.elapsed() - t_stage})
    return res.mesh


def _adam_phases(obj, x0, *, lr, decay, iters, budget, callback, clock):
    """Adam with a step decay: three phases at lr, lr / 3 and lr / 10 (the contour gradient
    does not vanish at the optimum, pixel noise stays; smaller steps settle it), splitting the
    iterations and the time budget."""
    x, n_it, n_ev = x0, 0, 0
    t_level = clock.elapsed()
    for k, factor in enumerate(_ADAM_PHASES):  # lr phases
        b = None
        if budget is not None:
            left = budget - (clock.elapsed() - t_level)
            b = max(left / (len(_ADAM_PHASES) - k), 1e-3)
        res = adam(obj, x, lr=lr * factor * decay, n_iter=max(1, iters // len(_ADAM_PHASES)),
                   time_budget=b, callback=callback, clock=clock)
        x = res.x
        n_it += res.n_iterations
        n_ev += res.n_evaluations
        if res.status in ("nonfinite", "diverged", "callback"):
            break
    return replace(res, n_iterations=n_it, n_evaluations=n_ev)


def _textured_stage(plan: _Plan, run: _Solver, sil_mesh: Mesh):
    """Fit the vertex colours (and, for sgd / lbfgs, the positions); returns the textured
    mesh and the colours."""
    t_stage = run.clock.elapsed()
    tex_mesh = sil_mesh if plan.textured_init == "silhouette" else plan.init
    if plan.textured_method == "sgd":
        tex_mesh, colors, res = _textured_solve(plan, run, tex_mesh, None)
        status, message = res.status, res.message
    else:
        colors = _lstsq_colors(tex_mesh, plan.views, plan.color_reg)
        status, message = "converged", "colours by sparse least squares on the hard render"
        if run.evaluate is not None:
            with run.clock.paused(caller=True):
                metrics = run.evaluate(tex_mesh, colors)
            h = run.history
            h.checkpoint(max(run.step, h.steps[-1] if h.steps else 0),
                         max(run.clock.elapsed(), h.seconds[-1] if h.seconds else 0.0), metrics)
        if plan.textured_method == "lbfgs":
            tex_mesh, colors, res = _textured_solve(plan, run, tex_mesh, colors)
            status, message = res.status, res.message
    mesh = colored_mesh(tex_mesh, colors)
    run.stages.append({"name": "textured", "method": plan.textured_method, "status": status,
                       "message": message, "seconds": run.clock.elapsed() - t_stage})
    if plan.texture == "uv" and status not in ("nonfinite", "failed"):
        mesh = _uv_texture_stage(plan, run, tex_mesh, colors)
    return mesh, colors


def _uv_texture_stage(plan: _Plan, run: _Solver, tex_mesh: Mesh, colors) -> Mesh:
    """The final geometry with a UV texture (:func:`geofit.fit.texture.fit_texture`: the
    dataset's lights or unlit colour, the vertex colours as the prior of texels no view sees);
    the vertex-coloured mesh if the time budget is already spent."""
    t_stage = run.clock.elapsed()
    stage = {"name": "texture", "method": "uv"}
    prev = run.stages[-1]  # the colours' stage (a sparse solve when "lstsq")
    need = _TEXTURE_PER_COLOURS * prev["seconds"] if prev["method"] == "lstsq" else 0.0
    if run.clock.over() or (plan.time_budget is not None and run.clock.remaining() < need):
        run.stages.append({**stage, "status": "time_budget", "seconds": 0.0,
                           "message": f"not run: {max(run.clock.remaining(), 0.0):.3g} s left "
                                      f"of the time budget, the texture needs about "
                                      f"{need:.3g} s: vertex colours kept"})
        return colored_mesh(tex_mesh, colors)
    views = plan.views
    bg = dataset_background(views)
    base = Mesh(tex_mesh.verts, tex_mesh.faces)
    tex = fit_texture(base, views.cameras, views.images, lights=dataset_lights(views),
                      background=bg, texel_px=plan.texel_px, prior=colors)
    mesh = Mesh(base.verts, base.faces, tex)
    H, W = tex.maps.shape[:2]
    run.stages.append({**stage, "status": "converged", "seconds": run.clock.elapsed() - t_stage,
                       "message": f"a {W} x {H} texel atlas by sparse (robust) least squares"})
    return mesh


def _textured_solve(plan: _Plan, run: _Solver, tex_mesh: Mesh, colors):
    """Positions and colours by the tutorial's SGD (``colors`` None: from 0.5, random views)
    or by joint L-BFGS over all views from ``colors``."""
    sgd_ = colors is None
    param = vertex_parameterization(tex_mesh, None if sgd_ else plan.large_steps)
    obj = _Objective(tex_mesh, plan.views, plan.textured_weights, textured=True, param=param,
                     settings=plan.settings(plan.views.image_size, persp=False),
                     views_per_step=plan.views_per_step if sgd_ else None,
                     rng=run.rng if sgd_ else None)
    obj.clock = run.clock
    c0 = np.full(3 * tex_mesh.n_verts, 0.5) if sgd_ else colors.ravel()
    x0 = np.concatenate([param.to_params(tex_mesh.verts).ravel(), c0])
    rec = run.recorder(100)

    def cb(info, obj=obj, rec=rec):
        return rec(obj, info, lambda x: obj.base.update_verts(obj.split(x)[0]),
                   lambda x: obj.split(x)[1])

    budget = None if plan.time_budget is None else max(plan.remaining(run.clock), 1e-3)
    if sgd_:
        res = sgd(obj, x0, lr=plan.lr, momentum=plan.momentum, n_iter=plan.textured_iters,
                  time_budget=budget, callback=cb, clock=run.clock)
    else:
        res = lbfgs_scipy(obj, x0, max_iter=plan.textured_iters, time_budget=budget,
                          callback=cb, clock=run.clock)
    v, colors = obj.split(res.x)
    run.add(res, rec)
    return tex_mesh.update_verts(v), colors, res


def _views_result(plan: _Plan, run: _Solver, mesh: Mesh, colors,
                  sil_mesh: Mesh) -> ViewsFitResult:
    """The overall status (the most serious of the stages') and the result."""
    run.bar.close()
    statuses = [s["status"] for s in run.stages]
    final = next(s for s in _STATUS_ORDER if s in statuses)

    msg = "; ".join(f"{s['name']} ({s['method']}): {s['status']} - {s['message']}"
                    for s in run.stages)
    # the topology report needs Open3D (its first import takes seconds under load): not
    # once the time budget is used up
    topo = None
    if not run.clock.over():
        with run.clock.paused():
            topo = topology(Mesh(mesh.verts, mesh.faces))
    msg = f"init: {plan.init_info.get('description', plan.init_name)}; {msg}; result: " + \
        (topo.describe() if topo is not None else "topology not checked (no time left)")
    uv = isinstance(mesh.textures, TexturesUV)
    if topo is not None and topo.n_self_intersecting_pairs > 0:
        msg += " (the fitted surface self-intersects)"
    return ViewsFitResult(status=final, message=msg, history=run.history,
                          n_params=mesh.n_verts * (6 if colors is not None else 3) + (
                              mesh.textures.maps.size if uv else 0),
                          seconds=run.clock.elapsed(), cpu_seconds=run.clock.cpu_elapsed(),
                          wall_seconds=run.clock.wall(),
                          total_cpu_seconds=run.clock.cpu_total(),
                          n_iterations=run.n_iterations, n_evaluations=run.n_evaluations,
                          mesh=mesh, colors=colors, silhouette_mesh=sil_mesh,
                          stages=run.stages,
                          method=f"{plan.silhouette_method}+{plan.textured_method}",
                          recipe=plan.recipe, init=plan.init_name, init_mesh=plan.init,
                          topology=topo)
