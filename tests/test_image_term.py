"""The hard differentiable image term (geofit.render.mesh.image_term)."""
import numpy as np
import pytest

from geofit import FoVPerspectiveCameras, ico_sphere, look_at_view_transform
from geofit.render.blending import BlendParams
from geofit.render.lighting import PointLights
from geofit.render.mesh import HardPhongShader, MeshRasterizer, MeshRenderer, RasterizationSettings
from geofit.render.mesh.image_term import HardImageLoss
from geofit.shapes import torus
from geofit.structures import Mesh, TexturesVertex

LIGHTS = PointLights(location=[[0.0, 1.0, -3.0]])


@pytest.fixture(scope="module")
def blob():
    R, T = look_at_view_transform(2.7, [10.0, 30.0], [0.0, 60.0])
    cams = FoVPerspectiveCameras(R=R, T=T)
    rng = np.random.default_rng(0)
    m = ico_sphere(2)
    V = m.verts * (1 + 0.1 * rng.standard_normal((m.n_verts, 1)))
    col = rng.uniform(0.2, 0.9, (m.n_verts, 3))
    return cams, V, m.faces, col


def _dirs(V):
    """Smooth deformation fields (no new folds of the projection for small steps)."""
    return {"translate": np.tile([1.0, 0.2, 0.0], (len(V), 1)), "scale": V.copy(),
            "smooth": np.stack([np.sin(2 * V[:, 1]), np.cos(3 * V[:, 2]),
                                np.sin(V[:, 0] + V[:, 2])], 1)}


def test_render_is_pytorch3d_hard_phong(blob):
    """The forward image equals MeshRenderer + HardPhongShader (TexturesVertex) to float32."""
    cams, V, F, col = blob
    loss = HardImageLoss(cams, np.zeros((2, 20, 20, 3)), lights=LIGHTS)
    img = loss.render(Mesh(V, F), col)
    ref = MeshRenderer(MeshRasterizer(cams, RasterizationSettings(image_size=20)),
                       HardPhongShader(cameras=cams, lights=LIGHTS,
                                       blend_params=BlendParams(background_color=(1.0, 1.0, 1.0)))
                       )(Mesh(V, F, textures=TexturesVertex(col)))[..., :3]
    np.testing.assert_allclose(img, ref, atol=1e-6)


def test_value_is_the_mean_squared_error(blob):
    """value == mean over views and pixels of the channel-summed squared error of render()."""
    cams, V, F, col = blob
    tgt = np.random.default_rng(1).uniform(0, 1, (2, 12, 12, 3))
    loss = HardImageLoss(cams, tgt, lights=LIGHTS)
    img = loss.render(Mesh(V, F), col)
    value = loss(Mesh(V, F), col).value
    np.testing.assert_allclose(value, np.mean(np.sum((img - tgt) ** 2, axis=-1)), rtol=1e-12)


def test_interior_gradient_matches_finite_differences(blob):
    """Without the edge term the gradient is exact: steps of 1e-6 change no pixel's face, so
    central differences of the value agree to ~1e-7 (positions and colours)."""
    cams, V, F, col = blob
    rng = np.random.default_rng(2)
    tgt = rng.uniform(0, 1, (2, 24, 24, 3))
    masks = rng.uniform(0, 1, (2, 24, 24))
    loss = HardImageLoss(cams, tgt, lights=LIGHTS, masks=masks, edges=False)
    _, gv, gc = loss(Mesh(V, F), col)
    h = 1e-6
    for _ in range(2):
        D = rng.standard_normal(V.shape)
        fd = (loss(Mesh(V + h * D, F), col).value - loss(Mesh(V - h * D, F), col).value) / (2 * h)
        np.testing.assert_allclose(np.sum(gv * D), fd, rtol=1e-5)
        C = rng.standard_normal(col.shape)
        fd = (loss(Mesh(V, F), col + h * C).value - loss(Mesh(V, F), col - h * C).value) / (2 * h)
        np.testing.assert_allclose(np.sum(gc * C), fd, rtol=1e-6)


def test_colour_gradient_closed_form_on_ambient_light(blob):
    """Ambient light only, black target: I = Ma La c, so dL/dc is 2 Ma La I b-weighted: for a
    uniform colour the gradient summed over vertices is 2 (Ma La)^2 c (covered fraction)."""
    from geofit.render.lighting import AmbientLights

    cams, V, F, _ = blob
    c = np.full((len(V), 3), 0.5)
    loss = HardImageLoss(cams, np.zeros((2, 16, 16, 3)), lights=AmbientLights(),
                         background=(0.0, 0.0, 0.0))
    img = loss.render(Mesh(V, F), c)
    covered = float(np.mean(img[..., 0] > 0))
    _, _, gc = loss(Mesh(V, F), c)
    np.testing.assert_allclose(gc.sum(axis=0), 2 * 0.5 * covered * np.ones(3), rtol=1e-10)


@pytest.mark.parametrize("shape", ["blob", "torus"])
def test_edge_gradient_matches_supersampled_finite_differences(blob, shape):
    """Interior + edge gradient against central differences (step 2e-2, about 0.15 px) of the
    16x16-supersampled loss of 24 x 24 images (which approximates the continuous loss the edge
    term differentiates) along smooth deformations: agreement to 10% (measured 0.5-6.5%: the
    bumpy blob shows a bias of +2 to +6% that does not move with the supersampling or the step,
    the contour sampling's; the torus is within 1.5%). The torus seen from above has
    self-occlusion edges (the near side of its tube in front of the far side). The interior term
    alone is far off (the visibility change dominates), so the test could fail."""
    _, V, F, col = blob
    R, T = look_at_view_transform(2.7, [30.0], [60.0])
    if shape == "torus":
        t = torus(0.8, 0.3, 24, 12)
        V, F = t.verts, t.faces
        col = np.random.default_rng(3).uniform(0.2, 0.9, (len(V), 3))
        R, T = look_at_view_transform(2.7, [35.0], [20.0])
    cams = FoVPerspectiveCameras(R=R, T=T)
    tgt = np.full((1, 24, 24, 3), 0.3)
    loss = HardImageLoss(cams, tgt, lights=LIGHTS, supersample=16, samples_per_pixel=4)
    _, gv, _ = loss(Mesh(V, F), col)
    gi = HardImageLoss(cams, tgt, lights=LIGHTS, supersample=16,
                       edges=False)(Mesh(V, F), col).grad_verts
    h = 2e-2
    for name, D in _dirs(V).items():
        fd = (loss(Mesh(V + h * D, F), col).value - loss(Mesh(V - h * D, F), col).value) / (2 * h)
        np.testing.assert_allclose(np.sum(gv * D), fd, rtol=0.1, err_msg=name)
        assert abs(np.sum(gi * D) - fd) > 0.3 * abs(fd), name


def test_zero_at_its_own_render(blob):
    """With its own render as the target the value and the interior gradients are 0 and the
    edge gradient is finite."""
    cams, V, F, col = blob
    tgt = HardImageLoss(cams, np.zeros((2, 16, 16, 3)), lights=LIGHTS).render(Mesh(V, F), col)
    value, gv, gc = HardImageLoss(cams, tgt, lights=LIGHTS, edges=False)(Mesh(V, F), col)
    assert value == pytest.approx(0.0, abs=1e-24)
    np.testing.assert_allclose(gv, 0.0, atol=1e-15)
    np.testing.assert_allclose(gc, 0.0, atol=1e-15)
    ge = HardImageLoss(cams, tgt, lights=LIGHTS).edge_gradient(Mesh(V, F), col)
    assert np.all(np.isfinite(ge))


def test_matches_the_soft_renderer_at_vanishing_blur(blob):
    """The soft Phong renderer with sigma = gamma = 1e-9 and a tiny blur radius gives the same
    image away from the outline and, for a loss on the interior pixels, the same colour gradient
    and the same vertex gradient as the hard term without its edge part."""
    from geofit.render.soft import SoftPhongRenderer, SoftRasterizationSettings

    cams, V, F, col = blob
    H = 20
    rng = np.random.default_rng(4)
    tgt = rng.uniform(0, 1, (2, H, H, 3))
    hard = HardImageLoss(cams, tgt, lights=LIGHTS, edges=False)
    img = hard.render(Mesh(V, F), col)
    soft = SoftPhongRenderer(cams, lights=LIGHTS, raster_settings=SoftRasterizationSettings(
        image_size=H, blur_radius=1e-9, faces_per_pixel=4, dtype=np.float64),
        blend_params=BlendParams(sigma=1e-9, gamma=1e-9))
    out = soft(Mesh(V, F), col)
    alpha = out.images[..., 3]
    interior = alpha > 1 - 1e-9
    assert interior.sum() > 100
    np.testing.assert_allclose(out.images[..., :3][interior], img[interior], atol=1e-9)
    masks = interior.astype(float)
    hard = HardImageLoss(cams, tgt, lights=LIGHTS, masks=masks, edges=False)
    _, gv, gc = hard(Mesh(V, F), col)
    g = np.zeros(out.images.shape)
    g[..., :3] = 2 * masks[..., None] * (out.images[..., :3] - tgt) / masks.size
    sg = out.vjp(g)
    np.testing.assert_allclose(sg.colors, gc, atol=1e-9 * np.abs(gc).max())
    np.testing.assert_allclose(sg.verts, gv, rtol=1e-5, atol=1e-6 * np.abs(gv).max())


def test_validation(blob):
    cams, V, F, col = blob
    with pytest.raises(TypeError, match="cameras"):
        HardImageLoss("cams", np.zeros((2, 8, 8, 3)))
    with pytest.raises(ValueError, match="target_images"):
        HardImageLoss(cams, np.zeros((3, 8, 8, 3)))
    with pytest.raises(ValueError, match="target_images"):
        HardImageLoss(cams, np.zeros((2, 8, 8, 2)))
    with pytest.raises(ValueError, match="target_images"):
        HardImageLoss(cams, np.zeros((2, 1, 8, 3)))
    with pytest.raises(ValueError, match="masks"):
        HardImageLoss(cams, np.zeros((2, 8, 8, 3)), masks=np.ones((2, 8, 7)))
    with pytest.raises(ValueError, match="supersample"):
        HardImageLoss(cams, np.zeros((2, 8, 8, 3)), supersample=0)
    with pytest.raises(ValueError, match="samples_per_pixel"):
        HardImageLoss(cams, np.zeros((2, 8, 8, 3)), samples_per_pixel=0.0)
    with pytest.raises(ValueError, match="edge_offset_px"):
        HardImageLoss(cams, np.zeros((2, 8, 8, 3)), edge_offset_px=-1.0)
    loss = HardImageLoss(cams, np.zeros((2, 8, 8, 3)))
    with pytest.raises(ValueError, match="vertex_colors"):
        loss(Mesh(V, F), col[:-1])


def test_color_operator_reproduces_the_loss(blob):
    """1/(N H W) sum_c |A_c x_c - y_c|^2 equals the loss (supersampled and masked too), and
    A^T (A x - y) * 2/(N H W) is its colour gradient."""
    cams, V, F, col = blob
    rng = np.random.default_rng(5)
    tgt = rng.uniform(0, 1, (2, 12, 12, 3))
    loss = HardImageLoss(cams, tgt, lights=LIGHTS, supersample=2,
                         masks=rng.uniform(0, 1, (2, 12, 12)))
    A, y = loss.color_operator(Mesh(V, F))
    value, _, gc = loss(Mesh(V, F), col)
    res = [A[c] @ col[:, c] - y[:, c] for c in range(3)]
    n = 2 * 12 * 12
    np.testing.assert_allclose(sum(float(r @ r) for r in res) / n, value, rtol=1e-10)
    g = np.stack([2.0 / n * (A[c].T @ res[c]) for c in range(3)], 1)
    np.testing.assert_allclose(g, gc, rtol=1e-8, atol=1e-14)


def test_one_cast_serves_the_loss_and_the_colour_operator(blob):
    """``pixel_hits`` cast once gives the loss, gradients and colour operator of a fresh cast
    exactly; it casts only the sub-pixels faces may cover, and hits of another mesh or of
    another type are refused."""
    cams, V, F, col = blob
    tgt = np.random.default_rng(6).uniform(0, 1, (2, 40, 40, 3))
    loss = HardImageLoss(cams, tgt, lights=LIGHTS, supersample=2)
    mesh = Mesh(V, F)
    hits = loss.pixel_hits(mesh)
    assert 0 < len(hits.ray) <= hits.n_cast < 0.8 * 2 * 80 * 80
    a, b = loss(mesh, col, hits=hits), loss(mesh, col)
    assert a.value == b.value
    np.testing.assert_array_equal(a.grad_verts, b.grad_verts)
    A1, y1 = loss.color_operator(mesh, hits)
    A2, y2 = loss.color_operator(mesh)
    np.testing.assert_array_equal(y1, y2)
    assert all((p != q).nnz == 0 for p, q in zip(A1, A2))
    with pytest.raises(ValueError, match="hits"):
        loss(Mesh(V * 1.01, F), col, hits=hits)
    with pytest.raises(TypeError, match="hits"):
        loss(mesh, col, hits=(hits.ray, hits.face))


def test_threads_give_bit_identical_values_and_gradients(blob):
    """The chunked edge casts (several chunks at 96 px), the views' coverage masks and
    contour samples on 2 threads give exactly the value and gradients of 1 thread."""
    cams, V, F, col = blob
    tgt = np.random.default_rng(4).uniform(0, 1, (2, 96, 96, 3))
    out = [HardImageLoss(cams, tgt, lights=LIGHTS, supersample=2, n_threads=n)(Mesh(V, F), col)
           for n in (1, 2)]  # threads
    assert out[0].value == out[1].value
    np.testing.assert_array_equal(out[0].grad_verts, out[1].grad_verts)
    np.testing.assert_array_equal(out[0].grad_colors, out[1].grad_colors)
    assert np.any(out[0].grad_verts != 0)
