"""OFF header and face-line checks before trimesh reads an OFF file (issue 28 point 4).

trimesh takes the header's counts on trust: ``element`` counts larger than the file, or a face
line ``1000000000 0 1 2``, load as something. :func:`check_off_counts` refuses, naming the
file: counts that are not non-negative integers, fewer vertex or face lines than declared,
a vertex line with fewer than 3 values, a face whose corner count is below 3 or does not match
the indices on its line (up to 4 colour values may follow), an index out of range.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from .obj import _tokens_per_line

__all__ = ["check_off_counts"]


def check_off_counts(data: bytes, path: Path) -> int:
    """Check an OFF file's counts and face lines; return the declared vertex count."""
    body = re.sub(rb"#[^\n\r]*", b"", data).replace(b"\r", b"\n")
    if not body.endswith(b"\n"):
        body += b"\n"
    blob = np.frombuffer(body, dtype=np.uint8)
    ntok = _tokens_per_line(blob)[2]
    try:
        toks = body.decode("ascii").split()
    except UnicodeDecodeError:
        raise ValueError(f"{path}: OFF file has non-ASCII bytes") from None
    lines = np.flatnonzero(ntok)  # non-empty lines
    per = ntok[lines]
    start = np.concatenate([[0], np.cumsum(per)[:-1]])
    if not len(lines) or not toks[0].endswith("OFF"):
        raise ValueError(f"{path}: not an OFF file (no 'OFF' header line)")
    if per[0] >= 3:  # "OFF nv nf ne" on one line
        header, first = toks[1:4], 1
    elif len(per) > 1:
        header, first = toks[start[1]:start[1] + 3], 2
    else:
        header, first = [], 1
    if len(header) < 2 or not all(t.isdigit() for t in header[:2]):
        raise ValueError(f"{path}: OFF header: expected the counts 'nv nf [ne]' as "
                         f"non-negative integers, got {' '.join(header)[:60]!r}")
    nv, nf = int(header[0]), int(header[1])
    have = len(per) - first
    if have < nv + nf:
        raise ValueError(f"{path}: the OFF header declares {nv} vertices and {nf} faces, the "
                         f"file has only {have} data lines (truncated file or wrong count)")
    vper = per[first:first + nv]
    if np.any(vper < 3):
        i = int(np.flatnonzero(vper < 3)[0])
        raise ValueError(f"{path}: OFF vertex {i} has {int(vper[i])} values (expected 3)")
    fs, fper = start[first + nv:first + nv + nf], per[first + nv:first + nv + nf]
    s0 = int(start[first + nv]) if nf else len(toks)
    try:  # every face token at once (exact integers up to 2**53)
        vals = np.array(toks[s0:], dtype=np.float64)
    except ValueError:
        raise ValueError(f"{path}: OFF face lines hold a value that is not a number") from None
    k_f = vals[fs - s0]
    if not np.all(np.isfinite(k_f) & (k_f == np.round(k_f)) & (np.abs(k_f) < 2**53)):
        raise ValueError(f"{path}: OFF face lines must start with an integer corner count")
    k = k_f.astype(np.int64)
    bad = (k < 3) | (fper < 1 + k) | (fper > 1 + k + 4)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"{path}: OFF face {i} declares {int(k[i])} corners but its line "
                         f"holds {int(fper[i]) - 1} values (expected {max(int(k[i]), 3)} "
                         f"indices, then at most 4 colour values)")
    pos = np.repeat(fs + 1, k) + np.arange(k.sum()) - np.repeat(np.cumsum(k) - k, k)
    idx_f = vals[pos - s0]
    if not np.all(idx_f == np.round(idx_f)):
        raise ValueError(f"{path}: OFF face indices must be integers")
    idx = idx_f.astype(np.int64)
    if idx.size and (idx.min() < 0 or idx.max() >= nv):
        raise ValueError(f"{path}: OFF face index {int(idx[(idx < 0) | (idx >= nv)][0])} is "
                         f"out of range for {nv} vertices")
    return nv
