"""The two ways :func:`geofit.fit.volume.fit_volume` runs: geofit's levels (hull, coarse to fine,
pruning, empty-space skipping, full-batch solves) and the tutorial's dense Adam recipe.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from ..structures.volume import carve as _carve
from ..structures.volume import silhouette_distances
from . import solvers
from ._progress import advance, progress_bar
from ._volume_problem import (_downsample, _elementwise, _Grid, _logit, _Objective, _rays,
                              _resample, _sigmoid)
from .history import Clock, FitHistory




#: Logits beyond this are saturated: sigmoid' < 2e-22, no gradient can bring them back.
_SATURATED = 50.0


def _saturation_check(x: np.ndarray, lr: float) -> str | None:
    """A message when Adam's steps left most parameters saturated (a too large step size)."""
    frac = float(np.mean(np.abs(x) > _SATURATED)) if x.size else 0.0
    if frac > 0.2:
        return (f"Adam: {100 * frac:.0f} % of the parameters were driven into saturation "
                f"(|logit| > {_SATURATED:g}, zero gradient): learning rate {lr:g} too large")
    return None


def _level_image_factor(H: int, W: int, level: int, S: int) -> int:
    """Largest integer factor <= S / level dividing both H and W."""
    f = max(1, int(round(S / level)))
    while f > 1 and (H % f or W % f):
        f -= 1
    return f


@dataclass
class _Plan:
    """The validated settings of one :func:`geofit.fit.volume.fit_volume` call."""

    imgs: np.ndarray            # (N, H, W, 3) in [0, 1]
    sils: np.ndarray            # (N, H, W) in [0, 1]
    cameras: object
    S: int                      # final grid size
    extent: float
    n_pts: int                  # samples per ray of the final renderer
    min_depth: float
    max_depth: float
    method: str
    huber_scale: float
    lr: float
    time_budget: float | None
    evaluator: Callable | None   # evaluator(volume) -> dict at checkpoints
    eval_every: int | None       # steps between checkpoints (None: levels and end only)
    callback: Callable | None    # callback(StepInfo) -> bool | None
    dtype: np.dtype
    progress: bool
    # geofit's levels
    levels: list | None = None
    iterations: list | None = None
    carve: bool = True
    carve_tolerance: int = 0
    carve_margin: float = 2.0
    prune_threshold: float = 1e-3
    prune_dilation: int = 2
    termination: float | None = None
    smoothness: tuple = (0.0, 0.0)
    # the tutorial's recipe
    batch_size: int = 10
    n_iter: int = 300
    rng: np.random.Generator | None = None


class _TrackedObjective:
    """``fun(x) -> (value, grad)`` of a level that remembers the terms of the last call, the
    first value and (``keep_best``: Adam keeps its best iterate) the best point seen."""

    def __init__(self, problem: _Objective, x0: np.ndarray, keep_best: bool = True):
        self.problem = problem
        self.terms: dict = {}
        self.first = None
        self.best = (np.inf, x0)
        self.keep_best = keep_best

    def __call__(self, x):
        v, g, terms = self.problem.evaluate(x)
        self.terms = terms
        if self.first is None:
            self.first = v
        if self.keep_best and v < self.best[0]:  # a copy of x (8 MB at 128^3)
            self.best = (v, np.array(x, dtype=np.float64))
        return v, g


class _Solver:
    """geofit's method: the grid fitted level by level (hull, pruning, skipping)."""

    def __init__(self, o: _Plan):
        self.o = o
        self.clock = Clock(o.time_budget)
        self.history = FitHistory()
        self.step_final = (o.max_depth - o.min_depth) / (o.n_pts - 1)
        self.stages: list = []
        self.total_iter = self.total_eval = 0
        self.step_counter = 0
        self.last_monitor = 0    # the step of the last checkpoint
        self.problem = None
        self.state = {"ld": None, "lc": None, "grid": None, "n_pts": None}
        self.dist = None
        self.bar = progress_bar(o.progress, sum(o.iterations), f"fit_volume[{o.method}]")

    def run(self) -> dict:
        """Fit every level; returns the fields of the result."""
        o = self.o
        status, message = "max_iter", ""
        for li, (level, n_iter_level) in enumerate(zip(o.levels, o.iterations)):  # levels
            t_level = self.clock.elapsed()
            # a level's set-up is not interruptible: under a time budget, a level whose set-up
            # (the last one's, scaled by the samples, ~ level^3) would not fit is not begun
            guess = 0.0 if not self.stages else self.stages[-1].get("setup_seconds", 0.0) * \
                (level / self.stages[-1]["level"]) ** 3
            if self.clock.over() or (li > 0 and self.clock.remaining() < guess):
                status = "time_budget"  # no time to set the next level up
                message = f"reached the time budget of {o.time_budget:g} s before level {level}^3"
                if not self.clock.over():
                    message += f" (its set-up would take about {guess:.3g} s)"
                break
            x0, info = self.setup_level(li, level)
            remaining = None if o.time_budget is None else self.clock.remaining()
            if remaining is not None and remaining <= 0:
                status = "time_budget"
                message = f"reached the time budget of {o.time_budget:g} s before level {level}^3"
                info.update(status="time_budget", iterations=0, seconds=0.0)
                self.stages.append(info)
                break
            res = self.solve_level(li, x0, n_iter_level, remaining)
            status, message = res.status, res.message
            self.end_level(level, res, info, t_level)
            if res.status in ("time_budget", "nonfinite", "diverged", "failed", "callback"):
                break
        self.bar.close()
        return self.result(status, message)

    # -- one level
    def allowed_voxels(self, li: int, grid: _Grid, step: float):
        """Initial extinction and colour grids of a level and the voxels that may hold
        density: (from the second level) near the occupied region, inside the hull."""
        o = self.o
        prev = self.previous_model()
        if prev is None:
            d0 = _sigmoid(np.array([-4.0]))[0]              # the tutorial's initial log-density
            sig_init = -math.log1p(-d0) / self.step_final   # ... per final sample, as extinction
            sigma_grid = np.full(grid.size, sig_init)
            colour_grid = np.full((3,) + grid.size, 0.5)
            allowed = np.ones(grid.size, bool)
        else:
            sigma, colour, prev_grid = prev
            sigma_grid = np.maximum(_resample(sigma, prev_grid, grid), 0.0)
            colour_grid = np.clip(_resample(colour, prev_grid, grid), 0.0, 1.0)
            allowed = (-np.expm1(-sigma_grid * self.step_final)) > o.prune_threshold
            if o.prune_dilation:
                allowed = ndimage.binary_dilation(allowed, np.ones((3, 3, 3), bool),
                                                  iterations=o.prune_dilation)
        if o.carve:
            if self.dist is None:  # full-resolution silhouettes at every level (thin parts)
                self.dist = silhouette_distances(o.sils > 0.5)
            cand = np.flatnonzero(allowed)  # only the candidates' centres (1/10 of 128^3)
            keep = _carve(self.dist, o.cameras, grid.centres(cand),
                          math.sqrt(3.0) * grid.voxel_size, o.carve_tolerance, o.carve_margin)
            allowed = np.zeros(grid.size, bool)
            allowed.reshape(-1)[cand[keep]] = True
        return sigma_grid, colour_grid, allowed

    def previous_model(self):
        """Extinction (per unit view depth) and colour grids of the level fitted last, and its
        grid (None before the first level); computed when the next level starts, so never after
        the last one."""
        st = self.state
        if st["grid"] is None:
            return None
        grid, af = st["grid"], np.flatnonzero(st["allowed"])
        dens_level = np.zeros(grid.n)
        dens_level[af] = _sigmoid(st["ld"][af])
        sigma = -np.log1p(-np.minimum(dens_level, 1.0 - 1e-15)) / st["step"]
        colour = _elementwise(_sigmoid, st["lc"])
        return sigma.reshape(grid.size), colour.reshape((3,) + grid.size), grid

    def setup_level(self, li: int, level: int):
        """Build the level's problem (rays, free voxels, sparse operator); returns the start
        point and the level's record."""
        o = self.o
        t_level = self.clock.elapsed()
        N, H, W, _ = o.imgs.shape
        grid = _Grid((level,) * 3, o.extent / level, np.zeros(3))
        n_pts = max(2, int(round(o.n_pts * level / o.S)))
        step = (o.max_depth - o.min_depth) / (n_pts - 1)
        f = _level_image_factor(H, W, level, o.S)
        Rh, Rw = H // f, W // f
        rgb = _downsample(o.imgs, f).reshape(-1, 3)
        sil = _downsample(o.sils, f).reshape(-1)
        orig, dirs, lengths = _rays(o.cameras, Rh, Rw, n_pts, o.min_depth, o.max_depth)
        sigma_grid, colour_grid, allowed = self.allowed_voxels(li, grid, step)
        # logits: of the densities only where they may be non-zero (the others are never read)
        af = np.flatnonzero(allowed)
        dens = np.zeros(grid.size)
        dens.reshape(-1)[af] = -np.expm1(-sigma_grid.reshape(-1)[af] * step)
        ld = np.zeros(grid.n)
        ld[af] = _logit(dens.reshape(-1)[af])
        lc = _elementwise(_logit, colour_grid).reshape(3, -1)
        problem = _Objective(grid, orig, dirs, lengths, rgb, sil, dens, allowed,
                             termination=o.termination if li > 0 else None,
                             n_pixels=N * Rh * Rw, huber_scale=o.huber_scale, dtype=o.dtype,
                             smoothness=tuple(v * (level / 64.0) ** 2 for v in o.smoothness))
        self.problem = problem
        problem.clock = self.clock
        self.state.update(ld=ld, lc=lc, grid=grid, n_pts=n_pts, allowed=allowed, step=step)
        x0 = problem.pack(ld, lc)
        info = {"level": level, "image_size": [Rh, Rw], "n_pts_per_ray": n_pts,
                "allowed_voxels": int(allowed.sum()), "free_density_voxels":
                problem.n_free_density, "colour_voxels": problem.n_columns,
                "rays": problem.n_rays_total, "rays_marched": len(problem.ray_ids),
                "samples": problem.n_samples, "nnz": int(problem.W.nnz),
                "samples_per_ray": problem.n_samples / max(problem.n_rays_total, 1),
                "setup_seconds": self.clock.elapsed() - t_level}
        self.history.note(self.step_counter, self.clock.elapsed(), f"level {level}^3", **info)
        return x0, info

    def callback(self, li: int, fun: _TrackedObjective):
        """The solver's per-iteration hook: a history row, the monitor, the bar."""
        o, p = self.o, fun.problem

        def cb(si):
            self.step_counter += 1
            self.history.record(self.step_counter, si.seconds, si.value, fun.terms,
                                n_params=p.n_params, stage=li)
            if o.evaluator is not None and o.eval_every is not None and \
                    self.step_counter - self.last_monitor >= o.eval_every:
                state_ld, state_lc = self.state["ld"].copy(), self.state["lc"].copy()
                p.unpack_into(np.asarray(si.x), self.state["ld"], self.state["lc"])
                self.run_monitor(self.step_counter)
                self.state["ld"], self.state["lc"] = state_ld, state_lc
            advance(self.bar, self.clock)
            if o.callback is not None:
                with self.clock.paused(caller=True):
                    return o.callback(si._replace(stage=li, terms=dict(fun.terms)))
            return None

        return cb

    def solve_level(self, li: int, x0: np.ndarray, n_iter: int, remaining):
        """Run the method on the level's problem."""
        o, problem, clock = self.o, self.problem, self.clock
        fun = _TrackedObjective(problem, x0, keep_best=o.method == "adam")
        callback = self.callback(li, fun)
        if problem.n_params == 0:
            value, _ = problem.evaluate(x0, want_grad=False)
            return solvers.SolveResult(x0, value, "converged", "nothing to fit at this level: "
                                       "no voxel inside the visual hull is seen by any ray "
                                       "(empty silhouettes?); the volume is empty", 0, 1, 0.0)
        if o.method == "adam":
            return self.solve_adam(fun, x0, n_iter, remaining, callback)
        if o.method == "lbfgs":
            return solvers.lbfgs_scipy(fun, x0, max_iter=n_iter, time_budget=remaining,
                                       ftol=1e-12, gtol=1e-12, memory=20, callback=callback,
                                       clock=clock)
        return solvers.lbfgs_nlopt(fun, x0, max_eval=int(n_iter * 1.25) + 1,
                                   time_budget=remaining, ftol_rel=1e-12, memory=20,
                                   callback=callback, clock=clock)

    def solve_adam(self, fun: _TrackedObjective, x0, n_iter: int, remaining, callback):
        """Adam at lr, then lr / 10 for the last quarter; the best iterate is kept, and a
        rising objective or saturated logits are reported as ``"diverged"``."""
        o, clock, lr = self.o, self.clock, self.o.lr
        n1 = max(1, int(round(0.75 * n_iter)))
        res = solvers.adam(fun, x0, lr=lr, n_iter=n1, time_budget=remaining,
                           callback=callback, clock=clock)
        if res.status == "max_iter" and n_iter - n1 > 0:
            rem2 = None if o.time_budget is None else clock.remaining()
            if rem2 is None or rem2 > 0:
                res2 = solvers.adam(fun, res.x, lr=lr * 0.1, n_iter=n_iter - n1,
                                    time_budget=rem2, callback=callback, clock=clock)
                res2.n_iterations += res.n_iterations
                res2.n_evaluations += res.n_evaluations
                res = res2
        if res.status == "max_iter":
            res.message = (f"Adam: {res.n_iterations} steps ({min(n1, res.n_iterations)} at "
                           f"lr {lr:g}, the rest at {0.1 * lr:g})")
        # Adam's last iterate can be worse than what it visited (a too large step size):
        # keep the best one, and say so when the objective ended above where it started
        best_v, best_x = fun.best
        if res.status in ("max_iter", "time_budget") and np.isfinite(best_v):
            last_v, _ = fun.problem.evaluate(res.x, want_grad=False)
            if best_v < last_v:
                res.x, res.value = best_x, best_v
            sat = _saturation_check(res.x, lr)
            if sat is not None:
                res.status = "diverged"
                res.message = f"{sat}; returning the best iterate ({best_v:.4g})"
            elif fun.first is not None and last_v > fun.first:
                res.status = "diverged"
                res.message = (f"Adam: the objective rose from {fun.first:.4g} to "
                               f"{last_v:.4g} (learning rate {lr:g} too large?); returning "
                               f"the best iterate ({best_v:.4g})")
        return res

    def end_level(self, level: int, res, info: dict, t_level: float) -> None:
        """Keep the level's result and hand its extinction and colours to the next level."""
        st, problem = self.state, self.problem
        ld, lc = st["ld"], st["lc"]
        self.total_iter += res.n_iterations
        self.total_eval += res.n_evaluations
        problem.unpack_into(res.x, ld, lc)
        info.update(status=res.status, iterations=res.n_iterations,
                    evaluations=res.n_evaluations, seconds=self.clock.elapsed() - t_level,
                    final_loss=res.value)
        self.stages.append(info)
        self.run_monitor(self.step_counter)

    # -- the model and the observer
    def current_volume(self):
        """The volume of the current state, opacities expressed for the final sampling."""
        o, st = self.o, self.state
        g = st["grid"]
        if g is None:
            return None
        af = np.flatnonzero(st["allowed"])  # the other voxels are empty
        v = _sigmoid(st["ld"][af])
        if st["n_pts"] != o.n_pts:  # express the opacities for the final sampling
            step = (o.max_depth - o.min_depth) / (st["n_pts"] - 1)
            v = -np.expm1(np.log1p(-np.minimum(v, 1.0 - 1e-15)) * (self.step_final / step))
        d = np.zeros(g.n)
        d[af] = v
        c = _elementwise(_sigmoid, st["lc"]).reshape((3,) + g.size)
        return g.volume(d.reshape(g.size), c)

    def run_monitor(self, step: int) -> None:
        if self.o.evaluator is None:
            return
        with self.clock.paused(caller=True):  # the caller's evaluator
            vol = self.current_volume()
            if vol is not None:
                self.history.checkpoint(step, self.clock.elapsed(), self.o.evaluator(vol))
        self.last_monitor = step

    def view_losses(self, message: str):
        """Each training view's mean loss at the end (a diagnostic: the clock is paused), and
        the message naming the views that fit much worse than the others."""
        o, problem, st = self.o, self.problem, self.state
        N = o.imgs.shape[0]
        if problem is None or st["ld"] is None:
            return None, message
        with self.clock.paused():
            rl = problem.ray_losses(problem.pack(st["ld"], st["lc"]))
            view_losses = rl.reshape(N, -1).mean(axis=1)
        med = float(np.median(view_losses))
        bad = np.flatnonzero(view_losses > max(3.0 * med, med + 0.01))
        if bad.size and N >= 3:
            message += (f"; views {bad.tolist()} fit much worse than the others (loss "
                        f"{', '.join(f'{view_losses[i] / max(med, 1e-12):.1f}x' for i in bad)} "
                        f"the median): wrong camera or inconsistent image?")
        return view_losses, message

    def result(self, status: str, message: str) -> dict:
        """The fields of the :class:`~geofit.fit.volume.VolumeFitResult`."""
        o, stages, problem = self.o, self.stages, self.problem
        if len(stages) > 1:
            per_level = ", ".join(f"{st['level']}^3 {st['status']}" for st in stages)
            message = f"levels: {per_level}; last level: {message}"
        # the per-view diagnostic costs one more evaluation: not when the time is up
        view_losses = None
        if status != "time_budget":
            view_losses, message = self.view_losses(message)
        result_volume = self.current_volume()
        if result_volume is None:  # no level ran: the initial model
            grid = _Grid((o.S,) * 3, o.extent / o.S, np.zeros(3))
            result_volume = grid.volume(np.zeros(grid.size), np.full((3,) + grid.size, 0.5))
        h = self.history
        if o.evaluator is not None and (not h.checkpoints
                                      or h.checkpoints[-1]["step"] != self.step_counter):
            self.run_monitor(self.step_counter)
        last = stages[-1] if stages else {}
        return dict(
            status=status, message=message, history=h,
            n_params=problem.n_params if problem is not None else 0,
            seconds=self.clock.elapsed(), cpu_seconds=self.clock.cpu_elapsed(),
            wall_seconds=self.clock.wall(), total_cpu_seconds=self.clock.cpu_total(),
            n_iterations=self.total_iter, n_evaluations=self.total_eval, volume=result_volume,
            n_active_voxels=int(last.get("free_density_voxels", 0)),
            n_colour_voxels=int(last.get("colour_voxels", 0)),
            n_occupied_voxels=int(np.count_nonzero(result_volume.densities)),
            samples_per_ray=float(last.get("samples_per_ray", 0.0)), n_pts_per_ray=o.n_pts,
            stages=stages, method=o.method, recipe="default", view_losses=view_losses)


class _TutorialObjective:
    """The tutorial's stochastic objective on the dense grid: ``batch_size`` random views per
    call; ``x = [log-densities (n), colour logits (3n)]``."""

    def __init__(self, o: _Plan):
        N, H, W, _ = o.imgs.shape
        self.o = o
        self.grid = _Grid((o.S,) * 3, o.extent / o.S, np.zeros(3))
        self.allowed = np.ones(self.grid.size, bool)
        orig, dirs, self.lengths = _rays(o.cameras, H, W, o.n_pts, o.min_depth, o.max_depth)
        self.orig, self.dirs = orig.reshape(N, H * W, 3), dirs.reshape(N, H * W, 3)
        self.rgb = o.imgs.reshape(N, H * W, 3)
        self.sil = o.sils.reshape(N, H * W)
        self.nv = self.grid.n
        self.batch = min(o.batch_size, N)
        self.terms: dict = {}
        self.samples = self.rays = 0

    def x0(self) -> np.ndarray:
        """The tutorial's initial model: log-density -4, colour logits 0."""
        return np.concatenate([np.full(self.nv, -4.0), np.zeros(3 * self.nv)])

    def volume(self, x) -> object:
        g = self.grid
        return g.volume(_sigmoid(x[:self.nv]).reshape(g.size),
                        _sigmoid(x[self.nv:]).reshape((3,) + g.size))

    def __call__(self, x):
        o, nv = self.o, self.nv
        N, H, W, _ = o.imgs.shape
        views = o.rng.permutation(N)[:self.batch]
        p = _Objective(self.grid, self.orig[views].reshape(-1, 3),
                       self.dirs[views].reshape(-1, 3), self.lengths,
                       self.rgb[views].reshape(-1, 3), self.sil[views].reshape(-1), None,
                       self.allowed, termination=None, n_pixels=self.batch * H * W,
                       huber_scale=o.huber_scale, dtype=o.dtype)
        v, g_loc, terms = p.evaluate(p.pack(x[:nv], x[nv:].reshape(3, nv)))
        grad = np.zeros_like(x)
        cols = p.columns
        grad[cols[p.free_idx]] = g_loc[:p.n_free_density]
        grad[nv:].reshape(3, nv)[:, cols] = g_loc[p.n_free_density:].reshape(3, -1)
        self.samples += p.n_samples
        self.rays += p.n_rays_total
        self.terms = terms
        return v, grad


def _fit_tutorial(o: _Plan) -> dict:
    """PyTorch3D's recipe: dense grid, Adam on random view batches, lr x 0.1 at 75%; returns
    the fields of the result."""
    N, H, W, _ = o.imgs.shape
    clock, history = Clock(o.time_budget), FitHistory()
    fun = _TutorialObjective(o)
    x0 = fun.x0()
    bar = progress_bar(o.progress, o.n_iter, "fit_volume[tutorial]")
    last_monitor = [0]

    def callback(si):
        step = len(history) + 1
        history.record(step, si.seconds, si.value, fun.terms, n_params=x0.size)
        if o.evaluator is not None and o.eval_every is not None and \
                step - last_monitor[0] >= o.eval_every:
            with clock.paused(caller=True):  # the caller's evaluator
                history.checkpoint(step, clock.elapsed(),
                                   o.evaluator(fun.volume(np.asarray(si.x))))
            last_monitor[0] = step
        advance(bar, clock)
        if o.callback is not None:
            with clock.paused(caller=True):
                return o.callback(si._replace(terms=dict(fun.terms)))
        return None

    res, n1 = _adam_then_tenth(fun, x0, o, callback, clock)
    bar.close()
    n_it, n_ev = res.n_iterations, res.n_evaluations
    res.status, res.message = _tutorial_status(res, np.asarray(history.loss), o.lr, n1)
    vol = fun.volume(res.x)
    if o.evaluator is not None:
        with clock.paused(caller=True):
            history.checkpoint(len(history), clock.elapsed(), o.evaluator(vol))
    nv = fun.nv
    spr = fun.samples / max(fun.rays, 1)
    stages = [{"level": o.S, "image_size": [H, W], "n_pts_per_ray": o.n_pts,
               "allowed_voxels": nv, "free_density_voxels": nv, "colour_voxels": nv,
               "samples_per_ray": spr, "status": res.status, "iterations": n_it,
               "evaluations": n_ev, "seconds": clock.elapsed(), "final_loss": res.value}]
    return dict(
        status=res.status, message=res.message, history=history, n_params=x0.size,
        seconds=clock.elapsed(), cpu_seconds=clock.cpu_elapsed(), wall_seconds=clock.wall(),
        total_cpu_seconds=clock.cpu_total(), n_iterations=n_it,
        n_evaluations=n_ev, volume=vol, n_active_voxels=nv, n_colour_voxels=nv,
        n_occupied_voxels=int(np.count_nonzero(vol.densities)), samples_per_ray=spr,
        n_pts_per_ray=o.n_pts, stages=stages, method="adam", recipe="tutorial")


def _adam_then_tenth(fun, x0, o: _Plan, callback, clock):
    """Adam for 75 % of ``o.n_iter`` steps at ``o.lr``, the rest at a tenth (a new Adam, as
    the tutorial); returns the result (with both phases' counts) and the first phase's steps."""
    n1 = max(1, int(round(0.75 * o.n_iter)))
    res = solvers.adam(fun, x0, lr=o.lr, n_iter=n1, time_budget=o.time_budget,
                       callback=callback, clock=clock)
    n_it, n_ev = res.n_iterations, res.n_evaluations
    if res.status == "max_iter" and o.n_iter > n1:
        rem = None if o.time_budget is None else clock.remaining()
        if rem is None or rem > 0:
            res = solvers.adam(fun, res.x, lr=o.lr * 0.1, n_iter=o.n_iter - n1,
                               time_budget=rem, callback=callback, clock=clock)
            n_it += res.n_iterations
            n_ev += res.n_evaluations
    res.n_iterations, res.n_evaluations = n_it, n_ev
    return res, n1


def _tutorial_status(res, losses: np.ndarray, lr: float, n1: int) -> tuple[str, str]:
    """Status and message of the tutorial recipe: random batches make single losses noisy, so
    the last few steps are compared with the loss of the initial model (the first step's)."""
    status, message, n_it = res.status, res.message, res.n_iterations
    k = max(1, min(5, len(losses) // 4))
    if status in ("max_iter", "time_budget") and len(losses) >= 2:
        if np.mean(losses[-k:]) >= losses[0]:
            status = "diverged"
            message = (f"Adam: the batch loss did not fall below the initial model's "
                       f"{losses[0]:.4g} (last {k} steps: {np.mean(losses[-k:]):.4g}); "
                       f"learning rate {lr:g} too large? The last iterate is returned")
        else:
            message = (f"Adam: {n_it} steps ({min(n1, n_it)} at lr {lr:g}, the rest at "
                       f"{0.1 * lr:g}); batch loss {losses[0]:.4g} -> "
                       f"{np.mean(losses[-k:]):.4g} (mean of the last {k})"
                       + ("" if status == "max_iter" else f"; {message}"))
    sat = _saturation_check(res.x, lr)
    if sat is not None and status in ("max_iter", "time_budget", "diverged"):
        status = "diverged"
        message = f"{sat}; {message}"
    return status, message
