"""The UV atlas and the texel least-squares solve (geofit.fit.texture)."""
import numpy as np
import pytest
from _helpers import glb_round_trip

from geofit import FoVPerspectiveCameras, ico_sphere, look_at_view_transform
from geofit.fit.texture import _bilinear, fit_texture, texel_operator, uv_atlas
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
    truth is smooth) and satisfies its normal equations where no texel was clipped."""
    cams, mesh, images = scene
    tex = fit_texture(mesh, cams, images, lights=LIGHTS)
    assert isinstance(tex, TexturesUV) and tex.maps.min() >= 0 and tex.maps.max() <= 1
    img = _render(Mesh(mesh.verts, mesh.faces, tex), cams, 32)
    assert psnr(img, images) > 38.0
    from geofit.fit.texture import _grid_laplacian

    size = tex.maps.shape[:2]
    A, y = texel_operator(HardImageLoss(cams, images, lights=LIGHTS), mesh, tex.faces_uvs,
                          tex.verts_uvs, size)
    L = _grid_laplacian(*size)
    assert np.all(L.sum(axis=1) == 0) and (L != L.T).nnz == 0
    for c in range(3):  # channels: (A^T A + lambda L + eps) t = A^T y where t is unclipped
        t = tex.maps[..., c].ravel()
        d = (A[c].T @ A[c]).diagonal()
        scale = d[d > 0].mean()
        r = A[c].T @ (A[c] @ t - y[:, c]) + 1e-3 * scale * (L @ t) + 1e-9 * scale * t
        free = (t > 0) & (t < 1)
        assert free.mean() > 0.9
        assert np.abs(r[free]).max() < 1e-8 * np.abs(A[c].T @ y[:, c]).max()


def test_fitted_texture_survives_obj_and_glb(scene, tmp_path):
    """save_mesh writes the fitted texture as .obj + .mtl + .png and as .glb. The OBJ reloads
    to the same renders up to the PNG's 8 bits; the GLB (float32 positions, vertices split at
    the seams) to the same per-corner positions and UVs and the same map up to 8 bits (its
    renders differ where float32 moves a pixel across a seam onto the other chart)."""
    cams, mesh, images = scene
    tex = fit_texture(mesh, cams, images, lights=LIGHTS)
    m = Mesh(mesh.verts, mesh.faces, tex)
    save_mesh(tmp_path / "cow.obj", m)
    assert (tmp_path / "cow.mtl").exists() and list(tmp_path.glob("*.png"))
    back = load_mesh(tmp_path / "cow.obj")
    assert isinstance(back.textures, TexturesUV)
    np.testing.assert_allclose(_render(back, cams, 32), _render(m, cams, 32), atol=2.5 / 255)
    back = glb_round_trip(m, tmp_path / "cow.glb")
    np.testing.assert_allclose(back.textures.maps, tex.maps, atol=0.5 / 255 + 1e-9)


def test_fit_texture_validation(scene):
    cams, mesh, images = scene
    with pytest.raises(ValueError, match="texel_px"):
        fit_texture(mesh, cams, images, texel_px=0.0)
    with pytest.raises(ValueError, match="smoothness"):
        fit_texture(mesh, cams, images, smoothness=-1.0)
    with pytest.raises(ValueError, match="target_images"):
        fit_texture(mesh, cams, images[:2])
    with pytest.raises(ValueError, match="texel_size"):
        uv_atlas(mesh, 0.0)
    with pytest.raises(ValueError, match="no view sees the mesh"):
        fit_texture(mesh, cams, images, masks=np.zeros(images.shape[:3]))
