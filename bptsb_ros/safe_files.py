"""Opening files named by the user as *regular files only*, and reading them with a size bound.

A FIFO blocks ``open()`` until a writer appears (forever), ``/dev/zero`` or ``/dev/urandom`` never ends, and a
directory or socket is no data at all. :func:`open_regular` refuses anything but a regular file: it checks
``os.stat`` before opening (so no device is ever opened) and the opened descriptor again with ``fstat`` (opened
with ``O_NONBLOCK``, so a file swapped for a FIFO in between cannot block the open either).
"""

from __future__ import annotations

import os
import stat
import tempfile
from pathlib import Path
from typing import BinaryIO

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


def write_text_atomic(path: Path, text: str) -> None:
    """Write ``path`` atomically: a unique temporary file beside it, then a rename (a crash never leaves half a
    file, and the temporary file is removed on any failure)."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
