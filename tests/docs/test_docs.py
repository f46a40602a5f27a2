"""The documentation: the README stays a front page, no page speaks of one machine, its temporary paths or
the work items its text came from, and the site builds with ``mkdocs build --strict`` (broken links, broken
anchors and docstring warnings are errors).

The site build needs the docs tools of the ``dev`` extra (mkdocs, mkdocs-material, mkdocstrings-python) and is
skipped only where mkdocs is not installed; the text checks need nothing.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path

import pytest
import yaml
from conftest import REPO_ROOT as REPO

README = REPO / "README.md"
README_MAX_LINES = 250

# (what is wrong, pattern): each a phrase that ties a page to one machine, one checkout or one work item.
MACHINE_PATTERNS = [
    ("an absolute path on one machine", re.compile(r"(?<![\w.~-])/(?:work|tmp|root)/")),
    ("'this machine'", re.compile(r"\bthis machine\b", re.IGNORECASE)),
    ("a reference to an issue", re.compile(r"\bissue\s*#|\bthe issue\b", re.IGNORECASE)),
]
PROSE_PATTERNS = MACHINE_PATTERNS + [
    ("'here' (say where)", re.compile(r"\bhere\b", re.IGNORECASE)),
    ("words about load", re.compile(r"\bunder (?:\w+ )?load\b|\bload average\b|\b(?:idle|shared|loaded) machine\b"
                                    r"|\bother engineers\b", re.IGNORECASE)),
]


def doc_sources() -> list[Path]:
    """The Markdown the README and the site are written in (REPRODUCTION.md is written by ``bptsb report``)."""
    return [README, *sorted((REPO / "docs").rglob("*.md")), REPO / "bptsb_ros" / "ros" / "TOPICS.md"]


def violations(text: str, patterns: list[tuple[str, re.Pattern[str]]]) -> list[str]:
    """``line N: what (matched text)`` for every match of ``patterns`` in ``text``."""
    found = []
    for number, line in enumerate(text.splitlines(), start=1):
        for what, pattern in patterns:
            for match in pattern.finditer(line):
                found.append(f"line {number}: {what} ({match.group(0)!r})")
    return found


@pytest.mark.parametrize("text", [
    "written to /tmp/run", "see /work/shared/data", "a key in /root/.ssh", "(/tmp/x)", "`/tmp/bench.json`",
    "on This Machine", "the issue's targets", "Issue #12", "issue#3", "measured here", "Here:",
    "under load 14-15", "under heavier load", "the idle machine", "the load average was 3", "other engineers' jobs",
])
def test_the_checks_catch_each_forbidden_phrase(text):
    assert violations(text, PROSE_PATTERNS), text


@pytest.mark.parametrize("text", [
    "runs/tmp/x", "bptsb_ros/work/x", "~/tmp/x", "a prefix such as /opt/ros-tools-jazzy", "there", "where",
    "hereafter", "the machine's specification: 2 cores", "issues a command", "download", "`load_average_at_start`",
    "reload the page", "https://example.org/tmp/x",
])
def test_the_checks_pass_ordinary_text(text):
    assert violations(text, PROSE_PATTERNS) == [], text


def test_readme_is_a_front_page():
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= README_MAX_LINES, f"README.md has {len(lines)} lines; at most {README_MAX_LINES}"


#: a Markdown link or image: [text](target) / ![alt](target "title")
_LINK = re.compile(r"!?\[(?:[^\][]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
_CODE = re.compile(r"^(```|~~~).*?^\1[^\n]*$|`[^`\n]*`", re.MULTILINE | re.DOTALL)


def relative_links(text: str) -> list[str]:
    """The relative link targets of a Markdown text (no scheme, no bare #anchor), outside code."""
    text = _CODE.sub("", text)
    return [t for t in _LINK.findall(text) if not re.match(r"[A-Za-z][A-Za-z0-9+.-]*:", t) and not t.startswith("#")]


def test_relative_links_are_found_outside_code():
    text = "[a](x.md) ![b](img/y.png \"t\") [c](https://e.org) [d](#anchor) `[e](code.md)`\n```\n[f](no.md)\n```\n"
    assert relative_links(text) == ["x.md", "img/y.png"]


def test_every_relative_link_resolves_in_the_repository():
    """README.md and every page link files by their path in the repository (the site build maps them)."""
    sources = [README, *sorted((REPO / "docs").rglob("*.md")), REPO / "bptsb_ros" / "ros" / "TOPICS.md",
               REPO / "REPRODUCTION.md", REPO / "bags" / "README.md"]
    missing = []
    for source in sources:
        for target in relative_links(source.read_text(encoding="utf-8")):
            if not (source.parent / target.split("#", 1)[0]).exists():
                missing.append(f"{source.relative_to(REPO)}: {target}")
    assert missing == [], "links to missing files:\n" + "\n".join(missing)


def test_every_public_module_has_an_api_page_and_bptsb_ros_api_comes_first():
    """Each module of the package (less private ones and ``__main__``) is documented by a page's ``:::``
    directive, itself or through a documented package (show_submodules); the API section opens with
    bptsb_ros.api."""
    import pkgutil

    import bptsb_ros

    config = yaml.safe_load((REPO / "mkdocs.yml").read_text(encoding="utf-8"))
    api = next(item["API reference"] for item in config["nav"] if isinstance(item, dict) and "API reference" in item)
    pages = [next(iter(entry.values())) for entry in api]
    assert pages[0] == "api/api.md"
    documented = set()
    for page in pages:
        documented |= set(re.findall(r"^::: ([\w.]+)$", (REPO / "docs" / page).read_text(), re.MULTILINE))
    assert "bptsb_ros.api" in documented
    modules = [m.name for m in pkgutil.walk_packages(bptsb_ros.__path__, "bptsb_ros.")
               if not any(part.startswith("_") for part in m.name.split("."))]
    assert len(modules) > 100
    undocumented = [m for m in modules if not any(m == d or m.startswith(d + ".") for d in documented)]
    assert undocumented == []


def test_pages_speak_of_no_machine_path_or_work_item():
    problems = []
    for path in doc_sources():
        for problem in violations(path.read_text(encoding="utf-8"), PROSE_PATTERNS):
            problems.append(f"{path.relative_to(REPO)} {problem}")
    assert problems == [], "\n".join(problems)


def test_strict_validation_is_configured():
    config = yaml.safe_load((REPO / "mkdocs.yml").read_text(encoding="utf-8"))
    assert config["strict"] is True
    assert config["validation"] == {"omitted_files": "warn", "absolute_links": "warn", "unrecognized_links": "warn",
                                    "anchors": "warn"}
    mkdocstrings = next(p["mkdocstrings"] for p in config["plugins"] if isinstance(p, dict) and "mkdocstrings" in p)
    assert mkdocstrings["handlers"]["python"]["options"]["docstring_style"] == "google"


class _Text(HTMLParser):
    """The visible text of an HTML page (scripts and styles left out)."""

    def __init__(self) -> None:
        super().__init__()
        self.parts: list[str] = []
        self._skip = 0

    def handle_starttag(self, tag, attrs):
        if tag in ("script", "style"):
            self._skip += 1

    def handle_endtag(self, tag):
        if tag in ("script", "style") and self._skip:
            self._skip -= 1

    def handle_data(self, data):
        if not self._skip:
            self.parts.append(data)


@pytest.mark.slow
def test_site_builds_strictly(tmp_path):
    pytest.importorskip("mkdocs", reason="the docs tools (pip install -e '.[dev]') are not installed")
    site = tmp_path / "site"
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)],
                          cwd=REPO, env=env, capture_output=True, text=True, timeout=300)
    warnings = [line for line in (proc.stdout + proc.stderr).splitlines() if "WARNING" in line or "ERROR" in line]
    assert proc.returncode == 0, "mkdocs build --strict failed:\n" + "\n".join(warnings or [proc.stderr[-3000:]])
    assert warnings == []

    # every page of the nav was written, the repository files the hook serves included
    for page in ("index.html", "REPRODUCTION/index.html", "ros/topics/index.html", "experiments/mnist/index.html",
                 "reproduction/runs/lissajous-closed-loop-paper/seed-0/agent/lissajous.png", "digit_targets.png"):
        assert (site / page).is_file(), page
    # the API reference rendered the docstrings (read statically: rclpy is not imported for api/ros)
    api = {name: (site / "api" / name / "index.html").read_text(encoding="utf-8")
           for name in ("api", "body", "brains", "training", "tasks", "experiments", "analysis", "sim", "bags",
                        "data", "config", "ros", "jobs", "files", "bench", "cli")}
    assert "Advance one step of" in api["body"]  # MSDN.step's docstring
    assert "bptsb_ros.ros.body_sim" in api["ros"]
    assert "BagWriter" in api["bags"]
    assert 'id="bptsb_ros.api.load_config"' in api["api"] and 'id="bptsb_ros.api.train"' in api["api"]
    # the docstrings' Sphinx roles are links or code, never raw text, and the links are there
    raw = [(name, m) for name, html in api.items() for m in re.findall(r":(?:func|class|meth|mod|attr|data):<code>",
                                                                      html)]
    assert raw == []
    assert '<a class="autorefs autorefs-internal" href="#bptsb_ros.training.guard.UpdateGuard">' in api["training"]
    assert api["api"].count('class="autorefs autorefs-internal"') >= 10  # bptsb_ros.api's roles: load_config, ...

    # every relative link and image of every page lands on a file of the site
    dead = []
    for page in sorted(site.rglob("*.html")):
        html = page.read_text(encoding="utf-8")
        for target in re.findall(r'(?:href|src)="([^"#?]+)[^"]*"', html):
            if re.match(r"[A-Za-z][A-Za-z0-9+.-]*:|//", target) or target.startswith("/"):
                continue
            resolved = (page.parent / target).resolve()
            if not (resolved.is_file() or (resolved / "index.html").is_file()):
                dead.append(f"{page.relative_to(site)}: {target}")
    assert dead == [], "\n".join(dead[:20])

    # what the site shows, docstrings included, ties itself to no machine (REPRODUCTION.md records where its
    # runs were made: it is the report's provenance)
    problems = []
    for page in sorted(site.rglob("*.html")):
        if page.relative_to(site).parts[0] == "REPRODUCTION":
            continue
        parser = _Text()
        parser.feed(page.read_text(encoding="utf-8"))
        for problem in violations("".join(parser.parts), MACHINE_PATTERNS):
            problems.append(f"{page.relative_to(site)} {problem}")
    assert problems == [], "\n".join(problems)
