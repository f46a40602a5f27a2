"""MkDocs hook (``hooks:`` in mkdocs.yml): serve repository files in the docs site, and keep every relative link
of the pages true both in the repository and in the site.

``REPRODUCTION.md`` (written by ``bptsb report``) with the figures it links under ``reproduction/runs/``,
and ``bptsb_ros/ros/TOPICS.md`` (shipped in the package) each have one source in the repository; the site
reads them from there, so the docs never hold a second copy that could go stale.

The pages link such files by their repository paths (``../REPRODUCTION.md`` from ``docs/index.md``), so that the
links work where the Markdown is read in the repository. The site places the repository's files differently
(``docs/`` is its root, :data:`PAGES` moves some): :func:`on_page_markdown` rewrites each link that leaves
``docs/`` to the file's place in the site, and :func:`on_files` serves every non-page file such a link names
(``requirements-ros.txt``) at its repository path. A link to a Markdown file outside ``docs/`` that is not one of
:data:`PAGES` is an error: it would be a page outside the navigation.
"""

from __future__ import annotations

import posixpath
import re
from pathlib import Path

from mkdocs.config.defaults import MkDocsConfig
from mkdocs.exceptions import PluginError
from mkdocs.structure.files import File, Files
from mkdocs.structure.pages import Page

ROOT = Path(__file__).resolve().parent.parent
DOCS = "docs"

# repository path -> path inside the site's docs tree
PAGES = {
    "REPRODUCTION.md": "REPRODUCTION.md",
    "bptsb_ros/ros/TOPICS.md": "ros/topics.md",
}
FIGURE_DIR = "reproduction/runs"

#: a Markdown link or image target: ``[text](target)`` / ``![alt](target "title")``
LINK = re.compile(r"(!?\[(?:[^\][]|\[[^\]]*\])*\]\(\s*<?)([^)\s>]+)(>?(?:\s+\"[^\"]*\")?\s*\))")
#: fenced code blocks and inline code, whose text is never a link
CODE = re.compile(r"^(```|~~~).*?^\1[^\n]*$|`[^`\n]*`", re.MULTILINE | re.DOTALL)
SCHEME = re.compile(r"[A-Za-z][A-Za-z0-9+.-]*:")


def _outside_links(text: str, repo_path: str):
    """(match, repository path of the target, fragment) for each relative link of ``text`` (a page at
    ``repo_path``) whose target lies outside ``docs/``; code is skipped."""
    code = [m.span() for m in CODE.finditer(text)]
    for match in LINK.finditer(text):
        if any(a <= match.start() < b for a, b in code):
            continue
        target = match.group(2)
        if SCHEME.match(target) or target.startswith(("#", "/")):
            continue
        path, _, fragment = target.partition("#")
        if not path:
            continue
        resolved = posixpath.normpath(posixpath.join(posixpath.dirname(repo_path), path))
        if resolved.startswith("../"):
            raise PluginError(f"{repo_path}: the link {target} leaves the repository")
        if resolved != DOCS and not resolved.startswith(DOCS + "/"):
            yield match, resolved, fragment


def _site_path(repo_path: str, where: str) -> str:
    """Where the repository file ``repo_path`` is in the site; PluginError for a page outside the navigation."""
    if repo_path in PAGES:
        return PAGES[repo_path]
    if repo_path.endswith(".md"):
        raise PluginError(f"{where} links {repo_path}, a Markdown file outside docs/ that the site does not serve "
                          "(scripts/mkdocs_hooks.py PAGES)")
    if not (ROOT / repo_path).is_file():
        raise PluginError(f"{where} links {repo_path}, which is not a file of the repository")
    return repo_path


def _repo_path(page_uri: str) -> str:
    """The repository path of the page served at ``page_uri`` (a path inside the site's docs tree)."""
    for repo, uri in PAGES.items():
        if uri == page_uri:
            return repo
    return f"{DOCS}/{page_uri}"


def on_files(files: Files, config: MkDocsConfig) -> Files:
    """Add the repository pages, the reproduction figures and every other repository file a page links to."""
    sources = dict(PAGES)
    for figure in sorted([*(ROOT / FIGURE_DIR).rglob("*.png"), *(ROOT / FIGURE_DIR).rglob("*.pdf")]):
        rel = figure.relative_to(ROOT).as_posix()  # the PNGs the page shows and the PDFs it links beside them
        sources[rel] = rel
    pages = [*(ROOT / DOCS).rglob("*.md"), *(ROOT / p for p in PAGES)]
    for page in pages:
        repo_path = page.relative_to(ROOT).as_posix()
        for _, target, _ in _outside_links(page.read_text(encoding="utf-8"), repo_path):
            sources.setdefault(target, _site_path(target, repo_path))
    for source, uri in sources.items():
        files.append(File.generated(config, uri, abs_src_path=str(ROOT / source)))
    return files


def on_page_markdown(markdown: str, page: Page, config: MkDocsConfig, files: Files) -> str:
    """Rewrite the page's links that leave ``docs/`` to where their targets are in the site."""
    repo_path = _repo_path(page.file.src_uri)
    out, last = [], 0
    for match, target, fragment in _outside_links(markdown, repo_path):
        site = _site_path(target, repo_path)
        rel = posixpath.relpath(site, posixpath.dirname(page.file.src_uri) or ".")
        out += [markdown[last:match.start(2)], rel + (f"#{fragment}" if fragment else "")]
        last = match.end(2)
    return "".join(out) + markdown[last:]
