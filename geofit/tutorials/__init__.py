"""The six workflows of PyTorch3D's introductory tutorials, end to end, in one run.

:func:`run_tutorials` runs the steps below on the default data (the tutorial files when
``GEOFIT_DATA`` or the cache holds them, else geofit's procedural stand-ins), writes every image,
mesh (OBJ), volume (npz), history (JSON) and chart into one folder, and then the report
(``report.html``, ``report.md``, ``report.json``, see :mod:`geofit.report`). Each step is a
function ``step_<name>(out, size="default", *, progress=True, seed=0) -> StepResult`` in the
module of that name (shared parts in ``_common``, the runner in ``runner``, the stability
scenarios that benchmarks/ share in :mod:`geofit.tutorials.stability`) that calls the
workflow's public API:

* ``fit_mesh`` -- deform_source_mesh_to_target_mesh: :func:`geofit.fit.fit_mesh`;
* ``render_mesh`` -- render_textured_meshes: :class:`geofit.render.MeshRenderer`;
* ``render_points`` -- render_colored_points: :class:`geofit.render.PointsRenderer`;
* ``fit_views`` -- fit_textured_mesh: :func:`geofit.fit.views.fit_mesh_to_views`;
* ``fit_volume`` -- fit_textured_volume: :func:`geofit.fit.volume.fit_volume`;
* ``nerf`` -- fit_simple_neural_radiance_field: :func:`geofit.fit.nerf.fit_nerf`.

Sizes: ``"full"`` is the tutorials' own size (image sizes, views, iterations); ``"default"`` is
reduced so that the whole run takes a few minutes on two cores; ``"tiny"`` is for tests (seconds
per step, numbers not meaningful). Every fitting step runs PyTorch3D's recipe (ported: same
model, losses, optimiser and schedule, at the step's size) next to geofit's own method, on the
same data, and measures both the same way.

A step that raises is recorded as ``"failed: <exception>: <message>"`` (with the traceback in
``<out>/<step>/error.txt``); it is never silently dropped.
"""
from .shared import SIZES, StepResult, TutorialsRun
from .fit_mesh import step_fit_mesh
from .fit_views import step_fit_views
from .fit_volume import step_fit_volume
from .nerf import step_nerf
from .render_mesh import step_render_mesh
from .render_points import step_render_points
from .runner import STEPS, run_step, run_tutorials

__all__ = [
    "SIZES",
    "STEPS",
    "StepResult",
    "TutorialsRun",
    "run_step",
    "run_tutorials",
    "step_fit_mesh",
    "step_fit_views",
    "step_fit_volume",
    "step_nerf",
    "step_render_mesh",
    "step_render_points",
]
