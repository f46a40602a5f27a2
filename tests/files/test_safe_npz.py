"""``safe_npz.load_npz`` on a member zipfile cannot decompress: one NpzError line, like any unreadable file."""

from __future__ import annotations

import io
import zipfile

import numpy as np
import pytest

from bptsb_ros.files.npz import NpzError, load_npz

DEFLATE64 = 9  # a compression method of the zip format that Python's zipfile does not implement


def _npz_with_method(path, method: int) -> None:
    """An .npz of one stored array ``x`` whose headers then claim compression ``method`` (local and central)."""
    buf = io.BytesIO()
    np.save(buf, np.arange(4.0))
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as zf:
        zf.writestr("x.npy", buf.getvalue())
    data = bytearray(path.read_bytes())
    for signature, offset in ((b"PK\x03\x04", 8), (b"PK\x01\x02", 10)):
        at = data.find(signature)
        data[at + offset: at + offset + 2] = method.to_bytes(2, "little")
    path.write_bytes(bytes(data))


def test_an_unsupported_compression_method_is_one_clear_line(tmp_path):
    path = tmp_path / "deflate64.npz"
    _npz_with_method(path, DEFLATE64)
    with pytest.raises(NpzError, match=r"deflate64\.npz: cannot read \(.*compression") as err:
        load_npz(path, ["x"])
    assert "\n" not in str(err.value)


def test_the_same_file_stored_plainly_reads(tmp_path):
    path = tmp_path / "stored.npz"
    _npz_with_method(path, zipfile.ZIP_STORED)
    np.testing.assert_array_equal(load_npz(path, ["x"])["x"], np.arange(4.0))
