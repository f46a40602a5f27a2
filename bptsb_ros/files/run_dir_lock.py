"""One bptsb process per output directory: an exclusive, non-blocking ``flock`` on ``DIR/.bptsb.lock``.

``bptsb train``, ``sweep`` and ``reproduce`` hold the lock of their output directory while they work in it, so
a second process pointed at the same directory refuses at once (:class:`RunDirLocked`) instead of mixing its
files with the first one's. The kernel releases an ``flock`` when its holder dies, however it dies, so the lock
file a killed process leaves behind blocks nobody; a holder that ends normally removes it.

The lock is re-entrant per thread (a sweep inside a ``reproduce`` run may lock the same directory again) and is
not inherited by child processes (the descriptor is close-on-exec; sweeps spawn their workers).
"""

from __future__ import annotations

import fcntl
import os
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

LOCK_NAME = ".bptsb.lock"
"""The lock file inside a locked directory (created and removed by this module only)."""

_held: dict[tuple[str, int], int] = {}  # (real path, thread id) -> nesting depth


class RunDirLocked(RuntimeError):
    """Another bptsb process holds the directory; one line for the user."""


def dir_is_empty(path: str | Path) -> bool:
    """True if ``path`` holds nothing but (possibly) a lock file of this module."""
    return all(entry.name == LOCK_NAME for entry in Path(path).iterdir())


def _holder_pid(fd: int) -> str:
    """The pid the holder wrote into the lock file, if it is one (the file is data: at most 20 digits)."""
    try:
        text = os.pread(fd, 32, 0).decode("ascii", "replace").strip()
    except OSError:
        return ""
    return f", pid {text}" if text.isdecimal() and text.isascii() and len(text) <= 20 else ""


def _acquire(directory: Path) -> int:
    """Open and lock ``directory/LOCK_NAME``; returns the descriptor. Raises :class:`RunDirLocked`."""
    path = directory / LOCK_NAME
    for _ in range(10):
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | os.O_NOFOLLOW, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            pid = _holder_pid(fd)
            os.close(fd)
            raise RunDirLocked(f"{directory} is in use: another bptsb process holds it ({path}{pid}); wait for "
                               "that one to finish or choose another directory") from None
        except BaseException:
            os.close(fd)
            raise
        # A holder that finishes unlinks the file while still holding it: the inode we locked must still be
        # the one at ``path``, or a third process may have created and locked a new file there meanwhile.
        try:
            now = os.stat(path, follow_symlinks=False)
        except FileNotFoundError:
            now = None
        mine = os.fstat(fd)
        if now is not None and (now.st_dev, now.st_ino) == (mine.st_dev, mine.st_ino):
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
            return fd
        os.close(fd)
    raise RunDirLocked(f"{directory} is in use: its lock file {path} keeps being replaced by other processes")


@contextmanager
def hold_run_dir(directory: str | Path) -> Iterator[Path]:
    """Hold the exclusive lock of ``directory`` (created, with its parents, if missing) for the ``with`` body.

    Raises:
        RunDirLocked: another process (or another thread) holds it; nothing in the directory was changed.
        OSError: the directory or its lock file cannot be created.
    """
    directory = Path(directory)
    created = not directory.exists()
    directory.mkdir(parents=True, exist_ok=True)
    key = (os.path.realpath(directory), threading.get_ident())
    if key in _held:
        _held[key] += 1
        try:
            yield directory
        finally:
            _held[key] -= 1
        return
    try:
        fd = _acquire(directory)
    except BaseException:
        if created:
            _remove_if_empty(directory)
        raise
    _held[key] = 1
    try:
        yield directory
    finally:
        del _held[key]
        try:
            os.unlink(directory / LOCK_NAME)  # still locked: see _acquire for why that order is safe
        except OSError:
            pass  # the directory itself was removed or made read-only meanwhile
        os.close(fd)
        if created:
            _remove_if_empty(directory)


def _remove_if_empty(directory: Path) -> None:
    """Remove a directory this process created and left empty (a refused or failed start leaves no trace)."""
    try:
        directory.rmdir()
    except OSError:
        pass  # not empty (or gone): keep it
