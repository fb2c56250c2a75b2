"""Step 2, render_textured_meshes: :class:`geofit.render.MeshRenderer` on the cow, next to
PyTorch3D's renders, and the stability cases."""
from __future__ import annotations

import time

import numpy as np

from ..render import (
    Materials,
    MeshRasterizer,
    MeshRenderer,
    PointLights,
    RasterizationSettings,
    SoftPhongShader,
    make_grid,
)
from ..structures import Mesh
from ..viz import image_panel, plot_accuracy_vs_time, save_png
from .shared import (
    GEOFIT_COLUMN,
    P3D_COLUMN,
    StepResult,
    begin_textured_step,
    look_at_cameras,
    method_record,
    method_series,
    pick_size,
    progress_bar,
    recipe_cut,
    run_cases,
)

__all__ = ["step_render_mesh"]


# --------------------------------------------------------------------------------------------
# 2. render textured meshes
# --------------------------------------------------------------------------------------------


def _render_stability(mesh, size: str) -> list[dict]:
    """The mesh renderer on awkward input: where does it break, and how."""
    s = pick_size(size, 32, 128, 256)

    def render(m, cams, **settings):
        r = MeshRenderer(MeshRasterizer(cams, RasterizationSettings(image_size=s, **settings)),
                         SoftPhongShader(lights=PointLights(location=[[0.0, 0.0, -3.0]])))
        img = r(m)
        return (f"ok: {100 * float((img[..., 3] > 0).mean()):.1f}% covered, "
                f"finite={bool(np.isfinite(img).all())}")

    front = look_at_cameras(2.7, 0.0, 180.0)
    v = mesh.verts.copy()
    e = mesh.edges[::5]
    v[e[:, 0]] = v[e[:, 1]]
    nan_v = mesh.verts.copy()
    nan_v[0] = np.nan
    cases = {
        "camera inside the mesh (dist 0.3)": lambda: render(mesh, look_at_cameras(0.3, 0.0, 180.0)),
        "mesh behind the camera": lambda: render(
            mesh.update_verts(mesh.verts + np.array([0.0, 0.0, -6.0])), front),
        "every 5th edge collapsed (zero-area faces)": lambda: render(mesh.update_verts(v), front),
        "camera at the pole (elev 90)": lambda: render(mesh, look_at_cameras(2.7, 90.0, 180.0)),
        "1 x 1 image": lambda: "ok: image shape " + str(MeshRenderer(
            MeshRasterizer(front, RasterizationSettings(image_size=1)),
            SoftPhongShader())(mesh).shape),
        "NaN vertex": lambda: render(Mesh(nan_v, mesh.faces, mesh.textures), front),
        "blur_radius > 0 (soft rasterization)": lambda: render(mesh, front, blur_radius=1e-4),
    }
    return run_cases(cases)


def step_render_mesh(out, size: str = "default", *, progress: bool = True, seed: int = 0
                     ) -> StepResult:
    """Render the textured mesh as the tutorial does; antialiasing cost against accuracy.

    Sizes: Image size of the tutorial's views (64 / 512 / 512) and of the batch of views (64 /
    256 / 512 with 4 / 20 / 20 views). Progress: a progress bar over the renders; seed: unused
    (rendering is deterministic); kept for a common signature. Writes into ``out/render_mesh``;
    the signature and the StepResult are :func:`run_step`'s.
    """
    res, d, t0, data, mesh = begin_textured_step(out, "render_mesh", size)
    S = pick_size(size, 64, 512, 512)
    SB = pick_size(size, 64, 256, 512)
    NB = pick_size(size, 4, 20, 20)
    res.config = {"mesh": data.name, "faces": mesh.n_faces, "image size": S,
                  "batch": f"{NB} views at {SB} px"}
    res.description = (
        "The tutorial's renders by Embree ray casting (one ray per pixel centre: PyTorch3D's "
        "hard rasterization with faces_per_pixel=1): the front view with the light in front, "
        "then behind; a second view with green specular highlights; a batch of views. The "
        "speed-accuracy chart measures antialiasing (rays per pixel) against the error to a "
        "6 x 6 supersampled reference render of the same view.")
    bar = progress_bar(progress, 5, "render_mesh")
    front = look_at_cameras(2.7, 0.0, 180.0)

    def renderer(cams, size_, lights, **settings):
        return MeshRenderer(MeshRasterizer(cams, RasterizationSettings(image_size=size_,
                                                                       **settings)),
                            SoftPhongShader(lights=lights))

    timings = {}
    t = time.perf_counter()
    img1 = renderer(front, S, PointLights(location=[[0.0, 0.0, -3.0]]))(mesh)
    timings["front view"] = time.perf_counter() - t
    bar.update(1)
    img2 = renderer(front, S, PointLights(location=[[0.0, 0.0, 1.0]]))(mesh)
    bar.update(1)
    t = time.perf_counter()
    img3 = renderer(look_at_cameras(2.7, 10.0, -150.0), S,
                    PointLights(location=[[2.0, 2.0, -2.0]]))(
        mesh, materials=Materials(specular_color=[[0.0, 1.0, 0.0]], shininess=10.0))
    timings["second view, green specular"] = time.perf_counter() - t
    bar.update(1)
    cams_b = look_at_cameras(2.7, np.linspace(0.0, 180.0, NB), np.linspace(-180.0, 180.0, NB))
    t = time.perf_counter()
    batch = renderer(cams_b, SB, PointLights(location=[[0.0, 0.0, -3.0]]))(mesh.extend(NB))
    timings[f"batch of {NB} views"] = time.perf_counter() - t
    bar.update(1)

    res.images["front view, light in front"] = save_png(img1[0, ..., :3], d / "front.png")
    res.images["front view, light behind"] = save_png(img2[0, ..., :3], d / "light_behind.png")
    res.images["second view, green specular"] = save_png(img3[0, ..., :3], d / "specular.png")
    res.images["batch of views"] = save_png(make_grid(batch, cols=min(NB, 5)), d / "batch.png")
    tex = getattr(mesh.textures, "maps", None)
    if tex is not None:
        tex = np.asarray(tex)
        res.targets["texture map (input)"] = save_png(tex[..., :3], d / "texture.png")

    # antialiasing: rays per pixel side against the error to a supersampled reference
    lights = PointLights(location=[[0.0, 0.0, -3.0]])
    sizes = pick_size(size, (32, 64), (128, 256, 512), (128, 256, 512))
    factors = pick_size(size, (1, 2), (1, 2, 3), (1, 2, 3, 4))
    ref_factor = pick_size(size, 3, 6, 8)
    methods = []
    reference = None
    for s_ in sizes:  # image sizes
        ref = renderer(front, s_, lights, supersample=ref_factor)(mesh)[0, ..., :3]
        if s_ == sizes[-1]:
            reference = ref
        secs, err = [], []
        for f in factors:  # supersampling factors
            r = renderer(front, s_, lights, supersample=f)
            t = time.perf_counter()
            img = r(mesh)[0, ..., :3]
            secs.append(time.perf_counter() - t)
            err.append(float(np.abs(img - ref).mean()))
        methods.append(method_record(
            f"{s_}px", f"{s_} x {s_}, 1..{factors[-1]} rays per pixel side",
            seconds=secs, curve={"mean_abs_error": err},
            final={"rays_per_pixel_side": list(factors), "seconds": secs,
                   "mean_abs_error": err}, status="ok"))
        res.metrics += [{"image": f"{s_} x {s_}", "rays per pixel": f * f,
                         "seconds": round(secs[i], 4), "mean |RGB - reference|": err[i]}
                        for i, f in enumerate(factors)]
    bar.update(1)
    bar.close()
    res.methods = methods
    res.metrics += [{"image": k, "seconds": round(v, 4)} for k, v in timings.items()]
    res.targets[f"reference ({ref_factor}x{ref_factor} rays per pixel)"] = save_png(
        reference, d / "reference.png")
    res.comparison = image_panel(
        [[reference, img1[0], img2[0], img3[0]]], d / "comparison.png",
        col_labels=[f"reference\n{ref_factor}x{ref_factor} rays/pixel",
                    "1 ray/pixel\n(PyTorch3D's)", "light behind", "second view\ngreen specular"])
    res.comparison_caption = ("The supersampled reference next to the tutorial's renders "
                              f"({data.name}).")
    res.charts["Speed and accuracy: antialiasing cost against the error to the reference"] = \
        plot_accuracy_vs_time(method_series(methods), [
            {"metric": "mean_abs_error", "label": "mean |RGB - reference| (log)", "logy": True}],
            d / "speed_accuracy.png", xlabel="render wall time (s, log)",
            title=f"render_mesh: rays per pixel against error ({data.name}, {size} size)")
    tex_px = 0 if tex is None else int(tex.shape[0] * tex.shape[1])
    res.param_counts = [{"model": "scene: vertices", "count": mesh.n_verts},
                        {"model": "scene: faces", "count": mesh.n_faces},
                        {"model": "scene: texture texels", "count": tex_px}]
    res.stability = _render_stability(mesh, size)
    # both rows in the same units (seconds per view and per megapixel), each at its stated size;
    # the tutorial's batch renders at the single view's size, a smaller one is marked as a cut
    t1, tb = timings["front view"], timings[f"batch of {NB} views"]
    res.headline = {
        P3D_COLUMN: f"1 view at {S} x {S}, 1 ray/pixel: {t1:.3f} s per view, "
              f"{t1 / (S * S) * 1e6:.2f} s per megapixel",
        GEOFIT_COLUMN: f"batch of {NB} views at {SB} x {SB}: {tb / NB:.3f} s per view, "
             f"{tb / (NB * SB * SB) * 1e6:.2f} s per megapixel"
             + recipe_cut(SB, S, "px per side")}
    if data.path is None:
        res.notes.append("The tutorial's cow was not found (set GEOFIT_DATA): the mesh is "
                         "geofit's procedural textured stand-in.")
    res.seconds = time.perf_counter() - t0
    return res
