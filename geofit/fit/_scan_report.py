"""What a point cloud can support: its noise, sampling density and outliers (issue 25).

:func:`scan_report` looks at a scan before :func:`geofit.fit.fit_mesh` fits it:

* **Sampling density**: the median distance of a point to its nearest other point
  (``spacing``).
* **Outliers**: points with fewer than ``min_neighbours`` other points within
  ``radius_factor * spacing`` (the test of Open3D's ``remove_radius_outlier``, the radius in
  units of the scan's own spacing, not of the unit box; read here off the k-nearest-neighbour
  distances the noise estimate needs anyway, which saves Open3D's second KD-tree: 1.6 s of
  4 s on 50,000 points, measured under load): stray returns scattered in the volume around a
  surface have almost no neighbours at the surface's sampling scale, surface points have
  dozens. A second test catches strays close to the surface: a point farther than
  ``residual_factor * max(noise, t_i)`` plus one spacing from the plane of its neighbours,
  with ``t_i`` the neighbours' own spread about that plane (the rms of their residuals).
  Where the surface is flat, ``t_i`` is the noise and the test is ``residual_factor`` noise
  levels; at a crease, a thin part or a tip the neighbours bend around the point and their
  plane misses a surface point by up to about twice their spread (a point on a 90 degree
  crease: 0.35 against 0.20 neighbourhood radii), which the noise of a clean scan (near 0)
  cannot cover. With the noise alone, 0.03-3 % of the points of *noise-free* scans were
  called outliers (fandisk's creases 658 of 20,000, the dolphin's fins 84); with the spread,
  none on the eight test shapes at 20,000 and 50,000 points, while 95-99 % of the strays
  caught before still are (1-5 % strays at noise 0.002-0.01; the rest lie within a few
  noise levels of the surface).
* **Noise**: for each (kept) point, the distance ``d_i`` to the least-squares plane of its
  ``k`` nearest other points (PCA, vectorised over all points); the noise level is the robust
  standard deviation ``1.4826 median |d_i - median d|`` divided by ``sqrt(1 + 1/k)`` (the
  plane's own centroid carries ``sigma^2 / k`` of variance). Curvature adds a bias of order
  ``kappa r^2 / 2`` with ``r`` the neighbourhood radius: a few 1e-4 of the unit box for
  50,000 points on a smooth shape, well under the noise of a real scan.

The fit uses the report to size the model (see :mod:`geofit.fit.adaptive`): the refinement
does not chase residuals at the noise level, and the mesh has no more faces than the scan has
points.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import numpy as np

__all__ = ["NOISE_NORMAL_WEIGHT", "DataReport", "EvidenceLimits", "evidence_limits",
           "scan_report"]

#: Weight of the normal-consistency term per unit of noise variance (normalised frame): the
#: remeshing fit of a scan with noise ``sigma`` weighs normal consistency
#: ``max(recipe's, NOISE_NORMAL_WEIGHT * sigma^2)``: 1e-3 at noise 0.01, 2.5e-4 at 0.005,
#: the recipe's 1e-5 (no smoothing) below noise 0.001. Measured on 20,000-point scans with
#: 1% strays (default 10 s budget, load 8-12): at noise 0.01 a weight of 1e-3 against 1e-5
#: took the chamfer-L2 to the true surface from 1.28e-4 to 1.03e-4 (suzanne) and 4.17e-5 to
#: 3.86e-5 (fandisk), while 1e-2 doubled it; at noise 0.005 a weight of 2.5e-4 took it from
#: 1.63e-4 to 9.9e-5 (suzanne), 2.0e-5 to 1.6e-5 (fandisk), 5.7e-5 to 2.8e-5 (teapot). The
#: uniform Laplacian (0.3, 3) and a stiffer large-steps lambda (10, 30) made it worse.
NOISE_NORMAL_WEIGHT = 10.0


@dataclass(frozen=True)
class DataReport:
    """What a point cloud supports (:func:`scan_report`); lengths in the cloud's frame.

    Attributes
    ----------
    n_points : int
        Points in the scan as given.
    n_outliers : int
        Points found to be outliers (removed before the fit).
    outlier_fraction : float
        ``n_outliers / n_points``.
    spacing : float
        Median distance of a point to its nearest other point (sampling density).
    noise : float
        Robust standard deviation of the points about their local planes (see the module).
    k : int
        Neighbours of the local plane fits.
    """

    n_points: int
    n_outliers: int
    outlier_fraction: float
    spacing: float
    noise: float
    k: int

    @property
    def n_inliers(self) -> int:
        """Points kept for the fit."""
        return self.n_points - self.n_outliers

    def scaled(self, s: float) -> "DataReport":
        """The same report with its lengths multiplied by ``s`` (another frame)."""
        return replace(self, spacing=self.spacing * s, noise=self.noise * s)

    def describe(self) -> str:
        """One line for a fit's message."""
        return (f"scan: {self.n_points} points, spacing {self.spacing:.3g}, noise "
                f"{self.noise:.3g}, {self.n_outliers} outliers removed "
                f"({self.outlier_fraction:.1%})")

    def as_dict(self) -> dict:
        return asdict(self)


def _plane_residuals(P: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(n,) signed distance of each point to the PCA plane of its neighbours ``idx (n, k)``,
    and (n,) the neighbours' rms distance to that plane (``sqrt(lambda_min / k)``)."""
    Q = P[idx]                                   # (n, k, 3)
    c = Q.mean(1)
    D = Q - c[:, None]
    C = np.einsum("nki,nkj->nij", D, D)
    lam, vec = np.linalg.eigh(C)                 # ascending eigenvalues
    nrm = vec[:, :, 0]
    spread = np.sqrt(np.maximum(lam[:, 0], 0.0) / idx.shape[1])
    return np.einsum("ij,ij->i", P - c, nrm), spread


def _robust_sigma(d: np.ndarray) -> float:
    return float(1.4826 * np.median(np.abs(d - np.median(d))))


def scan_report(points: np.ndarray, *, k: int = 16, radius_factor: float = 8.0,
                min_neighbours: int = 6,
                residual_factor: float = 4.0) -> tuple[DataReport, np.ndarray]:
    """Noise, sampling density and outliers of a point cloud; which points to keep.

    Parameters
    ----------
    points : (n, 3) float64
        The scan (finite, at least ``k + 1`` points; validated by the caller).
    k : int
        Neighbours of the local plane fits.
    radius_factor : float
        Radius of the density test, in units of the spacing.
    min_neighbours : int
        Fewest other points within that radius for a point to be kept.
    residual_factor : float
        A point farther than ``residual_factor * max(noise, t) + spacing`` from its
        neighbours' plane, ``t`` their rms distance to it, is an outlier too.

    Returns
    -------
    report : DataReport
    keep : (n,) bool
        The inliers.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> P = np.c_[rng.uniform(-1, 1, (4000, 2)), rng.normal(0, 0.01, 4000)]  # a noisy plane
    >>> rep, keep = scan_report(P)
    >>> bool(0.0075 < rep.noise < 0.0125) and rep.n_outliers < 10
    True
    """
    from scipy.spatial import cKDTree

    P = np.ascontiguousarray(points, dtype=np.float64)
    n = len(P)
    k = int(min(k, n - 1))
    tree = cKDTree(P)
    dist, idx = tree.query(P, k + 1)
    spacing = float(np.median(dist[:, 1]))
    m = int(min(min_neighbours, k))
    keep = dist[:, m] <= float(radius_factor) * spacing  # its m-th other point is near enough
    # local planes of the kept points from their kept neighbours
    ok = keep[idx[:, 1:]]
    d, spread = _plane_residuals(P, idx[:, 1:])
    clean = keep & ok.all(1)
    base = d[clean] if clean.sum() > k else d[keep]
    sigma = _robust_sigma(base) / np.sqrt(1.0 + 1.0 / k)
    far = np.abs(d - np.median(base)) > residual_factor * np.maximum(sigma, spread) + spacing
    keep &= ~far
    n_out = int(n - keep.sum())
    return DataReport(n_points=n, n_outliers=n_out, outlier_fraction=n_out / n,
                      spacing=spacing, noise=float(sigma), k=k), keep


@dataclass(frozen=True)
class EvidenceLimits:
    """How far the remeshing fit of a scan may refine (normalised frame; see
    :func:`evidence_limits`).

    Attributes
    ----------
    chamfer_l2, fscore : float
        Accuracy at which refinement stops (the user's, relaxed to the noise floor).
    noise : float
        The scan's noise level.
    max_faces : int
        Most faces the model may have (the scan's inlier count).
    """

    chamfer_l2: float
    fscore: float
    noise: float
    max_faces: int

    def eps_floor(self, n_faces: int) -> float:
        """Smallest edge-midpoint error worth refining for, with ``n_faces`` faces: the noise
        of a surface fitted to the ``max_faces / n_faces`` points each face has,
        ``noise * sqrt(n_faces / max_faces)`` (refinement stops where the residual is what the
        points' noise leaves, so dense scans still earn detail)."""
        return self.noise * float(np.sqrt(min(n_faces / self.max_faces, 1.0)))

    def weights(self, weights: dict) -> dict:
        """The recipe's term weights with smoothing that follows the noise: the
        normal-consistency weight becomes ``max(weights["normal"], NOISE_NORMAL_WEIGHT *
        noise^2)`` (unchanged on clean scans)."""
        return dict(weights, normal=max(weights["normal"],
                                        NOISE_NORMAL_WEIGHT * self.noise * self.noise))


def evidence_limits(report: DataReport, chamfer_l2: float, fscore: float,
                    tau: float) -> EvidenceLimits:
    """The accuracy a fit of a scan can reach, from its noise (``report`` in the fit's frame).

    A perfect surface, measured against points with Gaussian noise ``sigma`` along the
    normal, has a point-to-plane chamfer-L2 of about ``2 sigma^2`` (``sigma^2`` each way) and an
    F-score at ``tau`` of about ``erf(tau / (sigma sqrt 2))``: refining past that fits the
    noise. The targets become ``max(chamfer_l2, 2.5 sigma^2)`` and
    ``min(fscore, 0.98 erf(tau / (sigma sqrt 2)))``; edges whose midpoint error is within the
    noise left by the points of a face are not refined (:meth:`EvidenceLimits.eps_floor`); the
    model has at most as many faces as the scan has inliers.
    On clean scans (``sigma`` well under ``tau``) the targets are the user's.
    """
    from math import erf, sqrt

    s = max(report.noise, 1e-12)
    floor_f = erf(tau / (s * sqrt(2.0)))
    return EvidenceLimits(chamfer_l2=max(chamfer_l2, 2.5 * s * s),
                          fscore=min(fscore, 0.98 * floor_f), noise=s,
                          max_faces=max(report.n_inliers, 4))
