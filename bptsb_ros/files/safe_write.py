"""Opening files named by the user as *regular files only*, and reading them with a size bound.

A FIFO blocks ``open()`` until a writer appears (forever), ``/dev/zero`` or ``/dev/urandom`` never ends, and a
directory or socket is no data at all. :func:`open_regular` refuses anything but a regular file: it checks
``os.stat`` before opening (so no device is ever opened) and the opened descriptor again with ``fstat`` (opened
with ``O_NONBLOCK``, so a file swapped for a FIFO in between cannot block the open either).

Writing: every file the package writes goes through :func:`atomic_writer` / :func:`write_atomic` (a whole file at
once: a temporary file from ``tempfile`` beside the target, created with ``O_EXCL`` and never through a symbolic
link, then renamed over the target) or :func:`open_for_writing` (a file written as it goes: a log, a bag). Both
refuse a target that exists and is not a regular file — a device (``--out /dev/null`` must not replace the device
node), a FIFO, a directory, a socket or a symbolic link — with :class:`UnsafeFileError` naming it.
"""

from __future__ import annotations

import json
import math
import os
import stat
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any, BinaryIO

_KINDS = ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


class UnsafeFileError(ValueError):
    """A path that is not a regular file, or a file larger than allowed; the message names both."""


def _kind(mode: int) -> str:
    return next((name for test, name in _KINDS if test(mode)), "not a regular file")


def _check(path: Path, mode: int) -> None:
    if not stat.S_ISREG(mode):
        raise UnsafeFileError(f"{path} is {_kind(mode)}, not a regular file")


def open_regular(path: str | Path) -> BinaryIO:
    """``path`` opened for binary reading, refused (:class:`UnsafeFileError`) unless it is a regular file.

    Raises ``OSError`` (``FileNotFoundError`` …) when it cannot be opened at all.
    """
    path = Path(path)
    _check(path, os.stat(path).st_mode)
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    try:
        _check(path, os.fstat(fd).st_mode)
        os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def read_regular(path: str | Path, max_bytes: int) -> bytes:
    """The bytes of the regular file ``path``, at most ``max_bytes`` of them (:class:`UnsafeFileError` naming the
    limit when it is larger, checked before reading and again while reading, for a file that grows)."""
    with open_regular(path) as f:
        size = os.fstat(f.fileno()).st_size
        data = f.read(max_bytes + 1) if size <= max_bytes else b""
        if size > max_bytes or len(data) > max_bytes:
            raise UnsafeFileError(f"{path} holds {max(size, len(data))} bytes, more than the maximum of "
                                  f"{max_bytes} bytes")
    return data


def _read_umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


#: the process's umask, read once at import (reading it means setting it, which is not safe among threads)
_UMASK = _read_umask()


def check_write_target(path: str | Path) -> None:
    """Refuse (:class:`UnsafeFileError`) a ``path`` that exists and is not a regular file: a symbolic link (never
    followed, never replaced), a device, a FIFO, a directory or a socket. A missing path is fine."""
    path = Path(path)
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return
    if stat.S_ISLNK(mode):
        raise UnsafeFileError(f"{path} is a symbolic link; files are written only as regular files, never through "
                              "a link: remove it or choose another path")
    if not stat.S_ISREG(mode):
        raise UnsafeFileError(f"{path} is {_kind(mode)}, not a regular file; choose another path")


@contextmanager
def atomic_writer(path: str | Path, mode: str = "wb") -> Iterator[IO[Any]]:
    """A file object whose content replaces ``path`` atomically when the block ends without an error.

    The content goes to a new temporary file beside ``path`` (``tempfile.mkstemp``: ``O_EXCL``, a random name,
    never a planted symbolic link), which is renamed over ``path`` at the end: a crash or a full disk never leaves
    half a file, and the temporary file is removed on any failure. ``path`` must be absent or a regular file
    (:func:`check_write_target`, checked before and again just before the rename). ``mode``: ``"wb"`` or ``"w"``
    (UTF-8 text). The file gets the usual permissions (0666 less the umask).
    """
    path = Path(path)
    check_write_target(path)
    f, tmp = temp_file_beside(path, mode)
    try:
        with f:
            yield f
        check_write_target(path)
        os.replace(tmp, path)
    except BaseException as err:
        tmp.unlink(missing_ok=True)
        if isinstance(err, OSError) and err.filename is None:  # a full disk: name the file it was writing
            err.filename = str(path)
        raise


def temp_file_beside(path: str | Path, mode: str = "wb", suffix: str = ".tmp") -> tuple[IO[Any], Path]:
    """A new temporary file in ``path``'s folder (``.NAME.<random>SUFFIX``) open for writing, and its path: made
    by ``tempfile.mkstemp`` (``O_EXCL``: never an existing file, never through a symbolic link), with the usual
    permissions (0666 less the umask). The caller renames it into place or removes it."""
    if mode not in ("wb", "w"):
        raise ValueError(f"mode must be 'wb' or 'w', got {mode!r}")
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent)
    try:
        os.fchmod(fd, 0o666 & ~_UMASK)
        f = os.fdopen(fd, mode, **({} if "b" in mode else {"encoding": "utf-8"}))
        (f.raw if "b" in mode else f.buffer.raw).name = tmp  # its path in messages, not the descriptor's number
        return f, Path(tmp)
    except BaseException:
        os.close(fd)
        Path(tmp).unlink(missing_ok=True)
        raise


def write_atomic(path: str | Path, data: str | bytes) -> Path:
    """Write ``data`` (text as UTF-8) to ``path`` with :func:`atomic_writer`; returns ``path``."""
    with atomic_writer(path, "w" if isinstance(data, str) else "wb") as f:
        f.write(data)
    return Path(path)


def write_text_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically (:func:`write_atomic`)."""
    write_atomic(path, text)


def open_for_writing(path: str | Path, mode: str = "wb") -> IO[Any]:
    """``path`` created or truncated for writing as it goes (a log, a bag's data file), only as a regular file.

    Refused (:class:`UnsafeFileError`) when it exists and is not a regular file (:func:`check_write_target`); it is
    opened with ``O_NOFOLLOW`` (a symbolic link planted in between fails the open) and ``O_NONBLOCK`` (a FIFO
    planted in between cannot block it), and checked again once open. ``mode``: ``"wb"`` or ``"w"`` (UTF-8).
    """
    if mode not in ("wb", "w"):
        raise ValueError(f"mode must be 'wb' or 'w', got {mode!r}")
    path = Path(path)
    check_write_target(path)
    flags = os.O_WRONLY | os.O_CREAT | os.O_NONBLOCK | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
    fd = os.open(path, flags, 0o666)
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise UnsafeFileError(f"{path} is {_kind(st.st_mode)}, not a regular file; choose another path")
        os.ftruncate(fd, 0)
        os.set_blocking(fd, True)
        return os.fdopen(fd, mode, **({} if "b" in mode else {"encoding": "utf-8"}))
    except BaseException:
        os.close(fd)
        raise


def json_text(data: Any, **kwargs: Any) -> str:
    """``data`` as strict JSON text (``json.dumps`` with ``kwargs``): a float that is not finite — which JSON has
    no way to write, and which ``json.dumps`` writes as the invalid ``NaN`` — becomes ``null``."""
    return json.dumps(_finite_or_none(data), allow_nan=False, **kwargs)


def _finite_or_none(value: Any) -> Any:
    if getattr(value, "shape", None) == () and hasattr(value, "item"):  # a numpy or torch scalar
        value = value.item()
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite_or_none(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite_or_none(v) for v in value]
    return value
