"""Message objects from CDR bytes: rclpy's when ROS 2 is installed, else rosbags' from the bag's own schema.

Two decoders give messages with the same field names and values:

* ``rclpy``: ``rclpy.serialization.deserialize_message`` into the installed message class (needs rclpy and the
  message packages, i.e. a ROS 2 install or its wheels).
* ``rosbags``: the pure-Python CDR deserialiser of the ``rosbags`` package, with the message types parsed from the
  schema text the bag carries (every MCAP schema of a rosbag2 bag holds the full definition, nested types
  included), so a custom message type decodes as well as a standard one. A schema without text falls back to the
  ROS 2 Jazzy types that rosbags ships.

``auto`` (the default) uses rclpy for a type whose class is installed and rosbags for everything else (no rclpy,
or a type rclpy does not know). The two differ only in container types: rosbags gives numeric sequences and
arrays as numpy arrays (rclpy: ``array.array``, numpy for fixed-size arrays), ``uint8[]`` as a numpy uint8 array
(rclpy: ``array.array('B')`` / bytes) and a ``byte`` field as an int (rclpy: a 1-byte ``bytes``). ``len``,
indexing, iteration, ``np.asarray`` and ``bytes()`` treat both alike.

The schema text is untrusted bag data: rosbags compiles the types it parses into Python code, so every type and
field name is checked to be a plain identifier before anything is registered.
"""

from __future__ import annotations

import functools
import re
from collections.abc import Callable
from typing import Any

from mcap.records import Schema

from bptsb_ros.bags.errors import BagError, MessageDefinitionError
from bptsb_ros.bags.msgdefs import DELIMITER, get_message_class, message_definition, normalize_type

#: Decoder names accepted by :class:`MessageDecoder` (and ``read_messages(..., decoder=...)``).
DECODERS = ("auto", "rclpy", "rosbags")

_IDENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_TYPENAME = re.compile(r"[A-Za-z][A-Za-z0-9_]*(?:/[A-Za-z][A-Za-z0-9_]*){1,2}")
#: largest schema text parsed (a full MarkerArray definition is ~20 KB)
MAX_SCHEMA_BYTES = 1 << 20


@functools.cache
def rclpy_deserializer() -> Callable[[bytes, type], Any] | None:
    """``rclpy.serialization.deserialize_message``, or None when rclpy cannot be imported here."""
    try:
        from rclpy.serialization import deserialize_message
    except (ImportError, OSError):  # not installed, or its C libraries are missing (ROS not sourced)
        return None
    return deserialize_message


def _import_typesys() -> Any:
    try:
        from rosbags import typesys
    except ImportError:
        raise BagError("decoding a message without rclpy needs the rosbags package (pip install rosbags)") from None
    return typesys


def _check_name(kind: str, name: object, pattern: re.Pattern[str], msgtype: str) -> None:
    if not isinstance(name, str) or not pattern.fullmatch(name):
        raise BagError(f"the bag's schema of {msgtype} names a {kind} {name!r} that is not a plain identifier")


def _check_desc(desc: Any, msgtype: str) -> None:
    """A field descriptor ``(nodetype, ...)``: named types must be plain type names (recursing into arrays)."""
    from rosbags.interfaces import Nodetype

    node = Nodetype(desc[0])
    if node == Nodetype.NAME:
        _check_name("type", desc[1], _TYPENAME, msgtype)
    elif node in (Nodetype.ARRAY, Nodetype.SEQUENCE):
        _check_desc(desc[1][0], msgtype)
        _check_bound(desc[1][1], msgtype)
    else:
        _check_name("base type", desc[1][0], _IDENT, msgtype)
        _check_bound(desc[1][1], msgtype)


def _check_bound(bound: object, msgtype: str) -> None:
    """An array length or string bound: written into rosbags' generated code as it is, so a plain int only."""
    if type(bound) is not int and bound is not None:
        raise BagError(f"the bag's schema of {msgtype} gives a bound {bound!r} that is not a whole number")


#: most fields a schema's type may expand to (nested types and fixed arrays of strings or types counted per
#: element: rosbags writes a line of code for each); the largest installed message, InteractiveMarkerUpdate,
#: expands to 87, and generating the decoder of 1,000 string fields took 3.7 s (``string[4096]``: 20 s)
MAX_SCHEMA_FIELDS = 1_000
#: longest fixed array of numbers a schema may declare (decoded with numpy, whatever its length; a message that
#: holds it is bounded by the bag's chunks anyway); the installed messages have at most 36 elements
MAX_FIXED_ARRAY = 1_000_000
#: deepest nesting of types (the installed messages: 5)
MAX_SCHEMA_DEPTH = 32
#: most declaration lines (fields and constants, comments left out) a schema's text may hold, counted before it is
#: parsed: the installed InteractiveMarkerUpdate's full text has 112, and rosbags took 1.1 s to parse 5,000 and 19 s
#: for 60,000
MAX_SCHEMA_LINES = 2_000


def declaration_lines(text: str, encoding: str) -> int:
    """Lines of a schema's text that declare something (neither blank nor a comment nor a type's separator)."""
    comment = "#" if encoding == "ros2msg" else "//"
    return sum(1 for line in text.splitlines()
               if (body := line.split(comment, 1)[0].strip()) and not body.startswith(("MSG: ", "IDL: ", "====")))


def schema_size(typs: dict[str, Any], msgtype: str) -> int:
    """The fields ``msgtype`` expands to in the parsed schema ``typs``, nested types and fixed arrays of strings or
    types counted per element; :class:`BagError` as soon as it passes :data:`MAX_SCHEMA_FIELDS`, for a fixed array
    longer than :data:`MAX_FIXED_ARRAY`, or nesting deeper than :data:`MAX_SCHEMA_DEPTH` (a type that contains
    itself never ends)."""
    from rosbags.interfaces import Nodetype

    sizes: dict[str, int] = {}

    def field_size(desc: Any, depth: int) -> int:
        node = Nodetype(desc[0])
        if node == Nodetype.NAME:
            return type_size(desc[1], depth + 1)
        if node == Nodetype.ARRAY:
            element, length = desc[1]
            if length > MAX_FIXED_ARRAY:
                raise BagError(f"the bag's schema of {msgtype} declares a fixed array of {length:,} elements; the "
                               f"most read is {MAX_FIXED_ARRAY:,}")
            numeric = Nodetype(element[0]) == Nodetype.BASE and element[1][0] not in ("string", "wstring")
            return 1 if numeric else length * field_size(element, depth)
        if node == Nodetype.SEQUENCE:
            return field_size(desc[1][0], depth)
        return 1

    def type_size(name: str, depth: int) -> int:
        if depth > MAX_SCHEMA_DEPTH:
            raise BagError(f"the bag's schema of {msgtype} nests types more than {MAX_SCHEMA_DEPTH} deep (a type "
                           "that contains itself?)")
        if name not in sizes:
            if name not in typs:
                return 1  # a dangling name: rosbags says so when the type is used
            total = 0
            for _, desc in typs[name][1]:
                total += field_size(desc, depth)
                if total > MAX_SCHEMA_FIELDS:
                    raise BagError(f"the bag's schema of {msgtype} expands to more than {MAX_SCHEMA_FIELDS:,} fields "
                                   "(nested types and fixed arrays counted per element); that is not a message "
                                   "this package reads")
            sizes[name] = total
        return sizes[name]

    return type_size(msgtype, 0)


def check_typesdict(typs: dict[str, Any], msgtype: str) -> None:
    """Refuse parsed types whose names could not be plain Python identifiers (rosbags turns them into code), and
    schemas that expand too far (:func:`schema_size`)."""
    for name, (consts, fields) in typs.items():
        _check_name("type", name, _TYPENAME, msgtype)
        for fname, ftype, value in consts:
            _check_name("constant", fname, _IDENT, msgtype)
            _check_name("constant type", ftype, _IDENT, msgtype)
            if type(value) not in (bool, int, float, str):  # rosbags writes its repr() into the generated code
                raise BagError(f"the bag's schema of {msgtype} gives constant {fname} a value of type "
                               f"{type(value).__name__}, not a number, boolean or string")
        for fname, desc in fields:
            _check_name("field", fname, _IDENT, msgtype)
            _check_desc(desc, msgtype)
    schema_size(typs, msgtype)


def _types_from_schema(msgtype: str, encoding: str, text: str) -> dict[str, Any]:
    lines = declaration_lines(text, encoding)
    if lines > MAX_SCHEMA_LINES:
        raise BagError(f"the bag's schema of {msgtype} declares {lines:,} fields and constants; the most read is "
                       f"{MAX_SCHEMA_LINES:,}")
    typesys = _import_typesys()
    if encoding == "ros2msg":
        return typesys.get_types_from_msg(text, msgtype)
    if encoding == "ros2idl":  # rosbag2: each .idl introduced by a delimiter line and "IDL: pkg/msg/Type"
        typs: dict[str, Any] = {}
        parts = text.split(DELIMITER)[1:] if text.startswith(DELIMITER + "IDL: ") else [text]
        for part in parts:
            idl = part.split("\n", 1)[1] if part.startswith("IDL: ") else part
            typs.update(typesys.get_types_from_idl(idl))
        return typs
    raise BagError(f"the bag's schema of {msgtype} has encoding {encoding!r}; only ros2msg and ros2idl decode")


@functools.lru_cache(maxsize=64)
def _schema_store(msgtype: str, encoding: str, text: str) -> Any:
    """A rosbags typestore holding the types of one schema (its text is self-contained: nested types included)."""
    typesys = _import_typesys()
    try:
        typs = _types_from_schema(msgtype, encoding, text)
        check_typesdict(typs, msgtype)
        store = typesys.get_typestore(typesys.Stores.EMPTY)
        store.register(typs)
    except BagError:
        raise
    except Exception as exc:  # noqa: BLE001 - the parser raises assorted errors on malformed text
        why = " ".join(str(exc).split())[:240]  # one line: the parser's message quotes the text over lines
        raise BagError(f"the bag's schema of {msgtype} cannot be parsed: {type(exc).__name__}: {why}") from None
    if msgtype not in store.types:
        raise BagError(f"the bag's schema of {msgtype} does not define {msgtype}")
    return store


@functools.cache
def _jazzy_store() -> Any:
    typesys = _import_typesys()
    return typesys.get_typestore(typesys.Stores.ROS2_JAZZY)


def rosbags_decoder(schema: Schema) -> Callable[[bytes], Any]:
    """A function CDR bytes -> message object of ``schema``'s type, from its text (Jazzy's types without one)."""
    msgtype = normalize_type(schema.name)
    if len(schema.data) > MAX_SCHEMA_BYTES:
        raise BagError(f"the bag's schema of {msgtype} is {len(schema.data)} bytes, over {MAX_SCHEMA_BYTES}")
    if schema.data:
        try:
            text = schema.data.decode("utf-8")
        except UnicodeDecodeError:
            raise BagError(f"the bag's schema of {msgtype} is not UTF-8 text") from None
        store = _schema_store(msgtype, schema.encoding, text)
    else:
        store = _jazzy_store()
        if msgtype not in store.types:
            raise BagError(f"the bag has no definition of {msgtype} and ROS 2 Jazzy has no such type")
    try:  # rosbags generates the type's deserialiser here: a self-referencing or dangling schema fails in it
        msgdef = store.get_msgdef(msgtype)
    except Exception as exc:  # noqa: BLE001 - RecursionError, KeyError, TypesysError... from bag data
        why = " ".join(str(exc).split())[:240]
        raise BagError(f"the bag's schema of {msgtype} cannot be used: {type(exc).__name__}: {why}") from None

    def decode(data: bytes) -> Any:
        # rosbags' Typestore.deserialize_cdr refuses more than 3 bytes after the content. Bags of bptsb_ros 0.2.0 and
        # older carry up to 8 on their JointState topics (rclpy's serialize_message leaves them, and the nodes'
        # templates were made with it; now they are exact CDR, ros.raw_out), and rclpy's deserializer ignores them:
        # this reads the CDR body directly, for those bags.
        if len(data) < 4 or data[:2] not in (b"\x00\x00", b"\x00\x01"):
            raise BagError(f"a {msgtype} message is not CDR (encapsulation {bytes(data[:4]).hex() or 'empty'})")
        func = msgdef.deserialize_cdr_le if data[1] else msgdef.deserialize_cdr_be
        try:
            message, _pos = func(memoryview(data)[4:], 0, msgdef.cls, store)
        except Exception as exc:  # noqa: BLE001 - SerdeError, struct.error, UnicodeDecodeError... on bad bytes
            why = " ".join(str(exc).split())[:240]
            raise BagError(f"a {msgtype} message cannot be decoded: {type(exc).__name__}: {why}") from None
        return message

    return decode


def installed_mismatch(schema: Schema) -> str | None:
    """Why the bag's definition of a message type differs from the definition installed here (one line), or None:
    when they agree (compared as parsed: fields, types, bounds and constants, not comments), when the schema has no
    text or another encoding than the installed one, or when the type is not installed."""
    if not schema.data or len(schema.data) > MAX_SCHEMA_BYTES:
        return None
    try:
        msgtype = normalize_type(schema.name)
        installed = message_definition(msgtype)
        text = schema.data.decode("utf-8")
    except (MessageDefinitionError, UnicodeDecodeError, OSError):
        return None
    if installed.encoding != schema.encoding or text == installed.text:
        return None
    return _definition_difference(msgtype, schema.encoding, text, installed.text)


@functools.lru_cache(maxsize=64)
def _definition_difference(msgtype: str, encoding: str, text: str, installed: str) -> str | None:
    ours = _types_from_schema(msgtype, encoding, installed)
    try:
        theirs = _types_from_schema(msgtype, encoding, text)
    except BagError:
        raise
    except Exception:  # noqa: BLE001 - malformed text: the decoder says why it cannot be parsed
        return None
    check_typesdict(theirs, msgtype)
    for name in [msgtype, *sorted((set(ours) | set(theirs)) - {msgtype})]:  # the type itself first
        if ours.get(name) == theirs.get(name):
            continue
        if name not in theirs or name not in ours:
            what = "lacks the type" if name not in theirs else "adds a type"
            detail = f"{what} {name}"
        else:
            want, got = ours[name][1], theirs[name][1]
            names_want, names_got = [f for f, _ in want], [f for f, _ in got]
            if names_want != names_got:
                detail = (f"{name} has the fields {', '.join(names_got[:8])}, the installed one "
                          f"{', '.join(names_want[:8])}")
            else:
                field = next((f for (f, a), (_, b) in zip(want, got) if a != b), None)
                detail = f"{name}.{field} has another type" if field else f"{name} has other constants"
        return (f"the bag's schema of {msgtype} defines it differently from the installed {msgtype}: {detail}; its "
                "messages would decode differently with ROS and without, so they are not read (record the bag "
                "again, or read it where its definition is installed)")
    return None


class MessageDecoder:
    """Decodes the messages of one read: picks rclpy or rosbags per schema (see the module docstring).

    ``decoder``: ``auto`` (rclpy where it knows the type, else rosbags), ``rclpy`` or ``rosbags``.
    """

    def __init__(self, decoder: str = "auto") -> None:
        if decoder not in DECODERS:
            raise BagError(f"unknown message decoder {decoder!r}; choose one of {', '.join(DECODERS)}")
        self.decoder = decoder
        self._by_schema: dict[tuple[int, str, str, bytes], tuple[str, Callable[[bytes], Any]]] = {}

    def used(self, schema: Schema) -> str:
        """Which decoder (``rclpy`` or ``rosbags``) decodes the messages of ``schema``."""
        return self._for(schema)[0]

    def __call__(self, schema: Schema, data: bytes) -> Any:
        return self._for(schema)[1](data)

    def _for(self, schema: Schema) -> tuple[str, Callable[[bytes], Any]]:
        key = (schema.id, schema.name, schema.encoding, schema.data)
        found = self._by_schema.get(key)
        if found is None:
            found = self._by_schema[key] = self._choose(schema)
        return found

    def _choose(self, schema: Schema) -> tuple[str, Callable[[bytes], Any]]:
        problem = installed_mismatch(schema)
        if problem:  # rclpy would decode with the installed definition, rosbags with the bag's: neither is right
            raise BagError(problem)
        if self.decoder in ("auto", "rclpy"):
            deserialize = rclpy_deserializer()
            if deserialize is None and self.decoder == "rclpy":
                raise BagError("the rclpy message decoder needs rclpy, which cannot be imported here; "
                               "decoder='auto' or 'rosbags' reads the bag without ROS")
            if deserialize is not None:
                try:
                    cls = get_message_class(schema.name)
                except MessageDefinitionError:
                    if self.decoder == "rclpy":
                        raise
                else:
                    return "rclpy", functools.partial(_call_rclpy, deserialize, cls)
        return "rosbags", rosbags_decoder(schema)


def _call_rclpy(deserialize: Callable[[bytes, type], Any], cls: type, data: bytes) -> Any:
    return deserialize(data, cls)
