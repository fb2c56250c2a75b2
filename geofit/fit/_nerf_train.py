"""The training loop of :func:`geofit.fit.nerf.fit_nerf` as named steps.

:class:`_Solver` holds one fit: the occupancy (visual hull, coarse density grid), the
ray samplers, the Adam optimizer and its schedule, the held-out evaluation and the history.
One step draws a batch of rays (:meth:`_Solver.draw_batch`), renders them and
backpropagates the Huber losses in chunks over threads (:meth:`_Solver.loss_and_grads`),
and takes an Adam step with a non-finite guard (:meth:`_Solver.step`); checkpoints
render the held-out views with the clock paused (:meth:`_Solver.checkpoint`).
"""
from __future__ import annotations

import contextlib
import math

import numpy as np

from ..loss.robust import huber
from ..metrics import psnr
from .._threads import parallel_map
from ..nn.optim import Adam, exponential_decay, step_decay
from ..render.volume import (
    EmissionAbsorptionRaymarcher,
    ImplicitRenderer,
    MonteCarloRaysampler,
    NDCMultinomialRaysampler,
    NeuralRadianceField,
    OccupancyGrid,
    RayBundle,
)
from ._nerf_render import render_nerf, sample_images_at_xys
from ._progress import progress_bar
from .history import Clock, FitHistory, TimeUp
from .solvers import StepInfo

#: Candidate samples per chunk of a training step (bounds the memory of the caches).
_CHUNK_SAMPLES = 1 << 17
#: Under a time budget, the held-out renders (the reference one, then the checkpoints
#: together) take at most this share of it.
RENDER_SHARE = 0.2
#: A training step is split into at least this many chunks, whatever the thread count: the
#: chunks' gradients are summed in chunk order, so the same seed gives the same network on 1, 2
#: or 8 cores (a partition that followed the thread count changed the float32 sums).
_MIN_PARTS = 8


def _silhouette_weights(silhouettes: np.ndarray, margin: int) -> np.ndarray:
    """(N, H, W) 0/1 weights of the silhouette loss: 0 in a band ``margin`` pixels wide just
    inside each silhouette's edge, 1 elsewhere."""
    from scipy.ndimage import binary_erosion

    inside = silhouettes > 0.5
    core = np.stack([binary_erosion(m, structure=np.ones((3, 3), bool), iterations=margin,
                                    border_value=1) for m in inside])  # views
    return (~inside | core).astype(np.float64)


class _DensityGrid:
    """The coarse density grid: the network's opacity at a random point of each hull voxel."""

    #: Per update, a voxel's opacity estimate keeps this fraction of its previous value (a
    #: voxel is dropped only after several updates find it empty).
    decay = 0.7

    def __init__(self, hull: OccupancyGrid, cfg):
        self.hull = hull
        self.cfg = cfg
        self.cells = np.flatnonzero(hull.occupied.reshape(-1))
        self.opacity = np.ones(hull.occupied.size, dtype=np.float32)  # unknown: occupied
        self.opacity[~hull.occupied.reshape(-1)] = 0.0

    def update(self, field: NeuralRadianceField, rng: np.random.Generator, n_threads: int
               ) -> OccupancyGrid:
        hull = self.hull
        W, H, _ = hull.shape_xyz
        cz, rem = np.divmod(self.cells, H * W)
        cy, cx = np.divmod(rem, W)
        ijk = np.stack([cx, cy, cz], axis=1) + rng.random((self.cells.size, 3))
        pts = hull.bounds[0] + ijk * hull.voxel_size
        dirs = np.array([[0.0, 0.0, 1.0]])
        chunks = [pts[s:s + 65536] for s in range(0, len(pts), 65536)]

        def work(p):
            idx = np.zeros(len(p), dtype=np.int64)
            return field._forward(p, dirs, idx, None, False)[0][:, 0]

        new = np.concatenate(parallel_map(work, chunks, n_threads)) if len(pts) else \
            np.zeros(0, np.float32)
        old = self.opacity[self.cells]
        self.opacity[self.cells] = np.maximum(new, self.decay * np.minimum(old, 1.0))
        grid = self.opacity.reshape(hull.occupied.shape)
        occ = OccupancyGrid(grid > self.cfg.density_threshold, hull.bounds).dilate(1)
        return OccupancyGrid(occ.occupied & hull.occupied, hull.bounds, grid)


class _Solver:
    """One :func:`~geofit.fit.nerf.fit_nerf` run: set-up, steps, checkpoints, diagnosis."""

    def __init__(self, cfg, data, test, field: NeuralRadianceField, *, rng, clock: Clock,
                 n_threads: int, time_budget, eval_every, callback, progress: bool):
        self.cfg, self.data, self.test, self.field = cfg, data, test, field
        self.rng, self.clock, self.n_threads = rng, clock, n_threads
        self.time_budget, self.early_stopping = time_budget, cfg.early_stopping
        self.callback = callback
        self.batch = min(cfg.batch_size, data.N)
        self.setup_rays()
        self.setup_schedule()
        # the opacity regulariser starts with the density grid (after the warm-up), once the
        # network has found the object: from the start it would empty the hull before that
        self.reg_on = cfg.opacity_regularization > 0 and (self.density is None
                                                         or cfg.density_grid_warmup == 0)
        self.setup_evaluation(cfg.render_size)
        self.history = FitHistory()
        self.n_params = field.n_params
        # checkpoints every eval_every steps; by default every 1/20 of the steps, or with a
        # time budget every 1/20 of its seconds
        self.every_seconds = eval_every is None and time_budget is not None
        if eval_every is None:
            self.every = (time_budget / 20.0) if time_budget is not None else \
                max(cfg.n_iter // 20, 1)
        else:
            self.every = eval_every
        self.best = {"loss": math.inf, "params": None, "step": 0, "since": 0}
        self.last_good = {k: v.copy() for k, v in field.params.items()}
        self.spr_sum = 0.0
        self.stage = 0
        total = time_budget if time_budget is not None else cfg.n_iter
        self.bar = progress_bar(progress, total, "fit_nerf",
                                unit="s" if time_budget is not None else "it")

    # -- set-up
    def setup_rays(self) -> None:
        """The visual hull, the samplers, the renderer and (pixel sampling) the rays that can
        meet the hull."""
        cfg, data = self.cfg, self.data
        self.hull = None
        if cfg.occupancy != "none":
            self.hull = OccupancyGrid.from_silhouettes(
                data.silhouettes, data.cameras, resolution=cfg.hull_resolution,
                bounds=cfg.bounds, dilate_pixels=cfg.hull_dilate_pixels).dilate(1)
        raymarcher = EmissionAbsorptionRaymarcher()
        self.grid_sampler = NDCMultinomialRaysampler(
            image_width=data.W, image_height=data.H, n_pts_per_ray=cfg.n_pts_per_ray,
            min_depth=cfg.min_depth, max_depth=cfg.max_depth,
            stratified_sampling=cfg.stratified)
        if cfg.ray_sampling == "montecarlo":
            self.sampler = MonteCarloRaysampler(-1.0, 1.0, -1.0, 1.0, cfg.n_rays_per_image,
                                                cfg.n_pts_per_ray, cfg.min_depth,
                                                cfg.max_depth,
                                                stratified_sampling=cfg.stratified)
        else:
            self.sampler = self.grid_sampler
        self.density = _DensityGrid(self.hull, cfg) if cfg.occupancy == "density" else None
        self.renderer = ImplicitRenderer(
            self.sampler, raymarcher, occupancy=self.hull,
            min_transmittance=cfg.min_transmittance if self.density is not None else 0.0,
            occlusion_margin=cfg.occlusion_margin)
        self.pixel_rays = self.hit_pixels = None
        if cfg.ray_sampling == "pixels":
            self.setup_pixel_rays()
        self.base_lengths = np.linspace(cfg.min_depth, cfg.max_depth, cfg.n_pts_per_ray)
        self.img_flat = data.images.reshape(data.N, -1, 3)
        self.sil_flat = data.silhouettes.reshape(data.N, -1)
        self.sil_weight = None
        if cfg.silhouette_margin > 0 and cfg.ray_sampling == "pixels":
            self.sil_weight = _silhouette_weights(data.silhouettes,
                                                  cfg.silhouette_margin).reshape(data.N, -1)

    def setup_pixel_rays(self) -> None:
        """Every pixel's ray, and per view the pixels whose ray can meet the hull."""
        from scipy.ndimage import binary_dilation

        cfg, data = self.cfg, self.data
        full = self.grid_sampler(data.cameras, stratified_sampling=False)
        self.pixel_rays = RayBundle(full.origins.reshape(data.N, -1, 3),
                                    full.directions.reshape(data.N, -1, 3), None,
                                    full.xys.reshape(data.N, -1, 2))
        # every ray that meets the hull passes through the view's dilated silhouette (the hull
        # was carved from it, then grown by one voxel: allow two more pixels for that)
        grow = cfg.hull_dilate_pixels + 2
        self.hit_pixels = [np.flatnonzero(binary_dilation(data.silhouettes[i] > 0.5,
                                                          structure=np.ones((3, 3), bool),
                                                          iterations=grow))
                           for i in range(data.N)]  # views
        if any(h.size == 0 for h in self.hit_pixels):
            empty = [i for i, h in enumerate(self.hit_pixels) if h.size == 0]
            raise ValueError(f"silhouettes: no ray of view(s) {empty} meets the visual hull; "
                             "check the silhouettes and cameras")

    def setup_schedule(self) -> None:
        cfg = self.cfg
        if cfg.lr_schedule == "step":
            self.schedule = step_decay(cfg.lr, cfg.n_iter, at=cfg.lr_decay_at,
                                       factor=cfg.lr_decay_factor, reset=True)
        else:
            self.schedule = exponential_decay(cfg.lr, cfg.lr * cfg.lr_decay_factor, 10 ** 6)
        self.opt = Adam(self.field.params, lr=cfg.lr)

    def setup_evaluation(self, render_size) -> None:
        test = self.test
        self.size = None
        self.test_sil_weight = None
        if test is not None and self.sil_weight is not None:
            self.test_sil_weight = _silhouette_weights(test.silhouettes,
                                                       self.cfg.silhouette_margin)
        if test is not None:
            self.size = (test.H, test.W) if render_size is None else (int(render_size),) * 2

    # -- one step
    def lr_at(self, step: int, seconds: float) -> tuple[float, bool]:
        cfg = self.cfg
        if cfg.lr_schedule == "step":
            return self.schedule(step)
        frac = step / cfg.n_iter
        if self.time_budget is not None:
            frac = max(frac, seconds / self.time_budget)
        return self.schedule(int(min(frac, 1.0) * 10 ** 6))

    def draw_batch(self):
        """``batch`` random views and their rays (Monte Carlo, or pixels meeting the hull)
        with the target colours, silhouettes and silhouette weights."""
        cfg, data, rng = self.cfg, self.data, self.rng
        views = rng.choice(data.N, size=self.batch, replace=False)
        if cfg.ray_sampling == "montecarlo":
            bundle = self.sampler(data.cameras[views], seed=rng)
            xys = bundle.xys
            tgt_rgb = sample_images_at_xys(data.images[views], xys)
            tgt_sil = sample_images_at_xys(data.silhouettes[views][..., None], xys)[..., 0]
            flat = RayBundle(*(np.asarray(a).reshape(-1, a.shape[-1]) for a in bundle))
            return flat, tgt_rgb.reshape(-1, 3), tgt_sil.reshape(-1), None
        hit = self.hit_pixels
        pix = np.stack([rng.choice(hit[v], size=cfg.n_rays_per_image,
                                   replace=hit[v].size < cfg.n_rays_per_image)
                        for v in views])  # views
        rays = self.pixel_rays
        o = rays.origins[views[:, None], pix].reshape(-1, 3)
        d = rays.directions[views[:, None], pix].reshape(-1, 3)
        xys = rays.xys[views[:, None], pix].reshape(-1, 2)
        lengths = np.broadcast_to(self.base_lengths, (o.shape[0], cfg.n_pts_per_ray))
        if cfg.stratified:
            step = (cfg.max_depth - cfg.min_depth) / max(cfg.n_pts_per_ray - 1, 1)
            lengths = lengths + (rng.random((o.shape[0], 1)) - 0.5) * step
        flat = RayBundle(o, d, np.ascontiguousarray(lengths), xys)
        w = None if self.sil_weight is None else self.sil_weight[views[:, None], pix].reshape(-1)
        return (flat, self.img_flat[views[:, None], pix].reshape(-1, 3),
                self.sil_flat[views[:, None], pix].reshape(-1), w)

    def loss_and_grads(self, flat: RayBundle, tgt_rgb, tgt_sil, sil_w):
        """The loss terms, the parameter gradients and the samples per ray of a batch."""
        cfg, n_threads, renderer, field = self.cfg, self.n_threads, self.renderer, self.field
        R = flat.origins.shape[0]
        # chunks of at most _CHUNK_SAMPLES candidate samples (bounded memory) and at least
        # _MIN_PARTS of them, independent of the thread count (deterministic sums)
        n_parts = min(R, max(_MIN_PARTS, -(-R * cfg.n_pts_per_ray // _CHUNK_SAMPLES)))
        parts = [slice(i * R // n_parts, (i + 1) * R // n_parts) for i in range(n_parts)]
        reg_on = self.reg_on

        def work(sl):
            sub = RayBundle(*(a[sl] for a in flat))
            img, _, cache = renderer.render(None, field, ray_bundle=sub)
            lc, gc = huber(img[:, :3], tgt_rgb[sl], cfg.huber_scale)
            ls, gs = huber(img[:, 3], tgt_sil[sl], cfg.huber_scale)
            if sil_w is not None:
                ls, gs = ls * sil_w[sl], gs * sil_w[sl]
            G = np.empty_like(img)
            G[:, :3] = gc / (3 * R)
            G[:, 3] = gs / R
            lo, gd = 0.0, None
            if reg_on and cache.ray_index.size:
                a = cache.sample_densities()
                w = cfg.opacity_regularization / R
                lo = w * float(np.sum(a * (1.0 - a)))
                gd = w * (1.0 - 2.0 * a)
            grads = renderer.backward(field, cache, G, gd)
            k = cache.ray_index.size
            return lc.sum() / (3 * R), ls.sum() / R, lo, grads, k

        outs = parallel_map(work, [p for p in parts if p.stop > p.start], n_threads)
        terms = {"color": sum(o[0] for o in outs), "silhouette": sum(o[1] for o in outs)}
        if cfg.opacity_regularization > 0:
            terms["opacity"] = sum(o[2] for o in outs)
        grads = {k: sum(o[3][k] for o in outs) for k in outs[0][3]}
        return terms, grads, sum(o[4] for o in outs) / R

    def refresh_density(self, step: int) -> None:
        """Every ``density_grid_every`` steps after the warm-up: the density grid from the
        network (and the opacity regulariser switched on)."""
        cfg, density = self.cfg, self.density
        if density is None or step <= cfg.density_grid_warmup or \
                (step - cfg.density_grid_warmup - 1) % cfg.density_grid_every != 0:
            return
        self.renderer.occupancy = density.update(self.field, self.rng, self.n_threads)
        self.reg_on = cfg.opacity_regularization > 0
        if self.stage == 0:
            self.stage = 1
            self.history.note(step, self.clock.elapsed(), "density grid: skipping empty and "
                              "occluded samples", occupied=self.renderer.occupancy
                              .fraction_occupied)

    def step(self, step: int):
        """One Adam step; returns ``(loss, seconds, None)``, or ``(None, None, (status,
        message))`` when it stopped on a non-finite loss, gradient or parameter (the last
        finite parameters restored)."""
        field, clock = self.field, self.clock
        lr, reset = self.lr_at(step - 1, clock.elapsed())
        self.opt.set_lr(lr, reset=reset)
        self.refresh_density(step)
        flat, tgt_rgb, tgt_sil, sil_w = self.draw_batch()
        terms, grads, spr = self.loss_and_grads(flat, tgt_rgb, tgt_sil, sil_w)
        loss = sum(terms.values())
        finite = math.isfinite(loss) and all(np.all(np.isfinite(g)) for g in grads.values())
        if not finite:
            field.set_params(self.last_good)
            self.history.record(step, clock.elapsed(),
                                loss if math.isfinite(loss) else math.nan, terms,
                                n_params=self.n_params, stage=self.stage)
            return None, None, ("nonfinite", f"the loss or its gradient became NaN or inf at "
                                             f"step {step}; returning the last finite "
                                             "parameters")
        for k, v in field.params.items():  # parameter arrays
            self.last_good[k][...] = v
        self.opt.step(grads)
        if not all(np.all(np.isfinite(v)) for v in field.params.values()):
            field.set_params(self.last_good)
            return None, None, ("nonfinite", f"the parameters became NaN or inf at step "
                                             f"{step} (learning rate {lr:g} too large?); "
                                             "returning the last finite parameters")
        self.spr_sum += spr
        seconds = clock.elapsed()
        self.history.record(step, seconds, loss, terms, n_params=self.n_params,
                            stage=self.stage)
        return loss, seconds, None

    def observer(self):
        """The context of held-out evaluations: the clock paused, except under a time budget,
        which is wall-clock and so pays for them."""
        return contextlib.nullcontext() if self.time_budget is not None else self.clock.paused()

    # -- the loop
    def run(self) -> tuple[str, str]:
        """Steps until the budget, the callback, early stopping or a non-finite value stops
        the fit; returns the status and message."""
        cfg, clock = self.cfg, self.clock
        if self.density is not None and cfg.density_grid_warmup == 0:
            self.renderer.occupancy = self.density.update(self.field, self.rng,
                                                          self.n_threads)
        self.initial = None
        self.restored = False  # a checkpoint's parameters were put back
        self.last_render = None  # (step, renders, PSNR, loss) of the last checkpoint
        self.render_seconds = 0.0  # the longest held-out render so far (budget seconds)
        self.render_total = 0.0  # budget seconds spent in held-out renders
        self.skipped: list[str] = []  # held-out renders the time budget left out
        if self.test is not None:
            # the untrained network's held-out loss: the reference. With a time budget the
            # held-out renders are charged to it (the budget is wall-clock): this one may take
            # RENDER_SHARE of it, the periodic ones together as much of the time so far, and
            # the training stops early enough for the final render (timed on the renders so
            # far) to fit in
            with self.observer():
                limit = None if self.time_budget is None else \
                    clock.budget_elapsed() + RENDER_SHARE * self.time_budget
                out = self.timed_evaluate(limit)
                if out is None:
                    self.skipped.append("the untrained network's reference render")
                else:
                    self.initial = out[2]
        next_eval = self.every
        status, message = "max_iter", f"completed {cfg.n_iter} steps"
        for step in range(1, cfg.n_iter + 1):  # Adam steps
            loss, seconds, stop = self.step(step)
            if stop is not None:
                status, message = stop
                break
            self.tick(step, seconds, loss)
            # the budget's clock (Clock.remaining): the training leaves the final render's time
            out_of_time = self.time_budget is not None and \
                clock.remaining() <= self.render_seconds
            due = (seconds >= next_eval) if self.every_seconds else (step >= next_eval)
            if due and not out_of_time and self.time_budget is not None and \
                    clock.remaining() <= 2.0 * self.render_seconds:
                out_of_time = True  # this checkpoint's render would leave none for the last
            if due and not out_of_time and self.time_budget is not None and \
                    self.render_total + self.render_seconds > \
                    RENDER_SHARE * clock.budget_elapsed():
                due = False  # the held-out renders would take more than their share
                next_eval += self.every
            if due or out_of_time or step == cfg.n_iter:
                next_eval += self.every
                if self.checkpoint(step, loss):
                    status, message = "callback", f"the callback stopped the fit at step {step}"
                    break
                if self.early_stopping is not None and \
                        self.best["since"] >= self.early_stopping:
                    status = "converged"
                    message = (f"the held-out loss has not improved for {self.early_stopping} "
                               f"checkpoints; returning the best one (step {self.best['step']})")
                    break
            if out_of_time:
                status, message = "time_budget", (f"reached the time budget of "
                                                  f"{self.time_budget:g} s after {step} steps")
                break
        self.bar.close()
        return self.diagnose(status, message)

    def tick(self, step: int, seconds: float, loss: float) -> None:
        """Advance the progress bar (by a step, or by the seconds of a time budget)."""
        with self.clock.paused():
            if self.time_budget is not None:
                self.bar.update(min(seconds, self.time_budget) - self.bar.n)
            else:
                self.bar.update(1)
            if step % 10 == 0:
                self.bar.set_postfix(loss=f"{loss:.4g}")

    def diagnose(self, status: str, message: str) -> tuple[str, str]:
        """No progress is a divergence: a learning rate far too large kills the network
        rather than making it NaN. With held-out views: the held-out loss no better than the
        untrained network's; without: the training loss of the last tenth of the steps above
        80 % of that of the first ten steps."""
        h, cfg, best = self.history, self.cfg, self.best
        n_steps = len(h.steps)
        if status in ("max_iter", "time_budget"):
            L = np.asarray(h.loss)
            tail = L[-max(n_steps // 10, 1):].mean() if n_steps else math.nan
            head = L[:10].mean() if n_steps else math.nan
            last = h.checkpoints[-1].get("held_out_loss") if h.checkpoints else None
            if self.initial is not None and last is not None and last >= self.initial:
                status = "diverged"
                message = (f"no progress: the held-out loss went from {self.initial:.4g} "
                           f"(initial network) to {last:.4g} after {n_steps} steps; learning "
                           f"rate {cfg.lr:g} too large?")
            elif n_steps >= 50 and tail > 0.8 * head:
                status = "diverged"
                message = (f"no progress: the training loss went from {head:.4g} (first 10 "
                           f"steps) to {tail:.4g} (last {max(n_steps // 10, 1)} steps); "
                           f"learning rate {cfg.lr:g} too large?")
            if status == "diverged" and best["params"] is not None and last is not None and \
                    best["loss"] < last:
                self.field.set_params(best["params"])
                self.restored = True
                message += f"; returning the best checkpoint (step {best['step']})"
        if self.early_stopping is not None and best["params"] is not None:
            self.field.set_params(best["params"])
            self.restored = True
        return status, message

    # -- held-out views
    def final_render(self):
        """The held-out renders of the returned field: the last checkpoint's when it rendered
        this very field (no step and no restored checkpoint since), else a new render (within
        what is left of a time budget: ``(None, None, None)`` when it does not fit)."""
        last = self.last_render
        if last is not None and last[0] == len(self.history.steps) and not self.restored:
            return last[1], last[2], last[3]
        out = self.timed_evaluate(self.clock.deadline)
        if out is None:
            self.skipped.append("the final held-out render")
            return None, None, None
        return out

    def timed_evaluate(self, limit: float | None = None):
        """:meth:`evaluate`, keeping the longest render time (what the budget reserves); with
        ``limit`` (budget seconds) the render stops there and None is returned."""
        clock = self.clock
        t0 = clock.budget_elapsed()
        if limit is not None and t0 >= limit:  # no time: not even the rays are made
            return None
        check = None
        if limit is not None:
            def check():
                if clock.budget_elapsed() > limit:
                    raise TimeUp(f"reached the time budget of {self.time_budget:g} s")
        try:
            out = self.evaluate(check)
        except TimeUp:
            out = None
        took = clock.budget_elapsed() - t0
        self.render_seconds = max(self.render_seconds, took)
        self.render_total += took
        return out

    def evaluate(self, check=None):
        """Full renders of the held-out views, their PSNR and Huber loss (None, None when
        rendered at another size); ``check`` as :func:`render_nerf`'s."""
        cfg, test, size = self.cfg, self.test, self.size
        imgs = render_nerf(self.field, test.cameras, size, n_pts_per_ray=cfg.n_pts_per_ray,
                           min_depth=cfg.min_depth, max_depth=cfg.max_depth,
                           occupancy=self.hull, chunk_rays=cfg.chunk_rays,
                           n_threads=self.n_threads, check=check)
        if size != (test.H, test.W):
            return imgs, None, None
        rgb = np.clip(imgs[..., :3], 0.0, 1.0)
        lc = huber(imgs[..., :3], test.images, cfg.huber_scale)[0].mean()
        ls = huber(imgs[..., 3], test.silhouettes, cfg.huber_scale)[0]
        if self.test_sil_weight is not None:
            ls = ls * self.test_sil_weight
        return imgs, psnr(rgb, test.images), float(lc + ls.mean())

    def checkpoint(self, step: int, loss: float) -> bool:
        """Record metrics (clock paused); True to stop."""
        clock, best = self.clock, self.best
        with self.observer():
            seconds = clock.elapsed()
            metrics = None
            if self.test is not None:
                out = self.timed_evaluate(self.clock.deadline)
                if out is None:  # the time budget ran out during the render
                    self.skipped.append(f"the held-out render at step {step}")
                    return False
                imgs, p, hl = out
                self.last_render = (step, imgs, p, hl)  # reused by final_render
                metrics = {"psnr": p, "held_out_loss": hl}
                if hl < best["loss"]:
                    best.update(loss=hl, params={k: v.copy()
                                                 for k, v in self.field.params.items()},
                                step=step, since=0)
                else:
                    best["since"] += 1
            self.history.checkpoint(step, seconds, metrics or {"loss": loss})
            if self.callback is None:
                return False
            info = StepInfo(step, step, self.field.get_flat(), float(loss), seconds,
                            metrics=metrics)
            with clock.paused(caller=True):
                return bool(self.callback(info))
