"""MkDocs hook (``hooks:`` in mkdocs.yml): serve a few repository files in the docs site without copying them.

``REPRODUCTION.md`` (written by ``bptsb report``) with the figures it links under ``reproduction/runs/``,
and ``bptsb_ros/ros/TOPICS.md`` (shipped in the package) each have one source in the repository; the site
reads them from there, so the docs never hold a second copy that could go stale.
"""

from __future__ import annotations

from pathlib import Path

from mkdocs.config.defaults import MkDocsConfig
from mkdocs.structure.files import File, Files

ROOT = Path(__file__).resolve().parent.parent

# repository path -> path inside the site's docs tree
PAGES = {
    "REPRODUCTION.md": "REPRODUCTION.md",
    "bptsb_ros/ros/TOPICS.md": "ros/topics.md",
}
FIGURE_DIR = "reproduction/runs"


def on_files(files: Files, config: MkDocsConfig) -> Files:
    """Add the repository pages and the reproduction figures to the site's files."""
    sources = dict(PAGES)
    for figure in sorted([*(ROOT / FIGURE_DIR).rglob("*.png"), *(ROOT / FIGURE_DIR).rglob("*.pdf")]):
        rel = figure.relative_to(ROOT).as_posix()  # the PNGs the page shows and the PDFs it links beside them
        sources[rel] = rel
    for source, uri in sources.items():
        files.append(File.generated(config, uri, abs_src_path=str(ROOT / source)))
    return files
