"""Held-out evaluation of :func:`geofit.fit.fit_mesh_to_views` (:class:`ViewsEvaluator`; image
metrics from :mod:`geofit.metrics`)."""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..metrics import MeshEvaluator, psnr, silhouette_iou
from ..render import (
    BlendParams,
    MeshRasterizer,
    MeshRenderer,
    RasterizationSettings,
    SoftPhongShader,
)
from ..structures import Mesh, MultiViewDataset, TexturesVertex
from ._views_objective import dataset_background, dataset_lights

__all__ = ["ViewsEvaluator", "colored_mesh", "render_mesh_at_views"]

#: The grey of a mesh without fitted colours.
GREY = 0.7


def colored_mesh(mesh: Mesh, colors=None) -> Mesh:
    """``mesh`` with per-vertex colours (:class:`~geofit.structures.TexturesVertex`), clipped to
    [0, 1]; ``colors`` None: uniform grey (0.7)."""
    if colors is None:
        colors = np.full((mesh.n_verts, 3), GREY)
    return Mesh(mesh.verts, mesh.faces, TexturesVertex(np.clip(colors, 0.0, 1.0)))


def render_mesh_at_views(mesh: Mesh, views: MultiViewDataset, colors=None, *,
                         n_views: int | None = None) -> np.ndarray:
    """Render ``mesh`` at the cameras of ``views`` (e.g. a dataset's held-out views).

    Parameters
    ----------
    mesh : Mesh
        The mesh; its own textures are used when ``colors`` is None and it has some, else
        ``colors``, else uniform grey.
    views : MultiViewDataset
        Cameras, image size, lights and background: the dataset's lights, or unlit colour
        (``AmbientLights``) when it has none (a capture: its lighting is in its pixels), the
        one light choice of the views fit; the dataset's background colour when it has one.
    colors : (V, 3) float64, optional
        Vertex colours (clipped to [0, 1]).
    n_views : int, optional
        Render only the first ``n_views`` views.

    Returns
    -------
    (N, H, W, 3) float64
        Hard-rasterised (one ray per pixel) Phong-shaded RGB on the views' background, as the
        held-out metrics of :class:`ViewsEvaluator` see it.
    """
    if not isinstance(views, MultiViewDataset):
        raise TypeError(f"views: expected a MultiViewDataset, got {type(views)!r}")
    if colors is not None or mesh.textures is None:
        mesh = colored_mesh(mesh, colors)
    cams = views.cameras if n_views is None else views.cameras[np.arange(min(n_views,
                                                                             len(views)))]
    ras = MeshRasterizer(cams, RasterizationSettings(image_size=views.image_size))
    blend = BlendParams(background_color=dataset_background(views))
    r = MeshRenderer(ras, SoftPhongShader(cameras=cams, lights=dataset_lights(views),
                                          blend_params=blend))
    return np.asarray(r(mesh)[..., :3], np.float64)


class ViewsEvaluator:
    """Held-out silhouette IoU and RGB PSNR, and surface accuracy against the true mesh.

    Parameters
    ----------
    heldout : MultiViewDataset
        Binary silhouettes and (optionally) RGB of the held-out views (e.g. a dataset's
        ``held_out``).
    target_mesh : Mesh, optional
        The true surface (chamfer-L2 and F-score via :class:`geofit.metrics.MeshEvaluator`).
    n_samples : int
        Surface samples for the mesh metrics.
    taus : sequence of float
        F-score thresholds.

    Notes
    -----
    Predictions are rendered with :class:`geofit.render.MeshRenderer` (one ray per pixel: the
    hard render the targets were made with); the predicted silhouette is the coverage mask and
    the RGB is Phong shading of the vertex colours (or of the mesh's textures) with the
    dataset's light.
    """

    def __init__(self, heldout: MultiViewDataset, target_mesh: Mesh | None = None, *,
                 n_samples: int = 20000, taus: Sequence[float] = (0.01, 0.02)):
        if not isinstance(heldout, MultiViewDataset):
            raise TypeError(f"heldout: expected a MultiViewDataset, got {type(heldout)!r}")
        self.heldout = heldout
        self.mesh_eval = None
        self.taus = tuple(taus)
        if target_mesh is not None:

            self.mesh_eval = MeshEvaluator(target_mesh, n_samples=n_samples, taus=self.taus)

    def __call__(self, mesh: Mesh, colors=None, *, surface: bool = True) -> dict[str, float]:
        """Metrics of a prediction (keys ``iou``, ``psnr`` if ``colors`` or the mesh's own
        textures (e.g. a fit's UV texture), ``chamfer_l2``, ``fscore@tau`` if a target mesh and
        ``surface``)."""

        h = self.heldout
        H, W = h.image_size
        ras = MeshRasterizer(h.cameras, RasterizationSettings(image_size=(H, W)))
        out: dict[str, float] = {}
        frag = ras(mesh)
        if h.silhouettes is not None:
            out["iou"] = float(silhouette_iou(frag.mask, h.silhouettes).mean())
        if (colors is not None or mesh.textures is not None) and h.images is not None:
            out["psnr"] = psnr(render_mesh_at_views(mesh, h, colors), h.images)
        if surface and self.mesh_eval is not None:
            mm = self.mesh_eval.evaluate(Mesh(mesh.verts, mesh.faces))
            out["chamfer_l2"] = float(mm.chamfer_l2)
            for t in self.taus:
                out[f"fscore@{t:g}"] = float(mm.fscore[t])
        return out
