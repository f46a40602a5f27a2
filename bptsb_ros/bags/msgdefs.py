"""Full ROS 2 message definitions and type hashes, gathered the way rosbag2 does it.

rosbag2 (``rosbag2_cpp::LocalMessageDefinitionSource``) stores, as the MCAP schema of a topic, the text of the
top-level ``.msg`` file followed by every nested dependency, each introduced by a line of 80 ``=`` and a line
``MSG: pkg/Type``. Dependencies are found with a regular expression on the first word of each line, visited
depth first in sorted order, each one only once. This module reproduces that text byte for byte from the
``.msg`` files installed under ``<prefix>/share/<pkg>/msg/`` without needing a ROS environment: the share
directory is found through the ament index when ``AMENT_PREFIX_PATH`` is set, else next to the installed
Python package of the message package, else under ``sys.prefix``.
"""

from __future__ import annotations

import functools
import importlib
import importlib.util
import json
import os
import re
import sys
from dataclasses import dataclass
from pathlib import Path

from bptsb_ros.bags.errors import MessageDefinitionError

DELIMITER = "=" * 80 + "\n"

# Same pattern as rosbag2: the first word of a line, optionally followed by an array suffix, then whitespace.
_MSG_FIELD_TYPE = re.compile(r"(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+")
_IDL_INCLUDE = re.compile(r"(?:^|\n)#include\s+(?:\"|<)([a-zA-Z0-9_/]+)\.idl(?:\"|>)")
_PRIMITIVES = frozenset({
    "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16", "int32", "uint32",
    "int64", "uint64", "string", "wstring",
})
_NAME = r"[a-zA-Z][a-zA-Z0-9_]*"
_TYPE_RE = re.compile(rf"^({_NAME})/(?:({_NAME})/)?({_NAME})$")


@dataclass(frozen=True)
class MessageDefinition:
    """A schema as rosbag2 writes it: ``encoding`` is ``ros2msg`` (or ``ros2idl``), ``text`` the full text."""

    msgtype: str
    encoding: str
    text: str


def split_type(msgtype: str) -> tuple[str, str, str]:
    """Split ``pkg/msg/Type`` or ``pkg/Type`` into ``(pkg, "msg", "Type")``; raise for anything else."""
    match = _TYPE_RE.match(msgtype)
    if match is None:
        raise MessageDefinitionError(f"not a ROS 2 message type name: {msgtype!r} (expected 'pkg/msg/Type')")
    pkg, namespace, name = match.groups()
    return pkg, namespace or "msg", name


def normalize_type(msgtype: str) -> str:
    """Return the canonical ``pkg/msg/Type`` spelling of ``pkg/Type`` or ``pkg/msg/Type``."""
    pkg, namespace, name = split_type(msgtype)
    return f"{pkg}/{namespace}/{name}"


def _ament_share(pkg: str) -> Path | None:
    if not os.environ.get("AMENT_PREFIX_PATH"):
        return None
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
    except ImportError:
        return None
    try:
        return Path(get_package_share_directory(pkg))
    except (PackageNotFoundError, ValueError, OSError):
        return None


def _python_package_share(pkg: str) -> Path | None:
    try:
        spec = importlib.util.find_spec(pkg)
    except (ImportError, ValueError):
        return None
    if spec is None or not spec.submodule_search_locations:
        return None
    for location in spec.submodule_search_locations:
        # <prefix>/lib/pythonX.Y/site-packages/<pkg> -> <prefix>/share/<pkg>
        for ancestor in Path(location).resolve().parents:
            candidate = ancestor / "share" / pkg
            if candidate.is_dir():
                return candidate
    return None


@functools.cache
def find_share_dir(pkg: str) -> Path:
    """Return ``<prefix>/share/<pkg>`` of an installed ROS package (ament index, Python package, sys.prefix)."""
    for found in (_ament_share(pkg), _python_package_share(pkg)):
        if found is not None and found.is_dir():
            return found
    fallback = Path(sys.prefix) / "share" / pkg
    if fallback.is_dir():
        return fallback
    raise MessageDefinitionError(
        f"cannot find the share directory of ROS package {pkg!r} (looked in the ament index, next to the "
        f"Python package {pkg!r} and in {Path(sys.prefix) / 'share'}); is the message package installed?"
    )


@functools.cache
def _interface_file(msgtype: str, extension: str) -> str | None:
    pkg, namespace, name = split_type(msgtype)
    path = find_share_dir(pkg) / namespace / f"{name}{extension}"
    return path.read_text(encoding="utf-8") if path.is_file() else None


def _dependencies(text: str, pkg: str, extension: str) -> list[str]:
    if extension == ".idl":
        return sorted(set(_IDL_INCLUDE.findall(text)))
    deps = set()
    for word in _MSG_FIELD_TYPE.findall(text):
        if word in _PRIMITIVES:
            continue
        deps.add(word if "/" in word else f"{pkg}/{word}")
    return sorted(deps)


def _full_text(root: str, extension: str) -> str:
    seen: set[str] = set()

    def append(msgtype: str, depth: int) -> str:
        if depth <= 0:
            raise MessageDefinitionError(f"maximum recursion depth reached resolving the definition of {root}")
        text = _interface_file(msgtype, extension)
        if text is None:
            raise FileNotFoundError(msgtype)
        result = text
        for dep in _dependencies(text, split_type(msgtype)[0], extension):
            if dep not in seen:
                seen.add(dep)
                label = "MSG: " if extension == ".msg" else "IDL: "
                result += "\n" + DELIMITER + label + dep + "\n" + append(dep, depth - 1)
        return result

    return append(root, 50)


@functools.cache
def message_definition(msgtype: str) -> MessageDefinition:
    """Return the full definition of ``msgtype`` (``pkg/msg/Type``) as rosbag2 stores it in an MCAP schema.

    Falls back, as rosbag2 does, to the ``.idl`` files (encoding ``ros2idl``) when a ``.msg`` file is missing.
    Raises :class:`MessageDefinitionError` when neither exists.
    """
    canonical = normalize_type(msgtype)
    pkg, _, name = split_type(canonical)
    short = f"{pkg}/{name}"
    try:
        return MessageDefinition(canonical, "ros2msg", _full_text(short, ".msg"))
    except FileNotFoundError:
        pass
    try:
        root = f"{pkg}/msg/{name}"
        return MessageDefinition(canonical, "ros2idl", DELIMITER + "IDL: " + root + "\n" + _full_text(root, ".idl"))
    except FileNotFoundError as exc:
        raise MessageDefinitionError(
            f"no .msg or .idl definition found for {canonical} (missing {exc}) under {find_share_dir(pkg)}"
        ) from None


@functools.cache
def type_description_hash(msgtype: str) -> str:
    """Return the ``RIHS01_<sha256>`` type hash of ``msgtype`` from its installed ``.json`` type description.

    Returns ``""`` when the package ships no type description (pre-Iron packages), as rosbag2 does when the
    publisher reports no hash.
    """
    pkg, namespace, name = split_type(msgtype)
    path = find_share_dir(pkg) / namespace / f"{name}.json"
    if not path.is_file():
        return ""
    try:
        hashes = json.loads(path.read_text(encoding="utf-8"))["type_hashes"]
    except (ValueError, KeyError) as exc:
        raise MessageDefinitionError(f"malformed type description {path}: {exc}") from None
    wanted = f"{pkg}/{namespace}/{name}"
    for entry in hashes:
        if entry.get("type_name") == wanted:
            return str(entry["hash_string"])
    return ""


def get_message_class(msgtype: str) -> type:
    """Import and return the Python class of ``msgtype`` (``pkg/msg/Type`` or ``pkg/Type``)."""
    pkg, namespace, name = split_type(msgtype)
    # A bag is untrusted data: import only the module of an installed ROS message (its .msg file in the
    # package's share directory), never whatever module a schema name happens to spell.
    try:
        installed = namespace == "msg" and (find_share_dir(pkg) / "msg" / f"{name}.msg").is_file()
    except MessageDefinitionError:
        installed = False
    if not installed:
        raise MessageDefinitionError(f"{msgtype} is not an installed ROS 2 message (no {pkg}/msg/{name}.msg "
                                     "found); refusing to import a module a bag names")
    try:
        module = importlib.import_module(f"{pkg}.{namespace}")
    except ImportError as exc:
        raise MessageDefinitionError(f"cannot import the Python module of {msgtype}: {exc}") from None
    try:
        return getattr(module, name)
    except AttributeError:
        raise MessageDefinitionError(f"{pkg}.{namespace} has no message class {name!r}") from None
