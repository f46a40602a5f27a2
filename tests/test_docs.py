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

REPO = Path(__file__).resolve().parent.parent
README = REPO / "README.md"
README_MAX_LINES = 250

# Links of the README to files another step of the release writes; they must exist once it has run.
README_PENDING_TARGETS = {"CHANGELOG.md"}

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


def test_readme_links_resolve():
    text = README.read_text(encoding="utf-8")
    targets = re.findall(r"\]\(([^)\s]+)\)", text)
    assert targets, "README.md links nothing"
    missing = []
    for target in targets:
        if re.match(r"[a-z]+:", target) or target.startswith("#"):
            continue
        path = target.split("#", 1)[0]
        if path not in README_PENDING_TARGETS and not (REPO / path).exists():
            missing.append(target)
    assert missing == [], f"README.md links to missing files: {missing}"


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
    assert config["plugins"][1]["mkdocstrings"]["handlers"]["python"]["options"]["docstring_style"] == "google"


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
                 "reproduction/runs/lissajous-closed-loop-paper/agent/lissajous.png", "digit_targets.png"):
        assert (site / page).is_file(), page
    # the API reference rendered the docstrings (read statically: rclpy is not imported for api/ros)
    api = {name: (site / "api" / name / "index.html").read_text(encoding="utf-8")
           for name in ("body", "brains", "training", "tasks", "experiments", "analysis", "sim", "bags", "data",
                        "config", "ros")}
    assert "Advance one step of" in api["body"]  # MSDN.step's docstring
    assert "bptsb_ros.ros.body_sim" in api["ros"]
    assert "BagWriter" in api["bags"]

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
