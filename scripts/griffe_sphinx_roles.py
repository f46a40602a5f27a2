"""Griffe extension (mkdocs.yml, mkdocstrings ``extensions``): the docstrings' Sphinx roles as links in the site.

The package's docstrings name other objects the Sphinx way, ``:func:`read_checkpoint```, ``:class:`~a.b.C```,
``:mod:`bptsb_ros.api```, which read well in the source and in ``help()``. mkdocstrings does not know these
roles and would show them raw. Once the package is loaded, this extension resolves each role's target the way
Sphinx's Python domain does (an absolute path; ``.name`` in the current module; else the object's own scope, then
each enclosing scope, following imports) and writes it as an autorefs cross-reference
``[`name`][canonical.path]`` when the target is an object the site renders (public, documented, in the package);
anything else (private names, undocumented helpers, other libraries: ``torch.Tensor``) becomes plain code. So
every link the site shows resolves: an unresolved cross-reference would fail the strict build.
"""

from __future__ import annotations

import re
from typing import Any

from griffe import Alias, Extension, GriffeLoader, Module, Object

ROLE = re.compile(r":(?:py:)?(?:func|class|meth|mod|attr|data|exc|obj|const|type):`([^`]+)`")
_TITLED = re.compile(r"(.*?)\s*<([^>]+)>")


def _target(collection: Any, path: str) -> Object | None:
    """The object at ``path`` (an alias followed to what it names), or None."""
    try:  # griffe raises several kinds of error on the way: a missing name, an alias to another library, a cycle
        found = collection[path]
        return found.final_target if isinstance(found, Alias) else found
    except Exception:
        return None


def _rendered(obj: Object) -> bool:
    """Whether the site renders ``obj``: every part of its path public, a docstring on each object that is not a
    module (mkdocstrings leaves out undocumented members)."""
    node: Object | None = obj
    while node is not None:
        if node.name.startswith("_") and not (isinstance(node, Module) and node.name == "__init__"):
            return False
        if not isinstance(node, Module) and not node.docstring:
            return False
        node = node.parent
    return True


def resolve(obj: Object, text: str, collection: Any, package: str) -> Object | None:
    """The object the role target ``text`` names from ``obj``'s docstring, or None."""
    text = text.lstrip("~")
    module = obj if isinstance(obj, Module) else obj.module
    candidates = []
    if text.startswith("."):
        candidates.append(module.path + text)
        if module.parent is not None:
            candidates.append(module.parent.path + text)
    else:
        if text.split(".")[0] == package:
            candidates.append(text)
        scope: Object | None = obj
        while scope is not None:
            candidates.append(f"{scope.path}.{text}")
            scope = scope.parent
        candidates.append(f"{package}.{text}")
    for path in candidates:
        found = _target(collection, path)
        if found is not None and found.path.split(".")[0] == package:
            return found
    return None


SECTION = re.compile(r"\s*[A-Z][A-Za-z ]*:\s*$")


def code_lines(lines: list[str]) -> set[int]:
    """Indices of the lines of a (dedented) docstring that Markdown shows as code: fenced blocks, and indented
    blocks that follow a blank line (not the items of a Google section such as ``Args:``, which follow their
    header directly)."""
    code: set[int] = set()
    fenced = indented = False
    last_text = ""
    for i, line in enumerate(lines):
        stripped = line.strip()
        if stripped.startswith(("```", "~~~")):
            code.add(i)
            fenced = not fenced
            continue
        if fenced:
            code.add(i)
            continue
        indent = len(line) - len(line.lstrip())
        if stripped and indent >= 4 and (indented or (i > 0 and not lines[i - 1].strip()
                                                      and not SECTION.fullmatch(last_text))):
            indented = True
            code.add(i)
        elif stripped:
            indented = False
        if stripped:
            last_text = line
    return code


def rewrite(obj: Object, docstring: str, collection: Any, package: str) -> str:
    """``docstring`` with every role written as a cross-reference (rendered targets) or as code (the rest); in
    code blocks, as the bare name. A role's target may be broken over two lines."""
    import bisect

    lines = docstring.split("\n")
    code = code_lines(lines)
    starts = [0]
    for line in lines[:-1]:
        starts.append(starts[-1] + len(line) + 1)

    def replace(match: re.Match[str]) -> str:
        content = re.sub(r"\s+", "", match.group(1)) if "<" not in match.group(1) else match.group(1).strip()
        titled = _TITLED.fullmatch(content)
        title, target = (titled.group(1), re.sub(r"\s+", "", titled.group(2))) if titled else (None, content)
        shown = title or (target.lstrip("~").split(".")[-1] if target.startswith("~") else target.lstrip("."))
        if bisect.bisect_right(starts, match.start()) - 1 in code:
            return shown
        found = resolve(obj, target, collection, package)
        if found is None or not _rendered(found):
            return f"`{shown}`"
        return f"[`{shown}`][{found.path}]"

    return ROLE.sub(replace, docstring)


def _walk(obj: Object):
    yield obj
    for member in obj.members.values():
        if not isinstance(member, Alias):
            yield from _walk(member)


class SphinxRoles(Extension):
    """Rewrite the Sphinx roles of every docstring of the loaded package (see the module docstring)."""

    def on_package(self, *, pkg: Module, loader: GriffeLoader, **kwargs: Any) -> None:
        for obj in _walk(pkg):
            if obj.docstring is not None and ":" in obj.docstring.value:
                obj.docstring.value = rewrite(obj, obj.docstring.value, loader.modules_collection, pkg.name)
