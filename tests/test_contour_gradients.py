"""Finite-difference checks (float64, central differences) of the contour silhouette gradient
(geofit.render.soft.contour) and of the views fit's contour objective (geofit.fit.views).

The contour loss's *value* is the hard-mask pixel loss, piecewise constant in the vertices; its
gradient is that of the continuous loss ``S^2 / (4 H W N) sum_n integral (M_n - T_n)^2 dA`` (NDC
area). With a target ``T`` linear in NDC (a bilinear sample of a linear ramp is linear), the
continuous loss of a mesh whose projection does not fold is, up to a constant, the sum over its
projected triangles of ``area * (1 - 2 T(centroid))``: exact, with no sampling noise. The
gradient's samples are deterministic (midpoint rule along the contour), so the check is exact up
to the quadrature error of the midpoint rule, which ``samples_per_pixel`` makes small.
"""
import numpy as np
import pytest

from geofit import FoVPerspectiveCameras, Mesh, look_at_view_transform
from geofit.fit._views_objective import _ContourObjective
from geofit.fit.large_steps import vertex_parameterization
from geofit.render.soft.contour import ContourSilhouetteLoss
from geofit.shapes import plane

H, W = 48, 64
S = min(H, W)
A0, AX, AY = 0.5, 0.2, 0.1  # target T = A0 + AX x + AY y in NDC


def _ramp(n_views):
    """(N, H, W) target images, linear in the NDC position of the pixel centres."""
    col, row = np.meshgrid(np.arange(W), np.arange(H))
    x = (W - 1 - 2.0 * col) / S
    y = (H - 1 - 2.0 * row) / S
    return np.broadcast_to(A0 + AX * x + AY * y, (n_views, H, W)).copy()


def _cameras():
    R, T = look_at_view_transform(3.0, [10.0, -15.0], [5.0, -20.0])
    return FoVPerspectiveCameras(R=R, T=T)


def _mesh(n=2, seed=0):
    """A slightly bumpy square facing the cameras (its projection has no fold)."""
    m = plane(size=1.2, n=n)
    V = m.verts.copy()
    V += np.random.default_rng(seed).normal(scale=0.03, size=V.shape)
    return Mesh(V, m.faces)


def _continuous_loss(cams, verts, faces):
    """The continuous loss minus its constant, in closed form (see the module docstring)."""
    xy = cams.projection_jacobian(verts).xy            # (N, V, 2)
    p = xy[:, faces]                                   # (N, F, 3, 2)
    d1, d2 = p[:, :, 1] - p[:, :, 0], p[:, :, 2] - p[:, :, 0]
    area = np.abs(d1[..., 0] * d2[..., 1] - d1[..., 1] * d2[..., 0]) / 2.0
    c = p.mean(axis=2)
    T = A0 + AX * c[..., 0] + AY * c[..., 1]
    N = len(cams)
    return S * S / (4.0 * H * W * N) * float(np.sum(area * (1.0 - 2.0 * T)))


def _central_differences(fun, x, h=1e-6):
    g = np.empty(x.size)
    for i in range(x.size):  # coordinates of a tiny mesh
        e = np.zeros(x.size)
        e[i] = h
        xp, xm = (x.ravel() + e).reshape(x.shape), (x.ravel() - e).reshape(x.shape)
        g[i] = (fun(xp) - fun(xm)) / (2 * h)
    return g.reshape(x.shape)


def test_contour_loss_gradient_matches_finite_differences_of_the_continuous_loss():
    """ContourSilhouetteLoss's gradient equals central differences of the continuous loss
    (two views, a linear target, 9 vertices including interior ones that get no gradient)."""
    cams = _cameras()
    mesh = _mesh()
    loss = ContourSilhouetteLoss(cams, _ramp(len(cams)), samples_per_pixel=16.0)
    _, grad = loss(mesh)
    fd = _central_differences(lambda V: _continuous_loss(cams, V, mesh.faces), mesh.verts)
    assert np.abs(fd).max() > 1e-3                      # the check is not vacuous
    np.testing.assert_allclose(grad, fd, rtol=0, atol=2e-5 * np.abs(fd).max())
    np.testing.assert_allclose(grad[4], 0.0, atol=1e-15)  # the centre vertex: not on the contour


def test_contour_loss_gradient_converges_with_samples_per_pixel():
    """The midpoint-rule error of the gradient shrinks as samples per pixel grow (about 4x
    per doubling for a linear target): the gradient is that of the continuous loss."""
    cams = _cameras()
    mesh = _mesh()
    fd = _central_differences(lambda V: _continuous_loss(cams, V, mesh.faces), mesh.verts)
    err = [np.abs(ContourSilhouetteLoss(cams, _ramp(2), samples_per_pixel=s)(mesh)[1] - fd).max()
           for s in (0.25, 0.5, 1.0)]
    assert err[0] > 3 * err[1] > 9 * err[2]


class _ContinuousContourLoss:
    """The contour loss's gradient with the continuous loss's value, so that the views
    objective's value and gradient describe one function."""

    def __init__(self, loss):
        self.loss = loss

    def __call__(self, mesh):
        return _continuous_loss(self.loss.cameras, mesh.verts, mesh.faces), self.loss(mesh)[1]


@pytest.mark.parametrize("large_steps", [0.0, 4.0])
def test_views_contour_objective_matches_finite_differences(large_steps):
    """fit_mesh_to_views' contour objective (silhouette + edge + normal + Laplacian terms, in
    the identity or the large-steps parameterisation) has the gradient of its value."""
    cams = _cameras()
    mesh = _mesh(n=3, seed=1)
    closs = _ContinuousContourLoss(ContourSilhouetteLoss(cams, _ramp(2), samples_per_pixel=16.0))
    weights = {"silhouette": 1.0, "edge": 0.3, "normal": 0.05, "laplacian": 0.2}
    param = vertex_parameterization(mesh, large_steps)
    obj = _ContourObjective(mesh, closs, weights, param)
    x0 = param.to_params(mesh.verts).ravel()
    value, grad = obj(x0)
    assert set(obj.last["terms"]) == {"silhouette", "edge", "normal", "laplacian"}
    fd = _central_differences(lambda x: obj(x)[0], x0)
    np.testing.assert_allclose(grad, fd, rtol=0, atol=2e-5 * np.abs(fd).max())
