"""The default start of fit_mesh_to_views (geofit.fit._views_init) and the default fit's result.

No new gradient: the default fit composes the soft-silhouette objective of
geofit.fit._views_objective (finite-difference tests in test_fit_views.py) with remeshing.
"""
import math

import numpy as np
import pytest

from geofit.cameras import FoVPerspectiveCameras, look_at_view_transform
from geofit.datasets import tutorial_views
from geofit.fit import ViewsFitOptions, fit_mesh_to_views
from geofit.fit import init as _fit_init
from geofit.fit._views_init import remesh_to_length
from geofit.fit.init import shortest_edge
from geofit.fit.init import visual_hull_mesh
from geofit.structures.visual_hull import carve_hull, hull_field, pixel_footprint
from geofit.fit.views import RECIPES, ViewsEvaluator
from geofit.shapes import two_spheres
from geofit.structures import Mesh, TexturesVertex


def _colored(mesh):
    m = Mesh(mesh.verts, mesh.faces).normalize().mesh
    return Mesh(m.verts, m.faces, TexturesVertex(0.5 + 0.4 * np.sin(3.0 * m.verts)))


@pytest.fixture(scope="module")
def spheres():
    """Eight views of 32 px of two separate spheres."""
    return tutorial_views(4, mesh=_colored(two_spheres(level=2)), num_views=8, image_size=32,
                          num_held_out=4)


def test_pixel_footprint_is_the_pixel_size_at_the_point():
    """A FoV camera at distance d (fov 60 degrees, H pixels) sees 2 d tan(30 deg) / H world
    units per pixel at the point it looks at, and twice that at twice the distance."""
    R, T = look_at_view_transform(2.7, 0.0, [0.0, 90.0])
    cams = FoVPerspectiveCameras(R=R, T=T)
    want = 2.0 * 2.7 * math.tan(math.radians(30.0)) / 128
    np.testing.assert_allclose(pixel_footprint(cams, (128, 128), np.zeros(3)), want, rtol=1e-3)
    R, T = look_at_view_transform(5.4, 0.0, 0.0)
    np.testing.assert_allclose(pixel_footprint(FoVPerspectiveCameras(R=R, T=T), (128, 128),
                                               np.zeros(3)), 2.0 * want, rtol=1e-3)


def test_hull_field_matches_transform_points_screen():
    """The hull field's own projection reads the images where cameras.transform_points_screen
    puts the points (a slow per-view reference with scipy's map_coordinates)."""
    from scipy.ndimage import map_coordinates

    R, T = look_at_view_transform(2.7, [0.0, 30.0, -20.0], [0.0, 100.0, 200.0])
    cams = FoVPerspectiveCameras(R=R, T=T)
    rng = np.random.default_rng(0)
    sd = rng.normal(size=(3, 16, 20))
    P = rng.uniform(-1.0, 1.0, (50, 3))
    ref = np.full(len(P), np.inf)
    for i in range(3):  # views: the reference loop
        xy = cams[i].transform_points_screen(P, (16, 20))[0]
        ref = np.minimum(ref, map_coordinates(sd[i], [xy[:, 1] - 0.5, xy[:, 0] - 0.5], order=1,
                                              cval=-36.0))
    np.testing.assert_allclose(hull_field(sd, cams, P), ref, atol=1e-12)


def test_visual_hull_mesh_keeps_the_parts_and_covers_the_shape(spheres):
    """The visual hull of two separate spheres has two closed parts; carved at the 0.5 level
    without shrinking and barely decimated, it covers (nearly) all of the silhouettes'
    interior (> 0.9) and (nearly) nothing outside their 0.5 level in the training views."""
    from geofit.ops import topology
    from geofit.render import MeshRasterizer, RasterizationSettings

    hull = visual_hull_mesh(spheres.silhouettes, spheres.cameras, edge_px=0.5, shrink_px=0.0)
    mesh, info = hull.mesh, {"pixel_size": hull.pixel_size, "voxel_size": hull.voxel_size}
    topo = topology(mesh, self_intersections=False)
    assert topo.n_components == 2 and topo.is_closed and topo.is_manifold
    assert info["pixel_size"] > 0 and info["voxel_size"] > 0
    ras = MeshRasterizer(spheres.cameras, RasterizationSettings(image_size=(32, 32)))
    mask = ras(mesh).mask
    inner = spheres.silhouettes > 0.9
    assert (mask & inner).sum() >= 0.97 * inner.sum()
    assert (mask & (spheres.silhouettes <= 0.5)).sum() <= 0.01 * mask.sum()


def test_visual_hull_mesh_rejects_an_empty_hull(spheres):
    with pytest.raises(ValueError, match="silhouettes"):
        visual_hull_mesh(np.zeros_like(spheres.silhouettes), spheres.cameras)


@pytest.mark.parametrize("factor", [0.5, 2.0])
def test_remesh_to_length_keeps_the_hull_manifold(spheres, factor):
    """Remeshing the visual hull (marching cubes, decimated: what the default fit remeshes)
    keeps it edge-manifold and consistently oriented with its genus and parts, and moves the
    mean edge length towards the target."""
    from geofit.ops import topology

    mesh = visual_hull_mesh(spheres.silhouettes, spheres.cameras, edge_px=1.0).mesh
    t0 = topology(mesh, self_intersections=False)
    target = factor * float(mesh.edge_lengths.mean())
    out = remesh_to_length(mesh, target)
    t1 = topology(out, self_intersections=False)
    assert t1.n_nonmanifold_edges == 0 and t1.winding_consistent
    assert (t1.genus, t1.n_components, t1.n_boundary_loops) == \
        (t0.genus, t0.n_components, t0.n_boundary_loops)
    assert abs(out.edge_lengths.mean() - target) < abs(mesh.edge_lengths.mean() - target)


def test_default_fit_starts_from_the_hull_and_reports_topology(spheres):
    """The plain call starts from the visual hull (two parts kept), remeshes, says so, and
    reports the fitted mesh's topology; init="sphere" keeps the tutorial's ico-sphere."""
    res = fit_mesh_to_views(spheres, options=ViewsFitOptions(silhouette_iters=12), progress=False)
    assert res.init == "hull" and res.ok
    assert res.topology.n_components == 2 and res.topology.is_closed
    assert "visual hull" in res.message and "result: genus" in res.message
    assert res.summary()["init"] == "hull" and "topology" in res.summary()
    ev = ViewsEvaluator(spheres.held_out)
    assert ev(res.mesh)["iou"] > ev(res.init_mesh)["iou"] + 0.01
    sph = fit_mesh_to_views(spheres, options=ViewsFitOptions(init="sphere", silhouette_iters=2,
            remesh_rounds=0, textured_method="none"), progress=False)
    assert sph.init == "sphere" and sph.init_mesh.n_verts == 2562  # ico_sphere(4)
    assert RECIPES["tutorial"].init == "sphere"


def test_self_intersecting_result_says_so(spheres):
    """A result whose surface self-intersects (two overlapping spheres) says so in its
    message and its topology."""
    from geofit.shapes import ico_sphere

    s = ico_sphere(2)
    bad = Mesh(np.concatenate([0.4 * s.verts, 0.4 * s.verts + [0.3, 0.0, 0.0]]),
               np.concatenate([s.faces, s.faces + s.n_verts]))
    res = fit_mesh_to_views(spheres, options=ViewsFitOptions(init=bad, silhouette_method="none",
            textured_method="lstsq"), progress=False)
    assert res.topology.n_self_intersecting_pairs > 0
    assert "self-intersects" in res.message
    ok = fit_mesh_to_views(spheres, options=ViewsFitOptions(init=Mesh(0.4 * s.verts, s.faces),
            silhouette_method="none", textured_method="lstsq"), progress=False)
    assert "self-intersects" not in ok.message


def test_invalid_init_and_remesh_options(spheres):
    with pytest.raises(ValueError, match="init"):
        fit_mesh_to_views(spheres, options=ViewsFitOptions(init="cube"), progress=False)
    with pytest.raises(ValueError, match="remesh_rounds"):
        fit_mesh_to_views(spheres, options=ViewsFitOptions(remesh_rounds=-1), progress=False)
    with pytest.raises(ValueError, match="edge_px"):
        fit_mesh_to_views(spheres, options=ViewsFitOptions(edge_px=0.0), progress=False)


def test_close_unsupported_handles_fills_an_unseen_tunnel_and_keeps_a_seen_hole():
    """A hull grid with a one-node tunnel through a slab whose field is just below zero (no
    silhouette insists on it) is filled; the same tunnel with a field far below zero (a view
    sees through it, as through a torus's hole) stays open."""
    from geofit.structures.visual_hull import HullGrid, close_unsupported_handles

    field = np.full((12, 12, 12), -5.0)
    field[2:10, 2:10, 4:8] = 2.0     # a slab
    field[6, 6, 4:8] = -0.3          # a thin tunnel through it, barely outside a silhouette
    g = HullGrid(field, np.zeros(3), 1.0, 1.0)
    out = close_unsupported_handles(g, radius_px=1.0, tolerance_px=1.0)
    tunnel = np.zeros(field.shape, bool)
    tunnel[6, 6, 4:8] = True
    # the tunnel is blocked (its inner nodes filled; its mouths stay dimples) and nothing else
    assert out.filled[6, 6, 5:7].all() and not (out.filled & ~tunnel).any()
    assert out.n_filled == int(out.filled.sum()) and np.all(out.grid.field[out.filled] > 0)
    assert np.array_equal(out.grid.field[~out.filled], field[~out.filled])
    field[6, 6, 4:8] = -3.0          # seen through: far outside some silhouette
    kept = close_unsupported_handles(HullGrid(field, np.zeros(3), 1.0, 1.0), radius_px=1.0)
    assert kept.n_filled == 0


def test_visual_hull_mesh_close_handles_keeps_the_torus_hole():
    """The torus's hole is seen through by the tutorial's views: closing the hull's
    unsupported handles keeps genus 1 and one part."""
    from geofit.ops import topology
    from geofit.shapes import torus

    ds = tutorial_views(4, mesh=_colored(torus(1.0, 0.35, 32, 16)), num_views=12,
                        image_size=48, num_held_out=1)
    h = visual_hull_mesh(ds.silhouettes, ds.cameras, edge_px=2.0, close_handles=True)
    r = topology(h.mesh, self_intersections=False)
    assert (r.genus, r.n_components) == (1, 1)
    with pytest.raises(ValueError, match="voxel_px"):
        visual_hull_mesh(ds.silhouettes, ds.cameras, voxel_px=0.0)
    with pytest.raises(ValueError, match="refine"):
        visual_hull_mesh(ds.silhouettes, ds.cameras, refine=0)


def test_band_refinement_matches_the_fine_grid(spheres):
    """carve_hull(refine=3) on a 1.5 px grid reads the field where the 0.5 px grid does in the
    band around the surface, and has the same inside/outside everywhere on the common nodes
    (nothing inside is missed outside the band)."""
    fine = carve_hull(spheres.silhouettes, spheres.cameras, voxel_px=0.5)
    band = carve_hull(spheres.silhouettes, spheres.cameras, voxel_px=1.5, refine=3)
    np.testing.assert_allclose(band.voxel_size, fine.voxel_size, rtol=1e-12)
    np.testing.assert_allclose(band.origin, fine.origin)
    n = np.minimum(band.field.shape, fine.field.shape)
    a = band.field[:n[0], :n[1], :n[2]]
    b = fine.field[:n[0], :n[1], :n[2]]
    assert np.array_equal(a > 0, b > 0)
    near = np.abs(b) < 1.0
    np.testing.assert_allclose(a[near], b[near], atol=1e-12)


def test_signed_distance_upsample_follows_the_soft_outline():
    """A soft silhouette that ramps linearly across columns crosses 0.5 between pixel centres
    (at x0 = 10.3): at one sample per pixel the outline sits half-way between the centres
    around it (10.5), upsampled 4 times it sits within a fine pixel of x0."""
    from geofit.structures.visual_hull import signed_distance_images

    x = np.arange(32.0)
    x0 = 10.3
    s = np.clip(0.5 + 0.2 * (x0 - x), 0.0, 1.0)  # inside on the left
    sil = np.broadcast_to(s, (1, 8, 32)).copy()
    coarse = signed_distance_images(sil, 0.5)[0, 4]
    fine = signed_distance_images(sil, 0.5, upsample=4)[0, 16]
    xf = (np.arange(128) + 0.5) / 4 - 0.5  # fine pixel centres in image pixel coordinates
    # the outline: where the (linear between centres) signed distance crosses zero
    cross = lambda xs, d: np.interp(0.0, -d, xs)  # noqa: E731 (d decreases along x)
    assert abs(cross(x, coarse) - 10.5) < 1e-9
    assert abs(cross(xf, fine) - x0) <= 0.25
    assert np.array_equal(signed_distance_images(sil, 0.5, upsample=1), signed_distance_images(sil, 0.5))


def test_close_px_fills_pinholes_but_keeps_holes():
    """Closing with a 1 px disk fills a one-pixel pinhole (it no longer carves: the signed
    distance there turns positive) and keeps a hole of radius 5 px (negative at its centre)."""
    from geofit.structures.visual_hull import signed_distance_images

    yy, xx = np.mgrid[:48, :48]
    sil = ((yy - 24) ** 2 + (xx - 24) ** 2 < 20 ** 2).astype(float)
    sil[12, 24] = 0.0                                        # a pinhole
    sil[(yy - 28) ** 2 + (xx - 24) ** 2 < 25] = 0.0          # a hole of radius 5
    plain = signed_distance_images(sil[None], 0.5)[0]
    closed = signed_distance_images(sil[None], 0.5, close_px=1.0)[0]
    assert plain[12, 24] < 0 < closed[12, 24]
    assert closed[28, 24] < -3.0 and plain[28, 24] == closed[28, 24]


def test_fill_px_fills_pinholes_keeps_the_outline_and_holes():
    """``fill_px`` fills an enclosed background region of at most that many pixels (a 1 px
    and a 2 x 2 pinhole: the signed distance there turns positive), keeps a hole of radius
    5 px and a notch that reaches the border, and leaves every other pixel as it was."""
    from geofit.structures.visual_hull import signed_distance_images

    yy, xx = np.mgrid[:48, :48]
    sil = ((yy - 24) ** 2 + (xx - 24) ** 2 < 20 ** 2).astype(float)
    sil[12, 24] = 0.0                                        # a pinhole
    sil[20:22, 12:14] = 0.0                                  # a 2 x 2 pinhole
    sil[(yy - 28) ** 2 + (xx - 24) ** 2 < 25] = 0.0          # a hole of radius 5
    sil[23:25, :10] = 0.0                                    # a notch from the outside
    plain = signed_distance_images(sil[None], 0.5)[0] > 0
    filled = signed_distance_images(sil[None], 0.5, fill_px=4.0)[0] > 0
    one = signed_distance_images(sil[None], 0.5, fill_px=1.0)[0] > 0
    changed = filled & ~plain
    assert changed[12, 24] and changed[20:22, 12:14].all() and changed.sum() == 5
    assert one[12, 24] and not one[20, 12]
    assert not filled[28, 24] and not filled[23, 5] and not (plain & ~filled).any()
    fine = signed_distance_images(sil[None], 0.5, fill_px=4.0, upsample=2)[0] > 0
    assert fine[24:26, 48:50].all()  # the pinhole at (12, 24) on the twice finer grid


def test_grey_px_keeps_a_thin_part_whose_soft_values_stay_below_the_threshold():
    """A rod thinner than a pixel peaks below 0.5 in a soft silhouette (here a band 7 px wide
    at 0.3): ``grey_px=2`` keeps its core (more than 2 px from every pixel at or below
    ``grey_level``; inside a silhouette, all of it), the plain carving drops it; a hole seen
    through (values 0), the soft outline's ramp (0.5 -> 0 over 2 px) and a grey band 3 px
    wide are left as they were."""
    from geofit.structures.visual_hull import signed_distance_images

    yy, xx = np.mgrid[:48, :48]
    r = np.hypot(yy - 24, xx - 24)
    sil = np.clip((22.0 - r) / 2.0 + 0.5, 0.0, 1.0)         # a disk, soft ramp at r = 22
    sil[(yy - 30) ** 2 + (xx - 24) ** 2 < 16] = 0.0         # a hole seen through
    sil[14:21, 10:38] = 0.3                                  # a grey band 7 px wide
    plain = signed_distance_images(sil[None], 0.5)[0] > 0
    grey = signed_distance_images(sil[None], 0.5, grey_px=2.0)[0] > 0
    changed = grey & ~plain
    assert not plain[17, 12:36].any() and grey[17, 12:36].all()
    assert not changed[(yy - 30) ** 2 + (xx - 24) ** 2 < 16].any()
    assert not changed[r > 20].any() and not (plain & ~grey).any()
    rod = np.zeros((1, 32, 32))
    rod[0, 4:28, 8:15] = 0.3                                 # a free-standing rod, 7 px wide
    rod[0, 4:28, 20:23] = 0.3                                # and one 3 px wide: too thin
    kept = signed_distance_images(rod, 0.5, grey_px=2.0)[0] > 0
    assert kept[8:24, 11].all() and not kept[:, 8].any() and not kept[:, 20:23].any()


def _pinholed(spheres):
    """The spheres' silhouettes with a 2 x 2 pinhole deep inside the first view's, the cameras
    and the pinhole's pixel (y, x)."""
    from scipy.ndimage import distance_transform_edt

    sil = spheres.silhouettes.copy()
    y, x = np.unravel_index(np.argmax(distance_transform_edt(sil[0] > 0.5)), sil[0].shape)
    sil[0, y:y + 2, x:x + 2] = 0.0
    return sil, spheres.cameras, (y, x)


def test_hull_close_px_ignores_a_pinhole(spheres):
    """A 2 x 2 pinhole deep inside one view's silhouette carves a tunnel through the hull;
    with ``close_px=1`` the hull is node for node the one of the silhouettes without it."""
    sil, cams, (y, x) = _pinholed(spheres)
    ref = carve_hull(spheres.silhouettes, cams, voxel_px=0.75).field > 0
    holed = carve_hull(sil, cams, voxel_px=0.75).field > 0
    assert holed.sum() < ref.sum()
    ref_c = carve_hull(spheres.silhouettes, cams, voxel_px=0.75, close_px=1.0).field > 0
    closed = carve_hull(sil, cams, voxel_px=0.75, close_px=1.0).field > 0
    assert np.array_equal(closed, ref_c)
    ref_f = carve_hull(spheres.silhouettes, cams, voxel_px=0.75, fill_px=4.0).field > 0
    filled = carve_hull(sil, cams, voxel_px=0.75, fill_px=4.0)
    assert np.array_equal(filled.field > 0, ref_f) and filled.n_closed_pixels >= 4


def test_hull_field_margins_are_a_vote_over_the_sorted_views():
    """With margins (m_1, m_2) the field is min(s_1 + m_1, s_2 + m_2) of the views' sorted
    values (a slow per-point reference); (0,) is the plain minimum."""
    R, T = look_at_view_transform(2.7, [0.0, 30.0, -20.0], [0.0, 100.0, 200.0])
    cams = FoVPerspectiveCameras(R=R, T=T)
    rng = np.random.default_rng(1)
    sd = rng.normal(size=(3, 16, 20))
    P = rng.uniform(-1.0, 1.0, (40, 3))
    per_view = np.stack([hull_field(sd[i:i + 1], cams[i], P) for i in range(3)])  # (3, k)
    s = np.sort(per_view, axis=0)
    np.testing.assert_allclose(hull_field(sd, cams, P), s[0], atol=1e-12)
    np.testing.assert_allclose(hull_field(sd, cams, P, margins=(1.0, 0.25)),
                               np.minimum(s[0] + 1.0, s[1] + 0.25), atol=1e-12)
    field, plain = hull_field(sd, cams, P, margins=(1.0, 0.0), with_min=True)
    np.testing.assert_allclose(plain, s[0], atol=1e-12)


def test_hull_margins_keep_a_pinhole_and_carve_a_hole(spheres):
    """A 2 x 2 pinhole deep inside one view's silhouette carves a tunnel through the plain
    hull; with margins (1, 0) (one view must say more than a pixel outside, or two views
    outside) the hull is node for node the one without the pinhole, and the vote reports the
    nodes it kept. A hole of radius 4 px in the same view still carves."""
    sil, cams, (y, x) = _pinholed(spheres)
    plain = carve_hull(spheres.silhouettes, cams, voxel_px=0.75).field > 0
    holed = carve_hull(sil, cams, voxel_px=0.75).field > 0
    ref = carve_hull(spheres.silhouettes, cams, voxel_px=0.75, margins=(1.0, 0.0))
    voted = carve_hull(sil, cams, voxel_px=0.75, margins=(1.0, 0.0))
    tunnel = (plain & ~holed).sum()
    lost = ((ref.field > 0) & ~(voted.field > 0)).sum()  # only where a 2nd view agrees
    assert tunnel > 20 and lost < 0.2 * tunnel
    assert voted.n_vote_kept > ref.n_vote_kept
    big = spheres.silhouettes.copy()
    yy, xx = np.mgrid[:big.shape[1], :big.shape[2]]
    big[0][(yy - y) ** 2 + (xx - x) ** 2 < 16] = 0.0
    assert (carve_hull(big, cams, voxel_px=0.75, margins=(1.0, 0.0)).field > 0).sum() < \
        (ref.field > 0).sum()


def test_deep_vote_fills_the_tunnel_not_the_outline(spheres):
    """With ``vote_depth`` the vote only fills, and only deep inside its hull: the tunnel a
    2 x 2 pinhole in one view bores is mostly filled, the vote's shell of up to a pixel around
    the outline is not added (node counts near the plain hull's, well under the vote's), every
    node is inside the vote's hull, and without the pinhole nothing is kept."""
    sil, cams, _ = _pinholed(spheres)

    def n(g):
        return int((g.field > 0).sum())

    plain = carve_hull(spheres.silhouettes, cams, voxel_px=0.75)
    holed = carve_hull(sil, cams, voxel_px=0.75)
    vote = carve_hull(sil, cams, voxel_px=0.75, margins=(1.0, 0.0))
    deep = carve_hull(sil, cams, voxel_px=0.75, margins=(1.0, 0.0), vote_depth=1.5)
    tunnel = n(plain) - n(holed)
    assert tunnel > 20 and n(deep) - n(holed) > 0.6 * tunnel
    assert n(deep) < 1.03 * n(plain) and n(vote) > 1.1 * n(plain)
    assert not ((deep.field > 0) & ~(vote.field > 0)).any()  # the same grid (same vote box)
    assert deep.n_vote_kept > 0
    clean = carve_hull(spheres.silhouettes, cams, voxel_px=0.75, margins=(1.0, 0.0),
                       vote_depth=1.5)
    assert clean.n_vote_kept == 0


def test_deep_vote_options_are_validated(spheres):
    """vote_depth must be >= 0 and needs refine=1; the fit's hull_vote_depth likewise."""
    with pytest.raises(ValueError, match="vote_depth"):
        visual_hull_mesh(spheres.silhouettes, spheres.cameras, margins=(1.0, 0.0),
                         vote_depth=-1.0)
    with pytest.raises(ValueError, match="vote_depth"):
        visual_hull_mesh(spheres.silhouettes, spheres.cameras, margins=(1.0, 0.0),
                         vote_depth=1.5, refine=2)
    with pytest.raises(ValueError, match="hull_vote_depth"):
        fit_mesh_to_views(spheres, options=ViewsFitOptions(hull_vote_depth=-0.5),
                          progress=False)


def test_shortest_edge_keeps_faces_and_entries_bounded():
    """Below the entries bound the shortest edge is the face cap's (area / (0.433 e^2) =
    MAX_FACES / factor^2); above it, the model's expected entries per view at the returned
    edge equal MAX_ENTRIES_PER_PIXEL per pixel; it grows with the area and the blur."""
    from geofit.render.soft.rasterizer import TUTORIAL_BLUR_RADIUS as blur

    px = 0.02
    small = 6_000 * px * px  # 6 000 square pixels of surface
    for fac, size in ((1, (128, 128)), (2, (64, 64))):
        e = shortest_edge(small, px, fac, size, blur)
        np.testing.assert_allclose(small / (0.433 * e * e), _fit_init.MAX_FACES / fac ** 2,
                                   rtol=1e-12)
    big = 40_000 * px * px
    e = shortest_edge(big, px, 1, (128, 128), blur) / px  # pixels
    a, r = 40_000.0, math.sqrt(blur) * 64.0
    entries = a / 2 + a / (0.433 * e * e) * (_fit_init._BAND * r * e + math.pi * r * r)
    np.testing.assert_allclose(entries, _fit_init.MAX_ENTRIES_PER_PIXEL * 128 * 128,
                               rtol=1e-9)
    assert a / (0.433 * e * e) < _fit_init.MAX_FACES
    assert shortest_edge(2 * big, px, 1, (128, 128), blur) > e * px
    assert shortest_edge(big, px, 1, (128, 128), 2 * blur) > e * px


def test_shortest_edge_bounds_the_rasterizer_entries():
    """The model holds for the soft rasterizer itself: a sphere of 40 000 square pixels of
    surface, remeshed to the shortest edge, gives at most 15 % more entries per view than
    the bound (6 views of 128 px, the tutorial's blur)."""
    from geofit.render.soft import SoftRasterizationSettings, rasterize_soft
    from geofit.shapes import ico_sphere

    R, T = look_at_view_transform(2.7, [0.0, 30.0, -20.0, 10.0, 60.0, -45.0],
                                  [0.0, 60.0, 120.0, 180.0, 240.0, 300.0])
    cams = FoVPerspectiveCameras(R=R, T=T)
    px = pixel_footprint(cams, (128, 128), np.zeros(3))
    radius = math.sqrt(40_000.0 / (4.0 * math.pi)) * px
    s = ico_sphere(3)
    sphere = Mesh(s.verts * radius, s.faces)
    s_ = SoftRasterizationSettings.tutorial(128)
    e = shortest_edge(float(sphere.face_areas.sum()), px, 1, (128, 128), s_.blur_radius)
    mesh = remesh_to_length(sphere, e)
    fr = rasterize_soft(mesh, cams, s_)
    per_view = len(fr) / len(cams)
    bound = _fit_init.MAX_ENTRIES_PER_PIXEL * 128 * 128
    assert 0.7 * bound < per_view < 1.15 * bound


def test_hull_carving_options_are_validated(spheres):
    """upsample must be an integer >= 1, close_px >= 0 and margins a non-empty,
    non-increasing sequence of numbers >= 0; the fit's options likewise."""
    with pytest.raises(ValueError, match="upsample"):
        visual_hull_mesh(spheres.silhouettes, spheres.cameras, upsample=0)
    with pytest.raises(ValueError, match="close_px"):
        visual_hull_mesh(spheres.silhouettes, spheres.cameras, close_px=-1.0)
    for bad in ((), (0.0, 1.0), (-1.0,), (np.nan,), "ab", 3.0):
        with pytest.raises(ValueError, match="margins"):
            visual_hull_mesh(spheres.silhouettes, spheres.cameras, margins=bad)
    with pytest.raises(ValueError, match="hull_margins"):
        fit_mesh_to_views(spheres, options=ViewsFitOptions(hull_margins=(0.0, 1.0)),
                          progress=False)
    with pytest.raises(ValueError, match="hull_upsample"):
        fit_mesh_to_views(spheres, options=ViewsFitOptions(hull_upsample=0), progress=False)
    with pytest.raises(ValueError, match="hull_close_px"):
        fit_mesh_to_views(spheres, options=ViewsFitOptions(hull_close_px=-0.5), progress=False)
    with pytest.raises(ValueError, match="fill_px"):
        visual_hull_mesh(spheres.silhouettes, spheres.cameras, fill_px=-1.0)
    with pytest.raises(ValueError, match="hull_fill_px"):
        fit_mesh_to_views(spheres, options=ViewsFitOptions(hull_fill_px=-1.0), progress=False)
    with pytest.raises(ValueError, match="grey_px"):
        visual_hull_mesh(spheres.silhouettes, spheres.cameras, grey_px=-1.0)
    for bad in (-0.1, 0.5, 0.7):
        with pytest.raises(ValueError, match="grey_level"):
            visual_hull_mesh(spheres.silhouettes, spheres.cameras, grey_px=2.0, grey_level=bad)
    with pytest.raises(ValueError, match="hull_grey_px"):
        fit_mesh_to_views(spheres, options=ViewsFitOptions(hull_grey_px=-1.0), progress=False)
    with pytest.raises(ValueError, match="rgb_iters"):
        fit_mesh_to_views(spheres, options=ViewsFitOptions(rgb_iters=-1), progress=False)
    for name in ("rgb_weight", "rgb_silhouette", "rgb_large_steps", "rgb_color_reg",
                 "rgb_color_smooth", "rgb_inner_px", "rgb_supersample", "rgb_lr", "rgb_regularization",
                 "rgb_method"):
        with pytest.raises(ValueError, match=name):
            fit_mesh_to_views(spheres, options=ViewsFitOptions(**{name: -1}),
                              progress=False)
    for bad in (0, 1.5):
        with pytest.raises(ValueError, match="rgb_supersample"):
            fit_mesh_to_views(spheres, options=ViewsFitOptions(rgb_supersample=bad),
                              progress=False)


def test_rgb_stage_runs_after_the_silhouettes(spheres):
    """rgb_iters adds an "rgb" stage between the silhouette and the colour (and UV texture)
    stages; it moves the vertices (the RGB residual drives the geometry) and leaves them
    finite."""
    o = dict(init="sphere", silhouette_iters=4, levels=((0, 1),), remesh_rounds=0)
    base = fit_mesh_to_views(spheres, options=ViewsFitOptions(rgb_iters=0, **o),
                             progress=False)
    res = fit_mesh_to_views(spheres, options=ViewsFitOptions(rgb_iters=2, **o), progress=False)
    assert [s["name"] for s in res.stages] == ["silhouette", "rgb", "textured", "texture"]
    assert np.all(np.isfinite(res.mesh.verts))
    assert np.abs(res.mesh.verts - base.mesh.verts).max() > 0


def test_rgb_stage_keeps_the_silhouettes_when_asked(spheres):
    """rgb_silhouette > 0 adds the last level's silhouette term and regularisers to the RGB
    stage's objective: the result differs from the image term alone and stays finite."""
    o = dict(init="sphere", silhouette_iters=4, levels=((0, 1),), remesh_rounds=0, rgb_iters=2)
    alone = fit_mesh_to_views(spheres, options=ViewsFitOptions(rgb_silhouette=0.0, **o),
                              progress=False)
    both = fit_mesh_to_views(spheres, options=ViewsFitOptions(rgb_silhouette=1.0, **o),
                             progress=False)
    assert np.all(np.isfinite(both.mesh.verts))
    assert np.abs(both.mesh.verts - alone.mesh.verts).max() > 0


def test_closed_pixels_are_reported(spheres):
    """The hull counts what the closing filled, and the fit's message says it."""
    from scipy.ndimage import distance_transform_edt

    sil = spheres.silhouettes.copy()
    y, x = np.unravel_index(np.argmax(distance_transform_edt(sil[0] > 0.5)), sil[0].shape)
    sil[0, y, x] = 0.0
    h = visual_hull_mesh(sil, spheres.cameras, edge_px=2.0, close_px=1.0)
    assert h.n_closed_pixels >= 1 and visual_hull_mesh(sil, spheres.cameras).n_closed_pixels == 0


def test_rgb_stage_refines_a_given_mesh(spheres):
    """With silhouette_method="none" the RGB stage refines the given initial mesh, then the
    colour stages run."""
    from geofit import ico_sphere

    init = ico_sphere(2)
    res = fit_mesh_to_views(spheres, options=ViewsFitOptions(
        init=init, silhouette_method="none", rgb_iters=2, rgb_silhouette=1.0,
        texture="vertex"), progress=False)
    assert [s["name"] for s in res.stages] == ["rgb", "textured"]
    assert np.abs(res.mesh.verts - init.verts).max() > 0
    assert np.all(np.isfinite(res.mesh.verts))


def test_close_unsupported_handles_fills_a_hole_in_a_one_node_wall():
    """A wall one node thick with a 2 x 2 hole barely outside every silhouette (the tunnels
    that carving an open cylinder's zero-thickness wall leaves) is filled by the bridging
    lines, which a closing with a ball cannot do; the nodes beside the flat wall stay
    empty, and the same hole seen through (far outside a silhouette) stays open."""
    from geofit.structures.visual_hull import HullGrid, close_unsupported_handles

    field = np.full((14, 14, 7), -5.0)
    field[2:12, 2:12, 3] = 1.0      # the wall
    field[6:8, 6:8, 3] = -0.4       # the hole
    field[:, :, 2] = field[:, :, 4] = -0.6   # beside the wall: barely outside too
    out = close_unsupported_handles(HullGrid(field, np.zeros(3), 1.0, 1.0), radius_px=2.0)
    hole = np.zeros(field.shape, bool)
    hole[6:8, 6:8, 3] = True
    assert np.array_equal(out.filled, hole)
    field[6:8, 6:8, 3] = -3.0
    assert close_unsupported_handles(HullGrid(field, np.zeros(3), 1.0, 1.0),
                                     radius_px=2.0).n_filled == 0


def test_visual_hull_mesh_close_handles_lowers_the_open_cylinders_genus():
    """The hull of an open cylinder (a zero-thickness tube, genus 0) comes out of the
    carving with handles through its thin wall; closing them lowers the genus, which
    genus_before / genus_after report, and a fill that would not lower it is not kept."""
    from geofit.ops import topology
    from geofit.shapes import open_cylinder

    ds = tutorial_views(4, mesh=_colored(open_cylinder()), num_views=20, image_size=64,
                        num_held_out=1)
    plain = visual_hull_mesh(ds.silhouettes, ds.cameras, fill_px=9.0)
    h = visual_hull_mesh(ds.silhouettes, ds.cameras, fill_px=9.0, close_handles=4.0)
    g0 = topology(plain.mesh, self_intersections=False).genus
    assert h.genus_before is not None and h.genus_before > h.genus_after >= 1
    assert h.n_filled > 0 and plain.genus_before is None and plain.n_filled == 0
    assert topology(h.mesh, self_intersections=False).genus < g0


def test_decimate_parts_keeps_every_part():
    """Each part is decimated on its own to at least 48 faces (or kept as it is): a part
    far smaller than the edge keeps a shape, the parts' count is kept."""
    from geofit.fit.init import _decimate_parts
    from geofit.ops import topology
    from geofit.shapes import ico_sphere

    big, small = ico_sphere(4), ico_sphere(3)
    m = Mesh(np.concatenate([big.verts, 0.05 * small.verts + 3.0]),
             np.concatenate([big.faces, small.faces + big.n_verts]))
    out = _decimate_parts(m, 0.5)
    r = topology(out, self_intersections=False)
    assert (r.n_components, r.genus) == (2, 0)
    far = out.verts[:, 0] > 2.0
    n_small = int(far[out.faces[:, 0]].sum())
    assert n_small >= 48 and out.n_faces - n_small < big.n_faces


def test_close_handles_and_per_part_options_are_validated(spheres):
    """close_handles must be >= 0 and per_part a bool, in visual_hull_mesh and in the fit's
    options."""
    with pytest.raises(ValueError, match="close_handles"):
        visual_hull_mesh(spheres.silhouettes, spheres.cameras, close_handles=-1.0)
    with pytest.raises(TypeError, match="per_part"):
        visual_hull_mesh(spheres.silhouettes, spheres.cameras, per_part=1)
    with pytest.raises(ValueError, match="hull_close_handles"):
        fit_mesh_to_views(spheres, options=ViewsFitOptions(hull_close_handles=-2.0),
                          progress=False)
    with pytest.raises(TypeError, match="hull_per_part"):
        fit_mesh_to_views(spheres, options=ViewsFitOptions(hull_per_part="yes"),
                          progress=False)


def test_fit_reports_the_handles_it_closed():
    """With hull_close_handles the fit's first history note and its message say how many
    handles of the hull were closed and how many grid nodes filled."""
    from geofit.shapes import open_cylinder

    ds = tutorial_views(4, mesh=_colored(open_cylinder()), num_views=20, image_size=64,
                        num_held_out=1)
    fit = fit_mesh_to_views(ds, options=ViewsFitOptions(
        hull_close_handles=4.0, silhouette_method="none", texture="vertex"), progress=False)
    ev = fit.history.events[0]
    assert ev["hull_handles_closed"] > 0 and ev["hull_filled_nodes"] > 0
    assert ev["hull_genus"] > ev["hull_handles_closed"]
    assert "handles no silhouette supports closed" in fit.message


def _grey_slit_disk():
    """(1, 48, 48) soft silhouette: a disk with a soft ramp (0.5 at r = 22, 0 from r = 23),
    a grey slit 2 px wide at 0.05 running from its centre across its outline (a K-nearest
    cut along an inner occlusion contour), and a hole seen through (0)."""
    yy, xx = np.mgrid[:48, :48]
    r = np.hypot(yy - 24, xx - 24)
    sil = np.clip((22.0 - r) / 2.0 + 0.5, 0.0, 1.0)
    sil[23:25, 24:48] = np.minimum(sil[23:25, 24:48], 0.05)
    sil[(yy - 32) ** 2 + (xx - 16) ** 2 < 16] = 0.0
    return sil[None], r, (yy - 32) ** 2 + (xx - 16) ** 2 < 16


def test_grey_cores_cover_a_grey_slit_and_keep_the_ramp_and_holes():
    """The grey slit's pixels farther than the radius from every empty pixel are cores; the
    ramp outside the 0.5 outline, the slit's end within the radius of the background and
    the hole are not; a binary mask has no core outside itself; fill_grey_cores raises the
    cores at or below 0.5 to 1 and, given images, only those whose colour is not the
    background's."""
    from geofit.structures.visual_hull import fill_grey_cores, grey_cores

    sil, r, hole = _grey_slit_disk()
    core = grey_cores(sil, 2.0)[0]
    assert core[23:25, 26:40].all()                  # the slit inside
    assert not core[23:25, 45:48].any()              # its end, within 2 px of the background
    assert not core[(sil[0] <= 0.5) & (r > 21.5)].any() and not core[hole].any()
    low = core & (sil[0] <= 0.5)
    filled, n = fill_grey_cores(sil, 2.0)
    np.testing.assert_array_equal(filled[0][low], 1.0)
    np.testing.assert_array_equal(filled[0][~low], sil[0][~low])
    assert n == int(low.sum()) > 0
    img = np.ones(sil.shape + (3,))                  # white background everywhere ...
    img[0, 23:25, 30:48] = 0.4                       # ... but where faces cover the slit
    filled, n = fill_grey_cores(sil, 2.0, images=img, background=np.ones(3))
    seen = low & (img[0, ..., 0] < 1.0)
    assert n == int(seen.sum()) > 0 and n < int(low.sum())
    np.testing.assert_array_equal(filled[0][seen], 1.0)
    np.testing.assert_array_equal(filled[0][~seen], sil[0][~seen])
    with pytest.raises(ValueError, match="images"):
        fill_grey_cores(sil, 2.0, images=img[:, :10], background=np.ones(3))
    mask = (sil > 0.5).astype(np.float64)
    assert not (grey_cores(mask, 2.0) & (mask <= 0.5)).any()


def test_grey_cores_are_validated():
    from geofit.structures.visual_hull import grey_cores

    sil = _grey_slit_disk()[0]
    with pytest.raises(ValueError, match="silhouettes"):
        grey_cores(sil[0])
    with pytest.raises(ValueError, match="radius_px"):
        grey_cores(sil, 0.0)
    with pytest.raises(ValueError, match="level"):
        grey_cores(sil, 2.0, -0.1)


def test_silhouette_grey_px_covers_the_targets_grey_cores(spheres):
    """options.silhouette_grey_px raises a grey core planted in a target to 1, the hull keeps
    it and the fit's first note says how many pixels it covered; a negative value is
    refused."""
    from dataclasses import replace

    from scipy.ndimage import distance_transform_edt

    sil = spheres.silhouettes.copy()
    y, x = np.unravel_index(np.argmax(distance_transform_edt(sil[0] > 0.5)), sil[0].shape)
    sil[0, y - 1:y + 2, x - 1:x + 2] = 0.2  # grey, far from every empty pixel
    ds = replace(spheres, silhouettes=sil)
    opts = dict(silhouette_method="none", texture="vertex")
    fit = fit_mesh_to_views(ds, options=ViewsFitOptions(silhouette_grey_px=2.0, **opts),
                            progress=False)
    assert "9 grey target pixels covered" in fit.message
    with pytest.raises(ValueError, match="silhouette_grey_px"):
        fit_mesh_to_views(ds, options=ViewsFitOptions(silhouette_grey_px=-1.0, **opts),
                          progress=False)
