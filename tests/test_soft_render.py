"""Tests for geofit.render.soft (soft rasterizer, silhouette and Phong blends, vjps) and
geofit.render.soft.contour (the contour gradient of the hard silhouette loss).

Non-differentiable terms (tested away from them): which faces a pixel keeps (blur cut-off,
top-K, z >= 0), the choice of the nearest edge, barycentric clipping, relu of the diffuse term,
the specular mask n.l > 0 and the max over depths of the softmax blend.
"""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from geofit import (
    FoVOrthographicCameras,
    FoVPerspectiveCameras,
    Mesh,
    TexturesVertex,
    ico_sphere,
    look_at_view_transform,
)
from geofit.render import (
    AmbientLights,
    BlendParams,
    DirectionalLights,
    Materials,
    MeshRasterizer,
    MeshRenderer,
    PointLights,
    RasterizationSettings,
    SoftPhongShader,
)
from geofit.render.soft import (
    TUTORIAL_BLUR_RADIUS,
    SoftFragments,
    SoftPhongRenderer,
    SoftRasterizationSettings,
    SoftSilhouetteRenderer,
    SoftSilhouetteShader,
    phong_vertex_colors,
    rasterize_soft,
    sigmoid_alpha_blend,
    sigmoid_alpha_blend_vjp,
    softmax_rgb_blend_soft,
)
from geofit.render.soft.contour import ContourSilhouetteLoss, contour_edges

DATA = Path(__file__).parent / "data" / "soft_grad.npz"
S = 64
F_REF = 1280


@pytest.fixture(scope="module")
def ref():
    d = dict(np.load(DATA))
    return {k: (v.astype(np.float64) if v.dtype == np.float32 else v) for k, v in d.items()}


@pytest.fixture(scope="module")
def ref_scene(ref):
    mesh = Mesh(ref["src_verts"], ico_sphere(3).faces)
    cams = FoVPerspectiveCameras(R=ref["R"], T=ref["T"])
    return mesh, cams


def _noisy_mesh(level=1, seed=3, scale=0.9, noise=0.05):
    rng = np.random.default_rng(seed)
    m = ico_sphere(level)
    return Mesh(m.verts * scale + rng.normal(0, noise, m.verts.shape), m.faces)


def _angle(a, b):
    cos = float(np.sum(a * b) / (np.linalg.norm(a) * np.linalg.norm(b)))
    return math.acos(min(1.0, cos))


def _relerr(a, b):
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def _slots(fr: SoftFragments):
    """Flat slot index (n, y, x, k) of every entry in a (N, H, W, 50) layout."""
    H, W = fr.image_size
    return ((fr.view * H + fr.pixel // W) * W + fr.pixel % W) * 50 + fr.k


# ------------------------------------------------------------------------------------------
# PyTorch3D parity (tests/data/soft_grad.npz, see tests/data/README.md)
# ------------------------------------------------------------------------------------------


def test_silhouette_fragments_match_pytorch3d(ref, ref_scene):
    """Faces, signed distances and depths per slot agree with PyTorch3D's CPU rasterizer."""
    mesh, cams = ref_scene
    fr = rasterize_soft(mesh, cams, SoftRasterizationSettings.tutorial(S))
    ours = {int(s): i for i, s in enumerate(_slots(fr))}
    idx = np.array([ours.get(int(s), -1) for s in ref["sil_slot"]])
    assert np.all(idx >= 0)
    np.testing.assert_array_equal(fr.face[idx], ref["sil_face"])
    # float32 projection in PyTorch3D: |d dist| <~ 2 sqrt(dist) 1e-7
    np.testing.assert_allclose(fr.dist[idx], ref["sil_dists"], rtol=0, atol=2e-8)
    np.testing.assert_allclose(fr.depth[idx], ref["sil_zbuf"], rtol=0, atol=5e-5)
    # the band holds exactly the reference's entries (no extra faces)
    W = fr.image_size[1]
    row = fr.pixel // W
    r0, r1 = ref["band_rows"]
    assert np.count_nonzero((row >= r0) & (row < r1)) == len(ref["sil_slot"])


def test_silhouette_image_loss_and_gradient_match_pytorch3d(ref, ref_scene):
    """Soft silhouettes to 1e-5 at every pixel; the loss gradient to 1e-4 (norm, direction)."""
    mesh, cams = ref_scene
    out = SoftSilhouetteRenderer(cams, SoftRasterizationSettings.tutorial(S))(mesh)
    np.testing.assert_allclose(out.silhouettes, ref["sil_alpha"], rtol=0, atol=1e-5)
    np.testing.assert_array_equal(out.images[..., :3], 1.0)
    res = out.silhouettes - ref["target_silhouette"]
    assert float(np.sum(res ** 2)) == pytest.approx(float(ref["sil_loss"]), rel=1e-6)
    g = out.vjp(2.0 * res).verts
    gr = ref["sil_loss_grad_verts"]
    assert _relerr(g, gr) < 1e-4
    assert abs(np.linalg.norm(g) / np.linalg.norm(gr) - 1.0) < 1e-4
    assert _angle(g, gr) < 1e-4


def _phong_ref_renderer(cams):
    return SoftPhongRenderer(cams, PointLights(location=[[0.0, 0.0, -3.0]]), Materials(),
                             SoftRasterizationSettings.tutorial(S, perspective_correct=False),
                             BlendParams(sigma=1e-4, gamma=1e-4))


def test_phong_fragments_match_pytorch3d(ref, ref_scene):
    """Faces and clipped screen-space barycentrics (perspective_correct=False) per slot."""
    mesh, cams = ref_scene
    fr = rasterize_soft(mesh, cams, SoftRasterizationSettings.tutorial(S,
                                                                      perspective_correct=False,
                                                                      dtype=np.float64))
    assert fr._ctx["clip"] and not fr._ctx["perspective_correct"]
    ours = {int(s): i for i, s in enumerate(_slots(fr))}
    idx = np.array([ours.get(int(s), -1) for s in ref["rgb_slot"]])
    assert np.all(idx >= 0)
    np.testing.assert_array_equal(fr.face[idx], ref["rgb_face"])
    np.testing.assert_allclose(fr.bary.sum(1), 1.0, atol=1e-12)
    assert fr.bary.min() >= 0.0
    # PyTorch3D's float32 edge functions of grazing faces: up to ~2e-4 on the band
    np.testing.assert_allclose(fr.bary[idx], ref["rgb_bary"], rtol=0, atol=3e-4)
    assert np.median(np.abs(fr.bary[idx] - ref["rgb_bary"])) < 1e-6


def test_phong_image_matches_pytorch3d(ref, ref_scene):
    """Alpha to 1e-5 everywhere; RGB to 1e-5 on >= 99% of pixels (float32 depth rounding)."""
    mesh, cams = ref_scene
    out = _phong_ref_renderer(cams)(mesh, ref["src_colours"])
    err = np.abs(out.images - ref["rgb_images"])
    np.testing.assert_allclose(out.images[..., 3], ref["rgb_images"][..., 3], rtol=0, atol=1e-5)
    px = err[..., :3].max(-1)
    assert np.mean(px <= 1e-5) >= 0.99
    assert px.max() < 5e-5
    # the whole image to 1e-5 relative in norm (measured 1.1e-6; mean |d| 2e-7)
    assert _relerr(out.images, ref["rgb_images"]) < 1e-5


def _emulate_float32_depth(fr, zfar=100.0, znear=1.0):
    """Replace the depths by the float64 value whose z_inv equals PyTorch3D's float32 z_inv.

    softmax_rgb_blend weighs faces by exp(z_inv / gamma) with gamma = 1e-4, so the float32
    rounding of ``zbuf`` and of ``zfar - zbuf`` (~1e-7 absolute) moves the weights by ~1e-3
    relative; this reproduces that rounding (and PyTorch3D's float32 sum b0 z0 + b1 z1 + b2 z2).
    """
    f32 = np.float32
    b = fr.bary.astype(f32)
    zc = fr._ctx["z"][fr.view[:, None], fr._ctx["faces"][fr.face]].astype(f32)
    pz = (b[:, 0] * zc[:, 0] + b[:, 1] * zc[:, 1]) + b[:, 2] * zc[:, 2]
    zinv = (f32(zfar) - pz) / f32(zfar - znear)
    fr.__dict__["_bary_depth"] = (fr.bary, zfar - zinv.astype(np.float64) * (zfar - znear))


def test_phong_blend_matches_pytorch3d_given_its_fragments(ref, ref_scene):
    """With PyTorch3D's barycentrics (on the band) and its float32 depth rounding, every RGB
    pixel of the band agrees to 1e-5: the shading and blending formulas are the same."""
    mesh, cams = ref_scene
    fr = rasterize_soft(mesh, cams, SoftRasterizationSettings.tutorial(S,
                                                                      perspective_correct=False))
    ours = {int(s): i for i, s in enumerate(_slots(fr))}
    idx = np.array([ours[int(s)] for s in ref["rgb_slot"]])
    bary = fr.bary.copy()
    bary[idx] = ref["rgb_bary"]
    fr.__dict__["_bary_depth"] = (bary, fr.depth)
    _emulate_float32_depth(fr)
    sh = phong_vertex_colors(fr, mesh, ref["src_colours"], PointLights(location=[[0, 0, -3.0]]),
                             cams, Materials())
    bl = softmax_rgb_blend_soft(sh.colors, fr, BlendParams(), cams.znear, cams.zfar)
    r0, r1 = ref["band_rows"]
    np.testing.assert_allclose(bl.images[:, r0:r1], ref["rgb_images"][:, r0:r1], rtol=0,
                               atol=1e-5)


def test_phong_loss_gradients_match_pytorch3d(ref, ref_scene):
    """d rgb_loss / d verts and d colours: norm to 1e-4; direction to 1e-4 rad once PyTorch3D's
    float32 depth rounding is emulated (2e-4 rad without)."""
    mesh, cams = ref_scene
    r = _phong_ref_renderer(cams)
    out = r(mesh, ref["src_colours"])
    res = out.images[..., :3] - ref["target_rgb"]
    assert float(np.sum(res ** 2)) == pytest.approx(float(ref["rgb_loss"]), rel=1e-6)
    gi = np.zeros(out.images.shape)
    gi[..., :3] = 2.0 * res
    g = out.vjp(gi)
    gv, gc = ref["rgb_loss_grad_verts"], ref["rgb_loss_grad_colours"]
    assert abs(np.linalg.norm(g.verts) / np.linalg.norm(gv) - 1.0) < 1e-4
    assert _angle(g.verts, gv) < 2e-4
    assert _relerr(g.colors, gc) < 1e-4
    # emulated float32 depth rounding
    fr = rasterize_soft(mesh, cams, r.raster_settings)
    _emulate_float32_depth(fr)
    sh = phong_vertex_colors(fr, mesh, ref["src_colours"], r.lights, cams, r.materials)
    bl = softmax_rgb_blend_soft(sh.colors, fr, r.blend_params, cams.znear, cams.zfar)
    res = bl.images[..., :3] - ref["target_rgb"]
    gi[..., :3] = 2.0 * res
    g_col, g_d, g_z = bl.vjp(gi)
    gv2, gc2, gb = sh.vjp(g_col)
    gv2 = gv2 + fr.vjp(grad_dists=g_d, grad_zbuf=g_z, grad_bary=gb)
    assert _relerr(gv2, gv) < 1e-4
    assert _relerr(gc2, gc) < 1e-4


# ------------------------------------------------------------------------------------------
# Naive reference loop (PyTorch3D's RasterizeMeshesNaiveCpu, float64)
# ------------------------------------------------------------------------------------------


def _seg(q, a, c):
    """PyTorch3D's PointLineDistanceForward (squared; degenerate edge: distance to c)."""
    d = c - a
    l2 = d @ d
    if l2 <= 1e-8:
        return float((q - c) @ (q - c))
    t = min(max(d @ (q - a) / l2, 0.0), 1.0)
    e = q - a - t * d
    return float(e @ e)


def _naive_rasterize(xy, z, faces, H, W, blur, K, persp, clip, zclip):
    """Per pixel, per face loop following rasterize_meshes_cpu.cpp (no vectorisation)."""
    Sm = min(H, W)
    out = {}
    for j in range(H):  # pixels (reference loop)
        for i in range(W):
            qx, qy = (W - 1 - 2 * i) / Sm, (H - 1 - 2 * j) / Sm
            q = []
            for f in range(len(faces)):  # faces (reference loop)
                (x0, y0), (x1, y1), (x2, y2) = xy[faces[f]]
                z0, z1, z2 = z[faces[f]]
                area = (x2 - x0) * (y1 - y0) - (y2 - y0) * (x1 - x0)
                if abs(area) <= 1e-8 or min(z0, z1, z2) < max(zclip, 1e-8):
                    continue
                r = math.sqrt(blur)
                if (qx > max(x0, x1, x2) + r or qx < min(x0, x1, x2) - r
                        or qy > max(y0, y1, y2) + r or qy < min(y0, y1, y2) - r):
                    continue
                A = area + 1e-8
                b = [((qx - x1) * (y2 - y1) - (qy - y1) * (x2 - x1)) / A,
                     ((qx - x2) * (y0 - y2) - (qy - y2) * (x0 - x2)) / A,
                     ((qx - x0) * (y1 - y0) - (qy - y0) * (x1 - x0)) / A]
                if persp:
                    t = [b[0] * z1 * z2, b[1] * z0 * z2, b[2] * z0 * z1]
                    den = max(sum(t), 1e-8)
                    b = [v / den for v in t]
                bc = b
                if clip:
                    w = [max(v, 0.0) for v in b]
                    s = max(sum(w), 1e-5)
                    bc = [v / s for v in w]
                pz = bc[0] * z0 + bc[1] * z1 + bc[2] * z2
                if pz < 0:
                    continue
                P = xy[faces[f]]
                qq = np.array([qx, qy])
                dist = min(_seg(qq, P[0], P[1]), _seg(qq, P[0], P[2]), _seg(qq, P[1], P[2]))
                inside = all(v > 0 for v in b)
                if not inside and dist >= blur:
                    continue
                q.append((pz, f, -dist if inside else dist, tuple(bc)))
            q.sort()
            out[(j, i)] = q[:K]
    return out


def _with_sliver(mesh: Mesh) -> Mesh:
    """``mesh`` plus a sliver face in front of it whose shortest edge (5e-5) projects to a
    degenerate segment (squared NDC length <= 1e-8) while its area does not vanish."""
    V = np.vstack([mesh.verts, [[0.0, 0.0, 1.2], [5e-5, 0.0, 1.2], [0.0, 0.5, 1.2]]])
    n = len(mesh.verts)
    return Mesh(V, np.vstack([mesh.faces, [[n, n + 1, n + 2]]]))


@pytest.mark.parametrize("persp,clip,K,sliver", [
    (True, True, 3, False), (False, True, 50, False), (True, False, 2, False),
    (False, False, 4, False), (True, True, 3, True), (False, False, 50, True)])
def test_rasterizer_matches_naive_loop(persp, clip, K, sliver):
    """Every kept (pixel, face), its rank, signed distance, depth and barycentrics equal the
    loop reference's (float64, both), including the top-K cut and (``sliver``) a face with a
    degenerate projected edge (the distance to its end point)."""
    mesh = _noisy_mesh(1, seed=5)
    if sliver:
        mesh = _with_sliver(mesh)
    R, T = look_at_view_transform(2.2, [15.0, -30.0], [30.0, 200.0])
    cams = FoVPerspectiveCameras(R=R, T=T)
    H, W = 10, 12
    blur = 4e-3
    st = SoftRasterizationSettings(image_size=(H, W), blur_radius=blur, faces_per_pixel=K,
                                   perspective_correct=persp, clip_barycentric_coords=clip)
    fr = rasterize_soft(mesh, cams, st)
    p2f, zb, dd, bb = fr.pix_to_face, fr.zbuf, fr.dists, fr.bary_coords
    xy = cams.transform_points(mesh.verts)[..., :2]
    zv = cams.transform_points_view(mesh.verts)[..., 2]
    zclip = 0.5 if persp else 0.0
    n_entries = 0
    for n in range(len(cams)):  # views
        ref = _naive_rasterize(xy[n], zv[n], mesh.faces, H, W, blur, K, persp, clip, zclip)
        for (j, i), q in ref.items():
            n_entries += len(q)
            assert [f for _, f, _, _ in q] == list(p2f[n, j, i, :len(q)])
            assert np.all(p2f[n, j, i, len(q):] == -1)
            if q:
                np.testing.assert_allclose(zb[n, j, i, :len(q)], [e[0] for e in q], atol=1e-12)
                np.testing.assert_allclose(dd[n, j, i, :len(q)], [e[2] for e in q], atol=1e-12)
                np.testing.assert_allclose(bb[n, j, i, :len(q)], [e[3] for e in q], atol=1e-10)
    assert n_entries == len(fr) > 50
    if K <= 3:
        assert fr.stats["truncated_pixels"] > 0
    if sliver:  # the sliver's short edge is degenerate in every view, and the face is kept
        d = xy[:, -2] - xy[:, -3]
        assert np.all(np.sum(d * d, axis=1) <= 1e-8)
        assert np.any(fr.face == mesh.n_faces - 1)


def test_chunking_and_threads_do_not_change_the_result():
    """A tiny max_pairs (many chunks) and one or two threads give identical fragments."""
    mesh = _noisy_mesh(2)
    R, T = look_at_view_transform(2.7, [0.0, 40.0, 80.0], [0.0, 90.0, 200.0])
    cams = FoVPerspectiveCameras(R=R, T=T)
    base = rasterize_soft(mesh, cams, SoftRasterizationSettings.tutorial(32, n_threads=1))
    small = rasterize_soft(mesh, cams, SoftRasterizationSettings.tutorial(
        32, max_pairs=500, n_threads=2))
    assert small.stats["peak_pairs"] <= 500 < base.stats["peak_pairs"]
    np.testing.assert_array_equal(small.pix_to_face, base.pix_to_face)
    np.testing.assert_array_equal(small.dists, base.dists)
    assert base.stats["candidates"] >= base.stats["entries"] == len(base)
    assert base.stats["peak_bytes_estimate"] > 0



def test_blend_threads_do_not_change_the_result():
    """The sigmoid terms computed in blocks on two threads equal one thread's, bit for bit."""
    mesh = ico_sphere(4)
    R, T = look_at_view_transform(2.7, [0.0, 40.0, 80.0, 10.0], [0.0, 90.0, 200.0, 300.0])
    cams = FoVPerspectiveCameras(R=R, T=T)
    out = []
    for n in (1, 2):  # threads
        fr = rasterize_soft(mesh, cams, SoftRasterizationSettings.tutorial(
            96, n_threads=n, dtype=np.float64))
        S = sigmoid_alpha_blend(fr, 1e-4)
        out.append((S, sigmoid_alpha_blend_vjp(fr, S, 1e-4, S)))
    assert len(fr) > 2 * 65536  # enough entries for two blocks
    np.testing.assert_array_equal(out[1][0], out[0][0])
    np.testing.assert_array_equal(out[1][1], out[0][1])

# ------------------------------------------------------------------------------------------
# Finite differences
# ------------------------------------------------------------------------------------------

SIGMA_FD = 1e-3
BLUR_FD = math.log(1 / 1e-4 - 1) * SIGMA_FD


def _smooth_pixels(fr: SoftFragments, mesh: Mesh, shading=None, margin=1e-6) -> np.ndarray:
    """(N, H, W) True where no entry is near a switching point (see the module docstring)."""
    ctx = fr._ctx
    H, W = fr.image_size
    ok = np.abs(fr.dist - ctx["blur_radius"]) > 1e-4 * ctx["blur_radius"]
    ok &= np.abs(fr.dist) > 1e-9
    tri = ctx["faces"][fr.face]
    P = np.stack([ctx["x"][fr.view[:, None], tri], ctx["y"][fr.view[:, None], tri]], -1)
    q = np.stack([ctx["px"][fr.pixel % W], ctx["py"][fr.pixel // W]], 1)
    ds = []
    for a, b in ((0, 1), (0, 2), (1, 2)):  # the three edges
        A, d = P[:, a], P[:, b] - P[:, a]
        t = np.clip(np.einsum("ij,ij->i", q - A, d) / np.einsum("ij,ij->i", d, d), 0, 1)
        e = q - A - t[:, None] * d
        ds.append(np.einsum("ij,ij->i", e, e))
    ds = np.sort(np.stack(ds, 1), 1)
    ok &= ds[:, 1] - ds[:, 0] > margin
    if shading is not None:
        ok[shading.entries] &= np.abs(shading.cos) > 1e-4
    bad = np.zeros(fr.n_views * H * W, bool)
    np.logical_or.at(bad, fr.global_pixel, ~ok)
    return ~bad.reshape(fr.n_views, H, W)


def _fd_check(render, mesh, colors, h=1e-6, n_dirs=3, seed=0, tol=1e-5):
    rng = np.random.default_rng(seed)
    out = render(mesh, colors)
    good = _smooth_pixels(out.fragments, mesh, out._saved.get("shading"))
    assert good.mean() > 0.5
    G = rng.normal(size=out.images.shape) * good[..., None]
    grads = out.vjp(G)

    def L(m, c):
        return float(np.sum(render(m, c).images * G))

    V = mesh.verts
    for _ in range(n_dirs):  # random directions
        u = rng.normal(size=V.shape)
        fd = (L(mesh.update_verts(V + h * u), colors)
              - L(mesh.update_verts(V - h * u), colors)) / (2 * h)
        an = float(np.sum(grads.verts * u))
        assert abs(fd - an) <= tol * max(abs(an), 1e-3), (fd, an)
    if colors is not None:
        u = rng.normal(size=colors.shape)
        fd = (L(mesh, colors + h * u) - L(mesh, colors - h * u)) / (2 * h)
        an = float(np.sum(grads.colors * u))
        assert abs(fd - an) <= tol * abs(an)
    return grads


@pytest.fixture(scope="module")
def fd_scene():
    mesh = _noisy_mesh(1)
    R, T = look_at_view_transform(2.7, [10.0, 40.0], [20.0, 130.0])
    return mesh, FoVPerspectiveCameras(R=R, T=T)


@pytest.mark.parametrize("persp,clip", [(True, True), (False, False)])
def test_silhouette_vjp_matches_finite_differences(fd_scene, persp, clip):
    """<G, S(V)> differentiated by central differences along random vertex directions."""
    mesh, cams = fd_scene
    st = SoftRasterizationSettings(image_size=20, blur_radius=BLUR_FD, faces_per_pixel=50,
                                   perspective_correct=persp, clip_barycentric_coords=clip,
                                   dtype=np.float64)
    r = SoftSilhouetteRenderer(cams, st, BlendParams(sigma=SIGMA_FD))
    g = _fd_check(lambda m, c: r(m), mesh, None)
    assert g.colors is None


@pytest.mark.parametrize("persp,clip", [(True, True), (False, True), (True, False),
                                        (False, False)])
def test_phong_vjp_matches_finite_differences(fd_scene, persp, clip):
    """Positions (through distances, barycentrics, depths and shading normals) and colours."""
    mesh, cams = fd_scene
    st = SoftRasterizationSettings(image_size=20, blur_radius=BLUR_FD, faces_per_pixel=50,
                                   perspective_correct=persp, clip_barycentric_coords=clip,
                                   dtype=np.float64)
    r = SoftPhongRenderer(cams, PointLights(location=[[0.5, 1.0, -3.0]]),
                          Materials(shininess=10.0), st, BlendParams(sigma=SIGMA_FD, gamma=1e-2))
    colors = np.random.default_rng(1).uniform(0.2, 0.8, (mesh.n_verts, 3))
    _fd_check(r, mesh, colors)


@pytest.mark.parametrize("lights", [DirectionalLights(direction=[[0.3, 1.0, 0.5]]),
                                    AmbientLights(ambient_color=[[0.4, 0.6, 0.8]])])
def test_phong_vjp_other_lights(fd_scene, lights):
    """Directional light (no point-light position term) and ambient light."""
    mesh, cams = fd_scene
    st = SoftRasterizationSettings(image_size=16, blur_radius=BLUR_FD, faces_per_pixel=50,
                                   dtype=np.float64)
    r = SoftPhongRenderer(cams, lights, Materials(shininess=5.0), st,
                          BlendParams(sigma=SIGMA_FD, gamma=1e-2))
    colors = np.random.default_rng(2).uniform(0.2, 0.8, (mesh.n_verts, 3))
    _fd_check(r, mesh, colors)


def test_vertex_normal_gradient_closed_form():
    """Ambient-free white Lambert shading of a flat square facing a directional light: moving
    the whole square changes nothing (shading depends on orientation only) -> zero net force."""
    V = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]]) * 0.5
    mesh = Mesh(V, [[0, 1, 2], [0, 2, 3]])
    R, T = look_at_view_transform(2.0, 0.0, 0.0)
    cams = FoVOrthographicCameras(R=R, T=T)
    r = SoftPhongRenderer(cams, DirectionalLights(ambient_color=[[0, 0, 0]],
                                                  specular_color=[[0, 0, 0]],
                                                  direction=[[0, 0, 1.0]]),
                          raster_settings=SoftRasterizationSettings(image_size=8,
                                                                    dtype=np.float64))
    out = r(mesh, np.ones((4, 3)))
    covered = out.images[..., 3] > 0.5
    assert covered.any()
    # facing the light: diffuse = 0.3 everywhere the square covers (its normal is +z)
    np.testing.assert_allclose(out.images[..., :3][covered], 0.3, atol=1e-12)
    G = np.zeros(out.images.shape)
    G[..., :3] = covered[..., None]
    g = out.vjp(G)
    # at the optimum orientation (n . l = 1) the normal gradient vanishes: only the colours move
    np.testing.assert_allclose(g.verts[:, 2], 0.0, atol=1e-9)
    # barycentrics sum to area / (area + 1e-8) (PyTorch3D's epsilon; twice the NDC area is 1)
    np.testing.assert_allclose(g.colors.sum(0), 0.3 * covered.sum() * (1 - 1e-8), rtol=1e-9)


# ------------------------------------------------------------------------------------------
# Closed forms and invariants
# ------------------------------------------------------------------------------------------


def test_distance_and_gradient_of_a_single_triangle_closed_form():
    """An orthographic camera, one big triangle: a pixel beyond an edge has dist = s^2 (s its
    distance to the edge line) and moving the triangle by delta along the edge's outward
    normal changes it by -2 s delta."""
    R, T = look_at_view_transform(2.0, 0.0, 0.0)
    cams = FoVOrthographicCameras(R=R, T=T)
    # camera at +z looking at -z: view x = -world x; NDC x = view x
    V = np.array([[0.6, -0.5, 0.0], [-0.6, -0.5, 0.0], [0.0, 0.7, 0.0]])
    mesh = Mesh(V, [[0, 1, 2]])
    st = SoftRasterizationSettings(image_size=16, blur_radius=0.05, faces_per_pixel=1)
    fr = rasterize_soft(mesh, cams, st)
    ndc_y = cams.transform_points(V)[0, :, 1]
    assert np.allclose(ndc_y, V[:, 1])
    # pixels below the bottom edge (y = -0.5), horizontally inside it
    W = fr.image_size[1]
    px, py = fr._ctx["px"][fr.pixel % W], fr._ctx["py"][fr.pixel // W]
    sel = (py < -0.5) & (np.abs(px) < 0.3)
    assert sel.sum() >= 4
    s = -0.5 - py[sel]
    np.testing.assert_allclose(fr.dist[sel], s ** 2, rtol=1e-12)
    gd = np.zeros(len(fr))
    gd[sel] = 1.0
    g = fr.vjp(grad_dists=gd)
    # translating every vertex by delta along -y (the edge's outward normal) turns s into
    # s - delta: dL/d delta = -2 sum s = -sum_v dL/dy_v
    np.testing.assert_allclose(g[:, 1].sum(), 2.0 * s.sum(), rtol=1e-12)
    np.testing.assert_allclose(g[:, 0].sum(), 0.0, atol=1e-12)


def test_silhouette_blend_formula_and_vjp():
    """S = 1 - prod(1 - sigmoid(-d/sigma)) per pixel and dS/dd_k = -(p_k/sigma)(1 - S)."""
    mesh = _noisy_mesh(2)
    R, T = look_at_view_transform(2.7, 20.0, 30.0)
    cams = FoVPerspectiveCameras(R=R, T=T)
    fr = rasterize_soft(mesh, cams, SoftRasterizationSettings.tutorial(24, dtype=np.float64))
    S = sigmoid_alpha_blend(fr, 1e-4)
    p = 1.0 / (1.0 + np.exp(np.clip(fr.dist / 1e-4, -700, 700)))
    prod = np.ones(24 * 24)
    np.multiply.at(prod, fr.pixel, 1.0 - p)
    np.testing.assert_allclose(S.ravel(), 1.0 - prod, atol=1e-14)
    g = np.random.default_rng(0).normal(size=S.shape)
    gd = sigmoid_alpha_blend_vjp(fr, g, 1e-4)
    h = 1e-9
    k = np.argsort(np.abs(fr.dist))[len(fr) // 2]
    vals = []
    for sgn in (1, -1):  # perturb one entry's distance
        d2 = fr.dist.copy()
        d2[k] += sgn * h
        vals.append(np.sum(sigmoid_alpha_blend(dataclasses.replace(fr, dist=d2), 1e-4) * g))
    assert (vals[0] - vals[1]) / (2 * h) == pytest.approx(gd[k], rel=1e-5)
    shader = SoftSilhouetteShader()
    img = shader(fr)
    np.testing.assert_array_equal(img[..., 3], S)


def test_color_operator_reproduces_the_render():
    """For fixed geometry the Phong image is A c + b exactly (the colour Jacobian is A)."""
    mesh = _noisy_mesh(2)
    R, T = look_at_view_transform(2.7, [0.0, 50.0], [10.0, 100.0])
    cams = FoVPerspectiveCameras(R=R, T=T)
    r = SoftPhongRenderer(cams, PointLights(location=[[0.0, 2.0, 3.0]]),
                          raster_settings=SoftRasterizationSettings.tutorial(24, dtype=np.float64))
    c = np.random.default_rng(0).uniform(0, 1, (mesh.n_verts, 3))
    out = r(mesh, c)
    A, b = out.color_operator()
    for ch in range(3):  # channels
        np.testing.assert_allclose(A[ch] @ c[:, ch] + b[..., ch].ravel(),
                                   out.images[..., ch].ravel(), atol=1e-12)
    G = np.random.default_rng(1).normal(size=out.images.shape)
    G[..., 3] = 0.0
    gc = out.vjp(G).colors
    for ch in range(3):  # channels: vjp = A^T G
        np.testing.assert_allclose(gc[:, ch], A[ch].T @ G[..., ch].ravel(), atol=1e-10)
    sil = SoftSilhouetteRenderer(cams, SoftRasterizationSettings.tutorial(8))(mesh)
    with pytest.raises(ValueError, match="color_operator"):
        sil.color_operator()


def test_hard_soft_render_equals_ray_cast_render():
    """Blur 0 and K = 1 is PyTorch3D's hard rasterization: the same RGB as the Embree
    renderer's SoftPhongShader on pixels where both see the same face."""
    mesh = ico_sphere(3)
    cols = np.random.default_rng(0).uniform(0.1, 0.9, (mesh.n_verts, 3))
    R, T = look_at_view_transform(2.7, [0.0, 30.0], [0.0, 120.0])
    cams = FoVPerspectiveCameras(R=R, T=T)
    lights = PointLights(location=[[1.0, 1.0, 3.0]])
    soft = SoftPhongRenderer(cams, lights, raster_settings=SoftRasterizationSettings(
        image_size=32, blur_radius=0.0, faces_per_pixel=1))(mesh, cols)
    ras = MeshRasterizer(cams, RasterizationSettings(image_size=32))
    tm = Mesh(mesh.verts, mesh.faces, TexturesVertex(cols))
    hard = MeshRenderer(ras, SoftPhongShader(cameras=cams, lights=lights))(tm)
    frag = ras(tm)
    same = soft.fragments.pix_to_face[..., 0] == frag.face_id_image(local=True)
    assert same.mean() > 0.99
    np.testing.assert_allclose(soft.images[..., :3][same], hard[..., :3][same], atol=2e-5)


def test_no_nan_for_degenerate_geometry():
    """Collapsed faces, a vertex on the camera plane, a face behind the camera: finite images
    and gradients."""
    m = ico_sphere(2)
    V = m.verts.copy()
    V[:5] = V[0]                    # collapsed faces
    R, T = look_at_view_transform(2.7, 0.0, 0.0)
    cams = FoVPerspectiveCameras(R=R, T=T)
    C = cams.get_camera_center()[0]
    V[10] = C                       # on the camera plane
    V[11] = C + np.array([0.0, 0.0, 1.0])  # behind the camera
    mesh = Mesh(V, m.faces)
    r = SoftPhongRenderer(cams, raster_settings=SoftRasterizationSettings.tutorial(24))
    out = r(mesh, np.full((m.n_verts, 3), 0.5))
    assert np.all(np.isfinite(out.images))
    g = out.vjp(np.ones(out.images.shape))
    assert np.all(np.isfinite(g.verts)) and np.all(np.isfinite(g.colors))
    s = SoftSilhouetteRenderer(cams, SoftRasterizationSettings.tutorial(24))(mesh)
    assert np.all(np.isfinite(s.vjp(s.silhouettes).verts))


def test_empty_views_and_empty_mesh():
    """A view that sees nothing gives zero silhouettes, background RGB and zero gradients."""
    m = ico_sphere(1)
    R, T = look_at_view_transform(2.7, 0.0, [0.0, 180.0])
    T = T.copy()
    T[1, 0] = 50.0                  # second camera looks far to the side
    cams = FoVPerspectiveCameras(R=R, T=T)
    out = SoftPhongRenderer(cams, raster_settings=SoftRasterizationSettings.tutorial(16))(
        m, np.full((m.n_verts, 3), 0.5))
    assert out.images[1, ..., 3].max() == 0.0
    np.testing.assert_array_equal(out.images[1, ..., :3], 1.0)
    empty = Mesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64))
    s = SoftSilhouetteRenderer(cams, SoftRasterizationSettings.tutorial(8))(empty)
    assert len(s.fragments) == 0 and s.silhouettes.max() == 0.0
    assert s.vjp(np.ones((2, 8, 8))).verts.shape == (0, 3)


# ------------------------------------------------------------------------------------------
# Contour loss
# ------------------------------------------------------------------------------------------


def test_contour_edges_of_a_sphere_form_its_outline():
    """Seen from +z, the contour of an ico-sphere is a closed loop near the projected circle,
    with outward normals pointing away from the centre."""
    m = ico_sphere(3)
    R, T = look_at_view_transform(2.7, 0.0, 0.0)
    cams = FoVPerspectiveCameras(R=R, T=T)
    xy = cams.transform_points(m.verts)[0, :, :2]
    e, n = contour_edges(m, xy)
    deg = np.bincount(e.ravel(), minlength=m.n_verts)
    assert set(np.unique(deg[deg > 0])) == {2}          # every contour vertex on two edges
    mid = 0.5 * (xy[e[:, 0]] + xy[e[:, 1]])
    rho = math.tan(math.asin(1 / 2.7)) / math.tan(math.radians(30))  # projected radius
    np.testing.assert_allclose(np.linalg.norm(mid, axis=1), rho, rtol=0.02)
    assert np.all(np.einsum("ij,ij->i", n, mid) > 0)


def test_contour_gradient_closed_form_for_a_growing_sphere():
    """Target = everything (T = 1): the continuous loss falls at the rate -(perimeter in px) x
    (outward speed) / (H W); scaling the sphere by (1 + eps) moves its outline outward."""
    m = ico_sphere(4)
    R, T = look_at_view_transform(2.7, 0.0, 0.0)
    cams = FoVPerspectiveCameras(R=R, T=T)
    H = W = 64
    loss = ContourSilhouetteLoss(cams, np.ones((1, H, W)))
    value, g = loss(m)
    assert 0.0 < value < 1.0
    dL = float(np.sum(g * m.verts))  # d/d eps of L(verts (1 + eps))
    f = 1.0 / math.tan(math.radians(30))
    r, dist = 1.0, 2.7
    rho = f * r / math.sqrt(dist ** 2 - r ** 2)            # NDC radius of the outline
    drho = f * dist ** 2 / (dist ** 2 - r ** 2) ** 1.5     # d rho / d r
    expected = -(2 * math.pi * rho) * drho * (H / 2) ** 2 / (H * W)
    assert dL == pytest.approx(expected, rel=0.02)


def test_contour_ignores_interior_contours():
    """A small sphere in front of a big one, its outline inside the big one's: only the big
    outline is outer (moving the small one's outline does not change the silhouette)."""
    a, b = ico_sphere(4), ico_sphere(3)
    V = np.concatenate([a.verts * 0.8, b.verts * 0.2 + [0.0, 0.0, 1.2]])
    F = np.concatenate([a.faces, b.faces + a.n_verts])
    mesh = Mesh(V, F)
    R, T = look_at_view_transform(2.7, 0.0, 0.0)
    loss = ContourSilhouetteLoss(FoVPerspectiveCameras(R=R, T=T), np.zeros((1, 96, 96)))
    s = loss.samples(mesh, 0)
    f = 1.0 / math.tan(math.radians(30))
    rho_a = f * 0.8 / math.sqrt(2.7 ** 2 - 0.8 ** 2)
    rho_b = f * 0.2 / math.sqrt(1.5 ** 2 - 0.2 ** 2)
    assert s.weights.sum() == pytest.approx(2 * math.pi * (rho_a + rho_b), rel=0.02)
    assert s.weights[s.outer].sum() == pytest.approx(2 * math.pi * rho_a, rel=0.02)
    r = np.linalg.norm(s.points, axis=1)
    assert np.all(r[s.outer] > 0.9 * rho_a)
    np.testing.assert_array_equal(s.target, 0.0)


# ------------------------------------------------------------------------------------------
# Validation
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("kwargs,match", [
    ({"image_size": 0}, "image_size"),
    ({"image_size": "big"}, "image_size"),
    ({"image_size": (4.5, 4)}, "image_size"),
    ({"blur_radius": -1.0}, "blur_radius"),
    ({"faces_per_pixel": 0}, "faces_per_pixel"),
    ({"faces_per_pixel": True}, "faces_per_pixel"),
    ({"perspective_correct": 1}, "perspective_correct"),
    ({"clip_barycentric_coords": "yes"}, "clip_barycentric_coords"),
    ({"cull_backfaces": None}, "cull_backfaces"),
    ({"z_clip_value": -0.1}, "z_clip_value"),
    ({"max_pairs": 0}, "max_pairs"),
    ({"n_threads": 0}, "n_threads"),
])
def test_settings_validation(kwargs, match):
    with pytest.raises(ValueError, match=match):
        SoftRasterizationSettings(**kwargs)


def test_call_validation():
    m = ico_sphere(1)
    R, T = look_at_view_transform(2.7, 0.0, 0.0)
    cams = FoVPerspectiveCameras(R=R, T=T)
    st = SoftRasterizationSettings.tutorial(8)
    with pytest.raises(TypeError, match="mesh"):
        rasterize_soft(m.verts, cams, st)
    with pytest.raises(TypeError, match="cameras"):
        rasterize_soft(m, "camera", st)
    with pytest.raises(TypeError, match="raster_settings"):
        rasterize_soft(m, cams, RasterizationSettings(image_size=8))
    fr = rasterize_soft(m, cams, st)
    with pytest.raises(TypeError, match="fragments"):
        sigmoid_alpha_blend("fragments")
    with pytest.raises(ValueError, match="sigma"):
        sigmoid_alpha_blend(fr, 0.0)
    with pytest.raises(ValueError, match="grad_alpha"):
        sigmoid_alpha_blend_vjp(fr, np.ones((1, 4, 4)))
    with pytest.raises(ValueError, match="grad_dists"):
        fr.vjp(grad_dists=np.ones(len(fr) + 1))
    with pytest.raises(ValueError, match="grad_bary"):
        fr.vjp(grad_bary=np.ones((len(fr), 2)))
    with pytest.raises(TypeError, match="blend_params"):
        SoftSilhouetteShader(blend_params=(1e-4, 1e-4))
    with pytest.raises(ValueError, match="blend_params.sigma"):
        SoftSilhouetteRenderer(cams, st, BlendParams(sigma=-1.0))
    with pytest.raises(ValueError, match="vertex_colors"):
        phong_vertex_colors(fr, m, np.ones((3, 3)), PointLights(), cams, Materials())
    with pytest.raises(ValueError, match="fragments"):
        phong_vertex_colors(fr, ico_sphere(2), np.ones((162, 3)), PointLights(), cams,
                            Materials())
    cams2 = FoVPerspectiveCameras(R=np.stack([R[0]] * 3), T=np.stack([T[0]] * 3))
    with pytest.raises(ValueError, match="cameras"):
        phong_vertex_colors(rasterize_soft(m, cams2, st), m, np.ones((42, 3)), PointLights(),
                            FoVPerspectiveCameras(R=np.stack([R[0]] * 2),
                                                  T=np.stack([T[0]] * 2)), Materials())
    with pytest.raises(ValueError, match="lights.ambient_color"):
        phong_vertex_colors(rasterize_soft(m, cams2, st), m, np.ones((42, 3)),
                            PointLights(location=np.zeros((2, 3))), cams2, Materials())
    with pytest.raises(TypeError, match="lights"):
        phong_vertex_colors(fr, m, np.ones((42, 3)), object(), cams, Materials())
    with pytest.raises(ValueError, match="colors"):
        softmax_rgb_blend_soft(np.ones((len(fr), 2)), fr)
    r = SoftPhongRenderer(cams, raster_settings=st)
    out = r(m, np.ones((42, 3)))
    with pytest.raises(ValueError, match="grad_images"):
        out.vjp(np.ones((1, 8, 8, 3)))
    with pytest.raises(TypeError, match="cameras"):
        ContourSilhouetteLoss(None, np.ones((1, 8, 8)))
    with pytest.raises(ValueError, match="target_silhouettes"):
        ContourSilhouetteLoss(cams, np.ones((2, 8, 8)))
    with pytest.raises(ValueError, match="target_silhouettes"):
        ContourSilhouetteLoss(cams, np.ones((1, 1, 8)))
    with pytest.raises(ValueError, match="samples_per_pixel"):
        ContourSilhouetteLoss(cams, np.ones((1, 8, 8)), samples_per_pixel=0)
    with pytest.raises(TypeError, match="mesh"):
        ContourSilhouetteLoss(cams, np.ones((1, 8, 8)))(m.verts)
    with pytest.raises(ValueError, match="threshold"):
        ContourSilhouetteLoss(cams, np.ones((1, 8, 8)), threshold=-0.5)
    soft = np.linspace(0, 1, 64).reshape(1, 8, 8)
    np.testing.assert_array_equal(
        ContourSilhouetteLoss(cams, soft, threshold=0.9).targets, (soft >= 0.9) * 1.0)


def test_tutorial_blur_radius_value():
    """log(1/1e-4 - 1) * 1e-4: sigmoid(-blur / sigma) = 1e-4."""
    assert TUTORIAL_BLUR_RADIUS == pytest.approx(9.21024036697585e-4, rel=1e-12)
    assert 1.0 / (1.0 + math.exp(TUTORIAL_BLUR_RADIUS / 1e-4)) == pytest.approx(1e-4, rel=1e-9)


def test_docstring_examples_run():
    """The Examples sections of the soft renderer's modules run as doctests."""
    import doctest
    import importlib

    names = ["rasterizer", "renderer", "contour"]
    for name in names:
        mod = importlib.import_module(f"geofit.render.soft.{name}")
        result = doctest.testmod(mod, optionflags=doctest.NORMALIZE_WHITESPACE)
        assert result.attempted > 0 and result.failed == 0, mod.__name__


def test_soft_phong_shader_on_soft_fragments_is_the_differentiable_blend():
    """geofit.render.SoftPhongShader means PyTorch3D's: on the soft rasterizer's fragments it is
    the K-face softmax blend, the same images as SoftPhongRenderer; on hard fragments it stays
    the K = 1 render; its inputs are checked."""
    Shader = SoftPhongShader
    mesh = _noisy_mesh(1)
    colors = np.random.default_rng(3).uniform(0.2, 0.9, (mesh.n_verts, 3))
    tm = Mesh(mesh.verts, mesh.faces, textures=TexturesVertex(colors))
    R, T = look_at_view_transform(2.7, [0.0, 30.0], [0.0, 60.0])
    cams = FoVPerspectiveCameras(R=R, T=T)
    lights = PointLights(location=[[0.0, 1.0, -3.0]])
    st = SoftRasterizationSettings.tutorial(24)
    fr = rasterize_soft(tm, cams, st)
    images = Shader(cameras=cams, lights=lights)(fr, tm)
    ref = SoftPhongRenderer(cams, lights, raster_settings=st)(tm, colors).images
    np.testing.assert_allclose(images, ref, rtol=0, atol=1e-12)
    assert images.shape == (2, 24, 24, 4) and np.any(images[..., 3] < 1.0)
    with pytest.raises(ValueError, match="cameras"):
        Shader(lights=lights)(fr, tm)
    with pytest.raises(TypeError, match="meshes"):
        Shader(cameras=cams)(fr, mesh.verts)
    with pytest.raises(ValueError, match="shadows"):
        Shader(cameras=cams, shadows=True)(fr, tm)


# ------------------------------------------------------------------------------------------
# Storage type and memory
# ------------------------------------------------------------------------------------------


def _traced_phong_pass(dtype, image_size=64, num_views=20):
    """(fragments entries, output, peak traced bytes of forward + vjp) of a tutorial-like pass."""
    import tracemalloc

    mesh = ico_sphere(4)
    R, T = look_at_view_transform(2.7, np.zeros(num_views), np.linspace(-180, 180, num_views))
    ren = SoftPhongRenderer(FoVPerspectiveCameras(R=R, T=T),
                            lights=PointLights(location=[[0.0, 0.0, -3.0]]),
                            raster_settings=SoftRasterizationSettings.tutorial(image_size,
                                                                               dtype=dtype))
    tracemalloc.start()
    try:
        out = ren(mesh, np.full((mesh.n_verts, 3), 0.5))
        g = out.vjp(np.ones(out.images.shape))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    return len(out.fragments), out, g, peak


def test_float32_storage_is_the_default_and_bounds_the_memory():
    """Images and per-entry arrays are float32 by default (as PyTorch3D), the gradients float64;
    a 20-view Phong pass (forward + vjp) at 64 px peaks below 230 bytes per fragment entry (the
    benchmark's 128 px pass: 3.0 million entries, 492 MB; float64 storage: 791 MB) and below
    70 % of the float64 pass, whose images it matches to float32 precision."""
    assert SoftRasterizationSettings().dtype is np.float32
    m, out, g, peak = _traced_phong_pass(np.float32)
    fr = out.fragments
    assert out.images.dtype == np.float32
    assert fr.dist.dtype == fr.bary.dtype == fr.depth.dtype == np.float32
    assert fr.zbuf.dtype == np.float64 and g.verts.dtype == g.colors.dtype == np.float64
    assert m > 500_000
    assert peak < 230 * m, f"{peak / m:.0f} bytes per entry"
    m64, out64, g64, peak64 = _traced_phong_pass(np.float64)
    assert m64 == m and out64.images.dtype == np.float64
    assert peak < 0.7 * peak64, (peak, peak64)
    np.testing.assert_allclose(out.images, out64.images, rtol=0, atol=1e-5)
    scale = np.abs(g64.verts).max()
    np.testing.assert_allclose(g.verts, g64.verts, rtol=0, atol=1e-3 * scale)


@pytest.mark.parametrize("dtype", ["float16", np.int32, "x", None])
def test_settings_dtype_validation(dtype):
    with pytest.raises(ValueError, match="dtype: expected numpy.float32 or numpy.float64"):
        SoftRasterizationSettings(dtype=dtype)


def test_ranks_face_ordered_equals_the_three_key_lexsort():
    """With each pixel's entries in increasing face order (as one view of the rasterizer
    emits them), the two stable sorts rank exactly as the lexsort over (pixel, depth, face),
    depth ties included, for 16-bit and wider pixel indices."""
    from geofit.render.soft.fragments import _ranks

    rng = np.random.default_rng(3)
    n = 5000
    for n_pix in (300, 200_000):  # pixel ids that fit 16 bits, and that do not
        gp = rng.integers(0, n_pix, n)
        face = np.arange(n)  # increasing in array order: per pixel too
        depth = np.round(rng.random(n), 2)  # many exact ties
        ref = _ranks(gp, depth, face)
        np.testing.assert_array_equal(_ranks(gp, depth, face, True), ref)
        # the reference itself: rank = number of entries of the pixel before it in
        # (depth, face) order
        i = rng.integers(0, n, 50)
        for k in i:  # a few entries, checked by brute force
            same = gp == gp[k]
            before = (depth[same] < depth[k]) | ((depth[same] == depth[k]) & (face[same] < k))
            assert ref[k] == np.count_nonzero(before)
