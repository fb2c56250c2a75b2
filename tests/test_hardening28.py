"""Issue 28: one checked path resolver, pixel and array caps, atomic saves, one PLY reader,
wrapped errors and size estimates. Each test states the invariant it checks; each failed on
the main branch before the change (see the report of the hardening branch)."""
from __future__ import annotations

import json
import os
import signal
import sys

import numpy as np
import pytest
from PIL import Image

from geofit.io import load_mesh, load_obj, load_views


def _png(path, shape=(4, 6, 4), value=200):
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.full(shape, value, np.uint8)).save(path)
    return path


def _capture(root, frames):
    root.mkdir(parents=True, exist_ok=True)
    (root / "transforms.json").write_text(json.dumps(
        {"camera_angle_x": 0.7, "frames": [{"transform_matrix": np.eye(4).tolist(), **f}
                                           for f in frames]}))
    return root


# --------------------------------------------------------------------------- 1. path resolver
def test_extensionless_file_path_symlink_escape_refused(tmp_path):
    """``"file_path": "lnk"`` with ``lnk.png -> outside``: the extension candidate goes through
    the same check as the written path, so the outside file is never read."""
    secret = _png(tmp_path / "secret" / "s.png")
    cap = _capture(tmp_path / "cap", [{"file_path": "lnk"}])
    (cap / "lnk.png").symlink_to(secret)
    with pytest.raises(ValueError, match=r"frames\[0\]\.file_path: path 'lnk\.png' resolves "
                                         r"outside the capture folder"):
        load_views(cap)
    assert load_views(cap, allow_outside=True).images.shape == (1, 4, 6, 3)


def test_mask_path_symlink_escape_refused(tmp_path):
    """``mask_path`` goes through the resolver too (with and without an extension)."""
    secret = _png(tmp_path / "secret" / "m.png", (4, 6), 255)
    cap = _capture(tmp_path / "cap", [{"file_path": "a.png", "mask_path": "m"}])
    _png(cap / "a.png")
    (cap / "m.png").symlink_to(secret)
    with pytest.raises(ValueError, match=r"frames\[0\]\.mask_path: path 'm\.png' resolves "
                                         r"outside"):
        load_views(cap)


def test_fifo_and_folder_candidates_refused_without_opening(tmp_path):
    """A FIFO named by a capture or an MTL is refused from its file type (opening it would
    block forever); so is a folder."""
    cap = _capture(tmp_path / "cap", [{"file_path": "f"}])
    os.mkfifo(cap / "f.png")
    with pytest.raises(ValueError, match=r"file_path: .*f\.png' is a FIFO"):
        load_views(cap)
    (tmp_path / "m").mkdir()
    os.mkfifo(tmp_path / "m" / "t.png")
    (tmp_path / "m" / "m.mtl").write_text("newmtl a\nmap_Kd t.png\n")
    (tmp_path / "m" / "m.obj").write_text("mtllib m.mtl\nusemtl a\nv 0 0 0\nv 1 0 0\nv 0 1 0\n"
                                          "vt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n")
    with pytest.raises(ValueError, match=r"m\.mtl: line 2: map_Kd texture: .*is a FIFO"):
        load_obj(tmp_path / "m" / "m.obj")
    os.mkfifo(tmp_path / "user.obj")
    with pytest.raises(ValueError, match=r"user\.obj: expected a regular OBJ file, got a FIFO"):
        load_obj(tmp_path / "user.obj")


def test_trimesh_resolver_refuses_what_the_policy_refuses(tmp_path):
    """The trimesh route's resolver is a ``trimesh.resolvers.Resolver`` with the same policy."""
    import trimesh

    from geofit.io._paths import PathPolicy, trimesh_resolver

    (tmp_path / "in").mkdir()
    (tmp_path / "in" / "ok.bin").write_bytes(b"abc")
    (tmp_path / "out.bin").write_bytes(b"secret")
    (tmp_path / "in" / "lnk.bin").symlink_to(tmp_path / "out.bin")
    r = trimesh_resolver(PathPolicy(tmp_path / "in"), "scene.gltf")
    assert isinstance(r, trimesh.resolvers.Resolver)
    assert r.get("ok.bin") == b"abc"
    for bad, why in (("../out.bin", "leaves"), ("lnk.bin", "resolves outside"),
                     (str(tmp_path / "out.bin"), "absolute"), ("x" * 5000, "too long")):
        with pytest.raises(ValueError, match=why):
            r.get(bad)
