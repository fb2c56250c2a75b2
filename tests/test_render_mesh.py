"""Mesh rendering by ray casting: PyTorch3D parity, analytic cases, shading, batches, bad input."""
import json
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from geofit import Mesh, Meshes, TexturesUV, TexturesVertex, ico_sphere, plane, torus
from geofit.cameras import FoVOrthographicCameras, FoVPerspectiveCameras, look_at_view_transform
from geofit.raycast import RayCaster
from geofit.render import (AmbientLights, BlendParams, DirectionalLights, Fragments,
                           HardFlatShader, HardGouraudShader, HardPhongShader, Materials,
                           MeshRasterizer, MeshRenderer, MeshRendererWithFragments, PointLights,
                           RasterizationSettings, SoftGouraudShader, SoftPhongShader, TexturesFlat,
                           apply_lighting, flat_shading, gouraud_shading, make_grid, phong_shading,
                           sample_textures)
from geofit.render.lighting import diffuse, specular
from geofit.render.mesh.textures import sample_texels

DATA = Path(__file__).parent / "data"
REF = np.load(DATA / "render_mesh.npz")
F_COW = 5856

# The stored variants (tests/data/render_mesh_variants.json): name -> (view, image size, light,
# materials, batch, pix_to_face key, soft)
_TABLE = json.loads((DATA / "render_mesh_variants.json").read_text(encoding="utf-8"))
VARIANTS = {name: (v["view"], v["image_size"] if isinstance(v["image_size"], int)
                   else tuple(v["image_size"]), tuple(v["light"]),
                   v["materials"] and _TABLE["materials"][v["materials"]], v["batch"],
                   v["fragments"], v["soft"])
            for name, v in _TABLE["variants"].items()}


def _cow(textures=None) -> Mesh:
    """The tutorial cow's geometry as PyTorch3D's load_obj read it (no texture)."""
    return Mesh(REF["cow_verts"].astype(np.float64), REF["cow_faces"].astype(np.int64), textures)


def _cameras(view: str) -> FoVPerspectiveCameras:
    return FoVPerspectiveCameras(R=REF[f"{view}_R"].astype(np.float64),
                                 T=REF[f"{view}_T"].astype(np.float64))


def _render_variant(name, mesh):
    view, size, light, mat, batch, _, soft = VARIANTS[name]
    shader = (SoftPhongShader if soft else HardPhongShader)(lights=PointLights(location=[light]))
    renderer = MeshRendererWithFragments(
        MeshRasterizer(_cameras(view), RasterizationSettings(image_size=size, blur_radius=0.0,
                                                             faces_per_pixel=1)), shader)
    kw = {} if mat is None else {"materials": Materials(**mat)}
    return renderer(mesh.extend(batch) if batch > 1 else mesh, **kw)


def _rgba_key(name):
    return name + "_rgba" if name != "nonsquare" else "nonsquare_rgba"


# ------------------------------------------------------------------ PyTorch3D parity

@pytest.mark.parametrize("name", ["soft_128", "view2_128", "batch_128", "nonsquare", "soft_256",
                                  "view2_256", "batch_256"])
def test_fragments_match_pytorch3d(name):
    """Face ids agree on >= 99.5% of pixels (any difference sits on a triangle edge: the
    reference's |dists| there is below a hundredth of a pixel squared); where they agree the
    view depth, barycentrics and edge distances match PyTorch3D's float32 values."""
    _, fr = _render_variant(name, _cow())
    key = VARIANTS[name][5]
    p2f = REF[f"{key}_pix_to_face"].astype(np.int64)
    assert fr.pix_to_face.shape == p2f.shape
    agree = fr.pix_to_face == p2f
    assert agree.mean() >= 0.995
    if VARIANTS[name][4] > 1:  # packed ids: view b sees faces b*F ... b*F + F - 1
        b = np.arange(VARIANTS[name][4])[:, None, None, None]
        hit = fr.pix_to_face >= 0
        assert np.all((fr.pix_to_face // F_COW == b)[hit])
    if f"{key}_zbuf" in REF.files:
        H, W = fr.image_size
        px = (2.0 / min(H, W)) ** 2
        dists = REF[f"{key}_dists"]
        both = ~agree & (p2f >= 0) & (fr.pix_to_face >= 0)
        assert np.all(np.abs(dists[both]) < 0.01 * px)
        a = agree & (p2f >= 0)
        assert_allclose(fr.zbuf[a], REF[f"{key}_zbuf"][a], rtol=1e-5)
        assert_allclose(fr.bary_coords[a], REF[f"{key}_bary_coords"][a], atol=1e-3)
        assert_allclose(fr.dists[a], dists[a], atol=1e-3 * px)
        assert np.all(fr.zbuf[p2f < 0] == -1) or not np.all(agree)


@pytest.mark.parametrize("name", ["soft_128", "light2_128", "view2_128", "batch_128", "nonsquare",
                                  "soft_256", "view2_256", "batch_256"])
def test_soft_alpha_matches_pytorch3d(name):
    """SoftPhong's alpha is sigmoid(-dists / 1e-4) of the kept face: it depends on the geometry
    only, so it matches PyTorch3D's to float32 accuracy even without the texture."""
    img, fr = _render_variant(name, _cow())
    ref = REF[_rgba_key(name)][..., 3]
    key = VARIANTS[name][5]
    agree = (fr.pix_to_face == REF[f"{key}_pix_to_face"])[..., 0]
    assert_allclose(img[..., 3][agree], ref[agree], atol=2e-5)
    assert np.all(img[..., 3][~fr.mask] == 0)


@pytest.mark.parametrize("name", ["soft_128", "hard_128", "light2_128"])
def test_phong_matches_pytorch3d_with_its_texels(name):
    """Given PyTorch3D's own texels at each pixel, the Phong colour equals PyTorch3D's image:
    mean |dRGB| far below 1/255 where face ids agree, background exact."""
    _, fr = _render_variant(name, _cow())
    ref = REF[_rgba_key(name)]
    texels = REF["base_128_texels"][..., 0, :].reshape(-1, 3)[fr.pixel].astype(np.float32)
    light = VARIANTS[name][2]
    colors = phong_shading(fr, PointLights(location=[light]), fr.cameras, Materials(), texels)
    rgb = np.ones((128 * 128, 3), np.float32)
    rgb[fr.pixel] = colors
    rgb = rgb.reshape(1, 128, 128, 3)
    agree = (fr.pix_to_face == REF["base_128_pix_to_face"])[..., 0]
    err = np.abs(rgb - ref[..., :3])[agree]
    assert err.mean() <= 1.0 / 255 / 100
    assert err.max() <= 1e-3


def test_pixel_coords_and_normals_match_pytorch3d():
    """Interpolated world positions and (normalised) interpolated vertex normals per pixel."""
    _, fr = _render_variant("soft_128", _cow())
    p2f = REF["base_128_pix_to_face"]
    agree = ((fr.pix_to_face == p2f) & (p2f >= 0))[..., 0]
    pts = np.zeros((128 * 128, 3))
    pts[fr.pixel] = fr.hit_points
    assert_allclose(pts.reshape(1, 128, 128, 3)[agree],
                    REF["base_128_pixel_coords"][..., 0, :][agree], atol=1e-5)
    ref_n = REF["base_128_pixel_normals"][..., 0, :][agree].astype(np.float64)
    ref_n /= np.linalg.norm(ref_n, axis=-1, keepdims=True)
    assert_allclose(fr.normals[..., 0, :][agree], ref_n, atol=1e-4)
    assert_allclose(_cow().verts_normals, REF["cow_verts_normals"], atol=1e-5)


def _tutorial_cow():
    from geofit.data import find

    path = find("cow_mesh/cow.obj")
    if path is None:
        pytest.skip("the tutorial cow with its texture is not available (set GEOFIT_DATA to a "
                    "folder holding cow_mesh/cow.obj, cow.mtl, cow_texture.png)")
    from geofit.io import load_objs_as_meshes

    return load_objs_as_meshes([path])[0]


@pytest.mark.parametrize("name", list(VARIANTS))
def test_textured_cow_matches_pytorch3d(name):
    """Full RGBA parity on every stored variant (needs the tutorial's texture image): face ids
    agree on >= 99.5% of pixels and RGB differs by far less than 1/255 on average there."""
    img, fr = _render_variant(name, _tutorial_cow())
    ref = REF[_rgba_key(name)]
    agree = (fr.pix_to_face == REF[f"{VARIANTS[name][5]}_pix_to_face"])[..., 0]
    assert agree.mean() >= 0.995
    err = np.abs(img[..., :3] - ref[..., :3])[agree]
    assert err.mean() <= 1.0 / 255 / 50
    assert err.max() <= 2e-3
    assert_allclose(img[..., 3][agree], ref[..., 3][agree], atol=2e-5)


def test_texels_match_pytorch3d_sample_textures():
    """Bilinear UV lookup with PyTorch3D's convention reproduces its texels (needs the cow)."""
    _, fr = _render_variant("soft_128", _tutorial_cow())
    t = np.zeros((128 * 128, 3), np.float32)
    t[fr.pixel] = sample_textures(fr)
    p2f = REF["base_128_pix_to_face"]
    agree = ((fr.pix_to_face == p2f) & (p2f >= 0))[..., 0].ravel()  # (PyTorch3D samples uv=0
    assert agree.sum() > 1000                                           # on empty pixels)
    assert_allclose(t[agree], REF["base_128_texels"][..., 0, :].reshape(-1, 3)[agree], atol=2e-4)


# ------------------------------------------------------------------ analytic geometry

def _look(dist=3.0, elev=0.0, azim=0.0, **kw):
    R, T = look_at_view_transform(dist, elev, azim)
    return FoVPerspectiveCameras(R=R, T=T, **kw)


@pytest.mark.parametrize("ortho", [False, True])
def test_plane_hits_lie_on_pixel_rays(ortho):
    """Hits on a plane: the interpolated point projects back onto its pixel centre and its
    view depth is zbuf (both to float64 rounding), for perspective and orthographic cameras."""
    mesh = plane(size=2.0, n=3, z=0.25)
    R, T = look_at_view_transform(3.0, 20.0, 30.0)
    cams = FoVOrthographicCameras(R=R, T=T) if ortho else FoVPerspectiveCameras(R=R, T=T)
    fr = MeshRasterizer(cams, RasterizationSettings(image_size=(24, 40)))(mesh)
    assert fr.n_hits > 100
    ndc = cams.transform_points(fr.hit_points[None])[0]
    assert_allclose(ndc[:, :2], fr.hit_xy, atol=1e-12)
    z = (fr.hit_points @ cams.R[0] + cams.T[0])[:, 2]
    assert_allclose(fr.depth, z, rtol=1e-12)
    assert np.all(fr.bary >= 0)
    assert_allclose(fr.bary.sum(1), 1.0, atol=1e-12)


def test_sphere_agrees_with_general_raycaster():
    """The pixel-ray fast path and geofit.raycast.RayCaster see the same faces at the same
    depths (pixel rays from the camera's own pixel_rays)."""
    mesh = ico_sphere(3)
    cams = _look(2.5, 15.0, 40.0)
    fr = MeshRasterizer(cams, RasterizationSettings(image_size=48))(mesh)
    rays = cams.pixel_rays((48, 48))
    hits = RayCaster(mesh).cast(rays.origins.reshape(-1, 3), rays.directions.reshape(-1, 3),
                                tnear=0.5)
    assert_array_equal(np.flatnonzero(hits.hit), fr.pixel)
    same = hits.face_id[fr.pixel] == fr.face
    assert same.mean() > 0.99
    assert_allclose(hits.t[fr.pixel], fr.depth, rtol=1e-9)
    assert_allclose(hits.bary[fr.pixel][same], fr.bary[same], atol=1e-8)


def test_sphere_silhouette_area():
    """A unit sphere at distance 2.7 under a 60 degree FoV covers a disc of NDC radius
    tan(asin(1/2.7)) / tan(30 deg); the coverage matches its area to 0.5%."""
    fr = MeshRasterizer(_look(2.7), RasterizationSettings(image_size=256))(ico_sphere(5))
    r = np.tan(np.arcsin(1 / 2.7)) / np.tan(np.radians(30))
    assert_allclose(fr.mask.mean(), np.pi * r ** 2 / 4.0, rtol=0.005)


def test_screen_space_barycentrics_when_not_perspective_correct():
    """perspective_correct=False gives PyTorch3D's screen-space barycentrics: they interpolate
    the projected corners to the pixel centre, and zbuf is their interpolation of the corners'
    depths; perspective_correct=True interpolates the true 3-D point."""
    mesh = torus()
    cams = _look(3.0, 30.0, 10.0)
    pc = MeshRasterizer(cams, RasterizationSettings(image_size=32))(mesh)
    ss = MeshRasterizer(cams, RasterizationSettings(image_size=32, perspective_correct=False))(mesh)
    assert_array_equal(pc.pixel, ss.pixel)
    assert_array_equal(pc.face, ss.face)
    tri = mesh.faces[ss.face]
    proj = cams.transform_points(mesh.verts[None])[0]
    xy = np.einsum("kj,kjc->kc", ss.bary, proj[tri, :2])
    assert_allclose(xy, ss.hit_xy, atol=1e-12)
    z = (mesh.verts @ cams.R[0] + cams.T[0])[:, 2]
    assert_allclose(ss.depth, np.einsum("kj,kj->k", ss.bary, z[tri]), rtol=1e-12)
    assert np.abs(ss.bary - pc.bary).max() > 1e-3  # the two really differ


def test_batch_semantics():
    """extend(N), one mesh with N cameras, and N cameras with N different meshes."""
    sphere, tor = ico_sphere(2), torus(n_major=16, n_minor=8)
    R, T = look_at_view_transform(3.0, [0.0, 30.0, 60.0], [0.0, 90.0, 200.0])
    cams = FoVPerspectiveCameras(R=R, T=T)
    rast = MeshRasterizer(cams, RasterizationSettings(image_size=40))
    a = rast(sphere.extend(3))
    b = rast(sphere)  # one mesh seen by the three cameras
    assert a.n_views == b.n_views == 3
    assert_array_equal(a.pix_to_face, b.pix_to_face)
    F = sphere.n_faces
    view = np.arange(3)[:, None, None, None]
    assert np.all(((a.pix_to_face // F) == view)[a.pix_to_face >= 0])
    for i in range(3):  # each view equals its own single render
        single = rast(sphere, cameras=cams[i])
        assert_array_equal(a.pix_to_face[i] - i * F * (a.pix_to_face[i] >= 0),
                           single.pix_to_face[0])
        assert_allclose(a.zbuf[i], single.zbuf[0], rtol=1e-12)
    mixed = rast(Meshes([sphere, tor, sphere]))
    first = Meshes([sphere, tor, sphere]).mesh_to_faces_packed_first_idx()
    assert_array_equal(mixed.face_id_image(local=False)[1], mixed.pix_to_face[1, ..., 0])
    single_t = rast(tor, cameras=cams[1])
    assert_array_equal(mixed.face_id_image()[1], single_t.face_id_image()[0])
    assert np.all(mixed.pix_to_face[1][mixed.pix_to_face[1] >= 0] >= first[1])
    with pytest.raises(ValueError, match="batch sizes"):
        rast(Meshes([sphere, tor]))


def test_call_time_overrides():
    """Keyword arguments at call time replace the stored cameras, lights and materials."""
    mesh = ico_sphere(2)
    cams_a, cams_b = _look(3.0, 0.0, 0.0), _look(3.0, 40.0, 70.0)
    light = PointLights(location=[[1.0, 2.0, 3.0]])
    mat = Materials(diffuse_color=[[0.2, 0.9, 0.4]], shininess=5.0)
    stored = MeshRenderer(MeshRasterizer(cams_b, RasterizationSettings(image_size=32)),
                          HardPhongShader(cams_b, light, mat))
    generic = MeshRenderer(MeshRasterizer(cams_a, RasterizationSettings(image_size=32)),
                           HardPhongShader())
    assert_array_equal(generic(mesh, cameras=cams_b, lights=light, materials=mat), stored(mesh))
    assert not np.array_equal(generic(mesh), stored(mesh))


# ------------------------------------------------------------------ lighting and shading

def test_lighting_closed_forms():
    """Lambert and Phong terms at known angles, with PyTorch3D's default colours."""
    n = np.array([[0.0, 0.0, 1.0]] * 3)
    p = np.zeros((3, 3))
    ang = np.radians([0.0, 60.0, 120.0])
    loc = np.stack([np.sin(ang), np.zeros(3), np.cos(ang)], 1) * 5.0
    lights = PointLights(location=loc)
    d = lights.diffuse(n, p, batch_idx=np.arange(3))
    assert_allclose(d[:, 0], 0.3 * np.array([1.0, 0.5, 0.0]), atol=1e-12)
    # Mirror direction: camera where the reflected ray goes -> specular = Ls.
    cam = np.array([[-np.sin(ang[1]), 0.0, np.cos(ang[1])]]) * 7.0
    s = lights[1].specular(n[:1], p[:1], cam, np.array([64.0]))
    assert_allclose(s, [[0.2, 0.2, 0.2]], atol=1e-12)
    # Off the mirror by angle a: cos(a) ** shininess.
    a = np.radians(20.0)
    cam2 = np.array([[-np.sin(ang[1] + a), 0.0, np.cos(ang[1] + a)]])
    s2 = lights[1].specular(n[:1], p[:1], cam2, np.array([10.0]))
    assert_allclose(s2[0, 0], 0.2 * np.cos(a) ** 10, rtol=1e-12)
    # Light behind the surface: no diffuse and no specular even at the mirror direction.
    s3 = lights[2].specular(n[:1], p[:1], -cam, np.array([64.0]))
    assert_allclose(s3, 0.0)
    dl = DirectionalLights(direction=[[0.0, 0.0, 2.0]])
    assert_allclose(dl.diffuse(n, p), 0.3)
    amb = AmbientLights(ambient_color=[0.1, 0.2, 0.3])
    assert_allclose(amb.diffuse(n, p), 0.0)
    assert_allclose(amb.specular(n, p, cam, np.array([4.0])), 0.0)


def _loop_lighting(points, normals, loc, cam, mat_a, mat_d, mat_s, shin, la, ld, ls):
    """PyTorch3D's _apply_lighting written out point by point (reference)."""
    out = []
    for p, n in zip(points, normals):
        n = n / max(np.linalg.norm(n), 1e-6)
        l = loc - p
        l = l / max(np.linalg.norm(l), 1e-6)
        cos = n @ l
        v = cam - p
        v = v / max(np.linalg.norm(v), 1e-6)
        r = -l + 2 * cos * n
        spec = max(v @ r, 0.0) ** shin if cos > 0 else 0.0
        out.append((mat_a * la, mat_d * ld * max(cos, 0.0), mat_s * ls * spec))
    return [np.array(x) for x in zip(*out)]


def test_apply_lighting_matches_loop_reference():
    rng = np.random.default_rng(0)
    pts, nrm = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    loc, cam = np.array([0.3, 2.0, -1.0]), np.array([[1.0, -0.5, 4.0]])
    mat = Materials(ambient_color=[0.9, 0.8, 0.7], diffuse_color=[0.5, 0.6, 0.7],
                    specular_color=[0.1, 1.0, 0.3], shininess=7.0)
    lights = PointLights(ambient_color=[0.4, 0.5, 0.6], diffuse_color=[0.3, 0.2, 0.1],
                         specular_color=[0.9, 0.8, 0.7], location=[loc])
    a, d, s = apply_lighting(pts, nrm, lights, cam, mat)
    ra, rd, rs = _loop_lighting(pts, nrm, loc, cam[0], mat.ambient_color[0],
                                mat.diffuse_color[0], mat.specular_color[0], 7.0,
                                lights.ambient_color[0], lights.diffuse_color[0],
                                lights.specular_color[0])
    assert_allclose(np.broadcast_to(a, ra.shape), ra, rtol=1e-12)
    assert_allclose(d, rd, rtol=1e-12, atol=1e-15)
    assert_allclose(s, rs, rtol=1e-10, atol=1e-15)
    assert_allclose(diffuse(nrm, lights.diffuse_color, loc - pts), d / mat.diffuse_color, rtol=1e-12)
    assert_allclose(specular(pts, nrm, loc - pts, cam, 7.0, lights.specular_color),
                    s / mat.specular_color, rtol=1e-10, atol=1e-15)


def _flat_quad(colors):
    """A unit square facing +Z (two faces) with per-vertex colours."""
    V = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]])
    return Mesh(V, [[0, 1, 2], [0, 2, 3]], TexturesVertex(np.tile(colors, (4, 1))))


def test_phong_gouraud_flat_agree_on_a_flat_lambertian_quad():
    """Constant normal, directional light, no specular: all three shadings give
    (Ma La + Md Ld cos) * colour everywhere, the analytic value."""
    c = np.array([0.8, 0.5, 0.2])
    mesh = _flat_quad(c)
    lights = DirectionalLights(direction=[[0.0, 1.0, 1.0]])
    mat = Materials(specular_color=[0.0, 0.0, 0.0])
    cams = _look(3.0, 10.0, 20.0)
    expect = (0.5 + 0.3 * np.cos(np.radians(45.0))) * c
    for shader in (HardPhongShader, HardGouraudShader, HardFlatShader):
        img = MeshRenderer(MeshRasterizer(cams, RasterizationSettings(image_size=24)),
                           shader(lights=lights, materials=mat))(mesh)
        cov = img[0, ..., 3] == 1
        assert cov.sum() > 50
        assert_allclose(img[0][cov][:, :3], np.broadcast_to(expect, (cov.sum(), 3)), atol=1e-6)


def test_gouraud_interpolates_vertex_colours():
    """Gouraud colours are the barycentric interpolation of lit vertex colours."""
    mesh = ico_sphere(2)
    rng = np.random.default_rng(1)
    cols = rng.uniform(0.1, 0.9, (mesh.n_verts, 3))
    mesh = Mesh(mesh.verts, mesh.faces, TexturesVertex(cols))
    cams = _look(3.0)
    fr = MeshRasterizer(cams, RasterizationSettings(image_size=32))(mesh)
    lights, mat = PointLights(location=[[0, 2, 2]]), Materials()
    a, d, s = apply_lighting(mesh.verts, mesh.verts_normals, lights, cams.get_camera_center(), mat)
    shaded = cols * (a + d) + s
    expect = np.einsum("kj,kjc->kc", fr.bary, shaded[mesh.faces[fr.face]])
    assert_allclose(gouraud_shading(fr, lights, cams, mat), expect, atol=1e-5)
    img = MeshRenderer(MeshRasterizer(cams, RasterizationSettings(image_size=32)),
                       SoftGouraudShader(lights=lights))(mesh)
    assert img.shape == (1, 32, 32, 4)
    with pytest.raises(ValueError, match="TexturesVertex"):
        gouraud_shading(MeshRasterizer(cams, RasterizationSettings(image_size=8))(ico_sphere(1)),
                        lights, cams, mat)
    with pytest.raises(ValueError, match="shadows"):
        HardGouraudShader(shadows=True)


def test_flat_shading_uses_face_centroid_and_normal():
    mesh = ico_sphere(1)
    cams = _look(3.0, 20.0, 30.0)
    fr = MeshRasterizer(cams, RasterizationSettings(image_size=32))(mesh)
    lights, mat = PointLights(location=[[1, 2, 3]]), Materials(shininess=3.0)
    tex = np.ones((fr.n_hits, 3), np.float32)
    cen = mesh.verts[mesh.faces[fr.face]].mean(1)
    a, d, s = apply_lighting(cen, mesh.face_normals[fr.face], lights,
                             cams.get_camera_center(), mat)
    assert_allclose(flat_shading(fr, lights, cams, mat, tex), a + d + s, atol=1e-5)
    # All pixels of a face share one colour.
    col = flat_shading(fr, lights, cams, mat, tex)
    for f in np.unique(fr.face)[:5]:
        assert np.ptp(col[fr.face == f], axis=0).max() < 1e-6


def test_batched_lights_and_materials_apply_per_view():
    """With N lights / materials each view uses its own: equal to rendering views one by one."""
    mesh = ico_sphere(2)
    R, T = look_at_view_transform(3.0, [0.0, 20.0], [0.0, 50.0])
    cams = FoVPerspectiveCameras(R=R, T=T)
    lights = PointLights(location=[[0, 0, 3], [2, 1, -1]], diffuse_color=[[0.3] * 3, [0.6] * 3])
    mats = Materials(specular_color=[[1, 1, 1], [0, 1, 0]], shininess=[64.0, 5.0])
    rast = MeshRasterizer(cams, RasterizationSettings(image_size=24))
    both = MeshRenderer(rast, SoftPhongShader(lights=lights, materials=mats))(mesh.extend(2))
    for i in range(2):
        one = MeshRenderer(rast, SoftPhongShader(lights=lights[i], materials=mats[i]))(
            mesh, cameras=cams[i])
        assert_allclose(both[i], one[0], atol=1e-6)


# ------------------------------------------------------------------ textures

def test_uv_convention_on_a_tiny_texture():
    """grid = (2u - 1, 1 - 2v), align_corners: u = 0 / 1 are the first / last column centres,
    v = 1 is the top row; bilinear in between; border padding outside [0, 1]."""
    maps = np.array([[[0.0], [1.0]], [[2.0], [3.0]]])  # row 0 = top
    tex = TexturesUV(maps, [[0, 1, 2]], [[0.0, 1.0], [1.0, 1.0], [0.0, 0.0]])
    uv = np.array([[0.0, 1.0], [1.0, 1.0], [0.0, 0.0], [1.0, 0.0], [0.5, 0.5], [0.25, 1.0],
                   [-3.0, 2.0], [1.5, -0.2]])
    # Barycentrics reproducing those uv in the face (0,1), (1,1), (0,0).
    bary = np.stack([1 - uv[:, 0] - (1 - uv[:, 1]), uv[:, 0], 1 - uv[:, 1]], 1)
    got = sample_texels(tex, np.zeros((1, 3), int), np.zeros(len(uv), int), bary)[:, 0]
    assert_allclose(got, [0.0, 1.0, 2.0, 3.0, 1.5, 0.25, 0.0, 3.0], atol=1e-6)


def test_sample_texels_matches_structures_sampler():
    """The renderer's float32 lookup equals Mesh.sample_textures (float64) for UV, vertex and
    flat textures."""
    rng = np.random.default_rng(2)
    m = ico_sphere(2)
    F = m.n_faces
    maps = rng.uniform(size=(37, 53, 3))
    uv = TexturesUV(maps, rng.integers(0, 40, (F, 3)), rng.uniform(-0.1, 1.1, (40, 2)))
    vt = TexturesVertex(rng.uniform(size=(m.n_verts, 4)))
    fl = TexturesFlat(rng.uniform(size=(F, 3)))
    face = rng.integers(0, F, 500)
    bary = rng.dirichlet([1, 1, 1], 500)
    for tex in (uv, vt, fl, TexturesFlat([0.1, 0.2, 0.3])):
        mesh = Mesh(m.verts, m.faces, tex)
        # float32 UVs on a random (steep) 53-pixel-wide map: errors ~ 52 * 6e-8 per unit slope
        assert_allclose(sample_texels(tex, m.faces, face, bary),
                        mesh.sample_textures(face, bary), atol=1e-5)
    with pytest.raises(ValueError, match="colors"):
        sample_texels(TexturesFlat(np.ones((3, 3))), m.faces, face, bary)
    with pytest.raises(ValueError, match="colors"):
        TexturesFlat(np.ones((2, 2, 3)))


def test_untextured_mesh_is_white_and_flat_colour_renders():
    mesh = ico_sphere(2)
    cams = _look(3.0)
    amb = AmbientLights()
    r = MeshRenderer(MeshRasterizer(cams, RasterizationSettings(image_size=16)),
                     HardPhongShader(lights=amb))
    img = r(mesh)
    cov = img[0, ..., 3] == 1
    assert_allclose(img[0][cov][:, :3], 1.0)
    img2 = r(Mesh(mesh.verts, mesh.faces, TexturesFlat([0.2, 0.4, 0.6])))
    assert_allclose(img2[0][cov][:, :3], np.broadcast_to([0.2, 0.4, 0.6], (cov.sum(), 3)),
                    atol=1e-6)


# ------------------------------------------------------------------ beyond PyTorch3D

def test_supersampling_is_the_box_filter_of_the_large_render():
    mesh = torus()
    cams = _look(3.5, 30.0, 20.0)
    shader = SoftPhongShader(lights=PointLights(location=[[0, 3, 3]]))
    small = MeshRenderer(MeshRasterizer(cams, RasterizationSettings(image_size=(20, 30),
                                                                    supersample=3)), shader)
    big = MeshRenderer(MeshRasterizer(cams, RasterizationSettings(image_size=(60, 90))), shader)
    a, b = small(mesh), big(mesh)
    assert a.shape == (1, 20, 30, 4)
    assert_allclose(a, b.reshape(1, 20, 3, 30, 3, 4).mean(axis=(2, 4)), atol=1e-6)
    _, fr = MeshRendererWithFragments(small.rasterizer, shader)(mesh)
    assert fr.image_size == (60, 90) and fr.supersample == 3
    hard = MeshRenderer(small.rasterizer, HardPhongShader())(mesh)
    edge = (hard[0, ..., 3] > 0) & (hard[0, ..., 3] < 1)
    assert edge.sum() > 10  # antialiased silhouette


def _shadow_scene():
    """A 0.6-wide square floating at z = 1 above a 4 x 4 ground plane at z = 0."""
    ground = plane(size=4.0, n=8, z=0.0)
    lid = plane(size=0.6, n=1, z=1.0)
    V = np.concatenate([ground.verts, lid.verts])
    F = np.concatenate([ground.faces, lid.faces + ground.n_verts])
    return Mesh(V, F), ground.n_faces


def test_hard_shadows():
    """With a light straight above, the ground under the lid gets ambient light only; outside
    the shadow and with shadows off, images are identical."""
    mesh, n_ground = _shadow_scene()
    R, T = look_at_view_transform(eye=[[0.0, -3.0, 4.0]], at=[[0.0, 0.0, 0.0]],
                                  up=[[0.0, 0.0, 1.0]])
    cams = FoVPerspectiveCameras(R=R, T=T)
    lights = PointLights(location=[[0.0, 0.0, 5.0]])
    rast = MeshRasterizer(cams, RasterizationSettings(image_size=64))
    on = MeshRendererWithFragments(rast, HardPhongShader(lights=lights, shadows=True))
    off = MeshRenderer(rast, HardPhongShader(lights=lights))
    img_on, fr = on(mesh)
    img_off = off(mesh)
    p = np.zeros((64 * 64, 3))
    p[fr.pixel] = fr.hit_points
    p = p.reshape(64, 64, 3)
    ground = (fr.pix_to_face[0, ..., 0] >= 0) & (fr.pix_to_face[0, ..., 0] < n_ground)
    # Shadow of the lid from a light at height 5 through height 1: scale 5 / 4.
    r = np.max(np.abs(p[..., :2]), axis=-1)
    inside, outside = ground & (r < 0.3 * 1.25 - 0.05), ground & (r > 0.3 * 1.25 + 0.05)
    assert inside.sum() > 5 and outside.sum() > 100
    assert_allclose(img_on[0][inside][:, :3], 0.5, atol=1e-6)  # ambient only, white texture
    assert np.all(img_off[0][inside][:, :3] > 0.7)
    assert_array_equal(img_on[0][outside], img_off[0][outside])
    flat = MeshRenderer(rast, HardFlatShader(lights=lights, shadows=True))(mesh)
    assert_allclose(flat[0][inside][:, :3], 0.5, atol=1e-6)


def test_depth_normal_and_face_id_images():
    """Normals of a sphere point away from its centre; depth and face-id images use their
    background values."""
    mesh = ico_sphere(4)
    cams = _look(3.0, 10.0, 10.0)
    fr = MeshRasterizer(cams, RasterizationSettings(image_size=48))(mesh)
    nimg = fr.normal_image()[0]
    radial = fr.hit_points / np.linalg.norm(fr.hit_points, axis=1, keepdims=True)
    got = 2.0 * nimg.reshape(-1, 3)[fr.pixel] - 1.0
    assert np.mean(np.einsum("ki,ki->k", got, radial)) > 0.999
    view_n = 2.0 * fr.normal_image("view")[0].reshape(-1, 3)[fr.pixel] - 1.0
    assert np.all(view_n[:, 2] < 0.2)  # visible normals face the camera (-z in view space)
    d = fr.depth_image(background=np.inf)[0]
    assert np.all(np.isinf(d[~fr.mask[0]])) and np.all((d[fr.mask[0]] > 1.9)
                                                         & (d[fr.mask[0]] < 3.0))
    ids = fr.face_id_image()[0]
    assert np.all(ids[~fr.mask[0]] == -1) and ids.max() < mesh.n_faces
    with pytest.raises(ValueError, match="space"):
        fr.normal_image("screen")


# ------------------------------------------------------------------ bad input

def test_camera_inside_a_closed_mesh_sees_back_faces():
    """Documented: from inside, every ray hits the inside of the surface (back faces). They are
    shaded with their outward normals and no shadows, as in PyTorch3D, so a light behind the
    camera (outside the sphere) leaves them with the ambient term; culling back faces shows
    nothing."""
    mesh = ico_sphere(3)
    cams = FoVPerspectiveCameras(znear=0.01)  # at the origin, inside the unit sphere, looking +z
    rast = MeshRasterizer(cams, RasterizationSettings(image_size=32))
    img, fr = MeshRendererWithFragments(rast, SoftPhongShader(
        lights=PointLights(location=[[0, 0, -5]])))(mesh)
    assert fr.mask.all()
    assert np.all(np.isfinite(img))
    assert_allclose(fr.depth_image()[0].max(), 1.0, atol=0.05)
    normals = fr.hit_normals
    toward = fr.hit_points  # outward normals point away from the camera at the origin
    assert np.all(np.einsum("ki,ki->k", normals, toward) > 0)
    assert_allclose(img[0, ..., :3], 0.5, atol=1e-6)  # n . l < 0 everywhere: ambient only
    culled = MeshRasterizer(cams, RasterizationSettings(image_size=32, cull_backfaces=True))(mesh)
    assert culled.n_hits == 0


def test_cull_backfaces_from_outside_keeps_a_convex_mesh():
    mesh = ico_sphere(3)
    cams = _look(3.0, 20.0, 30.0)
    a = MeshRasterizer(cams, RasterizationSettings(image_size=40))(mesh)
    b = MeshRasterizer(cams, RasterizationSettings(image_size=40, cull_backfaces=True))(mesh)
    assert_array_equal(a.pixel, b.pixel)
    assert (a.face == b.face).mean() > 0.99
    # A single plane seen from behind disappears when culled.
    back = MeshRasterizer(_look(3.0, 0.0, 180.0), RasterizationSettings(image_size=16,
                                                                         cull_backfaces=True))
    assert back(plane()).n_hits == 0


def test_empty_mesh_renders_background():
    empty = Mesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64))
    r = MeshRendererWithFragments(MeshRasterizer(_look(), RasterizationSettings(image_size=8)),
                                  SoftPhongShader(blend_params=BlendParams(
                                      background_color=(0.1, 0.2, 0.3))))
    img, fr = r(empty)
    assert fr.n_hits == 0 and np.all(fr.pix_to_face == -1)
    assert_allclose(img[..., :3], np.broadcast_to([0.1, 0.2, 0.3], (1, 8, 8, 3)), atol=1e-7)
    assert np.all(img[..., 3] == 0)
    img2, fr2 = r(Meshes([empty, ico_sphere(1)]))
    assert fr2.n_hits > 0 and np.all(fr2.pix_to_face[0] == -1)
    assert np.all(np.isfinite(img2))


def test_zero_area_faces_are_never_hit():
    """A degenerate (collinear) face in front of a plane is never reported; nothing is NaN."""
    base = plane(size=2.0, n=2)
    V = np.concatenate([base.verts, [[-1.0, 0.0, 0.5], [0.0, 0.0, 0.5], [1.0, 0.0, 0.5]],
                        [[0.2, 0.2, 0.6]] * 3])
    nv = base.n_verts
    F = np.concatenate([base.faces, [[nv, nv + 1, nv + 2], [nv + 3, nv + 4, nv + 5]]])
    mesh = Mesh(V, F)
    img, fr = MeshRendererWithFragments(
        MeshRasterizer(_look(3.0), RasterizationSettings(image_size=64)),
        SoftPhongShader(lights=PointLights(location=[[0, 0, 3]])))(mesh)
    assert fr.n_hits > 0
    assert not np.isin(fr.face, [base.n_faces, base.n_faces + 1]).any()
    assert np.all(np.isfinite(img)) and np.all(np.isfinite(fr.normals))
    assert np.all(np.isfinite(mesh.verts_normals))


def test_light_at_a_surface_point_gives_finite_shading():
    """A point light exactly on the surface: zero light vector, normalised with an epsilon, so
    that point gets ambient only and nothing is NaN (also with shadows)."""
    mesh = plane(size=2.0, n=2)  # has a vertex at the origin
    cams = _look(3.0, 10.0, 0.0)
    for shadows in (False, True):
        img = MeshRenderer(MeshRasterizer(cams, RasterizationSettings(image_size=33)),
                           HardPhongShader(lights=PointLights(location=[[0.0, 0.0, 0.0]]),
                                           shadows=shadows))(mesh)
        assert np.all(np.isfinite(img))
    n = np.array([[0.0, 0.0, 1.0]])
    pts = np.zeros((1, 3))
    a, d, s = apply_lighting(pts, n, PointLights(location=[[0.0, 0.0, 0.0]]),
                             np.array([[0.0, 0.0, 3.0]]), Materials())
    assert_allclose(a, 0.5)
    assert_allclose(d, 0.0)
    assert_allclose(s, 0.0)


def test_missing_texture_is_a_clear_error(tmp_path, monkeypatch, capsys):
    """An OBJ whose MTL names a missing texture: loading raises FileNotFoundError naming it,
    and `geofit render` reports it and exits with 1."""
    from geofit.cli import main
    from geofit.io import load_mesh

    (tmp_path / "m.mtl").write_text("newmtl a\nKd 1 1 1\nmap_Kd missing.png\n")
    (tmp_path / "m.obj").write_text("mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\n"
                                    "vt 0 1\nusemtl a\nf 1/1 2/2 3/3\n")
    with pytest.raises(FileNotFoundError, match="missing.png"):
        load_mesh(tmp_path / "m.obj")
    assert main(["render", str(tmp_path / "m.obj"), "--out", str(tmp_path / "o")]) == 1
    assert "missing.png" in capsys.readouterr().err


@pytest.mark.parametrize("kw, match", [
    ({"blur_radius": 1e-4}, "blur_radius"),
    ({"faces_per_pixel": 2}, "faces_per_pixel"),
    ({"image_size": 0}, "image_size"),
    ({"image_size": (4, -1)}, "image_size"),
    ({"image_size": "big"}, "image_size"),
    ({"supersample": 0}, "supersample"),
    ({"z_clip_value": -1.0}, "z_clip_value"),
    ({"perspective_correct": "yes"}, "perspective_correct"),
    ({"n_threads": 0}, "n_threads"),
])
def test_rasterization_settings_validation(kw, match):
    with pytest.raises(ValueError, match=match):
        RasterizationSettings(**kw)


# Each row: the error, the text naming the bad argument, and the call given the sphere ``mesh``
# and its fragments ``fr``.
_BAD_RENDER_CALLS = [
    (ValueError, "cameras", lambda mesh, fr: MeshRasterizer()(mesh)),
    (TypeError, "cameras", lambda mesh, fr: MeshRasterizer(cameras="cam")(mesh)),
    (TypeError, "meshes", lambda mesh, fr: MeshRasterizer(_look())(np.zeros((3, 3)))),
    (TypeError, "raster_settings",
     lambda mesh, fr: MeshRasterizer(_look(), raster_settings={"image_size": 8})(mesh)),
    (ValueError, "at least one mesh", lambda mesh, fr: MeshRasterizer(_look())(Meshes([]))),
    (TypeError, "fragments", lambda mesh, fr: HardPhongShader()(np.zeros(3), mesh)),
    (ValueError, "lights",
     lambda mesh, fr: HardPhongShader(lights=PointLights(location=np.zeros((2, 3))))(fr, mesh)),
    (TypeError, "lights", lambda mesh, fr: HardPhongShader(lights="sun")(fr, mesh)),
    (ValueError, "materials",
     lambda mesh, fr: HardPhongShader(materials=Materials(shininess=[1.0, 2.0]))(fr, mesh)),
    (ValueError, "sigma",
     lambda mesh, fr: SoftPhongShader(blend_params=BlendParams(sigma=0.0))(fr, mesh)),
    (ValueError, "background_color",
     lambda mesh, fr: HardPhongShader(blend_params=BlendParams(background_color=(1, 1)))(
         fr, mesh)),
    (TypeError, "shadows", lambda mesh, fr: HardPhongShader(shadows="yes")),
    (TypeError, "rasterizer", lambda mesh, fr: MeshRenderer("r", HardPhongShader())),
    (TypeError, "shader", lambda mesh, fr: MeshRenderer(MeshRasterizer(), None)),
]


@pytest.fixture(scope="module")
def sphere_fragments():
    mesh = ico_sphere(1)
    return mesh, MeshRasterizer(_look(), RasterizationSettings(image_size=8))(mesh)


def test_sphere_fragments(sphere_fragments):
    assert isinstance(sphere_fragments[1], Fragments)


@pytest.mark.parametrize("error, match, call", _BAD_RENDER_CALLS,
                         ids=[f"{i}-{r[1]}" for i, r in enumerate(_BAD_RENDER_CALLS)])
def test_rasterizer_and_shader_validation(sphere_fragments, error, match, call):
    """Each invalid rasterizer, shader or renderer argument raises, naming the argument."""
    with pytest.raises(error, match=match):
        call(*sphere_fragments)


def test_lights_and_materials_validation():
    with pytest.raises(ValueError, match="location"):
        PointLights(location=[1.0, 2.0])
    with pytest.raises(ValueError, match="batch sizes"):
        PointLights(location=np.zeros((2, 3)), diffuse_color=np.zeros((3, 3)))
    with pytest.raises(ValueError, match="direction"):
        DirectionalLights(direction=[[np.nan, 0, 1]])
    with pytest.raises(ValueError, match="ambient_color"):
        AmbientLights(ambient_color=[[1, 1]])
    with pytest.raises(ValueError, match="shininess"):
        Materials(shininess=-1.0)
    with pytest.raises(ValueError, match="shininess"):
        Materials(shininess=np.ones((2, 2)))
    with pytest.raises(ValueError, match="n"):
        PointLights().extend(0)
    assert len(PointLights().extend(3)) == 3 and len(Materials().extend(2)) == 2


# ------------------------------------------------------------------ helpers and CLI

def test_make_grid_layout():
    imgs = np.zeros((5, 2, 3, 4), np.float32)
    for i in range(5):
        imgs[i, ..., :3] = i / 10
    g = make_grid(imgs, cols=3, pad=1, background=1.0)
    assert g.shape == (5, 11, 3)
    assert_allclose(g[0:2, 4:7], 0.1, atol=1e-7)      # image 1: row 0, column 1
    assert_allclose(g[3:5, 4:7], 0.4, atol=1e-7)      # image 4: row 1, column 1
    assert_allclose(g[3:5, 8:11], 1.0)               # empty cell
    assert make_grid(imgs, rgb=False).shape == (4, 9, 1)  # 2 x 3 grid by default
    with pytest.raises(ValueError, match="rows, cols"):
        make_grid(imgs, rows=2, cols=2)
    with pytest.raises(ValueError, match="images"):
        make_grid(np.zeros((2, 3)))


def test_image_grid_and_uv_plot():
    mpl = pytest.importorskip("matplotlib")
    mpl.use("Agg")
    import matplotlib.pyplot as plt

    from geofit.render import image_grid, plot_texture_uv, texturesuv_image_matplotlib

    fig = image_grid(np.random.default_rng(0).uniform(size=(5, 4, 4, 4)), rows=2, cols=3)
    shown = [ax for ax in fig.axes if ax.images]
    assert len(shown) == 5 and len(fig.axes) == 6
    plt.close(fig)
    tex = TexturesUV(np.ones((4, 4, 3)), [[0, 1, 2], [0, 2, 3]],
                     [[0, 0], [1, 0], [1, 1], [0, 1]])
    ax = plot_texture_uv(tex)
    assert len(ax.collections[0].get_segments()) == 6
    plt.close(ax.figure)
    ax = texturesuv_image_matplotlib(tex, subsample=None)
    assert len(ax.collections[0].get_offsets()) == 4
    plt.close(ax.figure)
    with pytest.raises(TypeError, match="textures"):
        plot_texture_uv(TexturesVertex(np.ones((3, 3))))


def test_cli_render_writes_images(tmp_path, monkeypatch, capsys):
    """`geofit render` renders the default mesh (procedural offline) and a batch grid."""
    from PIL import Image

    from geofit.cli import main

    monkeypatch.setenv("GEOFIT_DATA", str(tmp_path / "nothing-here"))
    monkeypatch.setenv("GEOFIT_SHIPPED_DATA", "0")  # not the cow installed with geofit
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    out = tmp_path / "out"
    assert main(["render", "--out", str(out), "--image-size", "32", "--views", "3"]) == 0
    img = np.asarray(Image.open(out / "render.png"))
    assert img.shape == (64, 64, 3)  # 2 x 2 grid of 32 px views
    assert (img < 250).any() and (img == 255).any()
    assert (out / "render_depth.png").exists() and (out / "render_normals.png").exists()
    assert "procedural_textured" in capsys.readouterr().out
    stl = tmp_path / "t.ply"
    torus().to_trimesh().export(stl)
    assert main(["render", str(stl), "--out", str(out), "--image-size", "24", "--normalize",
                 "--shadows", "--supersample", "2"]) == 0


def test_batch_of_differently_textured_meshes():
    """Each view of a mixed batch is shaded with its own mesh's texture (UV, vertex, flat)."""
    s = ico_sphere(2)
    uv = Mesh(s.verts, s.faces, TexturesUV(np.tile([0.0, 0.0, 1.0], (4, 4, 1)),
                                           np.zeros((s.n_faces, 3), np.int64), [[0.5, 0.5]]))
    vt = Mesh(s.verts, s.faces, TexturesVertex(np.tile([1.0, 0.0, 0.0], (s.n_verts, 1))))
    fl = Mesh(s.verts, s.faces, TexturesFlat([0.0, 1.0, 0.0]))
    R, T = look_at_view_transform(3.0, 0.0, [0.0, 90.0, 180.0])
    img = MeshRenderer(MeshRasterizer(FoVPerspectiveCameras(R=R, T=T),
                                      RasterizationSettings(image_size=16)),
                       HardPhongShader(lights=AmbientLights()))(Meshes([uv, vt, fl]))
    for b, rgb in enumerate(([0, 0, 1], [1, 0, 0], [0, 1, 0])):
        cov = img[b, ..., 3] == 1
        assert cov.sum() > 20
        assert_allclose(img[b][cov][:, :3], np.broadcast_to(rgb, (cov.sum(), 3)), atol=1e-6)


def test_every_public_renderer_imports_from_geofit_render():
    """geofit.render exports the renderers of every subpackage, the same objects."""
    import geofit.render as gr
    from geofit.render import mesh, points, soft, volume
    from geofit.structures import Volume

    names = ["MeshRenderer", "MeshRasterizer", "HardPhongShader", "SoftPhongShader",
             "HardGouraudShader", "SoftGouraudShader", "HardFlatShader", "SoftSilhouetteShader",
             "SoftSilhouetteRenderer", "SoftPhongRenderer", "rasterize_soft", "PointsRenderer",
             "PointsRasterizer", "AlphaCompositor", "NormWeightedCompositor",
             "NDCMultinomialRaysampler", "MonteCarloRaysampler", "EmissionAbsorptionRaymarcher",
             "AbsorptionOnlyRaymarcher", "VolumeRenderer", "ImplicitRenderer",
             "HarmonicEmbedding", "NeuralRadianceField"]
    for name in names:
        assert name in gr.__all__, name
        home = [m for m in (mesh, points, soft, volume) if name in m.__all__]
        assert len(home) == 1 and getattr(home[0], name) is getattr(gr, name), name
    assert Volume.__module__ == "geofit.structures.volume"


def test_the_0_1_flat_module_paths_are_gone():
    """0.2.0 removed the import hook of the 0.1 flat layout (CHANGELOG.md): the old paths do
    not import, the new ones do."""
    import importlib

    old_to_new = {"raysampling": "volume.raysampling", "raymarching": "volume.raymarching",
                  "implicit": "volume.implicit", "harmonic": "volume.harmonic",
                  "compositing": "points.compositing", "contour": "soft.contour",
                  "shading": "mesh.shading", "textures": "mesh.textures"}
    for old, new in old_to_new.items():
        with pytest.raises(ModuleNotFoundError):
            importlib.import_module(f"geofit.render.{old}")
        importlib.import_module(f"geofit.render.{new}")
