"""Helpers shared by several test files (imported as ``from _helpers import ...``; pytest puts
this folder on the path, as it does for ``conftest.py``)."""
from __future__ import annotations

import functools
import importlib.util
import tracemalloc
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def peak_bytes(fn, *args, **kwargs):
    """Run ``fn`` under tracemalloc; return (exception or None, peak traced bytes)."""
    tracemalloc.start()
    try:
        fn(*args, **kwargs)
        err = None
    except Exception as exc:  # noqa: BLE001 - returned to the test to inspect
        err = exc
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return err, peak


@functools.cache
def benchmark_module(name: str):
    """The module ``benchmarks/<name>.py`` (``name`` may hold a folder:
    ``"third_party/p3d_tutorials"``), loaded from its file (benchmarks/ is no package)."""
    spec = importlib.util.spec_from_file_location(f"_bench_{name.replace('/', '_')}",
                                                  ROOT / "benchmarks" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def glb_round_trip(mesh, path):
    """Save a UV-textured ``mesh`` as GLB at ``path`` and load it back; the reloaded mesh has a
    TexturesUV and the same per-corner positions and UVs (float32 in the file: 1e-6)."""
    from geofit.io import load_mesh, save_mesh
    from geofit.structures import TexturesUV

    save_mesh(path, mesh)
    back = load_mesh(path)
    assert isinstance(back.textures, TexturesUV)
    np.testing.assert_allclose(back.verts[back.faces], mesh.verts[mesh.faces], atol=1e-6)
    t = mesh.textures
    np.testing.assert_allclose(back.textures.verts_uvs[back.textures.faces_uvs],
                               t.verts_uvs[t.faces_uvs], atol=1e-6)
    return back
