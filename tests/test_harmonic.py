"""Harmonic embeddings against PyTorch3D 0.7.9 (tests/data/nerf.npz: the library module in its
options and the NeRF tutorial's own module), and their closed-form structure."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from geofit.render.volume.harmonic import HALF_PI_F32, HarmonicEmbedding, TutorialHarmonicEmbedding

REF = np.load(Path(__file__).parent / "data" / "nerf.npz")
POINTS = REF["points"]


def ulps(a, b):
    """Distance in float32 units in the last place."""
    ia = np.asarray(a, np.float32).view(np.int32).astype(np.int64)
    ib = np.asarray(b, np.float32).view(np.int32).astype(np.int64)
    return np.abs(ia - ib)


def test_library_default_float64_matches_pytorch3d():
    """HarmonicEmbedding() on float64 input: PyTorch3D's buffer and (10, 39) output."""
    emb = HarmonicEmbedding()
    np.testing.assert_array_equal(emb.frequencies, REF["lib_default_freqs"])
    out = emb(POINTS)
    assert out.shape == (10, 39) and out.dtype == np.float64
    np.testing.assert_allclose(out, REF["lib_default_f64"], rtol=0, atol=1e-15)


def test_library_default_float32_within_one_ulp():
    """float32 input: float32 output within one ulp of PyTorch3D's (sin implementations)."""
    out = HarmonicEmbedding()(POINTS.astype(np.float32))
    assert out.dtype == np.float32
    assert ulps(out, REF["lib_default_f32"]).max() <= 1


def test_library_cos_half_is_shifted_sine():
    """The library's second half is sin(theta + fl32(pi/2)), not cos: off by 4.37e-8 sin."""
    emb = HarmonicEmbedding(60, 0.1, append_input=False)
    np.testing.assert_array_equal(emb.frequencies, REF["lib_n60_freqs"])
    out = emb(POINTS)
    np.testing.assert_allclose(out, REF["lib_n60_f64"], rtol=0, atol=1e-15)
    theta = (POINTS[:, :, None] * emb.frequencies.astype(np.float64)).reshape(10, -1)
    low = theta[:, :3 * 0 + 1]  # frequency 0 of dimension 0 (|theta| < 0.15)
    cos_col = out[:, 180:181]
    np.testing.assert_allclose(cos_col, np.cos(low) - (HALF_PI_F32 - np.pi / 2) * np.sin(low),
                               rtol=0, atol=1e-15)
    assert np.abs(cos_col - np.cos(low)).max() > 0  # the quirk is really there
    exact = HarmonicEmbedding(60, 0.1, append_input=False, exact_cos=True)(POINTS)
    np.testing.assert_allclose(exact[:, 180:], np.cos(theta), rtol=0, atol=0)


def test_library_linspace_frequencies():
    """logspace=False: torch.linspace in float32 times omega_0 (1, 10/3, 17/3, 8) * 0.5."""
    emb = HarmonicEmbedding(4, 0.5, logspace=False)
    np.testing.assert_array_equal(emb.frequencies, REF["lib_logspace_false_freqs"])
    np.testing.assert_allclose(emb(POINTS), REF["lib_logspace_false"], rtol=0, atol=1e-15)
    assert emb.output_dim(3) == 27


def test_tutorial_embedding_float32_matches_notebook():
    """The tutorial module in float32 (dim 360): every column within one ulp of PyTorch3D."""
    emb = TutorialHarmonicEmbedding()
    np.testing.assert_array_equal(emb.frequencies, REF["tutorial_freqs_f32"])
    out = emb(POINTS.astype(np.float32))
    assert out.shape == (10, 360) and out.dtype == np.float32
    assert ulps(out, REF["tutorial_f32"]).max() <= 1


def test_tutorial_embedding_float64_buffer():
    """With a float64 buffer and input: sin/cos of the correctly rounded products."""
    emb = TutorialHarmonicEmbedding(buffer_dtype=np.float64)
    np.testing.assert_array_equal(emb.frequencies, REF["tutorial_freqs_f64"])
    np.testing.assert_allclose(emb(POINTS), REF["tutorial_f64"], rtol=0, atol=1e-15)


def test_column_order_and_append():
    """Columns go per input dimension then per frequency; appended input comes last."""
    emb = HarmonicEmbedding(3, 1.0)
    x = np.array([[0.1, 0.2, 0.3]])
    out = emb(x)
    f = np.array([1.0, 2.0, 4.0])
    np.testing.assert_allclose(out[0, :9], np.sin(np.outer([0.1, 0.2, 0.3], f).ravel()))
    np.testing.assert_array_equal(out[0, -3:], x[0])
    assert emb(np.zeros((2, 5, 3))).shape == (2, 5, 21)


def test_integer_input_is_widened():
    out = HarmonicEmbedding(2, 1.0)(np.array([[1, 2, 3]]))
    assert out.dtype == np.float64
    np.testing.assert_allclose(out[0, 0], np.sin(1.0))


@pytest.mark.parametrize("make, match", [
    (lambda: HarmonicEmbedding(0), "n_harmonic_functions"),
    (lambda: HarmonicEmbedding("six"), "n_harmonic_functions"),
    (lambda: HarmonicEmbedding(4, omega_0=0.0), "omega_0"),
    (lambda: TutorialHarmonicEmbedding(4, omega0=-1.0), "omega0"),
    (lambda: TutorialHarmonicEmbedding(4, buffer_dtype=np.int64), "buffer_dtype"),
    (lambda: HarmonicEmbedding()(np.float64(1.0)), r"\(\.\.\., d\)"),
    (lambda: HarmonicEmbedding()(np.array([[np.nan, 0.0, 0.0]])), "finite"),
    (lambda: HarmonicEmbedding()(np.array([["a"]])), "real numbers"),
    (lambda: TutorialHarmonicEmbedding()(np.zeros((2, 0))), r"\(\.\.\., d\)"),
])
def test_validation(make, match):
    """Invalid options and inputs raise ValueError naming the argument."""
    with pytest.raises(ValueError, match=match):
        make()
