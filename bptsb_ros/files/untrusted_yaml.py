"""Untrusted YAML (experiment configs, ``--set`` values, a bag's ``metadata.yaml``) read as bounded data.

``yaml.safe_load`` builds no objects, but a few hundred bytes of nested aliases (an "alias bomb") expand to
billions of nodes as soon as anything walks or prints the result. :func:`load_untrusted_yaml` counts the
expanded size on the composed node graph (where an alias is one shared node) before constructing anything,
and bounds the text length; :func:`bounded_repr` bounds what an error message repeats of a value, and
:func:`printable` escapes the control characters of untrusted text before it reaches a terminal.
"""

from __future__ import annotations

import re
import reprlib
from typing import Any

import yaml

_TAG = re.compile(r"tag '([^']*)'")


class UntrustedYamlError(ValueError):
    """Untrusted YAML text is too large, expands too far, is not text, or does not parse."""


class _BoundedLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that checks the expanded size of the document before constructing it."""

    max_nodes = 10_000

    def get_single_node(self):  # noqa: ANN201 - PyYAML's own signature
        node = super().get_single_node()
        if node is not None:
            _check_expansion(node, self.max_nodes)
        return node


def _check_expansion(root: yaml.Node, limit: int) -> None:
    """Raise UntrustedYamlError if the document under ``root`` has more than ``limit`` nodes once expanded, or if
    an alias refers to a node that contains it (``&a [*a]``: a document that expands forever)."""
    sizes: dict[int, int] = {}
    open_: set[int] = set()  # nodes whose children are being sized: meeting one again is a cycle
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    while stack:
        node, children_done = stack.pop()
        if id(node) in sizes:
            continue
        if isinstance(node, yaml.ScalarNode):
            sizes[id(node)] = 1
            continue
        kids = [k for pair in node.value for k in pair] if isinstance(node, yaml.MappingNode) else list(node.value)
        if children_done:
            total = 1 + sum(sizes[id(k)] for k in kids)
            if total > limit:
                raise UntrustedYamlError(f"YAML document expands to more than {limit} nodes (alias bomb?)")
            sizes[id(node)] = total
            open_.discard(id(node))
        else:
            if id(node) in open_:
                raise UntrustedYamlError("YAML document has a recursive alias (a node that contains itself), which "
                                         "expands without end")
            open_.add(id(node))
            stack.append((node, True))
            stack.extend((k, False) for k in kids if id(k) not in sizes)


def load_untrusted_yaml(text: str | bytes, what: str, *, max_bytes: int = 1 << 20, max_nodes: int = 10_000) -> Any:
    """Parse untrusted YAML text; every failure is an :class:`UntrustedYamlError` naming ``what``.

    Args:
        text: the document (bytes must be UTF-8).
        what: names the source in messages (``config file x.yaml``).
        max_bytes: longest text accepted.
        max_nodes: most nodes the document may expand to, aliases counted at every use.
    """
    if len(text) > max_bytes:
        raise UntrustedYamlError(f"{what} is {len(text)} bytes; the limit is {max_bytes}")
    if isinstance(text, bytes):
        try:
            text = text.decode("utf-8")
        except UnicodeDecodeError:
            raise UntrustedYamlError(f"{what} is not UTF-8 text") from None
    loader = type("Loader", (_BoundedLoader,), {"max_nodes": max_nodes})
    try:
        return yaml.load(text, Loader=loader)  # noqa: S506 - a SafeLoader subclass
    except UntrustedYamlError as err:
        raise UntrustedYamlError(f"{what}: {err}") from None
    except yaml.constructor.ConstructorError as err:  # a tag such as !!python/object: plain data only
        tag = _TAG.search(str(err.problem or ""))
        shown = bounded_repr(tag.group(1) if tag else str(err.problem), 120)
        raise UntrustedYamlError(f"{what} uses the YAML tag {shown}, which is not plain data (only safe YAML "
                                 "is read)") from None
    except yaml.YAMLError as err:
        raise UntrustedYamlError(f"{what} is not valid YAML: {bounded_repr(str(err), 300)}") from None


_REPR = reprlib.Repr()  # keyword arguments to Repr() need Python 3.12
_REPR.maxlevel, _REPR.maxdict, _REPR.maxlist, _REPR.maxtuple, _REPR.maxset = 2, 4, 4, 4, 4


def bounded_repr(value: Any, limit: int = 80) -> str:
    """``repr`` of ``value`` in at most ``limit`` characters, however deep or large the value."""
    _REPR.maxstring = _REPR.maxother = _REPR.maxlong = limit
    text = _REPR.repr(value)
    return text if len(text) <= limit else text[: limit - 1] + "…"


def printable(text: str) -> str:
    """``text`` with every character that is not printable (control bytes such as ESC, BEL or CR, bidirectional
    overrides, line separators) written as its escape (``\\x1b``, ``\\u202e``): untrusted names and excerpts printed
    in a message cannot set a terminal's title or colours, move its cursor or break the message's line."""
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)
