"""The UV atlas and the texel least-squares solve (geofit.fit.texture)."""
import numpy as np
import pytest
from _helpers import glb_round_trip

from geofit import FoVPerspectiveCameras, ico_sphere, look_at_view_transform
from geofit.fit.texture import (
    _bilinear,
    chart_laplacian,
    fit_texture,
    leave_views_out,
    ray_reliability,
    robust_scale,
    texel_charts,
    texel_operator,
    texture_problem,
    uv_atlas,
    uv_charts,
)
from geofit.io import load_mesh, save_mesh
from geofit.metrics import psnr
from geofit.render.blending import BlendParams
from geofit.render.lighting import PointLights
from geofit.render.mesh import HardImageLoss, HardPhongShader, MeshRasterizer, MeshRenderer
from geofit.render.mesh import RasterizationSettings
from geofit.structures import Mesh, TexturesUV, TexturesVertex

LIGHTS = PointLights(location=[[0.0, 1.0, -3.0]])


@pytest.fixture(scope="module")
def scene():
    R, T = look_at_view_transform(2.7, [0.0, 30.0, -30.0, 60.0, 10.0, -60.0],
                                  [0.0, 60.0, 120.0, 180.0, 240.0, 300.0])
    cams = FoVPerspectiveCameras(R=R, T=T)
    s = ico_sphere(3)
    col = 0.5 + 0.3 * np.sin(4.0 * s.verts) * np.cos(3.0 * s.verts[:, [1, 2, 0]])
    truth = Mesh(s.verts, s.faces, TexturesVertex(col))
    images = _render(truth, cams, 32)
    return cams, Mesh(s.verts, s.faces), images


def _render(mesh, cams, size):
    r = MeshRenderer(MeshRasterizer(cams, RasterizationSettings(image_size=size)),
                     HardPhongShader(cameras=cams, lights=LIGHTS,
                                     blend_params=BlendParams(background_color=(1.0, 1.0, 1.0))))
    return r(mesh)[..., :3].astype(np.float64)


def test_uv_atlas_covers_every_face_without_overlap(scene):
    """xatlas's charts: every corner's UV lies in [0, 1] and no two faces overlap in UV space
    (the summed UV areas equal the area of their union, measured by rasterising)."""
    _, mesh, _ = scene
    fuv, vuv, (H, W) = uv_atlas(mesh, 0.05)
    assert fuv.shape == mesh.faces.shape and vuv.min() >= -1e-9 and vuv.max() <= 1 + 1e-9
    tri = vuv[fuv]
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    assert np.all(area > 0)
    # sample points in every face: they must not fall inside another face of another chart
    rng = np.random.default_rng(0)
    b = rng.dirichlet(np.ones(3), size=(len(fuv), 4))
    p = np.einsum("fsj,fjd->fsd", b, tri).reshape(-1, 2)
    owner = np.repeat(np.arange(len(fuv)), 4)
    inside = np.zeros(len(p), np.int64)
    for f in range(0, len(fuv), 64):  # blocks of faces (a dense containment test)
        t = tri[f:f + 64]
        v0, v1, v2 = t[:, 0], t[:, 1], t[:, 2]
        def side(a, c):
            return ((c[None, :, 0] - a[None, :, 0]) * (p[:, None, 1] - a[None, :, 1])
                    - (c[None, :, 1] - a[None, :, 1]) * (p[:, None, 0] - a[None, :, 0]))
        s0, s1, s2 = side(v0, v1), side(v1, v2), side(v2, v0)
        inside += (((s0 > 1e-12) & (s1 > 1e-12) & (s2 > 1e-12))
                   | ((s0 < -1e-12) & (s1 < -1e-12) & (s2 < -1e-12))).sum(1)
    assert np.all(inside <= 1)  # only the face that owns the point
    assert owner.size == inside.size


def test_bilinear_weights_match_texturesuv_sampling():
    """The operator's bilinear lookup is TexturesUV.sample's (align_corners=True, border)."""
    rng = np.random.default_rng(1)
    maps = rng.uniform(0, 1, (5, 7, 3))
    uv = rng.uniform(-0.1, 1.1, (50, 2))
    ids, w = _bilinear(uv, (5, 7))
    got = np.einsum("kj,kjc->kc", w, maps.reshape(-1, 3)[ids])
    tex = TexturesUV(maps, np.arange(150).reshape(50, 3), np.repeat(uv, 3, axis=0))
    ref = tex.sample(np.arange(50), np.tile([1.0, 0.0, 0.0], (50, 1)))
    np.testing.assert_allclose(got, ref, atol=1e-12)


def test_texel_operator_reproduces_the_textured_render(scene):
    """A t - y is the residual of the hard render of TexturesUV(t) (MeshRenderer, float32)."""
    cams, mesh, images = scene
    fuv, vuv, size = uv_atlas(mesh, 0.05)
    t = np.random.default_rng(2).uniform(0, 1, size + (3,))
    loss = HardImageLoss(cams, images, lights=LIGHTS)
    A, y = texel_operator(loss, mesh, fuv, vuv, size)
    img = _render(Mesh(mesh.verts, mesh.faces, TexturesUV(t, fuv, vuv)), cams, 32)
    for c in range(3):  # channels
        np.testing.assert_allclose(A[c] @ t[..., c].ravel() - y[:, c],
                                   (img - images)[..., c].ravel(), atol=2e-5)


def test_fit_texture_holds_the_images(scene):
    """The solved texture re-renders the training views closely (> 38 dB; the vertex-coloured
    truth is smooth), robust or not, and the gradient of the least-squares objective vanishes
    at the least-squares texture where no texel was clipped (the rays weighted as
    fit_texture weighs them)."""
    cams, mesh, images = scene
    rob = fit_texture(mesh, cams, images, lights=LIGHTS)
    assert psnr(_render(Mesh(mesh.verts, mesh.faces, rob), cams, 32), images) > 38.0
    tex = fit_texture(mesh, cams, images, lights=LIGHTS, robust=None)
    assert isinstance(tex, TexturesUV) and tex.maps.min() >= 0 and tex.maps.max() <= 1
    img = _render(Mesh(mesh.verts, mesh.faces, tex), cams, 32)
    assert psnr(img, images) > 38.0
    size = tex.maps.shape[:2]
    loss = HardImageLoss(cams, images, lights=LIGHTS)
    problem, _ = texture_problem(loss, mesh, tex.faces_uvs, tex.verts_uvs, size,
                                 ray_weights=ray_reliability(loss, mesh))
    t = tex.maps.reshape(-1, 3)
    _, g = problem(t)
    free = (t > 0) & (t < 1)
    assert free.mean() > 0.9
    ref = max(np.abs(problem.A[c].T @ problem.y[:, c]).max() for c in range(3))
    assert np.abs(g[free]).max() < 1e-8 * ref


# ------------------------------------------------------------------------------------------
# the operator against the renderer, its transpose, the objective's gradient
# ------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def small():
    """An ico-sphere (level 1) seen by 3 cameras at 12 px, with its atlas and random texels."""
    R, T = look_at_view_transform(2.7, [10.0, -20.0, 40.0], [0.0, 120.0, 250.0])
    cams = FoVPerspectiveCameras(R=R, T=T)
    s = ico_sphere(1)
    mesh = Mesh(s.verts * [1.0, 0.8, 0.9], s.faces)
    fuv, vuv, size = uv_atlas(mesh, 0.08)
    rng = np.random.default_rng(5)
    targets = rng.uniform(0, 1, (3, 12, 12, 3))
    loss = HardImageLoss(cams, targets, lights=LIGHTS)
    t = rng.uniform(0, 1, size + (3,))
    return cams, mesh, fuv, vuv, size, loss, t


def test_texel_operator_equals_the_float64_render(small):
    """A t - y + target is the hard float64 render of TexturesUV(t) to 1e-12: the renderer's
    own Phong images of albedo 0 and 1 (render0 + (render1 - render0) * albedo) with the albedo
    sampled by TexturesUV at the rasterizer's fragments."""
    cams, mesh, fuv, vuv, size, loss, t = small
    A, y = texel_operator(loss, mesh, fuv, vuv, size)
    zero = loss.render(mesh, np.zeros((mesh.n_verts, 3)))
    one = loss.render(mesh, np.ones((mesh.n_verts, 3)))
    frag = MeshRasterizer(cams, RasterizationSettings(image_size=12))(mesh)
    albedo = np.zeros((3 * 12 * 12, 3))
    albedo[frag.pixel] = TexturesUV(t, fuv, vuv).sample(frag.face % mesh.n_faces, frag.bary)
    ref = zero + (one - zero) * albedo.reshape(3, 12, 12, 3)
    assert 30 < len(frag.pixel) < 3 * 12 * 12  # covered and background pixels
    for c in range(3):  # channels
        np.testing.assert_allclose(A[c] @ t[..., c].ravel() - y[:, c]
                                   + loss.targets[..., c].ravel(), ref[..., c].ravel(),
                                   rtol=0, atol=1e-12)


def test_texel_operator_transpose_dot_product(small):
    """<A x, z> = <x, A^T z> for random x, z (the transpose the normal equations use)."""
    cams, mesh, fuv, vuv, size, loss, _ = small
    A, _ = texel_operator(loss, mesh, fuv, vuv, size)
    rng = np.random.default_rng(6)
    for c in range(3):  # channels
        x, z = rng.normal(size=A[c].shape[1]), rng.normal(size=A[c].shape[0])
        assert (A[c] @ x) @ z == pytest.approx(x @ (A[c].T @ z), rel=1e-12, abs=1e-12)


@pytest.mark.parametrize("data_term, robust, weighted", [
    (True, None, False), (False, None, False), (True, 0.3, False), (True, None, True),
    (True, 0.3, True)])
def test_texture_objective_gradient_matches_finite_differences(small, data_term, robust,
                                                                weighted):
    """The gradient of TextureProblem (data + within-chart Laplacian + prior; the smoothness
    and prior terms alone; Cauchy's robust data term; each with the rays weighted by
    ray_reliability) against central differences in float64."""
    cams, mesh, fuv, vuv, size, loss, t = small
    prior = np.random.default_rng(7).uniform(0, 1, (mesh.n_verts, 3))
    u = ray_reliability(loss, mesh, outline_weight=0.2) if weighted else None
    problem, _ = texture_problem(loss, mesh, fuv, vuv, size, smoothness=0.3, prior=prior,
                                 prior_weight=0.05, ray_weights=u)
    problem.robust_scale = robust
    if not data_term:  # the regularisers alone (the scale s_c still from A)
        s = [problem.scale(c) for c in range(3)]
        problem.y = np.zeros_like(problem.y)
        problem.A = [0.0 * a for a in problem.A]
        problem.scale = lambda c: s[c]
    x = t.reshape(-1, 3)
    _, g = problem(x)
    rng = np.random.default_rng(8)
    idx = rng.choice(x.size, 40, replace=False)
    # E is quadratic without the robust term: a central difference is exact up to rounding
    # at any step; Cauchy's term is smooth: O(h^2) truncation
    h = 1e-2 if robust is None else 1e-5
    for k in idx:  # finite differences, entry by entry
        e = np.zeros(x.size)
        e[k] = h
        fd = (problem(x + e.reshape(x.shape))[0] - problem(x - e.reshape(x.shape))[0]) / (2 * h)
        assert fd == pytest.approx(g.ravel()[k], rel=1e-7 if robust else 1e-9, abs=1e-9)


def test_robust_rounds_never_increase_the_objective(small):
    """Each reweighted solve minimises a quadratic that majorises Cauchy's objective at the
    previous texels (IRLS): E never increases, and at the IRLS texels the solve with their
    own weights is a stationary point of the quadratic (its gradient, which equals E's at
    the same weights, is ~0)."""
    cams, mesh, fuv, vuv, size, loss, _ = small
    problem, _ = texture_problem(loss, mesh, fuv, vuv, size, smoothness=0.3)
    t = problem.solve()
    problem.robust_scale = robust_scale(problem, t, 1.0)
    values = [problem(t)[0]]
    for _ in range(6):  # IRLS rounds
        t = problem.solve_robust(1, t)
        values.append(problem(t)[0])
    assert np.all(np.diff(values) <= 1e-12 * values[0])
    assert values[-1] < values[0]
    u = problem.ray_weights(t)
    assert u.min() < 0.5 and u.max() <= 1.0  # the random targets disagree: some rays weigh less


@pytest.fixture(scope="module")
def too_wide(scene):
    """``(bad, inner)``: the scene's images with every view's outermost ring of object pixels
    replaced by the background (what a fitted outline one pixel too wide sees), and the
    (N, H, W) interiors without that ring."""
    from scipy.ndimage import binary_erosion

    _, _, images = scene
    obj = np.any(images < 1.0, axis=-1)
    inner = np.stack([binary_erosion(o) for o in obj])
    bad = images.copy()
    bad[obj & ~inner] = 1.0
    return bad, inner


@pytest.mark.parametrize("keeps_it_out", [dict(robust=2.0), dict(outline_weight=0.03)],
                         ids=["cauchy", "outline_weights"])
def test_texture_keeps_a_too_wide_outline_out(scene, too_wide, keeps_it_out):
    """On the too-wide-outline images plain least squares pulls the texels the ring's rays hit
    towards white, and the other views show that pale rim inside the object; Cauchy's robust
    solve, or least squares with the outline rays down-weighted (ray_reliability), keeps it
    out (renders of the images' interiors > 3 dB closer to the truth)."""
    cams, mesh, images = scene
    bad, inner = too_wide
    err = []
    for kw in (dict(robust=None, outline_weight=None),  # plain least squares
               dict(dict(robust=None, outline_weight=None), **keeps_it_out)):
        tex = fit_texture(mesh, cams, bad, lights=LIGHTS, **kw)
        img = _render(Mesh(mesh.verts, mesh.faces, tex), cams, 32)
        err.append(psnr(img[inner], images[inner]))
    assert err[1] > err[0] + 3.0


def test_leave_views_out_equals_solving_without_the_fold(small):
    """Weight 0 on a fold's rays is the solve on the other views' rows alone (a dense
    reference per fold and channel); the error is the fold's plain squared residual."""
    cams, mesh, _, _, _, loss, _ = small
    # texels twice the fixture's (1,148 texels, 318 seen, where the fixture has 4,690 with about
    # one ray each): views share texels, and the nine dense solves cost 1/70 of the fixture's
    fuv, vuv, size = uv_atlas(mesh, 0.16)
    problem, _ = texture_problem(loss, mesh, fuv, vuv, size, smoothness=0.3)
    n, R = 3, problem.A[0].shape[0]
    u = np.random.default_rng(11).uniform(0.2, 1.0, R)
    view = np.arange(R) // (R // n)
    ref = 0.0
    for k in range(n):  # folds = views here (3 folds of 3 views)
        keep, out = view != k, view == k
        for c in range(3):  # channels
            A = problem.A[c].toarray()
            s = problem.scale(c)
            lhs = A[keep].T @ (u[keep, None] * A[keep]) + s * (
                problem.smoothness * problem.L.toarray() + np.diag(problem.weights))
            rhs = A[keep].T @ (u[keep] * problem.y[keep, c]) + s * problem.weights * \
                problem.prior[:, c]
            r = A[out] @ np.linalg.solve(lhs, rhs) - problem.y[out, c]
            ref += r @ r
    assert leave_views_out(problem, n, n, u) == pytest.approx(ref, rel=1e-8)
    with pytest.raises(ValueError, match="n_folds"):
        leave_views_out(problem, n, 4)
    with pytest.raises(ValueError, match="n_folds"):
        leave_views_out(problem, n, 1)
    with pytest.raises(ValueError, match="equal blocks"):
        leave_views_out(problem, 7, 2)


def test_check_keeps_the_robust_texture_where_it_predicts_better(scene, too_wide):
    """On the too-wide-outline images the leave-views-out check keeps the robust texels (the
    same texture as without the check)."""
    cams, mesh, _ = scene
    bad, _ = too_wide
    checked = fit_texture(mesh, cams, bad, lights=LIGHTS)
    unchecked = fit_texture(mesh, cams, bad, lights=LIGHTS, check_folds=0)
    plain = fit_texture(mesh, cams, bad, lights=LIGHTS, robust=None)
    np.testing.assert_array_equal(checked.maps, unchecked.maps)
    assert np.abs(checked.maps - plain.maps).max() > 0.1


def test_chart_laplacian_closed_form():
    """t^T L t equals the sum of (t_i - t_j)^2 over the 4-neighbour pairs of one chart (a loop
    reference); free texels and pairs across charts are not linked."""
    rng = np.random.default_rng(9)
    H, W = 5, 6
    chart = rng.integers(-1, 3, H * W)
    L = chart_laplacian(chart, (H, W))
    t = rng.normal(size=H * W)
    ref = 0.0
    for r in range(H):  # the slow reference
        for c in range(W):
            i = r * W + c
            for j in ([i + 1] if c + 1 < W else []) + ([i + W] if r + 1 < H else []):
                if chart[i] == chart[j] and chart[i] >= 0:
                    ref += (t[i] - t[j]) ** 2
    assert t @ (L @ t) == pytest.approx(ref, rel=1e-12)
    np.testing.assert_allclose(np.asarray(L.sum(axis=1)).ravel(), 0.0, atol=0)
    assert (L != L.T).nnz == 0


def test_bilinear_lookups_never_read_another_chart(scene):
    """Seams: every texel a lookup inside a face reads (weight > 0) belongs to that face's
    chart (texel_charts), no texel is read by two charts, and the Laplacian links none."""
    _, mesh, _ = scene
    fuv, vuv, size = uv_atlas(mesh, 0.05)
    ch = texel_charts(fuv, vuv, size)
    assert ch.n_shared == 0
    face_chart = uv_charts(fuv)
    assert len(np.unique(face_chart)) > 1
    rng = np.random.default_rng(3)
    b = rng.dirichlet(np.ones(3), size=(len(fuv), 16))
    # and the corners and edge midpoints, where a lookup comes nearest another chart
    b = np.concatenate([b, np.broadcast_to(np.array(
        [[1, 0, 0], [0, 1, 0], [0, 0, 1], [.5, .5, 0], [0, .5, .5], [.5, 0, .5]], float),
        (len(fuv), 6, 3))], axis=1)
    uv = np.einsum("fsj,fjd->fsd", b, vuv[fuv]).reshape(-1, 2)
    ids, w = _bilinear(uv, size)
    owner = np.repeat(face_chart, b.shape[1])
    read = w > 1e-12
    assert np.array_equal(ch.chart[ids[read]], np.broadcast_to(owner[:, None], ids.shape)[read])
    L = chart_laplacian(ch.chart, size).tocoo()
    off = L.row != L.col
    assert np.all(ch.chart[L.row[off]] == ch.chart[L.col[off]])


def test_texels_no_view_sees_take_the_prior(scene):
    """With one view, the charts no ray reaches hold the prior (constant vertex colours)
    exactly, the texels stay in [0, 1], and the seen ones still reproduce the view."""
    cams, mesh, images = scene
    one = cams[np.array([0])]
    prior = np.tile([0.2, 0.6, 0.9], (mesh.n_verts, 1))
    tex = fit_texture(mesh, one, images[:1], lights=LIGHTS, prior=prior)
    assert tex.maps.min() >= 0 and tex.maps.max() <= 1
    A, _ = texel_operator(HardImageLoss(one, images[:1], lights=LIGHTS), mesh, tex.faces_uvs,
                          tex.verts_uvs, tex.maps.shape[:2])
    ch = texel_charts(tex.faces_uvs, tex.verts_uvs, tex.maps.shape[:2])
    seen = np.asarray(abs(A[0]).sum(axis=0)).ravel() > 0
    seen_charts = np.unique(ch.chart[seen])
    unseen = (ch.chart >= 0) & ~np.isin(ch.chart, seen_charts)
    assert unseen.sum() > 50
    np.testing.assert_allclose(tex.maps.reshape(-1, 3)[unseen], prior[:1].repeat(
        unseen.sum(), 0), atol=1e-9)
    img = _render(Mesh(mesh.verts, mesh.faces, tex), one, 32)
    assert psnr(img, images[:1]) > 38.0


def test_fitted_texture_survives_obj_and_glb(scene, tmp_path):
    """save_mesh writes the fitted texture as .obj + .mtl + .png and as .glb. The OBJ reloads
    to the same per-corner positions, UVs and map (up to the PNG's 8 bits) and renders; the GLB (float32 positions, vertices split at
    the seams) to the same per-corner positions and UVs and the same map up to 8 bits (its
    renders differ where float32 moves a pixel across a seam onto the other chart)."""
    cams, mesh, images = scene
    tex = fit_texture(mesh, cams, images, lights=LIGHTS)
    m = Mesh(mesh.verts, mesh.faces, tex)
    save_mesh(tmp_path / "cow.obj", m)
    assert (tmp_path / "cow.mtl").exists() and list(tmp_path.glob("*.png"))
    back = load_mesh(tmp_path / "cow.obj")
    assert isinstance(back.textures, TexturesUV)
    np.testing.assert_allclose(back.verts[back.faces], mesh.verts[mesh.faces], atol=1e-6)
    np.testing.assert_allclose(back.textures.verts_uvs[back.textures.faces_uvs],
                               tex.verts_uvs[tex.faces_uvs], atol=1e-6)
    np.testing.assert_allclose(back.textures.maps, tex.maps, atol=0.5 / 255 + 1e-9)
    np.testing.assert_allclose(_render(back, cams, 32), _render(m, cams, 32), atol=2.5 / 255)
    back = glb_round_trip(m, tmp_path / "cow.glb")
    np.testing.assert_allclose(back.textures.maps, tex.maps, atol=0.5 / 255 + 1e-9)


def test_fit_texture_validation(scene):
    cams, mesh, images = scene
    with pytest.raises(ValueError, match="texel_px"):
        fit_texture(mesh, cams, images, texel_px=0.0)
    with pytest.raises(ValueError, match="smoothness"):
        fit_texture(mesh, cams, images, smoothness=-1.0)
    with pytest.raises(ValueError, match="robust"):
        fit_texture(mesh, cams, images, robust=0.0)
    with pytest.raises(ValueError, match="robust_rounds"):
        fit_texture(mesh, cams, images, robust_rounds=-1)
    with pytest.raises(ValueError, match="check_folds"):
        fit_texture(mesh, cams, images, check_folds=-1)
    with pytest.raises(ValueError, match="target_images"):
        fit_texture(mesh, cams, images[:2])
    with pytest.raises(ValueError, match="texel_size"):
        uv_atlas(mesh, 0.0)
    with pytest.raises(ValueError, match="prior"):
        fit_texture(mesh, cams, images, prior=np.zeros((3, 3)))
    with pytest.raises(ValueError, match="prior_weight"):
        fit_texture(mesh, cams, images, prior=np.zeros((mesh.n_verts, 3)), prior_weight=0.0)
    with pytest.raises(ValueError, match="no view sees the mesh"):
        fit_texture(mesh, cams, images, masks=np.zeros(images.shape[:3]))


# ------------------------------------------------------------------------------------------
# the rays' reliability weights
# ------------------------------------------------------------------------------------------


def test_ray_reliability_matches_a_loop_reference(small):
    """Each covered ray weighs |cos| of its angle to the face normal, times outline_weight
    when a ray of its view that misses lies within outline_px pixels (a loop over rays and a
    brute-force nearest miss); misses weigh 1; all weights in [0, 1]."""
    cams, mesh, fuv, vuv, size, loss, _ = small
    u = ray_reliability(loss, mesh, outline_weight=0.25, outline_px=1.5)
    hits = loss.pixel_hits(mesh)
    H, W = loss.image_size
    N = len(cams)
    covered = np.zeros(N * H * W, bool)
    covered[hits.ray] = True
    ref = np.ones(N * H * W)
    nrm = mesh.face_normals
    for i, r in enumerate(hits.ray):  # reference: one ray at a time
        d = hits.dirs[i] / np.linalg.norm(hits.dirs[i])
        w = abs(float(nrm[hits.face[i]] @ d))
        v, rem = divmod(int(r), H * W)
        row, col = divmod(rem, W)
        miss = np.argwhere(~covered[v * H * W:(v + 1) * H * W].reshape(H, W))
        if len(miss) and np.hypot(*(miss - [row, col]).T).min() <= 1.5:
            w *= 0.25
        ref[r] = w
    np.testing.assert_allclose(u, ref, rtol=1e-12, atol=1e-15)
    assert u.min() >= 0 and u.max() <= 1 and np.any(u[hits.ray] < 0.25)


def test_ray_weights_scale_the_residuals(small):
    """texture_problem with ray_weights u has residuals sqrt(u) times those without (the
    same affine map, rows scaled), so its data term is sum_i u_i |r_i|^2."""
    cams, mesh, fuv, vuv, size, loss, t = small
    u = np.random.default_rng(12).uniform(0.0, 1.0, len(cams) * 12 * 12)
    plain, _ = texture_problem(loss, mesh, fuv, vuv, size)
    weighted, _ = texture_problem(loss, mesh, fuv, vuv, size, ray_weights=u)
    x = t.reshape(-1, 3)
    np.testing.assert_allclose(weighted.residuals(x), np.sqrt(u)[:, None] * plain.residuals(x),
                               rtol=1e-12, atol=1e-14)
    with pytest.raises(ValueError, match="ray_weights"):
        texture_problem(loss, mesh, fuv, vuv, size, ray_weights=u[:-1])
    with pytest.raises(ValueError, match="ray_weights"):
        texture_problem(loss, mesh, fuv, vuv, size, ray_weights=-u)
    with pytest.raises(ValueError, match="outline_weight"):
        ray_reliability(loss, mesh, outline_weight=1.5)
    with pytest.raises(ValueError, match="outline_weight"):
        ray_reliability(loss, mesh, outline_weight=-0.1)
    with pytest.raises(ValueError, match="outline_px"):
        ray_reliability(loss, mesh, outline_px=-1.0)
