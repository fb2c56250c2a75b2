"""Viewers answer at once: show_open3d asks the display first (a stale DISPLAY used to hang in
Open3D's create_window)."""
from __future__ import annotations

import socket
import threading
import time

import pytest

from geofit import ico_sphere
from geofit.cameras import FoVPerspectiveCameras
from geofit.render.open3d import display_problem, show_open3d


def _server(path, reply: bytes | None):
    """A Unix socket that accepts one connection and answers ``reply`` (None: never)."""
    srv = socket.socket(socket.AF_UNIX)
    srv.bind(str(path))
    srv.listen(1)
    done = threading.Event()

    def serve():
        conn, _ = srv.accept()
        conn.recv(12)
        if reply is not None:
            conn.sendall(reply)
        done.wait(5)
        conn.close()

    threading.Thread(target=serve, daemon=True).start()
    return srv, done


def test_no_display_and_stale_display(monkeypatch, tmp_path):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert "unset" in display_problem()
    monkeypatch.setenv("DISPLAY", f"{tmp_path}/gone.sock:0")  # nothing listens there
    assert "does not answer" in display_problem(0.5)
    monkeypatch.setenv("DISPLAY", "not-a-display")
    assert "not a display name" in display_problem(0.5)


def test_silent_server_times_out_and_answering_server_passes(monkeypatch, tmp_path):
    """A server that accepts but never completes the X11 set-up is a display that does not
    answer (within the timeout); one that replies is a display."""
    srv, done = _server(tmp_path / "silent.sock", None)
    monkeypatch.setenv("DISPLAY", f"{tmp_path}/silent.sock:0")
    t = time.perf_counter()
    why = display_problem(0.5)
    assert why is not None and "does not answer" in why and time.perf_counter() - t < 30
    done.set()
    srv.close()
    srv, done = _server(tmp_path / "x.sock", b"\x01\x00\x0b\x00\x00\x00\x00\x00")
    monkeypatch.setenv("DISPLAY", f"{tmp_path}/x.sock:0")
    assert display_problem(5.0) is None
    done.set()
    srv.close()


def test_show_open3d_refuses_a_stale_display(monkeypatch, tmp_path):
    """show_open3d raises with the reason instead of hanging in create_window."""
    pytest.importorskip("open3d")
    srv, done = _server(tmp_path / "silent.sock", None)
    monkeypatch.setenv("DISPLAY", f"{tmp_path}/silent.sock:0")
    with pytest.raises(RuntimeError, match="does not answer"):
        show_open3d(ico_sphere(1), FoVPerspectiveCameras(), run=False, timeout=0.5)
    done.set()
    srv.close()


def test_time_bar_reads_seconds_of_the_budget():
    """A bar over a time budget reads "7.9 s / 8.0 s", not tqdm's "7.93/8.0 [...1.26s/s]"."""
    from geofit.fit._progress import progress_bar

    bar = progress_bar(True, 8.0, "fit_nerf", unit="s")
    try:
        bar.update(7.93)
        text = str(bar)
    finally:
        bar.close()
    assert "7.9 s / 8.0 s" in text and "s/s" not in text and "7.93" not in text


def test_advance_draws_the_bar_with_the_clock_paused():
    """``advance`` steps the bar and shows its postfix while the fit's clock is paused."""
    from geofit.fit import Clock
    from geofit.fit._progress import advance

    clock = Clock()
    seen = []

    class Bar:
        def update(self, n=1):
            seen.append(("update", n, clock.is_paused))

        def set_postfix(self, **kw):
            seen.append(("postfix", kw, clock.is_paused))

    advance(Bar(), clock)
    advance(Bar(), clock, {"loss": "0.5"})
    assert seen == [("update", 1, True), ("update", 1, True), ("postfix", {"loss": "0.5"}, True)]
    assert not clock.is_paused


def test_open3d_offscreen_renderer_is_quiet():
    """Starting Open3D's offscreen renderer prints nothing (Filament's engine log and Open3D's
    INFO lines go to the C-level stdout; they are silenced around it), and importing geofit
    asks Open3D not to enable its Jupyter WebVisualizer banner."""
    import subprocess
    import sys

    script = (
        "import os, geofit\n"
        "assert os.environ['OPEN3D_DISABLE_WEB_VISUALIZER'] == 'true'\n"
        "from geofit.cameras import FoVPerspectiveCameras, look_at_view_transform\n"
        "from geofit.render.open3d import render_open3d\n"
        "R, T = look_at_view_transform(2.7)\n"
        "r = render_open3d(geofit.ico_sphere(1), FoVPerspectiveCameras(R=R, T=T), 16)\n"
        "print('IOU-READY', r.mask.mean() > 0)\n")
    res = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         timeout=300)
    if res.returncode != 0 and "IOU-READY" not in res.stdout:
        pytest.skip("Open3D's offscreen renderer cannot start here: " + res.stderr[-300:])
    out = res.stdout + res.stderr
    assert "IOU-READY True" in res.stdout
    for banner in ("FEngine", "CircularBuffer", "[Open3D INFO]", "WebVisualizer"):
        assert banner not in out, out
