"""Capture layouts, one module per layout, merged in one table (as trimesh's ``exchange/``).

Each layout module ends in a small table, ``_loaders = {"colmap": load_colmap}`` (and
``_savers`` for the layouts geofit writes), and a ``detect(path)`` that returns ``(layout,
file)`` when it recognises a capture folder or camera file, else None. This package merges them:
:data:`LOADERS`, :data:`SAVERS` and :func:`detect` (the layouts tried in the order of
:data:`_MODULES`). A new layout is one new module added to :data:`_MODULES`; nothing else
dispatches on layout names.

Layouts: ``nerfstudio`` (:mod:`.nerfstudio`), ``transforms`` and ``nerf_synthetic``
(:mod:`.transforms`), ``colmap`` text and binary (:mod:`.colmap`), ``opencv`` (:mod:`.opencv`,
geofit's own ``cameras.json``).
"""
from __future__ import annotations

from pathlib import Path

from . import colmap, nerfstudio, opencv, transforms

#: The layout modules, in the order :func:`detect` tries them.
_MODULES = (nerfstudio, transforms, colmap, opencv)

#: layout name -> ``load(file, options) -> MultiViewDataset``.
LOADERS = {k: v for m in _MODULES for k, v in m._loaders.items()}
#: layout name -> ``save(root, images, silhouettes, cameras, bit_depth, overwrite) -> Path``.
SAVERS = {k: v for m in _MODULES for k, v in getattr(m, "_savers", {}).items()}


def detect(path: Path) -> tuple[str, Path]:
    """``(layout, file)`` of a capture folder or camera file, by the first layout module that
    recognises it.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    ValueError
        If no layout recognises it.
    """
    if not path.exists():
        raise FileNotFoundError(f"path: no such file or folder {str(path)!r}")
    for module in _MODULES:
        found = module.detect(path)
        if found is not None:
            return found
    if path.is_file():
        raise ValueError(f"{path}: not a capture file (expected transforms.json, cameras.json "
                         "or COLMAP's cameras.txt / cameras.bin)")
    raise ValueError(f"{path}: no capture found (expected transforms.json, "
                     "transforms_train.json, cameras.txt and images.txt or cameras.bin and "
                     "images.bin (also under sparse/0), or cameras.json)")
