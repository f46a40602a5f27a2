"""Bounded loading of untrusted ``.npz`` files: every array's declared shape is checked before it is read.

``np.load`` trusts the ``.npy`` header inside each zip member: a 15 kB file may declare a 14.6 TiB array, and
a deflated member of zeros (a zip bomb) expands without limit. :func:`load_npz` opens the zip itself, reads
each wanted member's header (``numpy.lib.format``), and refuses, before reading any data, a header that is not
version 1.0/2.0, an object (pickled) dtype, a shape holding more than ``max_bytes`` in all, or a member whose
uncompressed size in the zip directory disagrees with its header; then it reads exactly the declared bytes.
"""

from __future__ import annotations

import math
import os
import stat
import zipfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.lib import format as npy_format

#: default bound on the data of the arrays one call reads: 1 GiB
MAX_NPZ_BYTES = 2**30
#: room for the zip's own headers and directory beyond the array data, bytes
_ZIP_SLACK = 2**20


class NpzError(ValueError):
    """An ``.npz`` that cannot be read safely; one line naming the file, the array and the problem."""


def _read_member(zf: zipfile.ZipFile, info: zipfile.ZipInfo, what: str, budget: int) -> np.ndarray:
    with zf.open(info) as fp:
        try:
            version = npy_format.read_magic(fp)
            if version == (1, 0):
                shape, fortran, dtype = npy_format.read_array_header_1_0(fp)
            elif version == (2, 0):
                shape, fortran, dtype = npy_format.read_array_header_2_0(fp)
            else:
                raise NpzError(f"{what}: .npy format version {version} is not supported (1.0 or 2.0)")
        except ValueError as err:  # numpy's messages for a bad magic string or header
            if isinstance(err, NpzError):
                raise
            raise NpzError(f"{what}: not a .npy array ({str(err)[:120]})") from None
        if dtype.hasobject:
            raise NpzError(f"{what}: dtype {dtype} holds Python objects (pickles are never loaded)")
        nbytes = math.prod(shape) * dtype.itemsize  # Python integers: no wrap-around
        if nbytes > budget:
            raise NpzError(f"{what}: declares shape {shape} of {dtype} ({nbytes} bytes), more than the "
                           f"{budget} bytes allowed")
        header = fp.tell()
        if info.file_size != header + nbytes:
            raise NpzError(f"{what}: declares shape {shape} of {dtype} ({nbytes} bytes) but the zip entry holds "
                           f"{info.file_size - header} bytes (corrupt or forged)")
        data = fp.read(nbytes + 1)
    if len(data) != nbytes:
        raise NpzError(f"{what}: holds {len(data)} bytes of data, its header declares {nbytes}")
    return np.frombuffer(data, dtype=dtype).reshape(shape, order="F" if fortran else "C")


def load_npz(path: str | Path, names: Sequence[str], max_bytes: int | None = None) -> dict[str, np.ndarray]:
    """The arrays ``names`` of the ``.npz`` at ``path`` (read-only views), at most ``max_bytes`` of data in all
    (default :data:`MAX_NPZ_BYTES`).

    Only a regular file is opened (a FIFO or device would block or never end); the file itself may be at most
    ``max_bytes`` + 1 MiB long. Raises :class:`NpzError` naming the file and the problem: not a regular file, not a
    zip, a missing array (the members present are listed, truncated), or any check of the module doc.
    """
    path = Path(path)
    max_bytes = MAX_NPZ_BYTES if max_bytes is None else max_bytes
    try:
        st = os.stat(path)
    except OSError as err:
        raise NpzError(f"{path}: cannot read ({err.strerror or err})") from None
    if not stat.S_ISREG(st.st_mode):
        raise NpzError(f"{path}: not a regular file")
    if st.st_size > max_bytes + _ZIP_SLACK:
        raise NpzError(f"{path}: {st.st_size} bytes, more than the {max_bytes + _ZIP_SLACK} bytes allowed")
    budget = max_bytes
    out: dict[str, np.ndarray] = {}
    try:
        with zipfile.ZipFile(path) as zf:
            members = {info.filename: info for info in zf.infolist()}
            for name in names:
                info = members.get(f"{name}.npy")
                if info is None:
                    present = ", ".join(sorted(n.removesuffix(".npy") for n in members)) or "none"
                    raise NpzError(f"{path} must hold arrays {', '.join(map(repr, names))}; it has "
                                   f"{present[:200]}")
                out[name] = _read_member(zf, info, f"{path}: array {name!r}", budget)
                budget -= out[name].nbytes
    except zipfile.BadZipFile as err:
        raise NpzError(f"{path}: not an .npz (zip) file ({err})") from None
    # NotImplementedError: zipfile's answer to a member compressed with a method it cannot decode (deflate64, say:
    # "compression method not supported"), one more unreadable file
    except (OSError, EOFError, zipfile.LargeZipFile, NotImplementedError) as err:
        raise NpzError(f"{path}: cannot read ({str(err)[:120]})") from None
    except ValueError as err:  # a shape that does not match the data, a bad dtype descriptor
        if isinstance(err, NpzError):
            raise
        raise NpzError(f"{path}: corrupt array ({str(err)[:120]})") from None
    return out
