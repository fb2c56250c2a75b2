"""The RGB refinement prototype (geofit.fit._rgb_refine; not in the default fit)."""
import numpy as np

from geofit import FoVPerspectiveCameras, ico_sphere, look_at_view_transform
from geofit.fit._rgb_refine import refine_rgb, solve_vertex_colors
from geofit.ops import uniform_laplacian
from geofit.render.lighting import PointLights
from geofit.render.mesh import HardImageLoss
from geofit.structures import Mesh

LIGHTS = PointLights(location=[[0.0, 1.0, -3.0]])


def _scene():
    R, T = look_at_view_transform(2.7, [0.0, 30.0, -20.0], [0.0, 120.0, 240.0])
    cams = FoVPerspectiveCameras(R=R, T=T)
    s = ico_sphere(2)
    col = 0.5 + 0.3 * np.sin(3.0 * s.verts)
    truth = Mesh(s.verts * [1.0, 0.8, 0.9], s.faces)
    images = HardImageLoss(cams, np.zeros((3, 24, 24, 3)), lights=LIGHTS).render(truth, col)
    return cams, s, images


def test_solved_colours_are_the_inner_minimum():
    """At the solved colours the colour gradient of L + reg |L_u C|^2 / V (+ the 1e-9 ridge
    towards grey) is zero (the
    envelope theorem the refinement's vertex gradient relies on)."""
    cams, s, images = _scene()
    loss = HardImageLoss(cams, images, lights=LIGHTS)
    C = solve_vertex_colors(loss, s, reg=1e-3)
    _, _, gc = loss(s, C)
    Lu = uniform_laplacian(s)
    g = gc + 2e-3 / s.n_verts * (Lu.T @ (Lu @ C)) + 2e-9 * (C - 0.5)  # the solve's 1e-9 ridge
    assert np.abs(g).max() < 1e-7 * np.abs(gc).max() + 1e-12


def test_refine_rgb_lowers_the_image_loss():
    """Five L-BFGS iterations from a sphere towards an ellipsoid's images lower the loss
    (measured 8% with 3 x 3 rays per pixel; at one ray per pixel the line search stalls after
    5%: the pixel loss is piecewise constant at the outline)."""
    cams, s, images = _scene()
    r = refine_rgb(s, cams, images, lights=LIGHTS, maxiter=5, supersample=3)
    assert r.n_evaluations >= 2 and min(r.values) < 0.95 * r.values[0]
    assert np.all(np.isfinite(r.mesh.verts)) and r.colors.shape == (s.n_verts, 3)


def test_refine_rgb_adam_lowers_the_image_loss_at_one_ray_per_pixel():
    """Adam (one evaluation a step, no line search) from a sphere towards an ellipsoid's
    images lowers the pixel loss at one ray per pixel, where L-BFGS's line search stalls; the
    result is the evaluated point of least objective."""
    cams, s, images = _scene()
    r = refine_rgb(s, cams, images, lights=LIGHTS, maxiter=8, supersample=1, method="adam",
                   lr=0.02)
    assert r.n_evaluations == 8 and min(r.values) < 0.9 * r.values[0]
    assert np.all(np.isfinite(r.mesh.verts)) and r.colors.shape == (s.n_verts, 3)


def test_refine_rgb_rejects_an_unknown_method_or_step():
    """``method`` must be "lbfgs" or "adam"; Adam needs a positive finite ``lr``."""
    import pytest

    cams, s, images = _scene()
    with pytest.raises(ValueError, match="method"):
        refine_rgb(s, cams, images, lights=LIGHTS, maxiter=1, method="sgd")
    for bad in (0.0, -1.0, np.nan):
        with pytest.raises(ValueError, match="lr"):
            refine_rgb(s, cams, images, lights=LIGHTS, maxiter=1, method="adam", lr=bad)


def test_projected_gradient_matches_finite_differences():
    """The variable-projection gradient (colours re-solved at every point, the envelope
    theorem) against central differences of the projected loss, float64, interior term only
    (the edge term differentiates the continuous loss, not the pixel value)."""
    from geofit.fit._rgb_refine import projected_image_loss

    cams, s, images = _scene()
    loss = HardImageLoss(cams, images, lights=LIGHTS, edges=False)
    mesh = Mesh(s.verts * 1.02, s.faces)
    _, gv, _ = projected_image_loss(loss, mesh, 1e-3)
    rng = np.random.default_rng(0)
    for _ in range(3):  # random directions
        d = rng.normal(size=mesh.verts.shape)
        h = 1e-6
        fp = projected_image_loss(loss, Mesh(mesh.verts + h * d, s.faces), 1e-3)[0]
        fm = projected_image_loss(loss, Mesh(mesh.verts - h * d, s.faces), 1e-3)[0]
        fd = (fp - fm) / (2 * h)
        an = float(np.sum(gv * d))
        assert abs(fd - an) < 1e-5 * abs(an) + 1e-12, (fd, an)


def test_colour_solve_matches_the_explicit_normal_equations():
    """The face-by-face assembly of the colours' normal equations (one factorisation for grey
    shading, one per channel otherwise) gives the colours of the explicit ray-by-vertex
    operator ``A^T A / n + R`` (coloured lights, masks, 2 x 2 rays a pixel)."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    from geofit.fit._rgb_refine import _ColorSolve

    cams, s, images = _scene()
    rng = np.random.default_rng(3)
    for lights in (LIGHTS, PointLights(location=[[0.0, 1.0, -3.0]],
                                       diffuse_color=[[0.6, 0.3, 0.2]])):
        loss = HardImageLoss(cams, images, lights=lights, supersample=2,
                             masks=rng.uniform(0.2, 1.0, images.shape[:3]))
        mesh = Mesh(s.verts * 1.02, s.faces)
        C, _ = _ColorSolve(mesh, 1e-3)(loss, mesh)
        A, y = loss.color_operator(mesh)
        n = images.shape[0] * images.shape[1] * images.shape[2]
        Lu = uniform_laplacian(mesh)
        R = (Lu.T @ Lu) * (1e-3 / mesh.n_verts) + 1e-9 * sp.identity(mesh.n_verts)
        for c in range(3):  # channels
            ref = spla.spsolve((A[c].T @ A[c] / n + R).tocsc(), A[c].T @ y[:, c] / n + 5e-10)
            np.testing.assert_allclose(C[:, c], ref, rtol=1e-8, atol=1e-10)


def test_refine_rgb_stops_at_the_clocks_deadline():
    """A clock past its deadline stops the refinement before its first evaluation, and a
    TimeUp raised inside ``extra`` (the silhouette objective checks the fit's clock) ends it
    as stopped, the start kept, instead of escaping."""
    from geofit.fit.history import Clock, TimeUp

    cams, s, images = _scene()
    r = refine_rgb(s, cams, images, lights=LIGHTS, maxiter=5, clock=Clock(deadline=1e-9))
    assert r.stopped and r.n_evaluations == 0 and r.colors is None
    np.testing.assert_array_equal(r.mesh.verts, s.verts)

    def extra(verts):
        raise TimeUp("reached the time budget")

    r = refine_rgb(s, cams, images, lights=LIGHTS, maxiter=5, extra=extra)
    assert r.stopped and r.n_evaluations == 0 and r.colors is None
    r = refine_rgb(s, cams, images, lights=LIGHTS, maxiter=5, extra=extra, method="adam",
                   lr=0.01)
    assert r.stopped and r.n_evaluations == 0 and r.colors is None


def test_dirichlet_stiffness_is_the_gradient_energy_of_a_linear_field():
    """On a planar mesh ``u^T K u`` of a linear field ``u = a . x`` is ``|a|^2 x area`` exactly
    (piecewise-linear interpolation reproduces it), whatever the mesh's size or refinement;
    ``K`` is symmetric with zero row sums."""
    from geofit.fit._rgb_refine import dirichlet_stiffness

    rng = np.random.default_rng(4)
    n = 7
    x, y = np.meshgrid(np.linspace(0.0, 1.0, n), np.linspace(0.0, 2.0, n))
    V = np.stack([x.ravel() + 0.02 * rng.standard_normal(n * n), y.ravel(),
                  np.zeros(n * n)], axis=1)
    i = np.arange(n - 1)
    q = (i[:, None] * n + i[None, :]).ravel()  # lower-left corners
    F = np.concatenate([np.stack([q, q + 1, q + n + 1], 1), np.stack([q, q + n + 1, q + n], 1)])
    a = np.array([0.7, -1.3, 0.0])
    for scale in (1.0, 3.0):  # sizes
        m = Mesh(V * scale, F)
        K = dirichlet_stiffness(m)
        u = (m.verts @ a)
        np.testing.assert_allclose(u @ (K @ u), (a @ a) * m.face_areas.sum(), rtol=1e-12)
        np.testing.assert_allclose((K - K.T).toarray(), 0.0, atol=1e-12)
        np.testing.assert_allclose(np.asarray(K.sum(axis=1)).ravel(), 0.0, atol=1e-12)


def test_colour_smoothness_solve_and_gradient():
    """With the Dirichlet prior the solved colours are the inner minimum (colour gradient of
    L + smooth C^T K_0 C zero), and the projected loss's vertex gradient matches central
    differences in float64 (K_0 of the solver's mesh held fixed, as in the refinement;
    interior term only)."""
    from geofit.fit._rgb_refine import _ColorSolve, dirichlet_stiffness, projected_image_loss

    cams, s, images = _scene()
    loss = HardImageLoss(cams, images, lights=LIGHTS, edges=False)
    mesh = Mesh(s.verts * 1.02, s.faces)
    smooth = 1e-3
    solver = _ColorSolve(mesh, 0.0, smooth)
    _, gv, C = projected_image_loss(loss, mesh, 0.0, solver)
    _, _, gc = loss(mesh, C)
    K = dirichlet_stiffness(mesh)
    g = gc + 2 * smooth * (K @ C) + 2e-9 * (C - 0.5)
    assert np.abs(g).max() < 1e-7 * np.abs(gc).max() + 1e-12
    C0 = solve_vertex_colors(loss, mesh, reg=0.0)
    assert np.sum(C * (K @ C)) < np.sum(C0 * (K @ C0))  # the prior smooths the colours
    rng = np.random.default_rng(1)
    for _ in range(3):  # random directions
        d = rng.normal(size=mesh.verts.shape)
        h = 1e-6
        fp = projected_image_loss(loss, Mesh(mesh.verts + h * d, s.faces), 0.0, solver)[0]
        fm = projected_image_loss(loss, Mesh(mesh.verts - h * d, s.faces), 0.0, solver)[0]
        fd = (fp - fm) / (2 * h)
        an = float(np.sum(gv * d))
        assert abs(fd - an) < 1e-5 * abs(an) + 1e-12, (fd, an)


def test_interior_masks_erode_the_thresholded_silhouettes():
    """A 10 x 10 square silhouette keeps its 6 x 6 core at 2 px (the cross erodes one pixel a
    side per step), itself at 0 px; soft values are thresholded at 0.5."""
    from geofit.fit._rgb_refine import interior_masks

    sil = np.zeros((2, 16, 16))
    sil[:, 3:13, 3:13] = 0.8
    sil[1, 0, 0] = 0.4  # below the threshold
    np.testing.assert_array_equal(interior_masks(sil, 0), sil > 0.5)
    core = np.zeros((16, 16))
    core[5:11, 5:11] = 1.0
    m = interior_masks(sil, 2)
    assert m.dtype == np.float64 and m.shape == sil.shape
    np.testing.assert_array_equal(m[0], core)
    np.testing.assert_array_equal(m[1], core)


def test_colour_solve_on_threads_is_bit_identical():
    """The colour solve's bincounts on 2 threads give exactly the colours and the projected
    value and gradient of 1 thread."""
    from geofit import set_num_threads
    from geofit.fit._rgb_refine import projected_image_loss

    cams, s, images = _scene()
    out = {}
    try:
        for n in (1, 2):  # threads
            set_num_threads(n)
            out[n] = projected_image_loss(HardImageLoss(cams, images, lights=LIGHTS), s, 1e-3)
    finally:
        set_num_threads(None)
    assert out[1][0] == out[2][0]
    np.testing.assert_array_equal(out[1][1], out[2][1])
    np.testing.assert_array_equal(out[1][2], out[2][2])
