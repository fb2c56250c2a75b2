"""Fixtures shared by several test files."""
from pathlib import Path

import numpy as np
import pytest

DATA = Path(__file__).parent / "data"


@pytest.fixture(scope="session")
def reference_arrays():
    """``load(name, dtype=None)``: every array of ``tests/data/<name>`` in a dict (cast to
    ``dtype`` when given), the file closed again."""

    def load(name: str, dtype=None) -> dict:
        with np.load(DATA / name) as d:
            return {k: d[k] if dtype is None else d[k].astype(dtype) for k in d.files}

    return load
