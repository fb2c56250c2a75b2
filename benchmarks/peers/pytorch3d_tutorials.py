"""PyTorch3D's own tutorial recipes and geofit's defaults, side by side, on this machine.

The README's PyTorch3D figures (268 s for tutorial 1, 1380 s / 25.6 dB / 0.962 for tutorial 5,
13.6 s a step for tutorial 6) were measured once on this 2-core machine kind with PyTorch3D
0.7.9's CPU build running each tutorial's recipe (the issues that set geofit's targets quote them).
This script re-measures them, when PyTorch3D is installed, next to geofit's default on the same
data, the same metric and the same clock, and writes ``results/peers_<workflow>.json``. Without
PyTorch3D it prints ``skipped: PyTorch3D not installed`` and exits 0.

Workflows (``python benchmarks/peers/pytorch3d_tutorials.py WORKFLOW [--steps N]``):

* ``fit_mesh`` -- deform_source_mesh_to_target_mesh: ico_sphere(4), SGD lr 1.0 momentum 0.9,
  5000 samples a side, chamfer 1 + edge 1 + normal 0.01 + Laplacian 0.1, 2000 steps; geofit:
  ``geofit.fit_mesh`` default recipe. Metric: chamfer-L2 and F@0.01 (geofit.metrics, exact
  point-to-surface distances, 100k samples a side, normalised frame) and loop seconds.
* ``fit_volume`` -- fit_textured_volume: 128^3 grid, 150 samples per ray over [0.1, 3], Huber
  (0.1) colour + silhouette, Adam lr 0.1, batch 10 views, lr x 0.1 at 75 %, 300 steps; geofit:
  ``geofit.fit_volume`` default. Metric: held-out PSNR / IoU (16 views at elevations 0 and 20).
* ``nerf`` -- fit_simple_neural_radiance_field: the tutorial's network (60 harmonics, 2 x 256
  Softplus), 750 Monte Carlo rays x 128 points per image, 6 images per step, Adam 1e-3, 3000
  steps; geofit: ``geofit.fit_nerf`` default for 15 minutes. Metric: seconds per step
  (extrapolated to 3000 steps when ``--steps`` cuts the recipe) and held-out PSNR.
* ``all`` -- the three in turn.

``--steps N`` cuts a PyTorch3D recipe to N steps (recorded as "recipe cut to N of M steps" in
the method's label and config; a cut run's accuracy does not compare with the full recipe's).
Data: ``$GEOFIT_DATA`` (dolphin, cow), rendered for both sides by geofit's
``tutorial_views`` (PyTorch3D's ``generate_cow_renders`` to float32 precision, see
/work/shared/reference/pytorch3d/tutorial_datasets.npz).
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _harness import BenchmarkReport, MethodRun, parser  # noqa: E402

WORKFLOWS = ("fit_mesh", "fit_volume", "nerf")
#: Steps of each tutorial's recipe.
RECIPE_STEPS = {"fit_mesh": 2000, "fit_volume": 300, "nerf": 3000}
#: The figures the README quotes, where they came from and with which settings.
QUOTED = {
    "fit_mesh": {"seconds": 268.0, "chamfer_l2": 6.1e-5, "fscore@0.01": 0.953,
                 "source": "issue 3 (PyTorch3D 0.7.9 CPU build, tutorial recipe: 2000 SGD "
                           "steps, 2-core machine of this kind)"},
    "fit_volume": {"seconds": 1380.0, "psnr": 25.6, "iou": 0.962,
                   "source": "issue 7 (PyTorch3D 0.7.9 CPU build, tutorial recipe: 300 Adam "
                             "steps of 10 views, 128^3, 150 samples per ray, 2-core machine "
                             "of this kind)"},
    "nerf": {"seconds_per_step": 13.6,
             "source": "issue 8 (PyTorch3D 0.7.9 CPU build, tutorial network and recipe, "
                       "2-core machine of this kind)"},
}
SKIP_MESSAGE = ("skipped: PyTorch3D not installed (pip install torch and pytorch3d to "
                "re-measure its tutorial recipes side by side with geofit)")


def pytorch3d_available() -> bool:
    """True when ``import torch, pytorch3d`` works."""
    try:
        import pytorch3d  # noqa: F401
        import torch  # noqa: F401
    except ImportError:
        return False
    return True


def _cut(workflow: str, steps: int | None) -> tuple[int, str]:
    full = RECIPE_STEPS[workflow]
    n = full if steps is None else min(int(steps), full)
    return n, ("" if n == full else f"recipe cut to {n} of {full} steps")


# ----------------------------------------------------------------------------- tutorial 1
def peer_fit_mesh(steps: int | None, quick: bool) -> list[MethodRun]:
    import torch
    from pytorch3d.io import load_obj
    from pytorch3d.loss import (chamfer_distance, mesh_edge_loss, mesh_laplacian_smoothing,
                                mesh_normal_consistency)
    from pytorch3d.ops import sample_points_from_meshes
    from pytorch3d.structures import Meshes
    from pytorch3d.utils import ico_sphere

    from geofit import Mesh, fit_mesh
    from geofit.data import find
    from geofit.metrics import MeshEvaluator

    path = find("dolphin/dolphin.obj")
    if path is None:
        raise SystemExit("fit_mesh: the dolphin was not found (set GEOFIT_DATA)")
    n_iter, cut = _cut("fit_mesh", 60 if quick else steps)
    verts, faces, _ = load_obj(str(path), load_textures=False)
    target = Mesh(verts.numpy().astype(np.float64), faces.verts_idx.numpy().astype(np.int64))
    evaluator = MeshEvaluator(target, n_samples=10_000 if quick else 100_000, taus=(0.01,),
                              normalize=True, seed=0)
    center = verts.mean(0)
    scale = (verts - center).abs().max()
    trg = Meshes(verts=[(verts - center) / scale], faces=[faces.verts_idx])
    src = ico_sphere(4, "cpu")
    deform = torch.zeros(src.verts_packed().shape, requires_grad=True)
    opt = torch.optim.SGD([deform], lr=1.0, momentum=0.9)
    t0 = time.perf_counter()
    for _ in range(n_iter):  # the tutorial's loop, as written
        opt.zero_grad()
        new = src.offset_verts(deform)
        loss_chamfer, _ = chamfer_distance(sample_points_from_meshes(trg, 5000),
                                           sample_points_from_meshes(new, 5000))
        loss = (loss_chamfer * 1.0 + mesh_edge_loss(new) * 1.0
                + mesh_normal_consistency(new) * 0.01
                + mesh_laplacian_smoothing(new, method="uniform") * 0.1)
        loss.backward()
        opt.step()
    seconds = time.perf_counter() - t0
    v = new.verts_packed().detach().numpy().astype(np.float64) * float(scale) + center.numpy()
    m = evaluator.evaluate(Mesh(v, new.faces_packed().numpy().astype(np.int64)))
    p3d = MethodRun("pytorch3d", f"PyTorch3D tutorial recipe{', ' + cut if cut else ''}",
                    config={"n_iter": n_iter, "recipe_cut": cut or None, "sgd_lr": 1.0,
                            "momentum": 0.9, "samples": 5000, "ico_level": 4,
                            "weights": {"chamfer": 1.0, "edge": 1.0, "normal": 0.01,
                                        "laplacian": 0.1}})
    p3d.add(seconds, chamfer_l2=m.chamfer_l2, fscore=m.fscore[0.01])
    p3d.final = {"seconds": seconds, "chamfer_l2": m.chamfer_l2, "fscore@0.01": m.fscore[0.01],
                 "n_verts": int(v.shape[0])}
    res = fit_mesh(target, progress=False)
    g = evaluator.evaluate(res.mesh)
    geo = MethodRun("geofit", "geofit fit_mesh default", config={"recipe": "default"},
                    status=res.status, message=res.message)
    geo.add(res.seconds, chamfer_l2=g.chamfer_l2, fscore=g.fscore[0.01])
    geo.final = {"seconds": res.seconds, "chamfer_l2": g.chamfer_l2,
                 "fscore@0.01": g.fscore[0.01], "n_verts": res.n_verts}
    return [p3d, geo]


# ----------------------------------------------------------------------------- tutorial 5
def _torch_cameras(cameras, idx=None):
    import torch
    from pytorch3d.renderer import FoVPerspectiveCameras

    R, T = cameras.R, cameras.T
    if idx is not None:
        R, T = R[idx], T[idx]
    return FoVPerspectiveCameras(R=torch.as_tensor(R, dtype=torch.float32),
                                 T=torch.as_tensor(T, dtype=torch.float32))


def _huber(x, y, scaling=0.1):
    """The tutorials' Huber loss, as written."""
    diff_sq = (x - y) ** 2
    return ((1 + diff_sq / (scaling ** 2)).clamp(1e-4).sqrt() - 1) * float(scaling)


def peer_fit_volume(steps: int | None, quick: bool) -> list[MethodRun]:
    import torch
    from pytorch3d.renderer import (EmissionAbsorptionRaymarcher, NDCMultinomialRaysampler,
                                    VolumeRenderer)
    from pytorch3d.structures import Volumes

    from geofit.fit import VolumeFitOptions, fit_volume
    from geofit.datasets import tutorial_views
    from geofit.metrics import psnr

    n_iter, cut = _cut("fit_volume", 4 if quick else steps)
    size = 32 if quick else 128
    data = tutorial_views(5, num_views=8 if quick else 40, image_size=size, num_held_out=16)
    test = data.held_out
    extent, vsize = 3.0, (32 if quick else 128)
    renderer = VolumeRenderer(
        raysampler=NDCMultinomialRaysampler(image_width=size, image_height=size,
                                            n_pts_per_ray=150, min_depth=0.1,
                                            max_depth=extent),
        raymarcher=EmissionAbsorptionRaymarcher())
    log_d = torch.nn.Parameter(-4.0 * torch.ones(1, vsize, vsize, vsize))
    log_c = torch.nn.Parameter(torch.zeros(3, vsize, vsize, vsize))

    def render(cams):
        n = cams.R.shape[0]
        vol = Volumes(densities=torch.sigmoid(log_d)[None].expand(n, *log_d.shape),
                      features=torch.sigmoid(log_c)[None].expand(n, *log_c.shape),
                      voxel_size=extent / vsize)
        return renderer(cameras=cams, volumes=vol)[0]

    images = torch.as_tensor(data.images, dtype=torch.float32)
    sils = torch.as_tensor(data.silhouettes, dtype=torch.float32)
    opt = torch.optim.Adam([log_d, log_c], lr=0.1)
    g = torch.Generator().manual_seed(0)
    t0 = time.perf_counter()
    for it in range(n_iter):  # the tutorial's loop
        if it == round(n_iter * 0.75):
            opt = torch.optim.Adam([log_d, log_c], lr=0.01)
        opt.zero_grad()
        idx = torch.randperm(len(data), generator=g)[:10].numpy()
        rgb, sil = render(_torch_cameras(data.cameras, idx)).split([3, 1], dim=-1)
        loss = (_huber(sil[..., 0], sils[idx]).abs().mean()
                + _huber(rgb, images[idx]).abs().mean())
        loss.backward()
        opt.step()
    seconds = time.perf_counter() - t0
    with torch.no_grad():
        out = render(_torch_cameras(test.cameras)).numpy().astype(np.float64)
    p_psnr = psnr(np.clip(out[..., :3], 0, 1), test.images)
    inter = ((out[..., 3] > 0.5) & (test.silhouettes > 0.5)).sum((1, 2))
    union = np.maximum(((out[..., 3] > 0.5) | (test.silhouettes > 0.5)).sum((1, 2)), 1)
    p3d = MethodRun("pytorch3d", f"PyTorch3D tutorial recipe{', ' + cut if cut else ''}",
                    config={"n_iter": n_iter, "recipe_cut": cut or None, "volume_size": vsize,
                            "n_pts_per_ray": 150, "lr": 0.1, "batch_size": 10})
    p3d.add(seconds, psnr=p_psnr, iou=float(np.mean(inter / union)))
    p3d.final = {"seconds": seconds, "psnr": p_psnr, "iou": float(np.mean(inter / union))}
    res = fit_volume(data, options=VolumeFitOptions(volume_size=vsize), progress=False)
    from geofit.fit.volume import volume_metrics

    m = volume_metrics(res.volume, test.images, test.silhouettes, test.cameras)
    geo = MethodRun("geofit", "geofit fit_volume default", config={"volume_size": vsize},
                    status=res.status, message=res.message)
    geo.add(res.seconds, psnr=m.psnr, iou=m.iou)
    geo.final = {"seconds": res.seconds, "psnr": m.psnr, "iou": m.iou,
                 "n_active_voxels": res.n_active_voxels}
    return [p3d, geo]


# ----------------------------------------------------------------------------- tutorial 6
def peer_nerf(steps: int | None, quick: bool) -> list[MethodRun]:
    import pytorch3d.renderer as p3d_renderer
    import torch
    from third_party.p3d_tutorials import tutorial6_cells
    from pytorch3d.renderer import (EmissionAbsorptionRaymarcher, ImplicitRenderer,
                                    MonteCarloRaysampler)

    from geofit import fit_nerf
    from geofit.datasets import tutorial_views

    n_iter, cut = _cut("nerf", 2 if quick else (20 if steps is None else steps))
    size = 32 if quick else 128
    data = tutorial_views(6, num_views=8 if quick else 40, image_size=size, num_held_out=16)
    renderer = ImplicitRenderer(
        raysampler=MonteCarloRaysampler(min_x=-1.0, max_x=1.0, min_y=-1.0, max_y=1.0,
                                        n_rays_per_image=750, n_pts_per_ray=128,
                                        min_depth=0.1, max_depth=3.0),
        raymarcher=EmissionAbsorptionRaymarcher())
    # the tutorial's NeuralRadianceField (60 harmonics, omega_0 0.1, 2 x 256 Softplus(10))
    model = tutorial6_cells(torch, p3d_renderer)[1]()
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    images = torch.as_tensor(data.images, dtype=torch.float32)
    sils = torch.as_tensor(data.silhouettes, dtype=torch.float32)[..., None]
    g = torch.Generator().manual_seed(0)
    t0 = time.perf_counter()
    for it in range(n_iter):  # the tutorial's loop (lr x 0.1 at 75 % of the 3000 steps)
        if it == round(RECIPE_STEPS["nerf"] * 0.75):
            for grp in opt.param_groups:
                grp["lr"] = 1e-4
        opt.zero_grad()
        idx = torch.randperm(len(data), generator=g)[:6].numpy()
        out, bundle = renderer(cameras=_torch_cameras(data.cameras, idx),
                               volumetric_function=model)
        rgb, sil = out.split([3, 1], dim=-1)
        xy = -bundle.xys.view(len(idx), -1, 1, 2)
        tgt_rgb = torch.nn.functional.grid_sample(images[idx].permute(0, 3, 1, 2), xy,
                                                  align_corners=True)
        tgt_sil = torch.nn.functional.grid_sample(sils[idx].permute(0, 3, 1, 2), xy,
                                                  align_corners=True)
        loss = (_huber(rgb, tgt_rgb.permute(0, 2, 3, 1).view(rgb.shape)).abs().mean()
                + _huber(sil, tgt_sil.permute(0, 2, 3, 1).view(sil.shape)).abs().mean())
        loss.backward()
        opt.step()
    seconds = time.perf_counter() - t0
    sps = seconds / max(n_iter, 1)
    p3d = MethodRun("pytorch3d", f"PyTorch3D tutorial network and recipe"
                    f"{', ' + cut if cut else ''}",
                    config={"n_iter": n_iter, "recipe_cut": cut or None, "n_rays_per_image": 750,
                            "n_pts_per_ray": 128, "batch_size": 6, "lr": 1e-3})
    p3d.add(seconds, step=n_iter)
    p3d.final = {"seconds": seconds, "seconds_per_step": sps,
                 "extrapolated_seconds_3000_steps": sps * RECIPE_STEPS["nerf"],
                 "n_params": int(sum(p.numel() for p in model.parameters()))}
    res = fit_nerf(data, time_budget=5.0 if quick else 900.0, progress=False)
    geo = MethodRun("geofit", "geofit fit_nerf default, 15 min", config={"time_budget": 900},
                    status=res.status, message=res.message)
    geo.add(res.seconds, psnr=res.psnr, step=res.n_iterations)
    geo.final = {"seconds": res.seconds, "psnr": res.psnr, "n_params": res.n_params,
                 "seconds_per_step": res.seconds / max(res.n_iterations, 1)}
    return [p3d, geo]


PEERS = {"fit_mesh": peer_fit_mesh, "fit_volume": peer_fit_volume, "nerf": peer_nerf}


def main(argv=None) -> int:
    p = parser(__doc__.splitlines()[0])
    p.add_argument("workflow", choices=(*WORKFLOWS, "all"))
    p.add_argument("--steps", type=int, default=None,
                   help="cut each PyTorch3D recipe to this many steps (default: the full "
                        "recipe; nerf: 20 steps, extrapolated to 3000)")
    args = p.parse_args(argv)
    if not pytorch3d_available():
        print(SKIP_MESSAGE, flush=True)
        return 0
    import pytorch3d
    import torch

    workflows = WORKFLOWS if args.workflow == "all" else (args.workflow,)
    for wf in workflows:  # workflows
        report = BenchmarkReport(f"peers_{wf}", config={
            "workflow": wf, "quick": args.quick, "steps": args.steps,
            "pytorch3d": pytorch3d.__version__, "torch": torch.__version__,
            "torch_threads": torch.get_num_threads()},
            reference={"quoted_in_readme": QUOTED[wf]},
            notes=["both sides run in this process on the same data, one after the other; "
                   "seconds are loop wall time (metric renders excluded)",
                   "the load (top-level 'load') says how busy the 2 cores were"])
        print(f"== {wf} ...", flush=True)
        for run in PEERS[wf](args.steps, args.quick):  # the two sides
            report.add(run)
            print(f"  {run.label}: {run.final}", flush=True)
        path = report.write(Path(args.out) / f"peers_{wf}.json")
        print(f"wrote {path}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
