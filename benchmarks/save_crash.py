"""Kill-during-save and disk-full checks of every writer (issue 28 point 3).

For each format (OBJ, PLY, STL, OFF, GLB meshes; .npz and .ply point clouds; JSON; a
transforms.json capture), an old file is saved at the target, then a forked child saves a new,
larger one over it and is killed with SIGKILL at each of the 8 steps of
:func:`geofit._atomic.atomic_write` (:data:`geofit._atomic.KILL_POINTS`, through its test
hook). Afterwards the target must load as exactly the old content or exactly the new one.
For the disk-full case the child runs under ``RLIMIT_FSIZE`` (half the new file's size,
SIGXFSZ ignored so the write fails with EFBIG as on a full disk): the save must raise OSError
and the old file must be intact.

Run ``python benchmarks/save_crash.py`` (prints JSON: per format and point, the outcome); the
tests run it in a subprocess, and ``benchmarks/fuzz_loaders.py`` counts its failures.
"""
from __future__ import annotations

import json
import os
import resource
import signal
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np


def _mesh(level: int):
    from geofit import TexturesVertex, ico_sphere

    m = ico_sphere(level)
    return m.__class__(m.verts, m.faces, TexturesVertex(np.full((m.n_verts, 3), 0.5)))


def _cloud(n: int):
    from geofit import PointCloud

    rng = np.random.default_rng(n)
    return PointCloud(rng.normal(size=(n, 3)), rng.uniform(size=(n, 3)))


def _views(n: int):
    from geofit.datasets import held_out_views

    return held_out_views(num_views=8, image_size=8, n_azimuths=n, elevations=(0.0,))


def _formats():
    """name -> (file name, save(path, new: bool), load(path) -> comparable value)."""
    from geofit._atomic import write_json
    from geofit.io import load_mesh, load_pointcloud, load_views, save_mesh, save_pointcloud
    from geofit.io import save_views

    # the data is made here, in the parent: a forked child only writes (no thread pools)
    meshes = {False: _mesh(1), True: _mesh(3)}
    clouds = {False: _cloud(50), True: _cloud(5000)}
    views = {False: _views(2), True: _views(4)}

    def mesh_fmt(ext):
        return (f"m{ext}", lambda p, new: save_mesh(p, meshes[new]),
                lambda p: load_mesh(p).n_verts)

    out = {ext[1:]: mesh_fmt(ext) for ext in (".obj", ".ply", ".stl", ".off", ".glb")}
    out["cloud_npz"] = ("c.npz", lambda p, new: save_pointcloud(p, clouds[new]),
                        lambda p: len(load_pointcloud(p).points))
    out["cloud_ply"] = ("c.ply", lambda p, new: save_pointcloud(p, clouds[new]),
                        lambda p: len(load_pointcloud(p).points))
    out["json"] = ("r.json", lambda p, new: write_json(p, {"n": list(range(20000 if new else 5))}),
                   lambda p: len(json.loads(p.read_text())["n"]))
    out["transforms"] = ("cap/transforms.json",
                         lambda p, new: save_views(p.parent, views[new], overwrite=True),
                         lambda p: len(load_views(p.parent).images))
    return out


def _value(load, path: Path):
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return load(path)
    except Exception as exc:  # noqa: BLE001 - a damaged file is the outcome being counted
        return f"unreadable: {type(exc).__name__}: {str(exc)[:120]}"


def _fork(body) -> int:
    """Run ``body()`` in a forked child; its exit status (negative: killed by that signal)."""
    pid = os.fork()
    if pid == 0:  # the child
        code = 1
        signal.alarm(60)  # a child that hangs (a lock held by a thread of the parent) ends
        try:
            code = body()
        finally:
            os._exit(code)
    _, status = os.waitpid(pid, 0)
    return -os.WTERMSIG(status) if os.WIFSIGNALED(status) else os.WEXITSTATUS(status)


def run(workdir: Path, formats=None) -> dict:
    """Every format x every kill point, and disk full; returns the outcomes and failure count."""
    import geofit._atomic as atomic

    results, failures = {}, 0
    fmts = _formats()
    for name in formats or fmts:  # a loop over the formats
        fname, save, load = fmts[name]
        ref = workdir / name / "ref"
        (ref / "old" / fname).parent.mkdir(parents=True, exist_ok=True)
        (ref / "new" / fname).parent.mkdir(parents=True, exist_ok=True)
        save(ref / "old" / fname, False)
        save(ref / "new" / fname, True)
        old, new = _value(load, ref / "old" / fname), _value(load, ref / "new" / fname)
        assert old != new and not str(old).startswith("unreadable"), (name, old, new)
        row = {}
        for point in atomic.KILL_POINTS:  # a loop over the 8 kill points
            target = workdir / name / point / fname
            target.parent.mkdir(parents=True, exist_ok=True)
            save(target, False)

            def body(point=point, target=target):
                def hook(step):
                    if step == point:
                        os.kill(os.getpid(), signal.SIGKILL)

                atomic._hook = hook
                save(target, True)
                return 0

            status = _fork(body)
            got = _value(load, target)
            outcome = "old" if got == old else "new" if got == new else f"corrupt: {got}"
            if status != -signal.SIGKILL:
                outcome += f" (child not killed: status {status})"
            row[point] = outcome
            failures += outcome not in ("old", "new")
        target = workdir / name / "disk_full" / fname
        target.parent.mkdir(parents=True, exist_ok=True)
        save(target, False)
        limit = max(1, (ref / "new" / fname).stat().st_size // 2)

        def full(target=target, limit=limit):
            signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
            resource.setrlimit(resource.RLIMIT_FSIZE, (limit, resource.RLIM_INFINITY))
            try:
                save(target, True)
            except OSError:
                return 3
            except Exception:  # noqa: BLE001 - any other type is a failure
                return 4
            return 0

        status = _fork(full)
        got = _value(load, target)
        raised = {3: "raised OSError", 4: "raised another type", 0: "returned normally"}.get(
            status, f"status {status}")
        intact = got == old
        row["disk_full"] = f"{raised}; old file {'intact' if intact else f'changed: {got}'}"
        failures += not (status == 3 and intact)
        results[name] = row
    return {"formats": results, "failures": failures,
            "kill_points": list(atomic.KILL_POINTS)}


def main(argv=None) -> int:
    with tempfile.TemporaryDirectory(prefix="geofit-save-crash-") as tmp:
        out = run(Path(tmp), (argv or sys.argv[1:]) or None)
    print(json.dumps(out, indent=1))
    return 1 if out["failures"] else 0


if __name__ == "__main__":
    sys.exit(main())
