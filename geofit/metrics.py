"""Accuracy against a reference: chamfer, F-score and normal consistency of surfaces; PSNR and
silhouette IoU of images.

Every benchmark in geofit reports these, computed the same way:

1. sample ``n_samples`` points uniformly by area on each surface (seeded, so the numbers are
   reproducible);
2. measure the **exact** Euclidean distance from every predicted sample to the target *surface*
   (``d_pt``) and from every target sample to the predicted surface (``d_tp``) with
   :class:`~geofit.raycast.PointToMeshDistance` (float64 closest points, no point-to-point
   nearest-neighbour bias);
3. combine:

   * ``chamfer_l2 = mean(d_pt**2) + mean(d_tp**2)`` -- the sum of the two mean squared
     distances, PyTorch3D's ``chamfer_distance`` convention (squared, mean per direction,
     directions summed), but against surfaces instead of a second point sample;
   * ``chamfer_l1 = mean(d_pt) + mean(d_tp)`` -- the same with unsquared distances (this is
     *not* PyTorch3D's ``norm=1``, which sums absolute coordinate differences);
   * ``precision(tau) = mean(d_pt < tau)``, ``recall(tau) = mean(d_tp < tau)`` and
     ``fscore(tau) = 2 P R / (P + R)`` (0 when both are 0) -- Knapitsch et al. 2017 (Tanks and
     Temples);
   * ``normal_consistency = (mean |n_p . n_t(closest)| + mean |n_t . n_p(closest)|) / 2``: the
     absolute cosine between the face normal at each sample and the face normal at its closest
     point on the other surface, averaged over both directions (Mescheder et al. 2019,
     Occupancy Networks). 1 means the orientations agree everywhere; orientation (sign) is
     ignored.

Distances are in the units of the meshes as given; pass ``normalize=True`` to evaluate in the
target's normalised frame (PyTorch3D's tutorial normalisation, :meth:`geofit.Mesh.normalize`,
applied to both meshes with the *target's* centre and scale), which is the frame in which the
benchmarks report.

Images: :func:`psnr` (``10 log10(max^2 / MSE)`` over every pixel and channel, inf for identical
images) and :func:`silhouette_iou` (per view, 1 where both silhouettes are empty).
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

from ._validate import as_rng, check_positive
from .ops import sample_points_from_meshes
from .raycast import PointToMeshDistance
from .structures import Mesh, as_mesh

__all__ = [
    "MeshEvaluator",
    "MeshMetrics",
    "chamfer_l1",
    "chamfer_l2",
    "evaluate_mesh",
    "fscore",
    "normal_consistency",
    "psnr",
    "silhouette_iou",
]


@dataclass(frozen=True)
class MeshMetrics:
    """Surface accuracy of a predicted mesh against a target (see :mod:`geofit.metrics`).

    Attributes
    ----------
    chamfer_l2 : float
        ``mean(d_pt**2) + mean(d_tp**2)``.
    chamfer_l1 : float
        ``mean(d_pt) + mean(d_tp)``.
    fscore : dict float -> float
        F-score at each threshold ``tau``.
    precision, recall : dict float -> float
        Fraction of predicted (resp. target) samples within ``tau`` of the other surface.
    normal_consistency : float
        Mean absolute cosine of the face normals at corresponding points, both directions.
    hausdorff : float
        ``max(max d_pt, max d_tp)`` over the samples.
    n_samples : int
        Samples per surface.
    """

    chamfer_l2: float
    chamfer_l1: float
    fscore: dict
    precision: dict
    recall: dict
    normal_consistency: float
    hausdorff: float
    n_samples: int

    def as_dict(self, prefix: str = "") -> dict[str, float]:
        """Flat ``{name: value}``; F-scores appear as ``fscore@<tau>`` (e.g. ``fscore@0.01``)."""
        out = {f"{prefix}chamfer_l2": self.chamfer_l2, f"{prefix}chamfer_l1": self.chamfer_l1,
               f"{prefix}normal_consistency": self.normal_consistency,
               f"{prefix}hausdorff": self.hausdorff}
        for tau in self.fscore:
            out[f"{prefix}fscore@{tau:g}"] = self.fscore[tau]
            out[f"{prefix}precision@{tau:g}"] = self.precision[tau]
            out[f"{prefix}recall@{tau:g}"] = self.recall[tau]
        return out

    def to_dict(self) -> dict:
        d = asdict(self)
        for k in ("fscore", "precision", "recall"):
            d[k] = {f"{tau:g}": v for tau, v in d[k].items()}
        return d


def _check_mesh(mesh, name: str) -> Mesh:
    mesh = as_mesh(mesh, name)  # a geofit, trimesh or Open3D mesh
    if mesh.n_faces == 0:
        raise ValueError(f"{name}: expected a mesh with at least one face, got 0 faces")
    return mesh


def _check_taus(taus) -> tuple[float, ...]:
    if np.ndim(taus) == 0:
        taus = (taus,)
    out = tuple(check_positive(t, "taus") for t in taus)
    if not out:
        raise ValueError("taus: expected at least one threshold, got none")
    return out


def _check_n(n) -> int:
    if not isinstance(n, (int, np.integer)) or isinstance(n, bool) or n < 1:
        raise ValueError(f"n_samples: expected an integer >= 1, got {n!r}")
    return int(n)


class _Surface:
    """Samples (points, normals) and a closest-point structure for one surface.

    A surface of zero total area (all triangles collapsed) has no area to sample; it is then
    represented by its referenced vertices, and distances to it are distances to those points.
    """

    def __init__(self, mesh: Mesh, n: int, rng: np.random.Generator):
        self.mesh = mesh
        self.normals_f = mesh.face_normals
        if float(mesh.face_areas.sum()) > 0:
            s = sample_points_from_meshes(mesh, n, seed=rng, return_normals=True)
            self.points, self.normals = s.points, s.normals
            self.degenerate = False
        else:
            used = np.unique(mesh.faces)
            self.points = mesh.verts[used]
            self.normals = np.zeros_like(self.points)
            self.degenerate = True
        self._scene = None

    def closest(self, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distances (k,) from P to this surface and the face normals (k, 3) there."""
        if self.degenerate:
            from scipy.spatial import cKDTree  # kept local: start-up

            d, _ = cKDTree(self.points).query(P)
            return d, np.zeros_like(P)
        if self._scene is None:
            self._scene = PointToMeshDistance(self.mesh)
        c = self._scene.query(P)
        return c.distances, self.normals_f[c.face_ids]


def _combine(d_pt, d_tp, cos_p, cos_t, taus, n) -> MeshMetrics:
    fs, pr, rc = {}, {}, {}
    for tau in taus:  # thresholds
        p = float(np.mean(d_pt < tau))
        r = float(np.mean(d_tp < tau))
        pr[tau], rc[tau] = p, r
        fs[tau] = 2 * p * r / (p + r) if p + r > 0 else 0.0
    return MeshMetrics(
        chamfer_l2=float(np.mean(d_pt ** 2) + np.mean(d_tp ** 2)),
        chamfer_l1=float(np.mean(d_pt) + np.mean(d_tp)),
        fscore=fs, precision=pr, recall=rc,
        normal_consistency=float(0.5 * (np.mean(cos_p) + np.mean(cos_t))),
        hausdorff=float(max(d_pt.max(), d_tp.max())),
        n_samples=int(n),
    )


class MeshEvaluator:
    """Build once over a target, evaluate many predicted meshes against it.

    The target's samples and closest-point scene are computed at construction; each
    :meth:`evaluate` samples the prediction with the same seed (so the same prediction gives the
    same numbers) and queries both ways.

    Parameters
    ----------
    target : Mesh
        The reference surface.
    n_samples : int
        Points sampled on each surface (default 100 000).
    taus : float or sequence of float
        F-score thresholds (default 0.01), in the evaluation frame's units.
    seed : int or numpy.random.Generator
        Seed for both samplings (default 0).
    normalize : bool
        Evaluate in the target's normalised frame: both meshes are mapped by
        ``(v - target_center) / target_scale`` (:meth:`geofit.Mesh.normalize` of the target).

    Raises
    ------
    TypeError
        If ``target`` is not a Mesh.
    ValueError
        If the target has no faces, ``n_samples`` < 1 or a threshold is not > 0.

    Examples
    --------
    >>> from geofit import ico_sphere
    >>> ev = MeshEvaluator(ico_sphere(3), n_samples=2000, taus=(0.01,))
    >>> m = ev.evaluate(ico_sphere(3))
    >>> m.chamfer_l2 < 1e-20, m.fscore[0.01]
    (True, 1.0)
    """

    def __init__(self, target: Mesh, *, n_samples: int = 100_000,
                 taus: float | Sequence[float] = 0.01, seed=0, normalize: bool = False):
        target = _check_mesh(target, "target")
        self.n_samples = _check_n(n_samples)
        self.taus = _check_taus(taus)
        self.normalize = bool(normalize)
        if self.normalize:
            norm = target.normalize()
            self.center, self.scale = norm.center, norm.scale
            target = norm.mesh
        else:
            self.center, self.scale = np.zeros(3), 1.0
        rng = as_rng(seed)
        self._rng_target, self._rng_pred = rng.spawn(2)
        self._pred_state = self._rng_pred.bit_generator.state
        self.target = target
        self._t = _Surface(target, self.n_samples, self._rng_target)

    def _frame(self, mesh: Mesh) -> Mesh:
        if not self.normalize:
            return mesh
        return mesh.update_verts((mesh.verts - self.center) / self.scale)

    def evaluate(self, pred: Mesh) -> MeshMetrics:
        """Metrics of ``pred`` against the target.

        Parameters
        ----------
        pred : Mesh
            The predicted surface, in the target's original frame (it is normalised with the
            target's transform when ``normalize=True``).

        Returns
        -------
        MeshMetrics
        """
        pred = self._frame(_check_mesh(pred, "pred"))
        self._rng_pred.bit_generator.state = self._pred_state  # same samples for the same mesh
        p = _Surface(pred, self.n_samples, self._rng_pred)
        d_pt, n_t_at_p = self._t.closest(p.points)
        d_tp, n_p_at_t = p.closest(self._t.points)
        cos_p = np.abs(np.einsum("ij,ij->i", p.normals, n_t_at_p))
        cos_t = np.abs(np.einsum("ij,ij->i", self._t.normals, n_p_at_t))
        return _combine(d_pt, d_tp, cos_p, cos_t, self.taus, self.n_samples)

    __call__ = evaluate

    def __repr__(self) -> str:
        return (f"MeshEvaluator(n_faces={self.target.n_faces}, n_samples={self.n_samples}, "
                f"taus={self.taus}, normalize={self.normalize})")


def evaluate_mesh(pred: Mesh, target: Mesh, *, n_samples: int = 100_000,
                  taus: float | Sequence[float] = 0.01, seed=0,
                  normalize: bool = False) -> MeshMetrics:
    """All metrics of ``pred`` against ``target`` in one pass (see :class:`MeshEvaluator`).

    Parameters
    ----------
    pred, target : Mesh
        Predicted and reference surfaces.
    n_samples : int
        Samples per surface (default 100 000).
    taus : float or sequence of float
        F-score thresholds.
    seed : int or numpy.random.Generator
        Sampling seed.
    normalize : bool
        Evaluate in the target's normalised frame.

    Returns
    -------
    MeshMetrics
    """
    ev = MeshEvaluator(target, n_samples=n_samples, taus=taus, seed=seed, normalize=normalize)
    return ev.evaluate(pred)


def chamfer_l2(pred: Mesh, target: Mesh, *, n_samples: int = 100_000, seed=0,
               normalize: bool = False) -> float:
    """``mean(d_pt**2) + mean(d_tp**2)`` with exact point-to-surface distances (see module)."""
    return evaluate_mesh(pred, target, n_samples=n_samples, seed=seed,
                         normalize=normalize).chamfer_l2


def chamfer_l1(pred: Mesh, target: Mesh, *, n_samples: int = 100_000, seed=0,
               normalize: bool = False) -> float:
    """``mean(d_pt) + mean(d_tp)`` with exact point-to-surface distances (see module)."""
    return evaluate_mesh(pred, target, n_samples=n_samples, seed=seed,
                         normalize=normalize).chamfer_l1


def fscore(pred: Mesh, target: Mesh, tau: float = 0.01, *, n_samples: int = 100_000, seed=0,
           normalize: bool = False) -> float:
    """F-score at ``tau``: harmonic mean of precision and recall (see module)."""
    tau = check_positive(tau, "tau")
    return evaluate_mesh(pred, target, n_samples=n_samples, taus=(tau,), seed=seed,
                         normalize=normalize).fscore[tau]


def normal_consistency(pred: Mesh, target: Mesh, *, n_samples: int = 100_000, seed=0,
                       normalize: bool = False) -> float:
    """Mean absolute cosine between corresponding face normals, both directions (see module)."""
    return evaluate_mesh(pred, target, n_samples=n_samples, seed=seed,
                         normalize=normalize).normal_consistency


# --------------------------------------------------------------------------------------------
# Images
# --------------------------------------------------------------------------------------------


def psnr(pred, target, max_value: float = 1.0, *, per_image: bool = False):
    """Peak signal-to-noise ratio ``10 log10(max_value^2 / MSE)`` in dB over all pixels and channels.

    Parameters
    ----------
    pred : (...) float64
        Prediction; with ``per_image``, a stack ``(N, ...)`` (e.g. ``(N, H, W, C)`` images).
    target : (...) float64
        Reference, of ``pred``'s shape.
    max_value : float
        The largest possible value (1 for images in [0, 1]).
    per_image : bool
        One PSNR per entry of the first axis (the MSE is averaged over the other axes).

    Returns
    -------
    float, or (N,) float64 with ``per_image``
        inf where the images are identical.

    Raises
    ------
    ValueError
        If the shapes differ, or ``per_image`` is set on a 0-d input.

    Examples
    --------
    >>> round(psnr(np.full(4, 0.1), np.zeros(4)), 6)
    20.0
    >>> psnr(np.stack([np.full(4, 0.1), np.zeros(4)]), np.zeros((2, 4)), per_image=True)
    array([20., inf])
    """
    p = np.asarray(pred, np.float64)
    t = np.asarray(target, np.float64)
    if p.shape != t.shape:
        raise ValueError(f"pred, target: expected equal shapes, got {p.shape} and {t.shape}")
    if per_image:
        if p.ndim == 0:
            raise ValueError("pred: per_image needs a leading image axis, got a scalar")
        mse = np.mean((p - t).reshape(len(p), -1) ** 2, axis=1)
        with np.errstate(divide="ignore"):
            return np.where(mse == 0.0, np.inf, 10.0 * np.log10(max_value ** 2 / mse))
    mse = float(np.mean((p - t) ** 2))
    return math.inf if mse == 0.0 else 10.0 * math.log10(max_value ** 2 / mse)


def silhouette_iou(pred, target, threshold: float = 0.5) -> np.ndarray:
    """Intersection over union of silhouettes, per view.

    Parameters
    ----------
    pred : (N, H, W) float64 or bool
        Predicted silhouettes; values above ``threshold`` count as inside.
    target : (N, H, W) float64 or bool
        Reference silhouettes.
    threshold : float

    Returns
    -------
    iou : (N,) float64
        1.0 for a view where both are empty.

    Raises
    ------
    ValueError
        If the shapes differ or are not (N, H, W).

    Examples
    --------
    >>> a = np.zeros((1, 2, 2)); a[0, 0] = 1
    >>> silhouette_iou(a, np.ones((1, 2, 2))).tolist()
    [0.5]
    """
    p = np.asarray(pred) > threshold
    t = np.asarray(target) > threshold
    if p.shape != t.shape or p.ndim != 3:
        raise ValueError(f"pred, target: expected equal shapes (N, H, W), got {p.shape} and "
                         f"{t.shape}")
    inter = np.count_nonzero(p & t, axis=(1, 2))
    union = np.count_nonzero(p | t, axis=(1, 2))
    return np.where(union > 0, inter / np.maximum(union, 1), 1.0)
