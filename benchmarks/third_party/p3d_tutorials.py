# Copyright (c) Meta Platforms, Inc. and affiliates. All rights reserved.
# PyTorch3D's tutorial code (BSD licence: LICENSE-pytorch3d beside this file); see README.md.
"""PyTorch3D's tutorials 1 (deform_source_mesh_to_target_mesh) and 4 (fit_textured_mesh), the
model, loop and renders of tutorial 5 (fit_textured_volume) and the model cells and loop of
tutorial 6 (fit_simple_neural_radiance_field), as written, imports changed to
``geofit.pytorch3d`` and ``geofit.pytorch3d.torch``: the one copy that
benchmarks/pytorch3d_port.py runs at full size (benchmarks/peers/pytorch3d_tutorials.py runs
tutorial 6's model on PyTorch itself) and tests/test_pytorch3d_tutorials.py at reduced size.

Each tutorial is a generator: it yields once when the cells before the loop have run and then
after each step of a loop (a dict of the notebook's variables), so that a caller can time the
loop body alone and evaluate between steps. Exhausting it runs the last cell (the final mesh
back in the target's frame, saved as ``final_model.obj`` in ``out_dir`` when one is given).
``plot_period=None`` skips the notebook's plots (a benchmark times the loop without them).
"""
from __future__ import annotations

import os

import matplotlib.pyplot as plt
import numpy as np

import geofit.pytorch3d.torch as torch
from geofit.pytorch3d.io import load_obj, load_objs_as_meshes, save_obj
from geofit.pytorch3d.loss import (
    chamfer_distance,
    mesh_edge_loss,
    mesh_laplacian_smoothing,
    mesh_normal_consistency,
)
from geofit.pytorch3d.ops import sample_points_from_meshes
from geofit.pytorch3d.renderer import (
    FoVPerspectiveCameras,
    MeshRasterizer,
    MeshRenderer,
    OpenGLPerspectiveCameras,
    PointLights,
    RasterizationSettings,
    SoftPhongShader,
    SoftSilhouetteShader,
    TexturesVertex,
    look_at_view_transform,
)
from geofit.pytorch3d.structures import Meshes, Volumes
from geofit.pytorch3d.transforms import so3_exponential_map
from geofit.pytorch3d.tutorial_utils import image_grid
from geofit.pytorch3d.utils import ico_sphere

__all__ = ["tutorial1", "tutorial4", "tutorial5", "tutorial6", "tutorial6_cells"]


def tutorial1(trg_obj: str, Niter: int, *, plot_period: int | None = None,
              out_dir: str | None = None):
    """Tutorial 1's cells on the target ``trg_obj`` for ``Niter`` SGD steps (see the module)."""
    torch.manual_seed(0)
    device = torch.device("cuda:0") if torch.cuda.is_available() else torch.device("cpu")
    verts, faces, aux = load_obj(trg_obj)
    faces_idx = faces.verts_idx.to(device)
    verts = verts.to(device)
    center = verts.mean(0)
    verts = verts - center
    scale = max(verts.abs().max(0)[0])
    verts = verts / scale
    trg_mesh = Meshes(verts=[verts], faces=[faces_idx])
    src_mesh = ico_sphere(4, device)

    def plot_pointcloud(mesh, title=""):
        points = sample_points_from_meshes(mesh, 5000)
        x, y, z = points.clone().detach().cpu().squeeze().unbind(1)
        fig = plt.figure(figsize=(5, 5))
        ax = fig.add_subplot(projection="3d")  # the notebook's Axes3D(fig)
        ax.scatter3D(x, z, -y)
        ax.set_title(title)
        ax.view_init(190, 30)
        plt.close(fig)

    if plot_period:
        plot_pointcloud(trg_mesh, "Target mesh")
        plot_pointcloud(src_mesh, "Source mesh")
    deform_verts = torch.full(src_mesh.verts_packed().shape, 0.0, device=device,
                              requires_grad=True)
    optimizer = torch.optim.SGD([deform_verts], lr=1.0, momentum=0.9)
    w_chamfer = 1.0
    w_edge = 1.0
    w_normal = 0.01
    w_laplacian = 0.1
    chamfer_losses, laplacian_losses, edge_losses, normal_losses = [], [], [], []
    state = {"src_mesh": src_mesh, "deform_verts": deform_verts, "scale": scale,
             "center": center, "chamfer_losses": chamfer_losses}
    yield state
    for i in range(Niter):
        optimizer.zero_grad()
        new_src_mesh = src_mesh.offset_verts(deform_verts)
        sample_trg = sample_points_from_meshes(trg_mesh, 5000)
        sample_src = sample_points_from_meshes(new_src_mesh, 5000)
        loss_chamfer, _ = chamfer_distance(sample_trg, sample_src)
        loss_edge = mesh_edge_loss(new_src_mesh)
        loss_normal = mesh_normal_consistency(new_src_mesh)
        loss_laplacian = mesh_laplacian_smoothing(new_src_mesh, method="uniform")
        loss = (loss_chamfer * w_chamfer + loss_edge * w_edge + loss_normal * w_normal
                + loss_laplacian * w_laplacian)
        description = "total_loss = %.6f" % loss
        chamfer_losses.append(float(loss_chamfer.detach().cpu()))
        edge_losses.append(float(loss_edge.detach().cpu()))
        normal_losses.append(float(loss_normal.detach().cpu()))
        laplacian_losses.append(float(loss_laplacian.detach().cpu()))
        if plot_period and i % plot_period == 0:
            plot_pointcloud(new_src_mesh, title="iter: %d" % i)
        loss.backward()
        optimizer.step()
        yield dict(state, i=i, description=description, new_src_mesh=new_src_mesh)
    final_verts, final_faces = new_src_mesh.get_mesh_verts_faces(0)
    final_verts = final_verts * scale + center
    state.update(final_verts=final_verts, final_faces=final_faces)
    if out_dir is not None:
        final_obj = os.path.join(str(out_dir), "final_model.obj")
        save_obj(final_obj, final_verts, final_faces)
        state.update(final_obj=final_obj)
    yield state


def tutorial4(obj_filename: str, image_size: int, Niter: int, *,
              plot_period: int | None = None, out_dir: str | None = None):
    """Tutorial 4's cells on the mesh ``obj_filename`` at ``image_size`` pixels, ``Niter`` steps
    of the silhouette loop and then of the textured loop (see the module)."""
    device = torch.device("cuda:0") if torch.cuda.is_available() else torch.device("cpu")
    mesh = load_objs_as_meshes([obj_filename], device=device)
    verts = mesh.verts_packed()
    N = verts.shape[0]
    center = verts.mean(0)
    scale = max((verts - center).abs().max(0)[0])
    mesh.offset_verts_(-center)
    mesh.scale_verts_((1.0 / float(scale)))
    num_views = 20
    elev = torch.linspace(0, 360, num_views)
    azim = torch.linspace(-180, 180, num_views)
    lights = PointLights(device=device, location=[[0.0, 0.0, -3.0]])
    R, T = look_at_view_transform(dist=2.7, elev=elev, azim=azim)
    cameras = OpenGLPerspectiveCameras(device=device, R=R, T=T)
    camera = OpenGLPerspectiveCameras(device=device, R=R[None, 1, ...], T=T[None, 1, ...])
    raster_settings = RasterizationSettings(image_size=image_size, blur_radius=0.0,
                                            faces_per_pixel=1)
    renderer = MeshRenderer(
        rasterizer=MeshRasterizer(cameras=camera, raster_settings=raster_settings),
        shader=SoftPhongShader(device=device, cameras=camera, lights=lights))
    meshes = mesh.extend(num_views)
    target_images = renderer(meshes, cameras=cameras, lights=lights)
    target_rgb = [target_images[i, ..., :3] for i in range(num_views)]
    target_cameras = [OpenGLPerspectiveCameras(device=device, R=R[None, i, ...],
                                               T=T[None, i, ...]) for i in range(num_views)]
    if plot_period:
        image_grid(target_images.cpu().numpy(), rows=4, cols=5, rgb=True)
    sigma = 1e-4
    raster_settings_silhouette = RasterizationSettings(
        image_size=image_size, blur_radius=np.log(1. / 1e-4 - 1.) * sigma, faces_per_pixel=50)
    renderer_silhouette = MeshRenderer(
        rasterizer=MeshRasterizer(cameras=camera, raster_settings=raster_settings_silhouette),
        shader=SoftSilhouetteShader())
    silhouette_images = renderer_silhouette(meshes, cameras=cameras, lights=lights)
    target_silhouette = [silhouette_images[i, ..., 3] for i in range(num_views)]
    if plot_period:
        image_grid(silhouette_images.cpu().numpy(), rows=4, cols=5, rgb=False)

    def visualize_prediction(predicted_mesh, renderer=renderer_silhouette,
                             target_image=target_rgb[1], title="", silhouette=False):
        inds = 3 if silhouette else range(3)
        with torch.no_grad():
            predicted_images = renderer(predicted_mesh)
        plt.figure(figsize=(20, 10))
        plt.subplot(1, 2, 1)
        plt.imshow(predicted_images[0, ..., inds].cpu().detach().numpy())
        plt.subplot(1, 2, 2)
        plt.imshow(target_image.cpu().detach().numpy())
        plt.title(title)
        plt.axis("off")
        plt.close("all")

    src_mesh = ico_sphere(4, device)
    raster_settings_soft = RasterizationSettings(
        image_size=image_size, blur_radius=np.log(1. / 1e-4 - 1.) * sigma, faces_per_pixel=50)
    renderer_silhouette = MeshRenderer(
        rasterizer=MeshRasterizer(cameras=camera, raster_settings=raster_settings_soft),
        shader=SoftSilhouetteShader())
    num_views_per_iteration = 2
    losses = {"silhouette": {"weight": 1.0, "values": []},
              "edge": {"weight": 1.0, "values": []},
              "normal": {"weight": 0.01, "values": []},
              "laplacian": {"weight": 1.0, "values": []}}

    def update_mesh_shape_prior_losses(mesh, loss):
        loss["edge"] = mesh_edge_loss(mesh)
        loss["normal"] = mesh_normal_consistency(mesh)
        loss["laplacian"] = mesh_laplacian_smoothing(mesh, method="uniform")

    verts_shape = src_mesh.verts_packed().shape
    deform_verts = torch.full(verts_shape, 0.0, device=device, requires_grad=True)
    optimizer = torch.optim.SGD([deform_verts], lr=1.0, momentum=0.9)
    state = {"N": N, "src_mesh": src_mesh, "deform_verts": deform_verts, "losses": losses}
    yield state
    for i in range(Niter):
        optimizer.zero_grad()
        new_src_mesh = src_mesh.offset_verts(deform_verts)
        loss = {k: torch.tensor(0.0, device=device) for k in losses}
        update_mesh_shape_prior_losses(new_src_mesh, loss)
        for j in np.random.permutation(num_views).tolist()[:num_views_per_iteration]:
            images_predicted = renderer_silhouette(new_src_mesh, cameras=target_cameras[j],
                                                   lights=lights)
            predicted_silhouette = images_predicted[..., 3]
            loss_silhouette = ((predicted_silhouette - target_silhouette[j]) ** 2).mean()
            loss["silhouette"] += loss_silhouette / num_views_per_iteration
        sum_loss = torch.tensor(0.0, device=device)
        for k, l in loss.items():
            sum_loss += l * losses[k]["weight"]
            losses[k]["values"].append(float(l.detach().cpu()))
        description = "total_loss = %.6f" % sum_loss
        if plot_period and i % plot_period == 0:
            visualize_prediction(new_src_mesh, title="iter: %d" % i, silhouette=True,
                                 target_image=target_silhouette[1])
        sum_loss.backward()
        optimizer.step()
        yield dict(state, i=i, description=description)
    state["sil_values"] = losses["silhouette"]["values"]

    renderer_textured = MeshRenderer(
        rasterizer=MeshRasterizer(cameras=camera, raster_settings=raster_settings_soft),
        shader=SoftPhongShader(device=device, cameras=camera, lights=lights))
    losses = {"rgb": {"weight": 1.0, "values": []},
              "silhouette": {"weight": 1.0, "values": []},
              "edge": {"weight": 1.0, "values": []},
              "normal": {"weight": 0.01, "values": []},
              "laplacian": {"weight": 1.0, "values": []}}
    deform_verts = torch.full(verts_shape, 0.0, device=device, requires_grad=True)
    sphere_verts_rgb = torch.full([1, verts_shape[0], 3], 0.5, device=device, requires_grad=True)
    optimizer = torch.optim.SGD([deform_verts, sphere_verts_rgb], lr=1.0, momentum=0.9)
    state.update(losses=losses, sphere_verts_rgb=sphere_verts_rgb)
    for i in range(Niter):
        optimizer.zero_grad()
        new_src_mesh = src_mesh.offset_verts(deform_verts)
        new_src_mesh.textures = TexturesVertex(verts_features=sphere_verts_rgb)
        loss = {k: torch.tensor(0.0, device=device) for k in losses}
        update_mesh_shape_prior_losses(new_src_mesh, loss)
        for j in np.random.permutation(num_views).tolist()[:num_views_per_iteration]:
            images_predicted = renderer_textured(new_src_mesh, cameras=target_cameras[j],
                                                 lights=lights)
            predicted_silhouette = images_predicted[..., 3]
            loss_silhouette = ((predicted_silhouette - target_silhouette[j]) ** 2).mean()
            loss["silhouette"] += loss_silhouette / num_views_per_iteration
            predicted_rgb = images_predicted[..., :3]
            loss_rgb = ((predicted_rgb - target_rgb[j]) ** 2).mean()
            loss["rgb"] += loss_rgb / num_views_per_iteration
        sum_loss = torch.tensor(0.0, device=device)
        for k, l in loss.items():
            sum_loss += l * losses[k]["weight"]
            losses[k]["values"].append(float(l.detach().cpu()))
        if plot_period and i % plot_period == 0:
            visualize_prediction(new_src_mesh, renderer=renderer_textured,
                                 title="iter: %d" % i, silhouette=False)
        sum_loss.backward()
        optimizer.step()
        yield dict(state, i=Niter + i, description=description)
    final_verts, final_faces = new_src_mesh.get_mesh_verts_faces(0)
    final_verts = final_verts * scale + center
    if out_dir is not None:
        final_obj = os.path.join(str(out_dir), "final_model.obj")
        save_obj(final_obj, final_verts, final_faces)
        state.update(final_obj=final_obj)
    yield state


def tutorial5(renderer, target_cameras, target_images, target_silhouettes, *,
              volume_extent_world: float, volume_size: int, batch_size: int, n_iter: int,
              n_shown: int, n_frames: int):
    """Tutorial 5's (fit_textured_volume) model, Huber loss, Adam loop (lr x 0.1 at 75 %),
    renders and rotating views on ``renderer``'s target views (the notebook renders the cow
    with its helper ``generate_cow_renders``): a ``volume_size``^3 grid over
    ``volume_extent_world``, ``n_iter`` steps of ``batch_size`` views, then ``n_shown`` target
    views and ``n_frames`` rotating ones rendered. Yields as :func:`tutorial1` does; the last
    dict adds ``frames`` and ``rotating_volume_frames``."""
    device = torch.device("cuda:0") if torch.cuda.is_available() else torch.device("cpu")

    class VolumeModel(torch.nn.Module):
        def __init__(self, renderer, volume_size=[64] * 3, voxel_size=0.1):
            super().__init__()
            self.log_densities = torch.nn.Parameter(-4.0 * torch.ones(1, *volume_size))
            self.log_colors = torch.nn.Parameter(torch.zeros(3, *volume_size))
            self._voxel_size = voxel_size
            self._renderer = renderer

        def forward(self, cameras):
            batch_size = cameras.R.shape[0]
            densities = torch.sigmoid(self.log_densities)
            colors = torch.sigmoid(self.log_colors)
            volumes = Volumes(
                densities=densities[None].expand(batch_size, *self.log_densities.shape),
                features=colors[None].expand(batch_size, *self.log_colors.shape),
                voxel_size=self._voxel_size,
            )
            return self._renderer(cameras=cameras, volumes=volumes)[0]

    def huber(x, y, scaling=0.1):
        diff_sq = (x - y) ** 2
        loss = ((1 + diff_sq / (scaling**2)).clamp(1e-4).sqrt() - 1) * float(scaling)
        return loss

    volume_model = VolumeModel(renderer, volume_size=[volume_size] * 3,
                               voxel_size=volume_extent_world / volume_size).to(device)
    lr = 0.1
    optimizer = torch.optim.Adam(volume_model.parameters(), lr=lr)
    losses = []
    state = {"volume_model": volume_model, "losses": losses}
    yield state
    for iteration in range(n_iter):
        if iteration == round(n_iter * 0.75):
            optimizer = torch.optim.Adam(volume_model.parameters(), lr=lr * 0.1)
        optimizer.zero_grad()
        batch_idx = torch.randperm(len(target_cameras))[:batch_size]
        batch_cameras = FoVPerspectiveCameras(
            R=target_cameras.R[batch_idx],
            T=target_cameras.T[batch_idx],
            znear=target_cameras.znear[batch_idx],
            zfar=target_cameras.zfar[batch_idx],
            aspect_ratio=target_cameras.aspect_ratio[batch_idx],
            fov=target_cameras.fov[batch_idx],
            device=device,
        )
        rendered_images, rendered_silhouettes = volume_model(batch_cameras).split([3, 1], dim=-1)
        sil_err = huber(rendered_silhouettes[..., 0], target_silhouettes[batch_idx]).abs().mean()
        color_err = huber(rendered_images, target_images[batch_idx]).abs().mean()
        loss = color_err + sil_err
        if iteration % 10 == 0:
            print(f"Iteration {iteration:05d}: color_err = {float(color_err):1.2e}"
                  f" mask_err = {float(sil_err):1.2e}")
        loss.backward()
        optimizer.step()
        losses.append(float(loss))
        if iteration % 10 == 0:
            im_show_idx = int(torch.randint(low=0, high=batch_size, size=(1,)))

            def clamp_and_detach(x):
                return x.clamp(0.0, 1.0).cpu().detach().numpy()

            fig, ax = plt.subplots(1, 2)
            ax[0].imshow(clamp_and_detach(rendered_images[im_show_idx]))
            ax[1].imshow(clamp_and_detach(rendered_silhouettes[im_show_idx, ..., 0]))
            plt.close(fig)
        yield dict(state, iteration=iteration)
    with torch.no_grad():
        frames = torch.cat([volume_model(target_cameras[i])[..., :3].clamp(0.0, 1.0)
                            for i in range(n_shown)])
    image_grid(frames.clamp(0., 1.).cpu().numpy(), rows=1, cols=n_shown, rgb=True, fill=True)
    plt.close("all")

    def generate_rotating_volume(volume_model, n_frames=50):
        logRs = torch.zeros(n_frames, 3, device=device)
        logRs[:, 1] = torch.linspace(0.0, 2.0 * 3.14, n_frames, device=device)
        Rs = so3_exponential_map(logRs)
        Ts = torch.zeros(n_frames, 3, device=device)
        Ts[:, 2] = 2.7
        frames = []
        for R, T in zip(Rs, Ts):
            camera = FoVPerspectiveCameras(
                R=R[None], T=T[None], znear=target_cameras.znear[0],
                zfar=target_cameras.zfar[0], aspect_ratio=target_cameras.aspect_ratio[0],
                fov=target_cameras.fov[0], device=device)
            frames.append(volume_model(camera)[..., :3].clamp(0.0, 1.0))
        return torch.cat(frames)

    with torch.no_grad():
        rotating_volume_frames = generate_rotating_volume(volume_model, n_frames=n_frames)
    image_grid(rotating_volume_frames.clamp(0., 1.).cpu().numpy(), rows=1, cols=n_frames,
               rgb=True, fill=True)
    plt.close("all")
    state.update(frames=frames, rotating_volume_frames=rotating_volume_frames)
    yield state


def tutorial6_cells(torch, renderer):
    """Tutorial 6's cells that define its model and loss: ``(HarmonicEmbedding,
    NeuralRadianceField, huber, sample_images_at_mc_locs)`` over ``torch`` (``geofit.pytorch3d.
    torch``, or PyTorch itself for the peers' benchmark) and ``renderer`` (the module that holds
    ``ray_bundle_to_ray_points`` and ``RayBundle``: ``geofit.pytorch3d.renderer`` or
    ``pytorch3d.renderer``)."""
    ray_bundle_to_ray_points, RayBundle = renderer.ray_bundle_to_ray_points, renderer.RayBundle

    class HarmonicEmbedding(torch.nn.Module):
        def __init__(self, n_harmonic_functions=60, omega0=0.1):
            super().__init__()
            self.register_buffer("frequencies",
                                 omega0 * (2.0 ** torch.arange(n_harmonic_functions)))

        def forward(self, x):
            embed = (x[..., None] * self.frequencies).view(*x.shape[:-1], -1)
            return torch.cat((embed.sin(), embed.cos()), dim=-1)

    class NeuralRadianceField(torch.nn.Module):
        def __init__(self, n_harmonic_functions=60, n_hidden_neurons=256):
            super().__init__()
            self.harmonic_embedding = HarmonicEmbedding(n_harmonic_functions)
            embedding_dim = n_harmonic_functions * 2 * 3
            self.mlp = torch.nn.Sequential(
                torch.nn.Linear(embedding_dim, n_hidden_neurons),
                torch.nn.Softplus(beta=10.0),
                torch.nn.Linear(n_hidden_neurons, n_hidden_neurons),
                torch.nn.Softplus(beta=10.0),
            )
            self.color_layer = torch.nn.Sequential(
                torch.nn.Linear(n_hidden_neurons + embedding_dim, n_hidden_neurons),
                torch.nn.Softplus(beta=10.0),
                torch.nn.Linear(n_hidden_neurons, 3),
                torch.nn.Sigmoid(),
            )
            self.density_layer = torch.nn.Sequential(
                torch.nn.Linear(n_hidden_neurons, 1),
                torch.nn.Softplus(beta=10.0),
            )
            self.density_layer[0].bias.data[0] = -1.5

        def _get_densities(self, features):
            raw_densities = self.density_layer(features)
            return 1 - (-raw_densities).exp()

        def _get_colors(self, features, rays_directions):
            spatial_size = features.shape[:-1]
            rays_directions_normed = torch.nn.functional.normalize(rays_directions, dim=-1)
            rays_embedding = self.harmonic_embedding(rays_directions_normed)
            rays_embedding_expand = rays_embedding[..., None, :].expand(
                *spatial_size, rays_embedding.shape[-1])
            color_layer_input = torch.cat((features, rays_embedding_expand), dim=-1)
            return self.color_layer(color_layer_input)

        def forward(self, ray_bundle, **kwargs):
            rays_points_world = ray_bundle_to_ray_points(ray_bundle)
            embeds = self.harmonic_embedding(rays_points_world)
            features = self.mlp(embeds)
            rays_densities = self._get_densities(features)
            rays_colors = self._get_colors(features, ray_bundle.directions)
            return rays_densities, rays_colors

        def batched_forward(self, ray_bundle, n_batches=16, **kwargs):
            n_pts_per_ray = ray_bundle.lengths.shape[-1]
            spatial_size = [*ray_bundle.origins.shape[:-1], n_pts_per_ray]
            tot_samples = ray_bundle.origins.shape[:-1].numel()
            batches = torch.chunk(torch.arange(tot_samples), n_batches)
            batch_outputs = [
                self.forward(RayBundle(
                    origins=ray_bundle.origins.view(-1, 3)[batch_idx],
                    directions=ray_bundle.directions.view(-1, 3)[batch_idx],
                    lengths=ray_bundle.lengths.view(-1, n_pts_per_ray)[batch_idx],
                    xys=None)) for batch_idx in batches]
            rays_densities, rays_colors = [
                torch.cat([batch_output[output_i] for batch_output in batch_outputs],
                          dim=0).view(*spatial_size, -1) for output_i in (0, 1)]
            return rays_densities, rays_colors

    def huber(x, y, scaling=0.1):
        diff_sq = (x - y) ** 2
        loss = ((1 + diff_sq / (scaling**2)).clamp(1e-4).sqrt() - 1) * float(scaling)
        return loss

    def sample_images_at_mc_locs(target_images, sampled_rays_xy):
        ba = target_images.shape[0]
        dim = target_images.shape[-1]
        spatial_size = sampled_rays_xy.shape[1:-1]
        images_sampled = torch.nn.functional.grid_sample(
            target_images.permute(0, 3, 1, 2),
            -sampled_rays_xy.view(ba, -1, 1, 2),  # note the sign inversion
            align_corners=True)
        return images_sampled.permute(0, 2, 3, 1).view(ba, *spatial_size, dim)

    return HarmonicEmbedding, NeuralRadianceField, huber, sample_images_at_mc_locs


def tutorial6(renderer_mc, neural_radiance_field, target_cameras, target_images,
              target_silhouettes, huber, sample_images_at_mc_locs, *, lr: float,
              batch_size: int, n_iter: int):
    """Tutorial 6's training loop: Adam on ``neural_radiance_field`` (lr x 0.1 at 75 %),
    ``batch_size`` random views a step, the Monte Carlo rays of ``renderer_mc``, Huber losses
    on the colours and silhouettes sampled at the rays (``huber`` and
    ``sample_images_at_mc_locs`` of :func:`tutorial6_cells`). Yields after the set-up and
    after each step (with that step's ``batch_idx`` and ``sampled_rays``)."""
    device = torch.device("cuda:0") if torch.cuda.is_available() else torch.device("cpu")
    optimizer = torch.optim.Adam(neural_radiance_field.parameters(), lr=lr)
    losses = []
    state = {"losses": losses}
    yield state
    for iteration in range(n_iter):
        if iteration == round(n_iter * 0.75):
            optimizer = torch.optim.Adam(neural_radiance_field.parameters(), lr=lr * 0.1)
        optimizer.zero_grad()
        batch_idx = torch.randperm(len(target_cameras))[:batch_size]
        batch_cameras = FoVPerspectiveCameras(
            R=target_cameras.R[batch_idx], T=target_cameras.T[batch_idx],
            znear=target_cameras.znear[batch_idx], zfar=target_cameras.zfar[batch_idx],
            aspect_ratio=target_cameras.aspect_ratio[batch_idx],
            fov=target_cameras.fov[batch_idx], device=device)
        rendered_images_silhouettes, sampled_rays = renderer_mc(
            cameras=batch_cameras, volumetric_function=neural_radiance_field)
        rendered_images, rendered_silhouettes = rendered_images_silhouettes.split([3, 1],
                                                                                  dim=-1)
        silhouettes_at_rays = sample_images_at_mc_locs(target_silhouettes[batch_idx, ..., None],
                                                       sampled_rays.xys)
        sil_err = huber(rendered_silhouettes, silhouettes_at_rays).abs().mean()
        colors_at_rays = sample_images_at_mc_locs(target_images[batch_idx], sampled_rays.xys)
        color_err = huber(rendered_images, colors_at_rays).abs().mean()
        loss = color_err + sil_err
        loss.backward()
        optimizer.step()
        losses.append(float(loss))
        yield dict(state, iteration=iteration, batch_idx=batch_idx, sampled_rays=sampled_rays)
