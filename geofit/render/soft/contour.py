"""A geometry-first silhouette loss: the hard silhouette's error, differentiated along the contour.

For views ``n = 1..N`` with target silhouettes ``T_n`` (values in [0, 1]) and the mesh's hard
coverage mask ``M_n``, the loss is the tutorial's silhouette term with a *hard* silhouette::

    L = 1/N sum_n mean_pixels (M_n - T_n)^2.

Its value is piecewise constant in the vertex positions (it changes when a pixel centre changes
sides), but it approximates the continuous integral ``1/(N H W) sum_n  integral (M_n - T_n)^2
dA`` (area in pixels), whose derivative is a boundary integral over the outer contour of the
mesh's projection (Reynolds transport; the edge-sampling view of Li et al. 2018)::

    dL = 1/(N H W) sum_n  contour-integral (1 - 2 T_n(x)) (dx . n_out) dl,

``1 - 2T = (1 - T)^2 - T^2`` being the change of the pixel loss when a point becomes covered.
So a contour point inside the target (T = 1) is pushed outwards, one outside it (T = 0) inwards,
whatever the distance to the target's boundary: the gradient is long-range, unlike a soft
rasterizer's, whose support ends ``sqrt(blur_radius)`` from the mesh's projection.

Discretisation (:class:`ContourSilhouetteLoss`):

1. contour edges of view ``n``: mesh edges whose two faces have opposite projected orientation
   (a fold of the projection) and boundary edges; the outward normal points away from the faces'
   third vertices;
2. samples along every contour edge (``samples_per_pixel`` per pixel of projected length,
   midpoint rule), each weighted by its share of the edge's NDC length;
3. a sample counts only if it lies on the *outer* boundary of the projection: the point
   ``offset_px`` pixels outside it must be uncovered in the hard mask (Embree ray casting via
   :class:`geofit.render.MeshRasterizer`); interior contours (a leg in front of the body) move
   nothing and get no gradient;
4. ``T`` is sampled bilinearly (0 outside the image), and the 2-D gradient ``(1 - 2T) w
   ((1 - t), t) n_out`` on the edge's ends is carried to the world vertices by the projection
   Jacobian (:meth:`geofit.cameras.CamerasBase.projection_jacobian`).

The gradient is that of the continuous loss, the value that of the pixel loss; use a solver that
does not need them to agree exactly (Adam), e.g. in the large-steps parameterisation.

References
----------
T.-M. Li, M. Aittala, F. Durand, J. Lehtinen, "Differentiable Monte Carlo Ray Tracing through
Edge Sampling", SIGGRAPH Asia 2018.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..._validate import as_array, check_positive
from ...cameras import CamerasBase
from ...structures import Mesh, Topology, as_mesh
from ..mesh.rasterizer import MeshRasterizer, RasterizationSettings

__all__ = ["ContourSamples", "ContourSilhouetteLoss", "contour_edges", "edge_samples"]


def _edge_faces(topology: Topology):
    """(E, 2) faces on each edge (-1 if none) and (E, 2) their vertex opposite the edge."""
    cache = topology.__dict__.setdefault("_contour_cache", {})
    if "edge_faces" in cache:
        return cache["edge_faces"]
    F = topology.faces
    nF = len(F)
    E = len(topology.edges)
    e = topology.faces_to_edges.ravel()          # (3F,) edge opposite corner c of face f
    f = np.repeat(np.arange(nF), 3)
    opp = F.ravel()                              # the corner itself
    order = np.argsort(e, kind="stable")
    e, f, opp = e[order], f[order], opp[order]
    first = np.r_[True, e[1:] != e[:-1]] if len(e) else np.zeros(0, bool)
    ef = np.full((E, 2), -1, np.int64)
    eo = np.full((E, 2), -1, np.int64)
    i1 = np.flatnonzero(first)
    ef[e[i1], 0], eo[e[i1], 0] = f[i1], opp[i1]
    i2 = np.flatnonzero(~first)
    second = i2[np.r_[True, e[i2][1:] != e[i2][:-1]]] if len(i2) else i2
    ef[e[second], 1], eo[e[second], 1] = f[second], opp[second]
    cache["edge_faces"] = (ef, eo)
    return ef, eo


def contour_edges(mesh: Mesh, xy: np.ndarray):
    """Contour edges of a projection and their outward 2-D normals.

    Parameters
    ----------
    mesh : Mesh
    xy : (V, 2) float64
        Projected vertex positions (NDC x, y).

    Returns
    -------
    edges : (c, 2) int64
        Vertex ids ``(a, b)`` of the contour edges (folds of the projection, and boundary edges).
    normals : (c, 2) float64
        Unit outward normals (away from the adjacent faces' third vertices).
    """
    ef, eo = _edge_faces(mesh.topology)
    F = mesh.faces
    p = xy[F]
    area = ((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1])
            - (p[:, 1, 1] - p[:, 0, 1]) * (p[:, 2, 0] - p[:, 0, 0]))
    s = np.sign(area)
    s[~np.isfinite(area)] = 0.0
    s0 = s[ef[:, 0]]
    s1 = np.where(ef[:, 1] >= 0, s[np.maximum(ef[:, 1], 0)], -s0)
    contour = (s0 != 0) & (s0 == -s1)
    ids = np.flatnonzero(contour)
    edges = mesh.edges[ids]
    a, b = xy[edges[:, 0]], xy[edges[:, 1]]
    c = xy[eo[ids, 0]]
    d = b - a
    n = np.stack([-d[:, 1], d[:, 0]], 1)
    flip = np.einsum("ij,ij->i", n, c - a) > 0
    n[flip] *= -1.0
    ln = np.linalg.norm(n, axis=1)
    n = np.divide(n, ln[:, None], out=np.zeros_like(n), where=ln[:, None] > 0)
    return edges, n


def edge_samples(a: np.ndarray, b: np.ndarray, size: int, samples_per_pixel: float):
    """Midpoint-rule samples along projected edges ``a -> b``.

    Parameters
    ----------
    a, b : (c, 2) float64
        NDC ends of the edges.
    size : int
        ``min(H, W)``: NDC length 2 is ``size`` pixels.
    samples_per_pixel : float
        Samples per pixel of projected length (at least one per edge).

    Returns
    -------
    edge : (s,) int64
        The edge of each sample.
    t : (s,) float64
        Its parameter along the edge (``p = a + t (b - a)``).
    weight : (s,) float64
        The NDC length it stands for.
    points : (s, 2) float64
        NDC positions.
    """
    length = np.linalg.norm(b - a, axis=1)
    k = np.maximum(np.ceil(length * size / 2.0 * samples_per_pixel), 1).astype(np.int64)
    e = np.repeat(np.arange(len(a)), k)
    j = np.arange(len(e)) - np.repeat(np.cumsum(k) - k, k)
    t = (j + 0.5) / k[e]
    w = length[e] / k[e]
    p = a[e] + t[:, None] * (b[e] - a[e])
    return e, t, w, p


class ContourSamples(NamedTuple):
    """Samples along the contour of one view (for plotting and tests).

    Attributes
    ----------
    points : (s, 2) float64
        NDC positions.
    normals : (s, 2) float64
        Outward unit normals.
    weights : (s,) float64
        NDC length each sample stands for.
    outer : (s,) bool
        Whether the sample lies on the outer boundary (counted).
    target : (s,) float64
        Target silhouette at the sample.
    """

    points: np.ndarray
    normals: np.ndarray
    weights: np.ndarray
    outer: np.ndarray
    target: np.ndarray


class ContourSilhouetteLoss:
    """Hard-silhouette loss with its contour (edge-sampling) gradient; see the module notes.

    Parameters
    ----------
    cameras : camera batch
        ``N`` cameras.
    target_silhouettes : (N, H, W) float64
        Targets in [0, 1].
    samples_per_pixel : float
        Contour samples per pixel of projected edge length (default 2).
    offset_px : float
        How far outside a sample (pixels) the mask is tested (default 0.75).
    threshold : float, optional
        Binarise the targets at this value first (``T >= threshold``). A soft silhouette
        (PyTorch3D's ``SoftSilhouetteShader``) of a closed mesh is already about 0.75 on the
        outline (two layers of faces with ``p = 1/2`` each), and more where many small faces lie
        within the blur radius, so its 0.5 level lies up to a pixel outside the outline; a
        higher level locates the outline better. Default: use the targets as given.

    Examples
    --------
    >>> import numpy as np
    >>> from geofit import FoVPerspectiveCameras, ico_sphere, look_at_view_transform
    >>> R, T = look_at_view_transform(2.7, 0.0, 0.0)
    >>> loss = ContourSilhouetteLoss(FoVPerspectiveCameras(R=R, T=T), np.ones((1, 16, 16)))
    >>> value, grad = loss(ico_sphere(2))
    >>> grad.shape, bool(value > 0)
    ((162, 3), True)
    """

    def __init__(self, cameras: CamerasBase, target_silhouettes, *,
                 samples_per_pixel: float = 2.0, offset_px: float = 0.75,
                 threshold: float | None = None):
        if not isinstance(cameras, CamerasBase):
            raise TypeError(f"cameras: expected a geofit camera batch, got {type(cameras)!r}")
        self.cameras = cameras
        N = len(cameras)
        self.targets = as_array(target_silhouettes, "target_silhouettes", (N, None, None))
        H, W = self.targets.shape[1:]
        if H < 2 or W < 2:
            raise ValueError(f"target_silhouettes: expected at least 2 x 2 pixels, got {(H, W)}")
        self.samples_per_pixel = check_positive(samples_per_pixel, "samples_per_pixel")
        self.offset_px = check_positive(offset_px, "offset_px")
        if threshold is not None:
            threshold = check_positive(threshold, "threshold")
            self.targets = (self.targets >= threshold).astype(np.float64)
        self.threshold = threshold
        self.image_size = (H, W)

    def _masks(self, mesh: Mesh) -> np.ndarray:
        ras = MeshRasterizer(self.cameras, RasterizationSettings(image_size=self.image_size))
        return ras(mesh).mask

    def _bilinear(self, img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Bilinear sample of ``img (H, W)`` at NDC points, 0 outside the image."""
        H, W = self.image_size
        S = min(H, W)
        c = (W - 1 - x * S) / 2.0
        r = (H - 1 - y * S) / 2.0
        pad = np.zeros((H + 2, W + 2))
        pad[1:-1, 1:-1] = img
        c = np.clip(c + 1.0, 0.0, W + 1.0)
        r = np.clip(r + 1.0, 0.0, H + 1.0)
        c0 = np.minimum(np.floor(c).astype(np.int64), W)
        r0 = np.minimum(np.floor(r).astype(np.int64), H)
        fc, fr = c - c0, r - r0
        return ((1 - fr) * ((1 - fc) * pad[r0, c0] + fc * pad[r0, c0 + 1])
                + fr * ((1 - fc) * pad[r0 + 1, c0] + fc * pad[r0 + 1, c0 + 1]))

    def _samples(self, mesh: Mesh, xy: np.ndarray, mask: np.ndarray, target: np.ndarray):
        H, W = self.image_size
        S = min(H, W)
        edges, nrm = contour_edges(mesh, xy)
        e, t, w, p = edge_samples(xy[edges[:, 0]], xy[edges[:, 1]], S, self.samples_per_pixel)
        n = nrm[e]
        q = p + n * (2.0 * self.offset_px / S)
        col = np.rint((W - 1 - q[:, 0] * S) / 2.0).astype(np.int64)
        row = np.rint((H - 1 - q[:, 1] * S) / 2.0).astype(np.int64)
        inside_img = (col >= 0) & (col < W) & (row >= 0) & (row < H)
        covered = np.zeros(len(q), bool)
        covered[inside_img] = mask[row[inside_img], col[inside_img]]
        T = self._bilinear(target, p[:, 0], p[:, 1])
        return edges, e, t, w, n, ~covered, T, p

    def samples(self, mesh: Mesh, view: int = 0) -> ContourSamples:
        """The contour samples of one view."""
        xy = self.cameras[view].projection_jacobian(mesh.verts).xy[0]
        mask = self._masks(mesh)[view]
        _, _, _, w, n, outer, T, p = self._samples(mesh, xy, mask, self.targets[view])
        return ContourSamples(p, n, w, outer, T)

    def __call__(self, mesh: Mesh):
        """Loss value (pixel loss) and its contour gradient.

        Returns
        -------
        value : float
            ``1/N sum_n mean (M_n - T_n)^2`` with the hard coverage mask ``M``.
        grad : (V, 3) float64
            The boundary-integral gradient of the continuous loss.
        """
        mesh = as_mesh(mesh, "mesh")  # a geofit, trimesh or Open3D mesh
        N = len(self.cameras)
        H, W = self.image_size
        S = min(H, W)
        V = mesh.n_verts
        masks = self._masks(mesh)
        value = float(np.mean((masks - self.targets) ** 2))
        with np.errstate(invalid="ignore", divide="ignore"):
            proj = self.cameras.projection_jacobian(mesh.verts)
        grad = np.zeros((V, 3))
        scale = S * S / (4.0 * H * W * N)
        for v in range(N):  # loop over views
            edges, e, t, w, n, outer, T, _ = self._samples(mesh, proj.xy[v], masks[v],
                                                           self.targets[v])
            if len(e) == 0:
                continue
            coef = scale * (1.0 - 2.0 * T) * w * outer
            ga = (coef * (1.0 - t))[:, None] * n
            gb = (coef * t)[:, None] * n
            ia, ib = edges[e, 0], edges[e, 1]
            gx = np.bincount(ia, ga[:, 0], V) + np.bincount(ib, gb[:, 0], V)
            gy = np.bincount(ia, ga[:, 1], V) + np.bincount(ib, gb[:, 1], V)
            J = np.where(np.isfinite(proj.jacobian[v]), proj.jacobian[v], 0.0)
            grad += gx[:, None] * J[:, 0, :] + gy[:, None] * J[:, 1, :]
        return value, grad
