"""The code cells of PyTorch3D's six tutorials in their call forms, on geofit.pytorch3d.

Changes from the notebooks: ``pytorch3d.*`` imports -> ``geofit.pytorch3d.*``, ``import torch``
-> ``import geofit.pytorch3d.torch as torch``, the tutorials' helper files ->
:mod:`geofit.pytorch3d.tutorial_utils`; the six notebooks' imports gathered once at the top of
this file; tutorials 1 and 4's cells, tutorial 5's model and loop and tutorial 6's model and
loop live in benchmarks/third_party/p3d_tutorials.py (one copy of PyTorch3D's code, which the
benchmarks also run); sizes reduced (steps, images, samples); data: geofit's procedural
stand-ins written as OBJ files into ``tmp_path`` (the tests run offline). Each test then checks something the tutorial relies on. ``tests/test_pytorch3d_notebooks.py``
runs PyTorch3D's own notebooks the same way when they are given.
"""
from __future__ import annotations

import os

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from _helpers import benchmark_module  # noqa: E402

import geofit  # noqa: E402
import geofit.pytorch3d.renderer as p3d_renderer  # noqa: E402
import geofit.pytorch3d.torch as torch  # noqa: E402
from geofit.fit.nerf import sample_images_at_xys  # noqa: E402
from geofit.pytorch3d.io import load_obj, load_objs_as_meshes  # noqa: E402
from geofit.pytorch3d.renderer import (  # noqa: E402
    AlphaCompositor,
    EmissionAbsorptionRaymarcher,
    FoVOrthographicCameras,
    FoVPerspectiveCameras,
    ImplicitRenderer,
    Materials,
    MeshRasterizer,
    MeshRenderer,
    MonteCarloRaysampler,
    NDCGridRaysampler,
    NDCMultinomialRaysampler,
    NormWeightedCompositor,
    PointLights,
    PointsRasterizationSettings,
    PointsRasterizer,
    PointsRenderer,
    PulsarPointsRenderer,
    RasterizationSettings,
    SoftPhongShader,
    TexturesVertex,
    VolumeRenderer,
    look_at_view_transform,
)
from geofit.pytorch3d.structures import Meshes, Pointclouds, Volumes  # noqa: E402
from geofit.pytorch3d.transforms import so3_exp_map  # noqa: E402
from geofit.pytorch3d.tutorial_utils import generate_cow_renders, image_grid  # noqa: E402
from geofit.pytorch3d.vis.plotly_vis import (  # noqa: E402
    AxisArgs,
    plot_batch_individually,
    plot_scene,
)
from geofit.pytorch3d.vis.texture_vis import texturesuv_image_matplotlib  # noqa: E402

#: Tutorials 1 and 4's cells, 5's and 6's models and loops: one copy (the benchmarks run it).
P3D = benchmark_module("third_party/p3d_tutorials")


@pytest.fixture
def dolphin_obj(tmp_path):
    path = tmp_path / "dolphin.obj"
    geofit.save_obj(path, geofit.data.procedural_target())
    return str(path)


@pytest.fixture
def cow_obj(tmp_path):
    (tmp_path / "cow_mesh").mkdir()
    path = tmp_path / "cow_mesh" / "cow.obj"
    geofit.save_obj(path, geofit.data.procedural_textured_mesh(12, 24, 64))
    return str(path)


def _ball_renders(renderer, n_views: int, azim_span: float, grid: int, density: float, rgb):
    """The volume and NeRF tests' dataset (the notebooks' ``generate_cow_renders`` is their
    helper file, not PyTorch3D): ``n_views`` cameras at distance 2.7 around the y axis
    (azimuths over ``azim_span`` degrees) and ``renderer``'s images of a ball of constant
    ``density`` and colour ``rgb`` in a ``grid``^3 volume of side 2: ``(cameras, (n_views, H,
    W, 4) RGB + silhouette)``."""
    R, T = look_at_view_transform(
        dist=2.7, elev=0.0, azim=np.linspace(-azim_span / 2, azim_span / 2, n_views) + 180.0)
    cameras = FoVPerspectiveCameras(R=R, T=T)
    g = np.linspace(-1, 1, grid)
    ball = (g[:, None, None] ** 2 + g[None, :, None] ** 2 + g[None, None, :] ** 2) < 0.5
    volumes = Volumes(
        densities=np.broadcast_to(ball * density, (n_views, 1, grid, grid, grid)),
        features=np.broadcast_to(np.stack([ball * c for c in rgb]), (n_views, 3, grid, grid, grid)),
        voxel_size=2.0 / grid)
    return cameras, renderer(cameras=cameras, volumes=volumes)[0]


def test_tutorial1_deform_source_mesh_to_target_mesh(dolphin_obj, tmp_path):
    """The deform tutorial's cells (benchmarks/third_party/p3d_tutorials.py); 20 steps lower
    the chamfer loss and the mesh is saved."""
    *steps, final = P3D.tutorial1(os.path.join(dolphin_obj), 20, plot_period=10,
                                  out_dir=str(tmp_path))
    chamfer_losses = final["chamfer_losses"]

    assert len(steps) == 21 and steps[-1]["description"].startswith("total_loss = ")
    assert np.mean(chamfer_losses[-3:]) < 0.5 * chamfer_losses[0]
    saved = geofit.load_mesh(final["final_obj"])
    np.testing.assert_allclose(saved.verts, final["final_verts"].detach().numpy(), rtol=1e-12)
    assert saved.n_faces == 5120


def test_tutorial2_render_textured_meshes(cow_obj):
    """The render tutorial's cells at 64 px; the light behind the cow darkens the image."""

    device = torch.device("cuda:0") if torch.cuda.is_available() else torch.device("cpu")
    obj_filename = cow_obj
    mesh = load_objs_as_meshes([obj_filename], device=device)
    plt.figure(figsize=(7, 7))
    texture_image = mesh.textures.maps_padded()
    plt.imshow(texture_image.squeeze().cpu().numpy())
    plt.axis("off")
    plt.figure(figsize=(7, 7))
    texturesuv_image_matplotlib(mesh.textures, subsample=None)
    plt.axis("off")
    R, T = look_at_view_transform(2.7, 0, 180)
    cameras = FoVPerspectiveCameras(device=device, R=R, T=T)
    raster_settings = RasterizationSettings(image_size=64, blur_radius=0.0, faces_per_pixel=1)
    lights = PointLights(device=device, location=[[0.0, 0.0, -3.0]])
    renderer = MeshRenderer(
        rasterizer=MeshRasterizer(cameras=cameras, raster_settings=raster_settings),
        shader=SoftPhongShader(device=device, cameras=cameras, lights=lights))
    images = renderer(mesh)
    plt.imshow(images[0, ..., :3].cpu().numpy())
    front = images[0, ..., :3].cpu().numpy().copy()
    covered = images[0, ..., 3].cpu().numpy() > 0.5
    lights.location = torch.tensor([0.0, 0.0, +1.0], device=device)[None]
    images = renderer(mesh, lights=lights)
    behind = images[0, ..., :3].cpu().numpy()
    R, T = look_at_view_transform(dist=2.7, elev=10, azim=-150)
    cameras = FoVPerspectiveCameras(device=device, R=R, T=T)
    lights.location = torch.tensor([[2.0, 2.0, -2.0]], device=device)
    materials = Materials(device=device, specular_color=[[0.0, 1.0, 0.0]], shininess=10.0)
    images = renderer(mesh, lights=lights, materials=materials, cameras=cameras)
    batch_size = 20
    meshes = mesh.extend(batch_size)
    elev = torch.linspace(0, 180, batch_size)
    azim = torch.linspace(-180, 180, batch_size)
    R, T = look_at_view_transform(dist=2.7, elev=elev, azim=azim)
    cameras = FoVPerspectiveCameras(device=device, R=R, T=T)
    lights.location = torch.tensor([[0.0, 0.0, -3.0]], device=device)
    images = renderer(meshes, cameras=cameras, lights=lights)
    image_grid(images.cpu().numpy(), rows=4, cols=5, rgb=True)
    verts, faces_idx, _ = load_obj(obj_filename)
    faces = faces_idx.verts_idx
    verts_rgb = torch.ones_like(verts)[None]
    textures = TexturesVertex(verts_features=verts_rgb.to(device))
    mesh = Meshes(verts=[verts.to(device)], faces=[faces.to(device)], textures=textures)
    mesh_batch = Meshes(verts=[verts.to(device), (verts + 2).to(device)],
                        faces=[faces.to(device), faces.to(device)])
    mesh_4 = mesh_batch.extend(2)
    plt.close("all")

    assert texture_image.shape[0] == 1 and texture_image.shape[-1] == 3
    assert images.shape == (20, 64, 64, 4)
    assert behind[covered].mean() < front[covered].mean()
    assert len(mesh_4) == 4 and mesh_4.num_verts_per_mesh().tolist()[1] == len(verts)
    fig = plot_scene({"subplot1": {"cow_mesh": mesh}})
    assert fig.data[0].type == "mesh3d" and len(fig.data[0].vertexcolor) == len(verts)
    fig = plot_scene({"subplot1": {"cow_mesh1": mesh_batch[0]}, "subplot2": {"cow_mesh2":
                                                                             mesh_batch[1]}})
    assert len(fig.data) == 2
    fig = plot_batch_individually(mesh_4)
    fig.update_layout(height=1000, width=500)
    fig2 = plot_scene({"cow_plot1": {"cows": mesh_batch}},
                      xaxis={"backgroundcolor": "rgb(200, 200, 230)"},
                      yaxis={"backgroundcolor": "rgb(230, 200, 200)"},
                      zaxis={"backgroundcolor": "rgb(200, 230, 200)"},
                      axis_args=AxisArgs(showgrid=True))
    fig3 = plot_batch_individually(mesh_4, ncols=2, subplot_titles=["cow1", "cow2", "cow3",
                                                                   "cow4"],
                                   xaxis={"backgroundcolor": "rgb(200, 200, 230)"},
                                   axis_args=AxisArgs(showgrid=True))
    assert len(fig.data) == 4 and len(fig3.data) == 4
    assert len(fig2.data[0].x) == 2 * len(verts)  # one trace for the batch
    assert fig2.layout.scene.xaxis.backgroundcolor == "rgb(200, 200, 230)"
    assert fig2.layout.scene.xaxis.showgrid


def test_tutorial3_render_colored_points(tmp_path):
    """The point-cloud tutorial's cells on a random coloured cloud at 64 px."""
    import geofit.pytorch3d.torch.nn.functional as F  # noqa: F401 - the tutorial's import

    rng = np.random.default_rng(0)
    obj_filename = str(tmp_path / "pointcloud.npz")
    np.savez(obj_filename, verts=rng.normal(size=(3000, 3)) * 3.0, rgb=rng.random((3000, 3)))
    device = torch.device("cuda:0") if torch.cuda.is_available() else torch.device("cpu")
    pointcloud = np.load(obj_filename)
    verts = torch.Tensor(pointcloud["verts"]).to(device)
    rgb = torch.Tensor(pointcloud["rgb"]).to(device)
    point_cloud = Pointclouds(points=[verts], features=[rgb])
    R, T = look_at_view_transform(20, 10, 0)
    cameras = FoVOrthographicCameras(device=device, R=R, T=T, znear=0.01)
    raster_settings = PointsRasterizationSettings(image_size=64, radius=0.003,
                                                  points_per_pixel=10)
    rasterizer = PointsRasterizer(cameras=cameras, raster_settings=raster_settings)
    renderer = PointsRenderer(rasterizer=rasterizer, compositor=AlphaCompositor())
    images = renderer(point_cloud)
    plt.imshow(images[0, ..., :3].cpu().numpy())
    renderer = PointsRenderer(rasterizer=rasterizer,
                              compositor=AlphaCompositor(background_color=(0, 0, 1)))
    images_blue = renderer(point_cloud)
    renderer = PointsRenderer(
        rasterizer=PointsRasterizer(cameras=cameras, raster_settings=raster_settings),
        compositor=NormWeightedCompositor())
    images_w = renderer(point_cloud)
    renderer = PointsRenderer(
        rasterizer=PointsRasterizer(cameras=cameras, raster_settings=raster_settings),
        compositor=NormWeightedCompositor(background_color=(1, 0, 0)))
    images_red = renderer(point_cloud)
    point_cloud_batch = Pointclouds(points=[verts, verts + 2],
                                    features=[rgb, torch.zeros_like(rgb)])
    plt.close("all")

    assert images.shape == (1, 64, 64, 3) and images_w.shape == (1, 64, 64, 3)
    empty = images_blue.numpy()[0].sum(-1) == 1.0
    empty &= np.all(images_blue.numpy()[0] == [0.0, 0.0, 1.0], axis=-1)
    assert empty.any() and np.all(images_red.numpy()[0][empty] == [1.0, 0.0, 0.0])
    assert len(point_cloud_batch[1]) == 1
    with pytest.raises(NotImplementedError, match="NormWeightedCompositor"):
        PulsarPointsRenderer(
            rasterizer=PointsRasterizer(cameras=cameras, raster_settings=raster_settings),
            n_channels=4).to(device)
    bg = torch.tensor([0.0, 1.0, 0.0, 1.0], dtype=torch.float32, device=device)
    assert bg.dtype == np.float64  # values are float64 whatever the dtype asked
    fig = plot_scene({"Pointcloud": {"person": point_cloud_batch[0],
                                     "person2": point_cloud_batch[1]}})
    fig2 = plot_batch_individually(point_cloud_batch, ncols=2)
    fig2.update_layout(height=500, width=500)
    fig3 = plot_batch_individually(point_cloud_batch,
                                   xaxis={"backgroundcolor": "rgb(200, 200, 230)"},
                                   subplot_titles=["Pointcloud1", "Pointcloud2"],
                                   axis_args=AxisArgs(showgrid=True))
    assert [d.type for d in fig.data] == ["scatter3d", "scatter3d"]
    assert fig.data[1].marker.color[0] == "rgb(0,0,0)"  # the all-black second cloud
    assert len(fig2.data) == 2 and fig3.layout.annotations[1].text == "Pointcloud2"


def test_tutorial4_fit_textured_mesh(cow_obj, tmp_path):
    """fit_textured_mesh's cells (benchmarks/third_party/p3d_tutorials.py) at 32 px and 6
    steps per loop: both losses go down, the colours get a gradient, the prediction is saved."""
    np.random.seed(0)
    *steps, final = P3D.tutorial4(cow_obj, 32, 6, plot_period=5, out_dir=str(tmp_path))
    sil_values, losses = final["sil_values"], final["losses"]

    assert len(steps) == 13 and final["N"] > 0
    assert steps[-1]["description"].startswith("total_loss")
    assert np.mean(sil_values[-2:]) < sil_values[0]
    assert np.mean(losses["rgb"]["values"][-2:]) < losses["rgb"]["values"][0]
    assert np.abs(final["sphere_verts_rgb"].data - 0.5).max() > 1e-4  # the colours moved
    assert geofit.load_mesh(final["final_obj"]).n_verts == 2562


def test_tutorial5_fit_textured_volume():
    """fit_textured_volume's model, huber and Adam loop (with its 10x learning-rate drop;
    benchmarks/third_party/p3d_tutorials.py) on a 16^3 volume and 8 views of 16 px rendered from
    a known volume: the loss goes down."""

    torch.manual_seed(0)
    render_size = 16
    volume_extent_world = 3.0
    raysampler = NDCMultinomialRaysampler(image_width=render_size, image_height=render_size,
                                          n_pts_per_ray=24, min_depth=0.1,
                                          max_depth=volume_extent_world)
    raymarcher = EmissionAbsorptionRaymarcher()
    renderer = VolumeRenderer(raysampler=raysampler, raymarcher=raymarcher)
    # the dataset: a ball of colour rendered by the same renderer
    target_cameras, rendered = _ball_renders(renderer, 8, 360.0, 16, 0.9, (0.9, 0.2, 0.5))
    target_images, target_silhouettes = rendered[..., :3], rendered[..., 3]

    *steps, final = P3D.tutorial5(renderer, target_cameras, target_images, target_silhouettes,
                                  volume_extent_world=volume_extent_world, volume_size=16,
                                  batch_size=4, n_iter=20, n_shown=4, n_frames=3)
    volume_model, losses = final["volume_model"], final["losses"]
    frames, rotating_volume_frames = final["frames"], final["rotating_volume_frames"]

    assert len(steps) == 21
    assert len(volume_model.parameters()) == 2
    assert np.mean(losses[-3:]) < 0.8 * losses[0]
    assert frames.shape == (4, 16, 16, 3)
    assert rotating_volume_frames.shape == (3, 16, 16, 3)
    # the fitted ball is in view of the turning camera (it looks at the origin from 2.7)
    assert float(rotating_volume_frames.max()) > 0.3


def test_tutorial5_and_6_data_generate_cow_renders():
    """The tutorials' helper unpacks as ``cameras, images, silhouettes`` tensors, and the
    loops' camera batching (``target_cameras.R[batch_idx]``...) works on them."""

    device = torch.device("cpu")
    target_cameras, target_images, target_silhouettes = generate_cow_renders(
        num_views=6, azimuth_range=180, image_size=16)
    target_cameras = target_cameras.to(device)
    target_images = target_images.to(device)
    target_silhouettes = target_silhouettes.to(device)
    batch_idx = torch.randperm(len(target_cameras))[:3]
    batch_cameras = FoVPerspectiveCameras(
        R=target_cameras.R[batch_idx], T=target_cameras.T[batch_idx],
        znear=target_cameras.znear[batch_idx], zfar=target_cameras.zfar[batch_idx],
        aspect_ratio=target_cameras.aspect_ratio[batch_idx], fov=target_cameras.fov[batch_idx],
        device=device)
    assert len(target_images) == 6 and target_images.shape == (6, 16, 16, 3)
    assert target_silhouettes.shape == (6, 16, 16)
    assert set(np.unique(target_silhouettes.numpy())) == {0.0, 1.0}
    np.testing.assert_array_equal(batch_cameras.R, target_cameras.R[batch_idx.numpy()])
    assert float(target_images[batch_idx][0].max()) > 0.1  # the cow is in every view


def test_tutorial6_fit_simple_neural_radiance_field():
    """The NeRF tutorial's HarmonicEmbedding, NeuralRadianceField, huber and Adam loop as
    written (benchmarks/third_party/p3d_tutorials.py), at a tiny size (8 frequencies, 16 hidden units, 4 views of 16 px, 64 rays of 16
    samples, 40 steps) on renders of a known volume; ``sample_images_at_mc_locs`` (grid_sample)
    is geofit's ``sample_images_at_xys``. The loop runs; the gradient it follows equals
    central differences of the loss on fixed rays."""

    torch.manual_seed(1)
    device = torch.device("cuda:0") if torch.cuda.is_available() else torch.device("cpu")
    target_cameras, truth = _ball_renders(VolumeRenderer(
        raysampler=NDCMultinomialRaysampler(image_width=16, image_height=16, n_pts_per_ray=32,
                                            min_depth=0.1, max_depth=3.0),
        raymarcher=EmissionAbsorptionRaymarcher()), 4, 180.0, 12, 0.8, (0.9, 0.3, 0.1))
    target_images, target_silhouettes = truth[..., :3], truth[..., 3]

    HarmonicEmbedding, NeuralRadianceField, huber, sample_images_at_mc_locs = \
        P3D.tutorial6_cells(torch, p3d_renderer)

    raysampler_mc = MonteCarloRaysampler(min_x=-1.0, max_x=1.0, min_y=-1.0, max_y=1.0,
                                         n_rays_per_image=64, n_pts_per_ray=16, min_depth=0.1,
                                         max_depth=3.0)
    raymarcher = EmissionAbsorptionRaymarcher()
    renderer_mc = ImplicitRenderer(raysampler=raysampler_mc, raymarcher=raymarcher)
    neural_radiance_field = NeuralRadianceField(n_harmonic_functions=8, n_hidden_neurons=16)
    def held_out_loss():  # fixed rays through all views (not in the tutorial: the test's check)
        with torch.no_grad():
            out, rays = renderer_mc(cameras=target_cameras,
                                    volumetric_function=neural_radiance_field, seed=0)
        ref = sample_images_at_mc_locs(truth, rays.xys)
        return float(huber(out, ref).abs().mean())

    before = held_out_loss()
    *_, last = P3D.tutorial6(renderer_mc, neural_radiance_field, target_cameras, target_images,
                             target_silhouettes, huber, sample_images_at_mc_locs, lr=1e-3,
                             batch_size=2, n_iter=40)
    losses, batch_idx, sampled_rays = last["losses"], last["batch_idx"], last["sampled_rays"]

    assert len(neural_radiance_field.parameters()) == 10
    # grid_sample (the tutorial's helper) samples as geofit's sample_images_at_xys
    np.testing.assert_allclose(
        sample_images_at_mc_locs(target_images[batch_idx], sampled_rays.xys).numpy(),
        sample_images_at_xys(target_images.numpy()[batch_idx.numpy()],
                             sampled_rays.xys.numpy()), atol=1e-12)
    # the full render and the rotating views: batched_forward, NDCGridRaysampler, so3_exp_map
    renderer_grid = ImplicitRenderer(raysampler=NDCGridRaysampler(
        image_height=8, image_width=8, n_pts_per_ray=16, min_depth=0.1, max_depth=3.0),
        raymarcher=raymarcher)
    logRs = torch.zeros(2, 3, device=device)
    logRs[:, 1] = torch.linspace(-3.14, 3.14, 2, device=device)
    Rs = so3_exp_map(logRs)
    Ts = torch.zeros(2, 3, device=device)
    Ts[:, 2] = 2.7
    with torch.no_grad():
        frames = [renderer_grid(cameras=FoVPerspectiveCameras(
            R=R[None], T=T[None], znear=target_cameras.znear[0], zfar=target_cameras.zfar[0],
            aspect_ratio=target_cameras.aspect_ratio[0], fov=target_cameras.fov[0],
            device=device), volumetric_function=neural_radiance_field.batched_forward)[0][..., :3]
            for R, T in zip(Rs, Ts)]
        direct = renderer_grid(cameras=FoVPerspectiveCameras(R=Rs[:1], T=Ts[:1]),
                               volumetric_function=neural_radiance_field)[0]
    rotating_nerf_frames = torch.cat(frames)
    assert rotating_nerf_frames.shape == (2, 8, 8, 3)
    np.testing.assert_allclose(rotating_nerf_frames.numpy()[0], direct.numpy()[0, ..., :3],
                               atol=1e-12)  # batched_forward = forward
    assert np.all(np.isfinite(losses)) and held_out_loss() != before
    assert float(neural_radiance_field.density_layer[0].bias.data[0]) != -1.5

    # the gradient the loop followed, checked by central differences on fixed rays (density
    # bias raised to 0.3 so that the field is not empty and every term has a gradient)
    neural_radiance_field.density_layer[0].bias.data[0] = 0.3
    params = neural_radiance_field.parameters()
    for p in params:
        p.grad = None
    out, rays = renderer_mc(cameras=target_cameras, volumetric_function=neural_radiance_field,
                            seed=0)
    ref = sample_images_at_mc_locs(truth, rays.xys)
    huber(out, ref).abs().mean().backward()

    def fixed_ray_loss():
        with torch.no_grad():
            o, _ = renderer_mc(cameras=target_cameras,
                               volumetric_function=neural_radiance_field, seed=0)
        return float(huber(o, ref).abs().mean())

    for p, k in ((params[0], 5), (params[-1], 0), (params[-4], 2)):  # a few coordinates
        g = p.grad.numpy().ravel()[k]
        flat = p.data.reshape(-1)
        flat[k] += 1e-6
        up = fixed_ray_loss()
        flat[k] -= 2e-6
        down = fixed_ray_loss()
        flat[k] += 1e-6
        np.testing.assert_allclose(g, (up - down) / 2e-6, rtol=1e-5, atol=1e-10)
