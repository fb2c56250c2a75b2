"""MkDocs hook: pages in docs/ may link files elsewhere in the repository.

A link such as ``../benchmarks/results/fit_mesh_shapes.md`` works on a repository browser;
for the site, every such target that exists is added to the build (Markdown as a page, the
rest copied as is) under ``repo/``, so the link resolves and ``mkdocs build --strict`` still
fails on a target that does not exist. Listed in ``mkdocs.yml`` under ``hooks``.
"""
from __future__ import annotations

import posixpath
import re
from pathlib import Path

from mkdocs.structure.files import File, InclusionLevel

_LINK = re.compile(r"\]\(([^)\s#]+)(?:#[^)\s]*)?\)")


def on_files(files, config):
    docs = Path(config["docs_dir"]).resolve()
    repo = docs.parent
    extra = set()
    for page in list(files.documentation_pages()):
        text = Path(page.abs_src_path).read_text(encoding="utf-8")
        for target in _LINK.findall(text):
            if "://" in target or target.startswith(("/", "mailto:")):
                continue
            rel = posixpath.normpath(posixpath.join(posixpath.dirname(page.src_uri), target))
            if not rel.startswith("../"):
                continue  # inside docs/: MkDocs checks it itself
            path = (docs / rel).resolve()
            if path.is_file() and repo in path.parents and docs not in path.parents:
                extra.add(rel)
    for rel in sorted(extra):
        inside = "repo/" + rel[len("../"):]
        dest = inside[:-3] + ".html" if inside.endswith(".md") else inside
        # Set explicitly: MkDocs' default exclusion of dot-paths would match the leading "..".
        files.append(File(rel, str(docs), config["site_dir"], config["use_directory_urls"],
                          dest_uri=dest, inclusion=InclusionLevel.NOT_IN_NAV))
    return files
