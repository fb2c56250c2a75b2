"""Held-out evaluation of :func:`geofit.fit.fit_mesh_to_views` (:class:`ViewsEvaluator`; image
metrics from :mod:`geofit.metrics`)."""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..structures import MultiViewDataset
from ..metrics import psnr, silhouette_iou
from ..structures import Mesh, TexturesVertex
from ._views_objective import dataset_lights

__all__ = ["ViewsEvaluator"]


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
    the RGB is Phong shading of the vertex colours with the dataset's light.
    """

    def __init__(self, heldout: MultiViewDataset, target_mesh: Mesh | None = None, *,
                 n_samples: int = 20000, taus: Sequence[float] = (0.01, 0.02)):
        if not isinstance(heldout, MultiViewDataset):
            raise TypeError(f"heldout: expected a MultiViewDataset, got {type(heldout)!r}")
        self.heldout = heldout
        self.mesh_eval = None
        self.taus = tuple(taus)
        if target_mesh is not None:
            from ..metrics import MeshEvaluator

            self.mesh_eval = MeshEvaluator(target_mesh, n_samples=n_samples, taus=self.taus)

    def __call__(self, mesh: Mesh, colors=None, *, surface: bool = True) -> dict[str, float]:
        """Metrics of a prediction (keys ``iou``, ``psnr`` if colours, ``chamfer_l2``,
        ``fscore@tau`` if a target mesh and ``surface``)."""
        from ..render import (
            BlendParams,
            MeshRasterizer,
            MeshRenderer,
            RasterizationSettings,
            SoftPhongShader,
        )

        h = self.heldout
        H, W = h.image_size
        ras = MeshRasterizer(h.cameras, RasterizationSettings(image_size=(H, W)))
        out: dict[str, float] = {}
        frag = ras(mesh)
        if h.silhouettes is not None:
            out["iou"] = float(silhouette_iou(frag.mask, h.silhouettes).mean())
        if colors is not None and h.images is not None:
            m = Mesh(mesh.verts, mesh.faces, TexturesVertex(np.clip(colors, 0.0, 1.0)))
            blend = BlendParams() if h.background is None else BlendParams(
                background_color=tuple(h.background.tolist()))  # the capture's background
            r = MeshRenderer(ras, SoftPhongShader(cameras=h.cameras, lights=dataset_lights(h),
                                                  blend_params=blend))
            out["psnr"] = psnr(np.asarray(r(m)[..., :3], np.float64), h.images)
        if surface and self.mesh_eval is not None:
            mm = self.mesh_eval.evaluate(Mesh(mesh.verts, mesh.faces))
            out["chamfer_l2"] = float(mm.chamfer_l2)
            for t in self.taus:
                out[f"fscore@{t:g}"] = float(mm.fscore[t])
        return out
