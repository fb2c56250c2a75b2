"""Long fuzz run of geofit's loaders over mutated tutorial files (issue 18).

Mutates the real tutorial files (the cow with its MTL and texture, the dolphin) and the test
shapes in ``$GEOFIT_DATA/shapes`` -- truncation, flipped bytes and bits, huge, zero and negative
indices, NaN / inf / overflowing numbers, control and non-UTF-8 bytes, \\r\\n and \\r line ends,
a BOM, 2-, 10- and 1000-gons, deleted and shuffled lines, missing or outside MTL and texture
files, textures that are not images (or are bombs, 16-bit, float), empty files and directories
-- plus PLY and npz point clouds built from the cow's vertices and mutated the same way.

Each input runs in a worker process (at most ``--workers``, default 2) with a timeout: a
worker that does not answer in time is killed and the input counted as a ``hang``; a worker
that dies is a ``crash``. The allowed outcomes are ``ok`` (a finite result, indices in range,
derived areas and normals finite), ``ok_warned`` (the same with geofit's documented
missing-MTL UserWarning), ``ValueError`` and ``FileNotFoundError`` whose message names a file.
Anything else -- another exception type, an error naming no file, a warning such as a numpy
RuntimeWarning, a non-finite result, a hang or a crash -- is counted under its own name.

Workers run with ``GEOFIT_MEMORY_LIMIT=1G`` and an address-space limit, so a decompression
bomb that slipped past the guards would show up as a MemoryError instead of taking the machine.

Writes ``benchmarks/results/fuzz_loaders.json`` (counts per family and outcome, examples of
every outcome outside the allowed set, the command, machine and load). Run from the repository
root, e.g. ``nice -n 10 python benchmarks/fuzz_loaders.py --n 20000``.
"""
from __future__ import annotations

import argparse
import datetime as _dt
import io
import json
import multiprocessing as mp
import os
import random
import re
import shutil
import struct
import sys
import tempfile
import time
import zipfile
import zlib
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

ALLOWED = ("ok", "ok_warned", "ValueError", "FileNotFoundError")
_MISSING_MTL = "material library not found"


def glb_container(doc: dict, binary: bytes = b"") -> bytes:
    """A GLB file: the glTF JSON ``doc`` and the ``binary`` chunk, each padded to 4 bytes, behind
    the 12-byte header (also used by tests/test_hardening28.py to build its malformed files)."""
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    binary += b"\0" * (-len(binary) % 4)
    body = struct.pack("<II", len(js), 0x4E4F534A) + js
    if binary:
        body += struct.pack("<II", len(binary), 0x004E4942) + binary
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


# ============================================================================ worker side
def _check_obj(d) -> str | None:
    if not (np.isfinite(d.verts).all() and np.isfinite(d.normals).all()
            and np.isfinite(d.verts_uvs).all()):
        return "non-finite vertices, normals or uvs"
    if d.faces.min() < 0 or d.faces.max() >= len(d.verts):
        return "face index out of range"
    if d.faces_uvs.min() < -1 or d.faces_uvs.max() >= max(len(d.verts_uvs), 1):
        return "uv index out of range"
    if d.faces_normals_idx.min() < -1 or d.faces_normals_idx.max() >= max(len(d.normals), 1):
        return "normal index out of range"
    for img in d.texture_images.values():
        if img.ndim != 3 or img.shape[2] != 3 or not np.isfinite(img).all():
            return "bad texture image"
    return None


def _check_mesh(m) -> str | None:
    if not np.isfinite(m.verts).all():
        return "non-finite vertices"
    if not (np.isfinite(m.face_areas).all() and np.isfinite(m.verts_normals).all()):
        return "non-finite areas or normals"
    maps = getattr(m.textures, "maps", None)
    if maps is not None and not np.isfinite(maps).all():
        return "non-finite texture"
    return None


def _check_cloud(c) -> str | None:
    for a in (c.points, c.features, c.normals):
        if a is not None and not np.isfinite(a).all():
            return "non-finite cloud arrays"
    return None


def _materialise(case: Path, task: dict) -> None:
    if case.exists():
        shutil.rmtree(case)
    case.mkdir(parents=True)
    for name, data in task["files"].items():
        p = case / name
        p.parent.mkdir(parents=True, exist_ok=True)
        if data is None:
            p.mkdir(exist_ok=True)
        else:
            p.write_bytes(data)
    for name, target in task.get("symlinks", {}).items():
        (case / name).parent.mkdir(parents=True, exist_ok=True)
        (case / name).symlink_to(case / target)  # relative to the case ("../secret": outside)
    for name in task.get("fifos", []):
        (case / name).parent.mkdir(parents=True, exist_ok=True)
        os.mkfifo(case / name)


def _run_task(task: dict, case: Path) -> tuple[str, str]:
    """(outcome, detail) of one input."""
    import warnings

    from geofit.io import load_mesh, load_obj, load_objs_as_meshes, load_pointcloud, load_views

    _materialise(case, task)
    entry = case / task["entry"]
    loader = {"load_obj": load_obj, "load_mesh": load_mesh,
              "load_objs_as_meshes": load_objs_as_meshes, "load_views": load_views,
              "load_pointcloud": load_pointcloud}[task["loader"]]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            with np.errstate(all="warn"):
                out = loader(entry, **task.get("kwargs", {}))
            exc = None
        except Exception as e:  # noqa: BLE001 - classified below
            exc = e
    odd = [w for w in caught if not (issubclass(w.category, UserWarning)
                                     and _MISSING_MTL in str(w.message))]
    if odd:
        w = odd[0]
        return f"warning:{w.category.__name__}", f"{str(w.message)[:300]} ({w.filename}:{w.lineno})"
    if exc is not None:
        name = type(exc).__name__
        msg = str(exc)
        if not isinstance(exc, (ValueError, FileNotFoundError)) or type(exc) not in (
                ValueError, FileNotFoundError):
            import traceback
            tb = "".join(traceback.format_exception(exc)[-3:])
            return f"other:{name}", f"{msg[:300]} | {tb[-600:]}"
        if not msg.strip():
            return f"{name}_empty_message", ""
        if not (str(case) in msg or task["entry"] in msg or msg.startswith("path:")
                or re.match(r"/\S+: ", msg)):  # a file outside the case (allow_outside=True)
            return f"{name}_names_no_file", msg[:300]
        return name, msg.replace(str(case), "<case>")[:200]
    if task.get("expect_error"):
        return "silent_wrong_load", f"{task['mutator']} loaded without an error"
    if task["loader"] == "load_views":
        bad = None if np.isfinite(out.images).all() else "non-finite images"
    elif task["loader"] == "load_obj":
        bad = _check_obj(out)
    elif task["loader"] == "load_pointcloud":
        bad = _check_cloud(out)
    else:
        meshes = [out] if task["loader"] == "load_mesh" else list(out)
        bad = next((b for b in map(_check_mesh, meshes) if b), None)
    if bad:
        return "nonfinite_or_out_of_range", bad
    return ("ok_warned" if caught else "ok"), ""


_BLOWUP_BYTES = 1 << 30  # peak memory above the worker's, for an input under 1 MB
_SMALL_INPUT = 1 << 20


def _run_forked(task: dict, case: Path, secret: Path, timeout: float) -> tuple[str, str]:
    """Run one input in a forked child: an audit hook records every ``open`` of a file under
    ``secret`` (outside the case: an escape), ``alarm`` turns a hang into SIGALRM, and the
    child's peak RSS (``wait4``) is compared with the worker's."""
    import resource
    import signal

    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    rfd, wfd = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child
        os.close(rfd)
        signal.alarm(max(1, int(timeout)))
        sec = os.path.realpath(secret) + os.sep
        opened: list = []

        def hook(event, args):
            if event == "open" and args and isinstance(args[0], (str, bytes, os.PathLike)):
                p = os.fsdecode(args[0])
                if os.path.realpath(p).startswith(sec):
                    opened.append(p)

        sys.addaudithook(hook)
        try:
            res = _run_task(task, case)
        except MemoryError:
            res = ("other:MemoryError", "")
        except BaseException as e:  # noqa: BLE001 - a failure of the harness itself
            res = (f"harness_error:{type(e).__name__}", str(e)[:300])
        if opened:
            res = ("escape", f"{task['mutator']}: opened {opened[0]}")
        os.write(wfd, json.dumps(res).encode())
        os._exit(0)
    os.close(wfd)
    chunks = []
    while True:
        b = os.read(rfd, 65536)
        if not b:
            break
        chunks.append(b)
    os.close(rfd)
    _, status, usage = os.wait4(pid, 0)
    peak = usage.ru_maxrss * 1024
    if os.WIFSIGNALED(status):
        sig = os.WTERMSIG(status)
        if sig == signal.SIGALRM:
            return "hang", f"{task['mutator']}: no answer in {timeout:g} s"
        return "crash", f"{task['mutator']}: killed by signal {sig}"
    try:
        outcome, detail = json.loads(b"".join(chunks))
    except ValueError:
        return "crash", f"{task['mutator']}: exit status {os.WEXITSTATUS(status)}, no answer"
    size = sum(len(v) for v in task["files"].values() if v)
    if size < _SMALL_INPUT and peak - base > _BLOWUP_BYTES:
        return "blowup", f"{task['mutator']}: peak {peak - base:,} bytes above the worker"
    return outcome, detail


def _worker(conn, workdir: str, address_space: int, timeout: float = 25.0) -> None:
    import resource

    if address_space:
        resource.setrlimit(resource.RLIMIT_AS, (address_space, address_space))
    os.environ["GEOFIT_MEMORY_LIMIT"] = "1G"
    import geofit.io  # noqa: F401 - import once, before the first timed input

    secret = Path(workdir) / "secret"  # files outside every case: reading one is an escape
    secret.mkdir(parents=True, exist_ok=True)
    (secret / "s.png").write_bytes(_png(np.full((4, 6, 3), 7, np.uint8)))
    conn.send("ready")
    case = Path(workdir) / "case"
    while True:
        task = conn.recv()
        if task is None:
            break
        try:
            res = _run_forked(task, case, secret, timeout)
        except Exception as e:  # noqa: BLE001 - a failure of the harness itself
            res = (f"harness_error:{type(e).__name__}", str(e)[:300])
        conn.send(res)


class _Worker:
    def __init__(self, ctx, workdir: Path, address_space: int, timeout: float = 25.0):
        self.workdir = workdir
        self.conn, child = ctx.Pipe()
        self.proc = ctx.Process(target=_worker, args=(child, str(workdir), address_space,
                                                      timeout), daemon=True)
        self.proc.start()
        child.close()
        if not self.conn.poll(120) or self.conn.recv() != "ready":
            raise RuntimeError("fuzz worker did not start")
        self.task = None
        self.started = 0.0

    def send(self, task: dict) -> None:
        self.task = task
        self.started = time.monotonic()
        self.conn.send(task)

    def kill(self) -> None:
        self.proc.kill()  # only this worker, which this script started
        self.proc.join(10)


# ============================================================================ inputs
_NUM_RE = re.compile(rb"-?\d+\.?\d*(?:[eE][-+]?\d+)?")
_SPECIAL_NUMBERS = [b"nan", b"NaN", b"inf", b"-inf", b"1e400", b"-1e400", b"1e154", b"1e39",
                    b"1e-400", b"-0", b"", b"1e", b"--1", b"0x1F", b"1,5", b"\xd9\xa1",
                    b"9" * 400, b"1" + b"0" * 30]
_CONTROL = [bytes([c]) for c in list(range(0, 9)) + list(range(14, 32)) + [127]] + [
    b"\x0b", b"\x0c", b"\r", "\u2028".encode(), "\x85".encode(), b"\x85", b"\xa0", b"\xc2\xa0"]


def _flip(b: bytes, r: random.Random, most: int = 12, bits: bool = False) -> bytes:
    """1 to ``most`` random bytes replaced (or single bits flipped)."""
    ba = bytearray(b)
    for _ in range(r.randint(1, most)):
        if ba:
            i = r.randrange(len(ba))
            ba[i] = ba[i] ^ (1 << r.randrange(8)) if bits else r.randrange(256)
    return bytes(ba)


def _line_bounds(b: bytes, r: random.Random) -> int:
    """A random position at the start of a line."""
    pos = r.randrange(len(b) + 1) if b else 0
    nl = b.rfind(b"\n", 0, pos)
    return nl + 1


def _special_line(r: random.Random, nv: int) -> bytes:
    big = r.choice([10**9, 2**31, 2**63 - 1, 2**63, 10**19, 10**40])
    choices = [
        f"f 1 2 {big}", f"f -1 -2 -{big}", f"f 0 1 2", f"f {nv} {nv + 1} 1", f"f -{nv + 1} 1 2",
        "f 1 2", "f 1", "f", "f " + " ".join(str(1 + i % max(nv, 1)) for i in range(10)),
        "f " + " ".join(str(1 + i % max(nv, 1)) for i in range(1000)),
        "f 1/1/1 2//2 3/3", "f 1/ 2/ 3/", "f 1//// 2 3", "f a b c", "f 1.5 2 3", "f +1 +2 +3",
        "f 1/99999 2/99999 3/99999", "f 1//-99 2//-99 3//-99",
        "v nan 0 0", "v inf 0 0", "v 1e400 0 0", "v 1e154 1e154 1e154", "v 1e39 0 0", "v 0 0",
        "v", "v 1 2 3 4 5 6 7", "vt nan 0", "vt 0", "vn 0 0", "vn inf 0 0",
        "usemtl", "usemtl missing", "mtllib", "mtllib missing.mtl", "mtllib ../outside.mtl",
        "mtllib /etc/hostname", "mtllib sub", "g", "s 1", "o x", "l 1 2", "p 1",
        "\ufeffv 0 0 0", "v 1\x1f2 3", "v 1\x002 3", "v 1\u20282 3", "v 1\xa02 3",
        "v " + "1" * 5000 + " 0 0",
    ]
    return r.choice(choices).encode("utf-8") + b"\n"


def _mutate_obj(b: bytes, r: random.Random) -> tuple[str, bytes]:
    """One mutation of OBJ bytes -> (name, bytes)."""
    nv = b.count(b"\nv ") + (1 if b.startswith(b"v ") else 0)
    kind = r.choice(["truncate", "flip_bytes", "flip_bits", "special_line", "special_line",
                     "number", "number", "control", "non_utf8", "crlf", "cr", "mixed_eol",
                     "bom", "delete_lines", "shuffle_lines", "duplicate", "keyword", "polygon",
                     "combo"])
    if kind == "truncate":
        return kind, b[: r.randrange(len(b) + 1)]
    if kind in ("flip_bytes", "flip_bits"):
        return kind, _flip(b, r, bits=kind == "flip_bits")
    if kind == "special_line":
        out = b
        for _ in range(r.randint(1, 3)):
            p = _line_bounds(out, r)
            out = out[:p] + _special_line(r, nv) + out[p:]
        return kind, out
    if kind == "number":
        out = b
        for _ in range(r.randint(1, 4)):
            m = _NUM_RE.search(out, r.randrange(len(out) + 1) if out else 0)
            if m:
                out = out[:m.start()] + r.choice(_SPECIAL_NUMBERS) + out[m.end():]
        return kind, out
    if kind == "control":
        out = b
        for _ in range(r.randint(1, 4)):
            p = r.randrange(len(out) + 1)
            out = out[:p] + r.choice(_CONTROL) + out[p:]
        return kind, out
    if kind == "non_utf8":
        out = b
        for _ in range(r.randint(1, 6)):
            p = r.randrange(len(out) + 1)
            out = out[:p] + bytes([r.randrange(128, 256)]) + out[p:]
        return kind, out
    if kind == "crlf":
        return kind, b.replace(b"\n", b"\r\n")
    if kind == "cr":
        return kind, b.replace(b"\n", b"\r")
    if kind == "mixed_eol":
        lines = b.split(b"\n")
        return kind, b"".join(ln + r.choice([b"\n", b"\r\n", b"\r", b"\n\n"]) for ln in lines)
    if kind == "bom":
        return kind, b"\xef\xbb\xbf" + b
    lines = b.split(b"\n")
    if kind == "delete_lines":
        for _ in range(r.randint(1, 20)):
            if lines:
                del lines[r.randrange(len(lines))]
        return kind, b"\n".join(lines)
    if kind == "shuffle_lines":
        i = r.randrange(len(lines))
        w = lines[i:i + r.randint(2, 200)]
        r.shuffle(w)
        lines[i:i + len(w)] = w
        return kind, b"\n".join(lines)
    if kind == "duplicate":
        return kind, b + b"\n" + b[: r.randrange(len(b) + 1)]
    if kind == "keyword":
        for _ in range(r.randint(1, 5)):
            i = r.randrange(len(lines))
            parts = lines[i].split(b" ", 1)
            if len(parts) == 2:
                lines[i] = r.choice([b"v", b"vt", b"vn", b"f", b"usemtl", b"mtllib", b"#",
                                     b"V", b"f\x00", b""]) + b" " + parts[1]
        return kind, b"\n".join(lines)
    if kind == "polygon":
        face_lines = [i for i, ln in enumerate(lines[:20000]) if ln.startswith(b"f ")]
        for _ in range(r.randint(1, 5)):
            if not face_lines:
                break
            i = r.choice(face_lines)
            corners = lines[i].split()[1:]
            k = r.choice([1, 2, 4, 10, 1000])
            lines[i] = b"f " + b" ".join((corners * (k // max(len(corners), 1) + 1))[:k])
        return kind, b"\n".join(lines)
    # combo: two mutations
    name1, out = _mutate_obj(b, r)
    name2, out = _mutate_obj(out, r)
    return f"combo", out


def _png(arr: np.ndarray, **kw) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(arr).save(buf, format="PNG", **kw)
    return buf.getvalue()


def _image(arr: np.ndarray, fmt: str, mode: str | None = None) -> bytes:
    from PIL import Image

    im = Image.fromarray(arr)
    if mode:
        im = im.convert(mode)
    buf = io.BytesIO()
    im.save(buf, format=fmt)
    return buf.getvalue()


def _png_bomb(w: int, h: int) -> bytes:
    def chunk(kind: bytes, data: bytes) -> bytes:
        return (struct.pack(">I", len(data)) + kind + data
                + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF))

    comp = zlib.compressobj(9)
    row = b"\0" * (w + 1)
    idat = b"".join(comp.compress(row) for _ in range(h)) + comp.flush()
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0))
            + chunk(b"IDAT", idat) + chunk(b"IEND", b""))


def _png_header_only(w: int, h: int) -> bytes:
    ihdr = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 13) + b"IHDR" + ihdr
            + struct.pack(">I", zlib.crc32(b"IHDR" + ihdr) & 0xFFFFFFFF))


class Inputs:
    """Seeded generator of fuzz tasks from the tutorial and shape files."""

    def __init__(self, data: Path, seed: int):
        self.r = random.Random(seed)
        self.cow_obj = (data / "cow_mesh" / "cow.obj").read_bytes()
        self.cow_mtl = (data / "cow_mesh" / "cow.mtl").read_bytes()
        self.cow_png = (data / "cow_mesh" / "cow_texture.png").read_bytes()
        self.objs = {"cow": self.cow_obj, "dolphin": (data / "dolphin" / "dolphin.obj").read_bytes()}
        for p in sorted((data / "shapes").glob("*.obj")):
            self.objs[p.stem] = p.read_bytes()
        # small valid texture-bearing OBJ for MTL / image families
        self.tiny_obj = (b"mtllib m.mtl\nusemtl a\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\n"
                         b"vt 0 0\nvt 1 0\nvt 0 1\nvt 1 1\nf 1/1 2/2 3/3\nf 2/2 4/4 3/3\n")
        rng = np.random.default_rng(seed)
        rgb = rng.integers(0, 256, (16, 16, 3), dtype=np.uint8)
        self.images = {
            "png_rgb": _png(rgb), "png_rgba": _image(rgb, "PNG", "RGBA"),
            "png_palette": _image(rgb, "PNG", "P"), "png_grey": _image(rgb, "PNG", "L"),
            "png_1bit": _image(rgb, "PNG", "1"), "png_la": _image(rgb, "PNG", "LA"),
            "png_16bit": _png(rng.integers(0, 65536, (16, 16), dtype=np.uint16)),
            "tiff_float": _image(rng.random((16, 16)).astype(np.float32), "TIFF"),
            "tiff_float_huge": _image(np.full((4, 4), 1e30, np.float32), "TIFF"),
            "tiff_float_nan": _image(np.full((4, 4), np.nan, np.float32), "TIFF"),
            "tiff_int32": _image(rng.integers(0, 2**31 - 1, (8, 8)).astype(np.int32), "TIFF"),
            "jpeg": _image(rgb, "JPEG"), "jpeg_cmyk": _image(rgb, "JPEG", "CMYK"),
            "gif": _image(rgb, "GIF"), "bmp": _image(rgb, "BMP"), "webp": _image(rgb, "WEBP"),
            "cow": self.cow_png, "bomb_12k": _png_bomb(12000, 12000),
            "bomb_20k": _png_bomb(20000, 20000), "header_100k": _png_header_only(100000, 100000),
            "header_0": _png_header_only(0, 0), "empty": b"", "text": b"not an image\n",
            "obj_bytes": self.tiny_obj,
        }
        cloud = np.array([ln.split()[1:4] for ln in self.cow_obj.decode().splitlines()
                          if ln.startswith("v ")], dtype=np.float64)
        self.cloud = cloud
        self.colours = rng.integers(0, 256, (len(cloud), 3), dtype=np.uint8)
        self.normals = rng.normal(size=(len(cloud), 3))
        buf = io.BytesIO()  # a ~250 KB .npz whose array decodes to 240 MB (ratio ~1000)
        with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as z:
            with z.open("verts.npy", "w", force_zip64=True) as fh:
                np.lib.format.write_array_header_1_0(
                    fh, {"descr": "<f8", "fortran_order": False, "shape": (10_000_000, 3)})
                for _ in range(30):
                    fh.write(bytes(8_000_000))
        self.npz_bomb = buf.getvalue()

    # ---------------------------------------------------------------------- families
    def obj(self, name: str) -> dict:
        r = self.r
        src = self.objs[name]
        mut, data = _mutate_obj(src, r)
        files: dict = {"mesh/m.obj": data}
        if name == "cow":  # the real MTL and texture next to it
            files["mesh/cow.mtl"] = self.cow_mtl
            files["mesh/cow_texture.png"] = self.cow_png
        extra = r.random()
        if extra < 0.03:
            mut, files["mesh/m.obj"] = "empty", b""
        elif extra < 0.05:
            mut, files["mesh/m.obj"] = "directory", None
        loader = r.choice(["load_obj", "load_obj", "load_mesh", "load_objs_as_meshes"])
        kwargs = {}
        if name == "cow" and r.random() < 0.5:
            kwargs["load_textures"] = False  # the texture decode dominates: half without it
        return {"family": f"obj:{name}", "mutator": mut, "files": files, "entry": "mesh/m.obj",
                "loader": loader, "kwargs": kwargs}

    def material(self) -> dict:
        """The cow's MTL and texture (or the tiny OBJ's) missing, outside, mutated, not images."""
        r = self.r
        cow = r.random() < 0.4
        obj = self.cow_obj if cow else self.tiny_obj
        mtl_name = b"cow.mtl" if cow else b"m.mtl"
        tex_name = b"cow_texture.png"
        mtl = self.cow_mtl if cow else b"newmtl a\nmap_Kd cow_texture.png\nKd 1 1 1\nNs 10\n"
        tex = self.cow_png if cow else self.images["png_rgb"]
        files = {"mesh/m.obj": obj, "outside.png": self.images["png_rgb"],
                 "outside.mtl": mtl.replace(b"map_Kd cow_texture.png", b"map_Kd outside.png")}
        symlinks = {}
        kind = r.choice(["missing_mtl", "mtl_dir", "mtl_outside_rel", "mtl_outside_abs",
                         "mtl_symlink_out", "missing_texture", "texture_dir", "texture_outside",
                         "texture_abs", "texture_symlink_out", "texture_not_image",
                         "texture_mutated", "texture_truncated", "mtl_values", "mtl_mutated",
                         "texture_is_obj", "map_kd_options", "no_vt"])
        mesh_mtl = f"mesh/{mtl_name.decode()}"
        files[mesh_mtl] = mtl
        files["mesh/cow_texture.png"] = tex
        if kind == "missing_mtl":
            del files[mesh_mtl]
        elif kind == "mtl_dir":
            files[mesh_mtl] = None
        elif kind in ("mtl_outside_rel", "mtl_outside_abs", "mtl_symlink_out"):
            target = {"mtl_outside_rel": b"../outside.mtl", "mtl_outside_abs": b"/etc/hostname",
                      "mtl_symlink_out": b"link.mtl"}[kind]
            files["mesh/m.obj"] = obj.replace(b"mtllib " + mtl_name, b"mtllib " + target)
            if kind == "mtl_symlink_out":
                symlinks["mesh/link.mtl"] = "outside.mtl"
        elif kind == "missing_texture":
            del files["mesh/cow_texture.png"]
        elif kind == "texture_dir":
            files["mesh/cow_texture.png"] = None
        elif kind in ("texture_outside", "texture_abs", "texture_symlink_out"):
            target = {"texture_outside": b"../outside.png", "texture_abs": b"/etc/hostname",
                      "texture_symlink_out": b"link.png"}[kind]
            files[mesh_mtl] = mtl.replace(b"map_Kd " + tex_name, b"map_Kd " + target)
            if kind == "texture_symlink_out":
                symlinks["mesh/link.png"] = "outside.png"
        elif kind == "texture_not_image":
            files["mesh/cow_texture.png"] = r.choice(
                [b"", b"hello", bytes(r.randrange(256) for _ in range(r.randint(1, 300))),
                 self.tiny_obj, mtl, b"\x89PNG\r\n\x1a\n"])
        elif kind == "texture_mutated":
            files["mesh/cow_texture.png"] = _flip(tex, r, 20)
        elif kind == "texture_truncated":
            files["mesh/cow_texture.png"] = tex[: r.randrange(len(tex))]
        elif kind == "mtl_values":
            key = r.choice([b"Ka", b"Kd", b"Ks", b"Ns"])
            val = b" ".join(r.choice(_SPECIAL_NUMBERS + [b"-5", b"0.5", b"2"]) for _ in range(
                r.randint(0, 4)))
            files[mesh_mtl] = mtl + key + b" " + val + b"\n"
        elif kind == "mtl_mutated":
            _, files[mesh_mtl] = _mutate_obj(mtl, r)
        elif kind == "texture_is_obj":
            files[mesh_mtl] = mtl.replace(b"map_Kd " + tex_name, b"map_Kd m.obj")
        elif kind == "map_kd_options":
            files[mesh_mtl] = mtl.replace(b"map_Kd ", b"map_Kd -s 1 1 1 -o 0 0 ")
        elif kind == "no_vt":
            files["mesh/m.obj"] = b"\n".join(ln for ln in obj.split(b"\n")
                                             if not ln.startswith(b"vt "))
        loader = r.choice(["load_obj", "load_mesh", "load_objs_as_meshes"])
        kwargs = {"allow_outside": True} if r.random() < 0.2 else {}
        return {"family": "material" + (":cow" if cow else ":tiny"), "mutator": kind,
                "files": files, "symlinks": symlinks, "entry": "mesh/m.obj", "loader": loader,
                "kwargs": kwargs}

    def image(self) -> dict:
        """Texture images of every kind, and mutations of them, behind the tiny OBJ."""
        r = self.r
        name = r.choice(list(self.images))
        data = self.images[name]
        mut = "as_is"
        if r.random() < 0.5 and data and not name.startswith("bomb"):
            mut = r.choice(["truncate", "flip_bytes"])
            if mut == "truncate":
                data = data[: r.randrange(len(data))]
            else:
                data = _flip(data, r, 10)
        files = {"mesh/m.obj": self.tiny_obj, "mesh/m.mtl": b"newmtl a\nmap_Kd t.img\n",
                 "mesh/t.img": data}
        loader = r.choice(["load_obj", "load_mesh"])
        return {"family": f"image:{name}", "mutator": mut, "files": files, "entry": "mesh/m.obj",
                "loader": loader}

    def ply(self) -> dict:
        r = self.r
        n = len(self.cloud)
        fmt = r.choice(["ascii", "binary_little_endian", "binary_big_endian"])
        cols = r.random() < 0.5
        nrm = r.random() < 0.5
        props = [("x", "f8" if r.random() < 0.5 else "f4"), ("y", "f4"), ("z", "f4")]
        if nrm:
            props += [("nx", "f4"), ("ny", "f4"), ("nz", "f4")]
        if cols:
            props += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
        ply_names = {"f8": "double", "f4": "float", "u1": "uchar"}
        head = (f"ply\nformat {fmt} 1.0\ncomment fuzz\nelement vertex {n}\n"
                + "".join(f"property {ply_names[t]} {p}\n" for p, t in props)
                + "element face 0\nproperty list uchar int vertex_indices\nend_header\n").encode()
        cols_arr = [self.cloud[:, 0], self.cloud[:, 1], self.cloud[:, 2]]
        if nrm:
            cols_arr += list(self.normals.T)
        if cols:
            cols_arr += list(self.colours.T)
        if fmt == "ascii":
            table = np.stack(cols_arr, axis=1)
            fmts = " ".join("%d" if t == "u1" else "%.9g" for _, t in props)
            buf = io.StringIO()
            np.savetxt(buf, table, fmt=fmts)
            body = buf.getvalue().encode()
        else:
            e = "<" if fmt == "binary_little_endian" else ">"
            dt = np.dtype([(p, e + t) for p, t in props])
            rec = np.zeros(n, dt)
            for (p, _), c in zip(props, cols_arr):
                rec[p] = c
            body = rec.tobytes()
        data = head + body
        kind = r.choice(["as_is", "truncate", "truncate_header", "flip_bytes", "count", "count",
                         "format", "property", "end_header", "ascii_tokens", "control", "crlf",
                         "non_ascii_header", "empty", "directory", "garbage"])
        if kind == "truncate":
            data = data[: r.randrange(len(data))]
        elif kind == "truncate_header":
            data = data[: r.randrange(len(head))]
        elif kind == "flip_bytes":
            data = _flip(data, r)
        elif kind == "count":
            new = r.choice([0, 1, n - 1, n + 1, 10**8, 2**31, 2**63, 10**30, -1, "abc", "1.5",
                            ""])
            data = data.replace(f"element vertex {n}".encode(), f"element vertex {new}".encode())
        elif kind == "format":
            data = data.replace(fmt.encode(), r.choice([b"binary", b"ascii 2.0", b"ASCII",
                                                        b"binary_little_endian",
                                                        b"binary_big_endian", b"ascii"]), 1)
        elif kind == "property":
            data = data.replace(b"property float y", r.choice(
                [b"property double y", b"property char y", b"property list uchar float y",
                 b"property float128 y", b"property y", b"property float x", b""]), 1)
        elif kind == "end_header":
            data = data.replace(b"end_header\n", r.choice([b"", b"end_header", b"end_header x\n",
                                                          b"end_header\r\n"]), 1)
        elif kind == "ascii_tokens" and fmt == "ascii":
            for _ in range(r.randint(1, 4)):
                m = _NUM_RE.search(data, len(head) + r.randrange(len(body)))
                if m:
                    data = data[:m.start()] + r.choice(_SPECIAL_NUMBERS) + data[m.end():]
        elif kind == "control":
            p = len(head) + r.randrange(len(body) + 1)
            data = data[:p] + r.choice(_CONTROL) + data[p:]
        elif kind == "crlf":
            data = data.replace(b"\n", b"\r\n") if fmt == "ascii" else \
                head.replace(b"\n", b"\r\n") + body
        elif kind == "non_ascii_header":
            data = data.replace(b"comment fuzz", b"comment \xff\xfe caf\xc3\xa9")
        elif kind == "empty":
            data = b""
        elif kind == "garbage":
            data = bytes(r.randrange(256) for _ in range(r.randint(0, 400)))
        files = {"c.ply": None if kind == "directory" else data}
        return {"family": f"ply:{fmt}", "mutator": kind, "files": files, "entry": "c.ply",
                "loader": "load_pointcloud"}

    def npz(self) -> dict:
        r = self.r
        n = len(self.cloud)
        arrays = {r.choice(["verts", "verts", "points", "xyz"]): self.cloud}
        if r.random() < 0.6:
            arrays[r.choice(["rgb", "colors", "features"])] = r.choice(
                [self.colours, self.colours / 255.0, self.colours.astype(np.int32) * 10,
                 self.colours[:-1], self.colours[:, :2], self.colours.astype(np.float32)])
        if r.random() < 0.3:
            arrays["normals"] = r.choice([self.normals, self.normals[:-1], self.normals[:, :2]])
        kind = r.choice(["as_is", "truncate", "flip_bytes", "dtype", "shape", "huge_header",
                         "object", "npy_as_npz", "empty_zip", "not_zip", "empty", "directory",
                         "nan", "extra_entries", "stored", "pickle"])
        buf = io.BytesIO()
        compressed = r.random() < 0.5
        if kind == "dtype":
            k = next(iter(arrays))
            arrays[k] = arrays[k].astype(r.choice(["f2", "f4", "i8", "u1", "c16", "U8", "b1",
                                                   "S4", "M8[s]"]))
        elif kind == "shape":
            k = next(iter(arrays))
            arrays[k] = r.choice([self.cloud[:, :2], self.cloud.ravel(), self.cloud[None],
                                  self.cloud[:0], np.float64(3.0)])
        elif kind == "nan":
            pts = self.cloud.copy()
            pts[r.randrange(n), r.randrange(3)] = r.choice([np.nan, np.inf, -np.inf, 1e300])
            arrays[next(iter(arrays))] = pts
        if kind in ("huge_header", "object", "extra_entries", "empty_zip", "pickle"):
            with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED if compressed else
                                 zipfile.ZIP_STORED) as z:
                if kind == "huge_header":
                    h = io.BytesIO()
                    np.lib.format.write_array_header_1_0(h, {
                        "descr": "<f8", "fortran_order": False,
                        "shape": r.choice([(10**9, 3), (2**40, 3), (10**6, 3), (n, 3)])})
                    z.writestr("verts.npy", h.getvalue() + self.cloud.tobytes()[
                        : r.randrange(n * 24)])
                elif kind == "object":
                    h = io.BytesIO()
                    np.save(h, np.array([[1, 2, 3]], dtype=object), allow_pickle=True)
                    z.writestr("verts.npy", h.getvalue())
                elif kind == "pickle":
                    z.writestr("verts.npy", b"\x80\x04\x95" + bytes(20))
                elif kind == "extra_entries":
                    h = io.BytesIO()
                    np.save(h, self.cloud)
                    z.writestr("verts.npy", h.getvalue())
                    z.writestr("dir/", b"")
                    z.writestr("../evil.npy", b"x")
            data = buf.getvalue()
        elif kind == "npy_as_npz":
            np.save(buf, self.cloud)
            data = buf.getvalue()
        elif kind == "not_zip":
            data = bytes(r.randrange(256) for _ in range(r.randint(1, 500)))
        elif kind == "empty":
            data = b""
        else:
            (np.savez_compressed if compressed else np.savez)(buf, **arrays)
            data = buf.getvalue()
            if kind == "truncate":
                data = data[: r.randrange(len(data))]
            elif kind == "flip_bytes":
                data = _flip(data, r)
        files = {"c.npz": None if kind == "directory" else data}
        return {"family": "npz", "mutator": kind, "files": files, "entry": "c.npz",
                "loader": "load_pointcloud"}

    # ---------------------------------------------------------------------- issue 28 families
    def _transforms(self, frames: list) -> bytes:
        return json.dumps({"camera_angle_x": 0.7, "frames": [
            {"transform_matrix": np.eye(4).tolist(), **f} for f in frames]}).encode()

    def targeted(self) -> dict:
        """Issue 28's cases: symlinked extension-less paths, pixel bombs, FIFOs, ASCII PLY
        ranges, OFF counts, deep or huge JSON, long paths, out-of-range glTF indices. Every one
        must raise (``expect_error``): a load is a silent wrong load."""
        r = self.r
        png = self.images["png_rgb"]
        bomb = self.images["bomb_12k"]
        tri_obj = (b"mtllib m.mtl\nusemtl a\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\n"
                   b"f 1/1 2/2 3/3\n")
        ply_head = (b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n"
                    b"property float y\nproperty float z\nproperty uchar red\n"
                    b"property uchar green\nproperty uchar blue\nelement face %d\n"
                    b"property list uchar int vertex_indices\nend_header\n")
        verts = b"0 0 0 0 0 0\n1 0 0 0 0 0\n0 1 0 0 0 0\n"
        cases = {
            "views_symlink_extensionless": dict(
                files={"cap/transforms.json": self._transforms([{"file_path": "lnk"}])},
                symlinks={"cap/lnk.png": "../secret/s.png"}, entry="cap", loader="load_views"),
            "views_mask_symlink": dict(
                files={"cap/transforms.json": self._transforms(
                    [{"file_path": "a.png", "mask_path": "m"}]), "cap/a.png": png},
                symlinks={"cap/m.png": "../secret/s.png"}, entry="cap", loader="load_views"),
            "views_dotdot": dict(
                files={"cap/transforms.json": self._transforms(
                    [{"file_path": "../../secret/s"}])}, entry="cap", loader="load_views"),
            "obj_texture_symlink": dict(
                files={"mesh/m.obj": tri_obj, "mesh/m.mtl": b"newmtl a\nmap_Kd t\n"},
                symlinks={"mesh/t": "../secret/s.png"}, entry="mesh/m.obj", loader="load_obj"),
            "glb_uri_outside": dict(
                files={"m.glb": glb_container({"asset": {"version": "2.0"},
                                           "images": [{"uri": "../secret/s.png"}]})},
                entry="m.glb", loader="load_mesh"),
            "gltf_buffer_symlink": dict(
                files={"m.gltf": json.dumps({"asset": {"version": "2.0"}, "buffers": [
                    {"uri": "b.bin", "byteLength": 4}]}).encode()},
                symlinks={"b.bin": "../secret/s.png"}, entry="m.gltf", loader="load_mesh"),
            "views_fifo": dict(files={"cap/transforms.json": self._transforms(
                [{"file_path": "f"}])}, fifos=["cap/f.png"], entry="cap", loader="load_views"),
            "obj_texture_fifo": dict(files={"mesh/m.obj": tri_obj,
                                            "mesh/m.mtl": b"newmtl a\nmap_Kd t.png\n"},
                                     fifos=["mesh/t.png"], entry="mesh/m.obj",
                                     loader="load_obj"),
            "obj_mtllib_fifo": dict(files={"mesh/m.obj": tri_obj}, fifos=["mesh/m.mtl"],
                                    entry="mesh/m.obj", loader="load_obj"),
            "glb_uri_fifo": dict(files={"m.glb": glb_container({"asset": {"version": "2.0"},
                                                            "images": [{"uri": "p.png"}]})},
                                 fifos=["p.png"], entry="m.glb", loader="load_mesh"),
            "views_pixel_bomb": dict(files={"cap/transforms.json": self._transforms(
                [{"file_path": "b.png"}]), "cap/b.png": bomb}, entry="cap",
                loader="load_views"),
            "obj_pixel_bomb": dict(files={"mesh/m.obj": tri_obj, "mesh/b.png": bomb,
                                          "mesh/m.mtl": b"newmtl a\nmap_Kd b.png\n"},
                                   entry="mesh/m.obj", loader="load_obj"),
            "glb_pixel_bomb": dict(files={"m.glb": glb_container(
                {"asset": {"version": "2.0"}, "buffers": [{"byteLength": len(bomb)}],
                 "bufferViews": [{"buffer": 0, "byteLength": len(bomb)}],
                 "images": [{"bufferView": 0, "mimeType": "image/png"}]}, bomb)},
                entry="m.glb", loader="load_mesh"),
            "npz_ratio_bomb": dict(files={"c.npz": self.npz_bomb}, entry="c.npz",
                                   loader="load_pointcloud"),
            "ply_colour_300": dict(files={"c.ply": ply_head % 1 + verts.replace(
                b"0 0 0 0 0 0", b"0 0 0 300 0 0", 1) + b"3 0 1 2\n"}, entry="c.ply",
                loader=r.choice(["load_mesh", "load_pointcloud"])),
            "ply_colour_minus5": dict(files={"c.ply": ply_head % 1 + verts.replace(
                b"0 0 0 0 0 0", b"0 0 0 -5 0 0", 1) + b"3 0 1 2\n"}, entry="c.ply",
                loader=r.choice(["load_mesh", "load_pointcloud"])),
            "ply_short_vertex_line": dict(files={"c.ply": ply_head % 1 + verts.replace(
                b"0 0 0 0 0 0", b"0 0 0 1 2", 1) + b"3 0 1 2\n"}, entry="c.ply",
                loader=r.choice(["load_mesh", "load_pointcloud"])),
            "ply_face_count_huge": dict(files={"c.ply": ply_head % 999999999999 + verts
                                               + b"3 0 1 2\n3 0 2 1\n"}, entry="c.ply",
                                        loader="load_mesh"),
            "ply_face_count_line": dict(files={"c.ply": ply_head % 1 + verts
                                               + b"1000000000 0 1 2\n"}, entry="c.ply",
                                        loader="load_mesh"),
            "off_face_count_line": dict(files={"o.off": b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n"
                                                        b"1000000000 0 1 2\n"},
                                        entry="o.off", loader="load_mesh"),
            "off_counts_huge": dict(files={"o.off": b"OFF\n3 999999999 0\n0 0 0\n1 0 0\n"
                                                    b"0 1 0\n3 0 1 2\n"},
                                    entry="o.off", loader="load_mesh"),
            "json_deep": dict(files={"cap/transforms.json": b"[" * 100000 + b"]" * 100000},
                              entry="cap", loader="load_views"),
            "json_huge_int": dict(files={"cap/transforms.json": b'{"frames": [{"file_path": '
                                         b'"a.png", "fl_x": ' + b"7" * 4400 + b"}]}"},
                                  entry="cap", loader="load_views"),
            "views_long_path": dict(files={"cap/transforms.json": self._transforms(
                [{"file_path": "a" * 5000}])}, entry="cap", loader="load_views"),
            "glb_index_ffffffff": dict(files={"m.glb": glb_container(
                {"asset": {"version": "2.0"}, "scene": 0xFFFFFFFF, "scenes": []})},
                entry="m.glb", loader="load_mesh"),
        }
        kind = r.choice(sorted(cases))
        task = {"family": "targeted", "mutator": kind, "expect_error": True, "kwargs": {},
                **cases[kind]}
        return task

    def plan(self, n: int, families=None) -> list[tuple[str, str | None]]:
        """The family of every input, in a shuffled order; weights keep the run near 30 min."""
        weights = {("obj", "dolphin"): 12, ("obj", "suzanne"): 12, ("obj", "woody"): 12,
                   ("obj", "teapot"): 9, ("obj", "fandisk"): 6, ("obj", "cow"): 9,
                   ("obj", "ogre"): 0.7, ("material", None): 11, ("image", None): 8,
                   ("ply", None): 11, ("npz", None): 9, ("targeted", None): 10}
        weights = {k: v for k, v in weights.items() if (k[0] != "obj" or k[1] in self.objs)
                   and (not families or k[0] in families)}
        total = sum(weights.values())
        out = []
        for k, w in weights.items():
            out += [k] * max(1, round(n * w / total))
        self.r.shuffle(out)
        return out

    def make(self, key: tuple[str, str | None]) -> dict:
        fam, name = key
        return self.obj(name) if fam == "obj" else getattr(self, fam)()


# ============================================================================ driver
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=20000, help="number of inputs (default 20000)")
    ap.add_argument("--workers", type=int, default=2, help="worker processes (at most 2 here)")
    ap.add_argument("--timeout", type=float, default=30.0, help="seconds before a hang")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--address-space", default="6G",
                    help="RLIMIT_AS of each worker (bytes, K/M/G suffix; 0: none)")
    ap.add_argument("--data", default=os.environ.get("GEOFIT_DATA", ""),
                    help="folder with cow_mesh/, dolphin/, shapes/ (default $GEOFIT_DATA)")
    ap.add_argument("--families", default="",
                    help="comma-separated families to run (obj, material, image, ply, npz, "
                         "targeted); default all")
    ap.add_argument("--no-saves", action="store_true",
                    help="skip the kill-during-save / disk-full run (benchmarks/save_crash.py)")
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent / "results"
                                         / "fuzz_loaders.json"))
    args = ap.parse_args(argv)
    from geofit._memory import parse_bytes

    data = Path(args.data)
    if not (data / "cow_mesh" / "cow.obj").is_file():
        print(f"tutorial data not found under {data!r} (set GEOFIT_DATA)", file=sys.stderr)
        return 2
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from _harness import machine_info

    address_space = 0 if args.address_space in ("0", "") else parse_bytes(args.address_space)
    load_before = os.getloadavg()
    t0 = time.time()
    inputs = Inputs(data, args.seed)
    plan = inputs.plan(args.n, [f for f in args.families.split(",") if f])
    ctx = mp.get_context("spawn")
    root = Path(tempfile.mkdtemp(prefix="geofit-fuzz-"))
    counts: dict = defaultdict(Counter)
    mutators: dict = defaultdict(Counter)
    examples: dict = defaultdict(list)
    n_workers = max(1, min(args.workers, 2))
    child_timeout = max(1.0, args.timeout - 5.0)  # the child's alarm, before the worker's
    workers = [_Worker(ctx, root / f"w{i}", address_space, child_timeout)
               for i in range(n_workers)]
    todo = iter(plan)
    done = 0
    busy: dict = {}

    def record(task: dict, outcome: str, detail: str) -> None:
        nonlocal done
        done += 1
        counts[task["family"]][outcome] += 1
        if outcome not in ALLOWED:
            mutators[outcome][f"{task['family']}/{task['mutator']}"] += 1
            if len(examples[outcome]) < 8:
                examples[outcome].append({"family": task["family"], "mutator": task["mutator"],
                                          "loader": task["loader"], "detail": detail})
        if done % 1000 == 0:
            bad = sum(v for c in counts.values() for k, v in c.items() if k not in ALLOWED)
            print(f"{done}/{len(plan)} inputs, {time.time() - t0:.0f} s, {bad} outside the "
                  f"allowed set", flush=True)

    try:
        for i, w in enumerate(workers):
            task = next(todo, None)
            if task is not None:
                w.send(inputs.make(task))
                busy[i] = w
        while busy:
            conns = {w.conn: i for i, w in busy.items()}
            ready = mp.connection.wait(list(conns), timeout=1.0)
            now = time.monotonic()
            for conn in ready:
                i = conns[conn]
                w = busy[i]
                try:
                    outcome, detail = conn.recv()
                except (EOFError, OSError):
                    outcome, detail = "crash", f"worker exit code {w.proc.exitcode}"
                    w.kill()
                    workers[i] = w = _Worker(ctx, root / f"w{i}", address_space,
                                            child_timeout)
                record(w.task, outcome, detail)
                nxt = next(todo, None)
                if nxt is None:
                    del busy[i]
                else:
                    w.send(inputs.make(nxt))
            for i, w in list(busy.items()):
                if w.conn in ready:
                    continue
                if not w.proc.is_alive():
                    outcome, detail = "crash", f"worker exit code {w.proc.exitcode}"
                elif now - w.started > args.timeout:
                    outcome, detail = "hang", f"no answer in {args.timeout:g} s"
                else:
                    continue
                task = w.task
                w.kill()
                workers[i] = w = _Worker(ctx, root / f"w{i}", address_space,
                                            child_timeout)
                record(task, outcome, detail)
                nxt = next(todo, None)
                if nxt is None:
                    del busy[i]
                else:
                    busy[i] = w
                    w.send(inputs.make(nxt))
    finally:
        for w in workers:
            try:
                w.conn.send(None)
            except (OSError, BrokenPipeError):
                pass
            w.proc.join(10)
            if w.proc.is_alive():
                w.kill()
        shutil.rmtree(root, ignore_errors=True)

    saves = None
    if not args.no_saves:  # kill during save at 8 points and disk full, every format
        import save_crash

        with tempfile.TemporaryDirectory(prefix="geofit-fuzz-saves-") as tmp:
            saves = save_crash.run(Path(tmp))
    totals = Counter()
    for c in counts.values():
        totals.update(c)
    issue28 = {  # the acceptance counts of issue 28 (all must be 0)
        "escapes": totals.get("escape", 0), "hangs": totals.get("hang", 0),
        "blowups": totals.get("blowup", 0),
        "silent_wrong_loads": totals.get("silent_wrong_load", 0)
        + totals.get("nonfinite_or_out_of_range", 0),
        "unclear_errors": sum(v for k, v in totals.items()
                              if k.startswith(("other:", "warning:")) or k.endswith(
                                  ("_names_no_file", "_empty_message"))),
        "crashes": totals.get("crash", 0),
        "harness_errors": sum(v for k, v in totals.items() if k.startswith("harness_error")),
        "save_failures": None if saves is None else saves["failures"],
    }
    outside = {k: v for k, v in totals.items() if k not in ALLOWED}
    result = {
        "schema": "geofit-fuzz/1",
        "benchmark": "fuzz_loaders",
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "command": " ".join([Path(sys.executable).name, *sys.argv]),
        "machine": machine_info(),
        "config": {"n_inputs": len(plan), "workers": n_workers, "timeout_s": args.timeout,
                   "seed": args.seed, "worker_address_space": args.address_space,
                   "worker_GEOFIT_MEMORY_LIMIT": "1G", "data": str(data),
                   "loadavg_before": list(load_before), "loadavg_after": list(os.getloadavg())},
        "allowed_outcomes": list(ALLOWED),
        "issue28": issue28,
        "saves": saves,
        "seconds": round(time.time() - t0, 1),
        "totals": dict(sorted(totals.items(), key=lambda kv: -kv[1])),
        "outside_allowed": sum(outside.values()),
        "counts": {fam: dict(sorted(c.items())) for fam, c in sorted(counts.items())},
        "outside_by_mutator": {k: dict(v.most_common(20)) for k, v in mutators.items()},
        "examples_outside_allowed": dict(examples),
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps({"totals": result["totals"], "outside_allowed": result["outside_allowed"],
                      "issue28": issue28, "seconds": result["seconds"]}, indent=1))
    print(f"wrote {out}")
    return 0 if not outside and not any(issue28.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
