"""The same mesh and camera in Open3D: an offscreen render to compare with, and the viewer.

:func:`render_open3d` renders meshes with Open3D's ``OffscreenRenderer`` (Filament; headless on
software Vulkan with ``libvulkan1`` and ``mesa-vulkan-drivers``) from geofit cameras converted by
:func:`geofit.cameras.to_open3d`, and returns colour, view depth and coverage. Open3D's lighting
model is not Phong's, so compare silhouettes and depth, and colours only by eye.

:func:`show_open3d` opens Open3D's interactive viewer at the same viewpoint.
"""
from __future__ import annotations

import atexit
import contextlib
import gc
import os
import sys
from typing import NamedTuple

import numpy as np

from ..cameras import FoVPerspectiveCameras, PerspectiveCameras, to_open3d
from ..structures import Mesh, Meshes, TexturesUV, TexturesVertex, as_mesh, as_meshes
from .mesh.textures import TexturesFlat

__all__ = ["Open3DRender", "mesh_to_open3d", "render_open3d", "show_open3d"]

# The cameras with an Open3D (pinhole) equivalent: FoV cameras and calibrated ones, whose
# principal point may lie off the image centre (captures).
_PINHOLE = (FoVPerspectiveCameras, PerspectiveCameras)


def _check_pinhole(cameras, name: str = "cameras") -> None:
    if not isinstance(cameras, _PINHOLE):
        raise TypeError(f"{name}: expected FoVPerspectiveCameras or PerspectiveCameras (Open3D "
                        f"has pinhole cameras only), got {type(cameras)!r}")


class Open3DRender(NamedTuple):
    """Output of :func:`render_open3d`.

    Attributes
    ----------
    images : (N, H, W, 3) float32
        RGB in [0, 1] as Open3D renders it: its own lights, exposure and tone mapping (the
        background colour is tone mapped too, so white comes out light grey).
    depth : (N, H, W) float64
        View-space depth (PyTorch3D's zbuf), ``inf`` where no surface is seen.
    mask : (N, H, W) bool
        Pixels that see the mesh (finite depth).
    """

    images: np.ndarray
    depth: np.ndarray
    mask: np.ndarray


def mesh_to_open3d(mesh: Mesh):
    """An ``open3d.geometry.TriangleMesh`` with the mesh's normals and colours.

    TexturesUV become per-corner UVs plus the texture image (8-bit); TexturesVertex become vertex colours; a TexturesFlat colour is painted on every
    vertex (per-face colours are written on a copy of the mesh with three vertices per face).

    Returns
    -------
    (open3d.geometry.TriangleMesh, open3d.geometry.Image or None)
        The mesh and its texture image (None without a UV texture).
    """
    import open3d as o3d  # kept local: start-up

    tex = mesh.textures
    if isinstance(tex, TexturesFlat) and tex.per_face:
        if len(tex.colors) != mesh.n_faces:
            raise ValueError(f"textures.colors: expected shape ({mesh.n_faces}, "
                             f"{tex.n_channels}), got {tex.colors.shape}")
        V = mesh.verts[mesh.faces.ravel()]
        F = np.arange(3 * mesh.n_faces).reshape(-1, 3)
        soup = Mesh(V, F)
        m = soup.to_open3d()
        m.vertex_normals = o3d.utility.Vector3dVector(np.repeat(mesh.face_normals, 3, axis=0))
        m.vertex_colors = o3d.utility.Vector3dVector(
            np.clip(np.repeat(tex.colors[:, :3], 3, axis=0), 0, 1))
        return m, None
    m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.array(mesh.verts)),
                                  o3d.utility.Vector3iVector(mesh.faces.astype(np.int32)))
    m.vertex_normals = o3d.utility.Vector3dVector(np.array(mesh.verts_normals))
    image = None
    if isinstance(tex, TexturesUV):
        uv = tex.verts_uvs[tex.faces_uvs].reshape(-1, 2)  # same (u, v) convention as OBJ
        m.triangle_uvs = o3d.utility.Vector2dVector(uv)
        m.triangle_material_ids = o3d.utility.IntVector(np.zeros(mesh.n_faces, np.int32))
        img = np.clip(tex.maps[..., :3] if tex.maps.shape[2] >= 3 else
                      np.repeat(tex.maps[..., :1], 3, axis=2), 0, 1)
        image = o3d.geometry.Image(np.ascontiguousarray((img * 255 + 0.5).astype(np.uint8)))
        m.textures = [image]
    elif isinstance(tex, TexturesVertex) and tex.n_channels >= 3:
        m.vertex_colors = o3d.utility.Vector3dVector(np.clip(tex.verts_features[:, :3], 0, 1))
    elif isinstance(tex, TexturesFlat):
        m.paint_uniform_color(np.clip(np.resize(tex.colors[0], 3), 0, 1))
    return m, image


def _as_views(meshes, cameras):
    meshes = as_meshes(meshes)  # geofit, trimesh or Open3D meshes
    _check_pinhole(cameras)
    nm, nc = len(meshes), len(cameras)
    N = max(nm, nc)
    if nm == 0 or nm not in (1, N) or nc not in (1, N):
        raise ValueError(f"meshes and cameras: batch sizes must be 1 or N, got {nm} meshes and "
                         f"{nc} cameras")
    return [meshes[b if nm > 1 else 0] for b in range(N)], [cameras[b if nc > 1 else 0]
                                                             for b in range(N)]


def _size(image_size) -> tuple[int, int]:
    if isinstance(image_size, (int, np.integer)):
        image_size = (int(image_size), int(image_size))
    H, W = (int(v) for v in image_size)
    if H < 1 or W < 1:
        raise ValueError(f"image_size: expected positive (H, W), got {image_size!r}")
    return H, W


_RENDERER: dict = {}  # at most one cached OffscreenRenderer: {"size": (W, H), "r": renderer}


def _release_renderer() -> None:
    """Free the cached renderer (emptied first: Filament aborts if a material is still used)."""
    r = _RENDERER.pop("r", None)
    _RENDERER.clear()
    if r is not None:
        with quiet_open3d():
            r.scene.clear_geometry()
            del r
            gc.collect()


atexit.register(_release_renderer)


@contextlib.contextmanager
def quiet_open3d():
    """Silence Open3D and Filament inside the block: Open3D's log below errors, and the process's
    C-level stdout and stderr sent to the null device (Filament prints its engine log, "FEngine
    (64 bits) created ...", straight to file descriptor 1, which Python's ``sys.stdout`` and
    ``contextlib.redirect_stdout`` never see; a notebook kernel shows it in the cell's output).
    Python-level output is flushed first and restored after; an exception passes through."""
    import open3d as o3d

    level = o3d.utility.get_verbosity_level()
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (AttributeError, OSError, ValueError):
            pass
    saved = []
    try:
        with open(os.devnull, "wb") as null:
            for fd in (1, 2):
                try:
                    saved.append((fd, os.dup(fd)))
                    os.dup2(null.fileno(), fd)
                except OSError:  # no such descriptor (embedded interpreters): leave it
                    pass
            yield
    finally:
        for fd, copy in saved:
            os.dup2(copy, fd)
            os.close(copy)
        o3d.utility.set_verbosity_level(level)


def _offscreen(W: int, H: int):
    """The cached OffscreenRenderer of size W x H (starting Filament costs seconds)."""
    import open3d as o3d  # kept local: start-up

    if _RENDERER.get("size") != (W, H):
        _release_renderer()
        with quiet_open3d():
            _RENDERER["r"] = o3d.visualization.rendering.OffscreenRenderer(W, H)
        _RENDERER["size"] = (W, H)
    return _RENDERER["r"]


def render_open3d(meshes, cameras, image_size, *, background_color=(1.0, 1.0, 1.0),
                  lit: bool = True) -> Open3DRender:
    """Render meshes from geofit cameras with Open3D's offscreen renderer.

    Parameters
    ----------
    meshes : Mesh or Meshes
        One mesh per view, or one mesh for every camera.
    cameras : FoVPerspectiveCameras or PerspectiveCameras
        ``N`` cameras (or one for every mesh), converted with :func:`geofit.cameras.to_open3d`
        (Open3D's pinhole intrinsics keep a principal point off the image centre).
    image_size : int or (H, W)
    background_color : (3,) float
        RGB of the background.
    lit : bool
        Open3D's ``defaultLit`` shader (its default image-based light plus a sun) or
        ``defaultUnlit`` (the raw texture / vertex colours).

    Returns
    -------
    Open3DRender
        ``images (N, H, W, 3)``, ``depth (N, H, W)`` (view z, inf on the background) and
        ``mask (N, H, W)``.

    Raises
    ------
    TypeError, ValueError
        For wrong inputs. Errors from Open3D (no rendering backend) propagate as RuntimeError.

    Notes
    -----
    The renderer is created once per image size and kept (Filament's start-up and shader
    compilation take seconds on a software Vulkan device); it is released at exit or when
    another size is asked for.
    """
    import open3d as o3d  # kept local: start-up

    H, W = _size(image_size)
    views, cams = _as_views(meshes, cameras)
    rendering = o3d.visualization.rendering
    renderer = _offscreen(W, H)
    images = np.zeros((len(views), H, W, 3), np.float32)
    depth = np.full((len(views), H, W), np.inf)
    try:
        renderer.scene.set_background(np.r_[np.asarray(background_color, float), 1.0])
        current = None
        for b, (mesh, cam) in enumerate(zip(views, cams)):  # loop over views
            if mesh is not current:
                renderer.scene.clear_geometry()
                if mesh.n_faces:
                    m, image = mesh_to_open3d(mesh)
                    mat = rendering.MaterialRecord()
                    mat.shader = "defaultLit" if lit else "defaultUnlit"
                    if image is not None:
                        mat.albedo_img = image
                    renderer.scene.add_geometry("mesh", m, mat)
                current = mesh
            p = to_open3d(cam, (H, W))[0]
            renderer.setup_camera(p.intrinsic, p.extrinsic)
            images[b] = np.asarray(renderer.render_to_image(), np.float32)[..., :3] / 255.0
            z = np.asarray(renderer.render_to_depth_image(z_in_view_space=True), np.float64)
            depth[b] = np.where(np.isfinite(z), z, np.inf) if mesh.n_faces else np.inf
    finally:
        renderer.scene.clear_geometry()
    return Open3DRender(images, depth, np.isfinite(depth))


def display_problem(timeout: float = 3.0) -> str | None:
    """Why no display would answer a viewer (a sentence), or None when one answers.

    ``DISPLAY`` / ``WAYLAND_DISPLAY`` unset; or the X server they name does not complete the
    X11 connection set-up within ``timeout`` seconds (a stale ``DISPLAY`` of a closed SSH
    session or a stopped Xvfb); or the Wayland socket does not accept a connection. Standard
    library only: a socket and the 12-byte X11 set-up request, so the answer takes at most
    ``timeout`` seconds and never blocks in Open3D or GLFW.
    """
    import socket
    import struct

    wayland = os.environ.get("WAYLAND_DISPLAY")
    display = os.environ.get("DISPLAY")
    if not display and not wayland:
        return "no display (DISPLAY and WAYLAND_DISPLAY are unset)"
    if not display:
        path = wayland if os.path.isabs(wayland) else os.path.join(
            os.environ.get("XDG_RUNTIME_DIR", "/tmp"), wayland)
        try:
            with socket.socket(socket.AF_UNIX) as s:
                s.settimeout(timeout)
                s.connect(path)
            return None
        except OSError as exc:
            return f"the Wayland display {wayland!r} does not answer ({exc.strerror or exc})"
    host, _, rest = display.rpartition(":")
    number = rest.split(".")[0]
    if not number.isdigit():
        return f"DISPLAY={display!r} is not a display name (host:number)"
    local = host in ("", "unix") or host.startswith("/")
    try:
        with socket.socket(socket.AF_UNIX if local else socket.AF_INET) as s:
            s.settimeout(timeout)
            if local:
                s.connect(host if host.startswith("/") else f"/tmp/.X11-unix/X{number}")
            else:
                s.connect((socket.gethostbyname(host), 6000 + int(number)))
            # the X11 set-up request: little-endian, protocol 11.0, no authorisation; any
            # reply (success, failure or "authenticate") means a server answers
            s.sendall(struct.pack("<BxHHHHxx", ord("l"), 11, 0, 0, 0))
            if not s.recv(8):
                return f"the X display {display!r} closed the connection"
    except OSError as exc:
        return f"the X display {display!r} does not answer ({exc.strerror or exc})"
    return None


def show_open3d(mesh, cameras, image_size=(512, 512), *, index: int = 0, run: bool = True,
                timeout: float = 3.0):
    """Open Open3D's interactive viewer on ``mesh`` at the viewpoint of ``cameras[index]``.

    Parameters
    ----------
    mesh : Mesh
    cameras : FoVPerspectiveCameras or PerspectiveCameras
    image_size : int or (H, W)
        Window size (the camera's field of view is kept).
    index : int
        Which camera of the batch.
    run : bool
        Run the viewer's event loop (blocks until the window is closed) and close it. With
        False the ``open3d.visualization.Visualizer`` is returned, its window open and its view
        set, for scripting (``capture_screen_float_buffer``) or tests; call
        ``destroy_window()`` when done.
    timeout : float
        Seconds the display has to answer (:func:`display_problem`) before a window is made.

    Returns
    -------
    open3d.visualization.Visualizer or None

    Raises
    ------
    RuntimeError
        On Linux, at once (within ``timeout``) and saying why, when no display answers: unset
        ``DISPLAY`` (with ``run=True``; with ``run=False`` Open3D may still find an offscreen
        fallback), or a ``DISPLAY`` naming an X server that does not answer (a stale
        ``DISPLAY``, which would otherwise hang in ``create_window``). Also if Open3D cannot
        create a window.
    """
    import open3d as o3d  # kept local: start-up

    mesh = as_mesh(mesh, "mesh")  # a geofit, trimesh or Open3D mesh
    _check_pinhole(cameras)
    if not isinstance(index, (int, np.integer)) or not -len(cameras) <= index < len(cameras):
        raise ValueError(f"index: expected an integer in [0, {len(cameras)}), got {index!r}")
    H, W = _size(image_size)
    if sys.platform.startswith("linux"):
        # issue 18: with no display run() waits for ever; issue 26: a stale DISPLAY (no X
        # server behind it) hangs create_window. Ask the display first, with a timeout.
        why = display_problem(timeout)
        if why is not None and (run or "unset" not in why):
            raise RuntimeError(f"show_open3d: {why}, so the viewer could never be closed; use "
                               "render_open3d(...) for an offscreen image, or run=False to "
                               "script the viewer")
    m, _ = mesh_to_open3d(mesh)
    vis = o3d.visualization.Visualizer()
    with quiet_open3d():
        made = vis.create_window(window_name="geofit", width=W, height=H)
    if not made:
        raise RuntimeError("Open3D could not create a viewer window (no display?)")
    vis.add_geometry(m)
    ctr = vis.get_view_control()
    params = to_open3d(cameras[int(index)], (H, W))[0]
    if not ctr.convert_from_pinhole_camera_parameters(params, allow_arbitrary=True):
        vis.destroy_window()
        raise RuntimeError("Open3D rejected the camera parameters")
    opt = vis.get_render_option()
    opt.mesh_show_back_face = True
    if not run:
        return vis
    vis.run()
    vis.destroy_window()
    return None
