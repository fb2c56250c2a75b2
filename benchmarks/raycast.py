"""Ray-casting and closest-point throughput on the CPU.

Casts one primary ray per pixel of a 1024 x 1024 image of the normalised cow (camera
``look_at_view_transform(2.7, 0, 180)``, FoV 60, PyTorch3D pixel centres) and reports rays per
second for :class:`geofit.raycast.RayCaster` on all threads and on one thread, for the bare
embreex ``scene.run`` call it wraps, and for the float64 refinement stage on its own; then the
scene rebuild time of ``update_verts`` (5k and 100k faces) and the closest-point throughput of
:class:`geofit.raycast.PointToMeshDistance`.

Run from the repository root::

    GEOFIT_DATA=/path/to/data python benchmarks/raycast.py [--quick]

Writes ``benchmarks/results/raycast.json`` and ``raycast.png``.
"""
from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
from _harness import BenchmarkReport, machine_info, markdown_table, parser

import geofit
from geofit.raycast import PointToMeshDistance, RayCaster

SHARED_COW = Path("/work/shared/data/cow_mesh/cow.obj")


def load_cow():
    """The cow via geofit.data, else trimesh on the shared copy, else a procedural mesh."""
    try:
        from geofit.data import load_textured_mesh

        dm = load_textured_mesh()
        if dm.name == "cow":
            return dm.mesh, f"cow via geofit.data ({dm.path})"
    except ImportError:
        pass
    if SHARED_COW.exists():
        import trimesh

        tm = trimesh.load(SHARED_COW, process=False, force="mesh")
        return geofit.Mesh(tm.vertices, tm.faces), f"cow via trimesh ({SHARED_COW})"
    return geofit.ico_sphere(5), "procedural ico_sphere(5) (no cow found)"


def pixel_rays(size: int):
    """One ray per pixel centre; directions have view-space z = 1 (t is view depth)."""
    try:
        from geofit.cameras import FoVPerspectiveCameras, look_at_view_transform

        R, T = look_at_view_transform(2.7, 0, 180)
        rays = FoVPerspectiveCameras(fov=60.0, R=R, T=T).pixel_rays((size, size))
        return (rays.origins.reshape(-1, 3), rays.directions.reshape(-1, 3),
                "geofit.cameras.FoVPerspectiveCameras.pixel_rays")
    except ImportError:
        pass
    # PyTorch3D conventions by hand: camera at C = (0, 0, -2.7) looking at the origin; view
    # axes x = up x z, y = z x x, z = (at - C) / |at - C|; pixel i sits at 1 - (2i + 1) / W.
    C = np.array([0.0, 0.0, -2.7])
    z = -C / np.linalg.norm(C)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    c = 1.0 - (2 * np.arange(size) + 1) / size
    ys, xs = np.meshgrid(c, c, indexing="ij")
    f = np.tan(np.deg2rad(30.0))
    d = (xs.ravel()[:, None] * f) * x + (ys.ravel()[:, None] * f) * y + z
    return np.broadcast_to(C, d.shape).copy(), d, "numpy pinhole (PyTorch3D pixel centres)"


def timed(fn, repeat):
    """Best and median wall time of ``repeat`` calls, and the last result."""
    ts, out = [], None
    for _ in range(repeat):  # repetitions
        t0 = time.perf_counter()
        out = fn()
        ts.append(time.perf_counter() - t0)
    return out, float(np.min(ts)), float(np.median(ts))


def main() -> None:
    args = parser(__doc__.splitlines()[0]).parse_args()
    load_before = os.getloadavg()
    size = 256 if args.quick else 1024
    repeat = 3 if args.quick else 5
    n_points = 100_000 if args.quick else 1_000_000

    raw_mesh, source = load_cow()
    mesh = raw_mesh.normalize().mesh
    origins, directions, ray_source = pixel_rays(size)
    r = len(origins)
    print(f"mesh: {source}: {mesh.n_verts} verts, {mesh.n_faces} faces (normalised)")
    print(f"rays: {r} ({size}x{size}) from {ray_source}")
    info = machine_info()
    print(f"machine: {info['cpu']}, {info['cpu_affinity']} CPUs, {info['os']}; load average "
          f"{load_before[0]:.2f} (other processes share these CPUs)")

    rows = []  # (stage, seconds best, seconds median, rays/s)

    def row(name, best, med, n):
        rows.append((name, best, med, n / best))
        print(f"  {name:<52s} best {best * 1e3:8.1f} ms  median {med * 1e3:8.1f} ms  "
              f"{n / best / 1e6:6.2f} M/s")

    # --- build
    rc, b_best, _b_med = timed(lambda: RayCaster(mesh), repeat)
    print(f"RayCaster build: best {b_best * 1e3:.1f} ms")
    rc1 = RayCaster(mesh, n_threads=1)
    print(f"primary rays (n_threads={rc.n_threads} vs 1):")
    hits, best, med = timed(lambda: rc.cast(origins, directions), repeat)
    row(f"RayCaster.cast, {rc.n_threads} threads", best, med, r)
    hits1, best, med = timed(lambda: rc1.cast(origins, directions), repeat)
    row("RayCaster.cast, 1 thread", best, med, r)
    identical = all(np.array_equal(a, b) for a, b in zip(hits, hits1))
    occ, best, med = timed(lambda: rc.occluded(origins, directions), repeat)
    row(f"RayCaster.occluded, {rc.n_threads} threads", best, med, r)
    occ_agrees = bool(np.array_equal(occ, hits.hit))

    # --- the bare embreex call on the same (normalised, unit-direction) float32 rays
    from embreex import mesh_construction, rtcore_scene

    scene = rtcore_scene.EmbreeScene(robust=True)
    lo, hi = mesh.verts.min(0), mesh.verts.max(0)
    center, scale = 0.5 * (lo + hi), 0.5 * float(np.max(hi - lo))
    mesh_construction.TriangleMesh(scene, ((mesh.verts - center) / scale).astype(np.float32),
                                   mesh.faces.astype(np.int32))
    o32 = ((origins - center) / scale).astype(np.float32)
    u = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    d32 = u.astype(np.float32)
    scene.run(o32[:1], d32[:1])  # commit
    raw, best, med = timed(lambda: scene.run(o32, d32, output=1), repeat)
    row("raw embreex scene.run(output=1), 1 call", best, med, r)
    raw_hit = raw["geomID"] >= 0
    raw_agree = float(np.mean(raw_hit == hits.hit))

    # --- float64 refinement alone (what cast adds per hit): gather + Moller-Trumbore
    from geofit.raycast.embree import moller_trumbore

    h = np.flatnonzero(hits.hit)
    V, F = mesh.verts, mesh.faces

    def refine():
        tri = F[hits.face_id[h]]
        t, bu, bv, _ = moller_trumbore(origins[h], directions[h], V[tri[:, 0]], V[tri[:, 1]],
                                        V[tri[:, 2]])
        return t, np.stack([1.0 - bu - bv, bu, bv], axis=1)

    (_t_ref, _), best, med = timed(refine, repeat)
    row(f"float64 refinement only ({len(h)} hits), 1 thread", best, med, len(h))
    t32 = raw["tfar"][h].astype(np.float64) * scale / np.linalg.norm(directions[h], axis=1)
    same_face = raw["primID"][h] == hits.face_id[h]
    t_change = np.abs(t32 - hits.t[h])[same_face] / hits.t[h][same_face]
    print(f"hit fraction: {hits.hit.mean():.4f}; threads identical to 1 thread: {identical}; "
          f"occluded == hit: {occ_agrees}; raw embreex hit/miss agreement: {raw_agree:.6f}")
    print(f"float32 t vs refined float64 t (same face): median rel {np.median(t_change):.2e}, "
          f"max rel {t_change.max():.2e}")

    # --- scene rebuild (update_verts) at two sizes
    rebuild = []
    rng = np.random.default_rng(0)
    for name, m in (("ico_sphere(4)", geofit.ico_sphere(4)),
                    ("torus 500x100", geofit.torus(1.0, 0.35, 500, 100))):
        rcm = RayCaster(m)
        jitter = m.verts + rng.normal(scale=1e-3, size=m.verts.shape)
        _, best, med = timed(lambda rcm=rcm, j=jitter: rcm.update_verts(j), repeat)
        rebuild.append((name, m.n_faces, best, med))
        print(f"update_verts rebuild, {name} ({m.n_faces} faces): best {best * 1e3:.1f} ms, "
              f"median {med * 1e3:.1f} ms")

    # --- closest points
    P = rng.uniform(-1.2, 1.2, (n_points, 3))
    pm, pb_best, _ = timed(lambda: PointToMeshDistance(mesh), repeat)
    print(f"PointToMeshDistance build: best {pb_best * 1e3:.1f} ms; {n_points} query points "
          "uniform in [-1.2, 1.2]^3:")
    closest_rows = []
    for one_ring in (True, False):
        pm = PointToMeshDistance(mesh, one_ring=one_ring)
        res, best, med = timed(lambda pm=pm: pm.query(P), max(1, repeat - 2))
        closest_rows.append((f"PointToMeshDistance.query, one_ring={one_ring}", best, med,
                             n_points / best))
        print(f"  one_ring={one_ring!s:<5}: best {best:.2f} s, median {med:.2f} s, "
              f"{n_points / best / 1e6:.3f} M points/s, mean distance {res.distances.mean():.6f}")

    # --- report
    report = BenchmarkReport("raycast", config={
        "mesh": source, "n_verts": mesh.n_verts, "n_faces": mesh.n_faces,
        "image_size": [size, size], "n_rays": r, "rays_from": ray_source,
        "camera": "look_at_view_transform(2.7, 0, 180), FoVPerspectiveCameras(fov=60)",
        "repeat": repeat, "n_threads": rc.n_threads, "quick": bool(args.quick),
        "closest_points": n_points, "GEOFIT_DATA": os.environ.get("GEOFIT_DATA"),
        "loadavg_1_5_15_before": list(load_before), "loadavg_1_5_15_after": list(os.getloadavg()),
    })
    report.notes += [
        "Times are wall-clock best (and median) of `repeat` calls; rays/s = n / best.",
        ("RayCaster.cast includes validation, the float32 transform, the Embree call, and the "
        "float64 Moller-Trumbore refinement of every hit; the raw embreex row is the bare "
        "scene.run call on pre-made float32 arrays (no refinement, one thread)."),
        ("The refinement row times geofit.raycast.embree.moller_trumbore with the "
        "gathers it needs, on the hit rays only."),
    ]
    report.tables["primary_rays"] = [
        {"stage": s, "seconds_best": b, "seconds_median": m, "per_second": p}
        for s, b, m, p in rows]
    report.tables["primary_rays_summary"] = {
        "hit_fraction": float(hits.hit.mean()), "threads_identical": identical,
        "occluded_equals_hit": occ_agrees, "raw_embreex_hit_agreement": raw_agree,
        "float32_vs_float64_t_rel_median": float(np.median(t_change)),
        "float32_vs_float64_t_rel_max": float(t_change.max()),
        "build_seconds_best": b_best,
    }
    report.tables["update_verts_rebuild"] = [
        {"mesh": n, "n_faces": f, "seconds_best": b, "seconds_median": m}
        for n, f, b, m in rebuild]
    report.tables["closest_points"] = [
        {"stage": s, "seconds_best": b, "seconds_median": m, "per_second": p}
        for s, b, m, p in closest_rows] + [{"stage": "build", "seconds_best": pb_best}]
    out = report.write(args.out / "raycast.json")
    print(markdown_table(["stage", "best (ms)", "median (ms)", "M/s"],
                         [(s, f"{b * 1e3:.1f}", f"{m * 1e3:.1f}", f"{p / 1e6:.2f}")
                          for s, b, m, p in rows]))
    png = plot(rows, closest_rows, rebuild, args.out / "raycast.png",
               f"{mesh.n_faces}-face {source.split(' ')[0]}, {size}x{size} rays, {info['cpu']}")
    print(f"wrote {out} and {png}")


def plot(rows, closest_rows, rebuild, path: Path, title: str) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 3.6), gridspec_kw={"width_ratios": [3, 2]})
    names = [r[0] for r in rows] + [c[0] for c in closest_rows]
    vals = [r[3] / 1e6 for r in rows] + [c[3] / 1e6 for c in closest_rows]
    ax = axes[0]
    ax.barh(range(len(names)), vals, color=["C0"] * len(rows) + ["C2"] * len(closest_rows))
    ax.set_yticks(range(len(names)), names, fontsize=7)
    ax.invert_yaxis()
    ax.set_xlabel("million rays (or points) per second")
    for i, v in enumerate(vals):
        ax.text(v, i, f" {v:.2f}", va="center", fontsize=7)
    ax = axes[1]
    ax.bar([f"{n}\n{f} faces" for n, f, _, _ in rebuild], [b * 1e3 for _, _, b, _ in rebuild],
           color="C1")
    ax.set_ylabel("update_verts rebuild (ms)")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


if __name__ == "__main__":
    main()
