"""MNIST loader: IDX decoding, MD5 verification, splits, clear errors; never the network."""

from __future__ import annotations

import gzip
import hashlib
import struct

import numpy as np
import pytest

from bptsb_ros.cli import main
from bptsb_ros.data import mnist
from bptsb_ros.data.mnist import MnistError, load_split, parse_idx, write_custom_set


def tiny_set(n: int = 10, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return rng.integers(0, 256, (n, 28, 28), dtype=np.uint8), (np.arange(n) % 10).astype(np.uint8)


def test_idx_bytes_decode_by_hand():
    # magic 0x00000803, dims 2 x 28 x 28 (big-endian), then the pixels
    pixels = np.arange(2 * 28 * 28, dtype=np.uint64).astype(np.uint8)
    raw = struct.pack(">BBBBiii", 0, 0, 8, 3, 2, 28, 28) + pixels.tobytes()
    out = parse_idx(raw, "x")
    assert out.shape == (2, 28, 28) and out[1, 0, 0] == (784 % 256) and out[0, 0, 5] == 5
    labels = parse_idx(struct.pack(">BBBBi", 0, 0, 8, 1, 3) + bytes([7, 0, 9]), "y")
    assert labels.tolist() == [7, 0, 9]


@pytest.mark.parametrize("raw, message", [
    (b"\x01\x00\x08\x01", "bad magic"),
    (struct.pack(">BBBBi", 0, 0, 0x0D, 1, 3) + bytes(12), "not unsigned bytes"),
    (struct.pack(">BBBBi", 0, 0, 8, 1, 5) + bytes(3), "truncated or corrupt"),
    (struct.pack(">BBBB", 0, 0, 8, 3) + bytes(4), "truncated IDX header"),
])
def test_bad_idx_is_named(raw, message):
    with pytest.raises(MnistError, match=message):
        parse_idx(raw, "file.idx")


@pytest.mark.parametrize("gz", [True, False])
def test_custom_set_round_trip_and_split(tmp_path, gz):
    x, y = tiny_set(20)
    write_custom_set(tmp_path, x, y, gz=gz)
    split = load_split(tmp_path)  # no training files: first 80 % / last 20 % of the test set
    assert split.name == "test-8k-2k" and not split.standard
    assert split.train_x.shape == (16, 784) and split.test_x.shape == (4, 784)
    np.testing.assert_array_equal(split.train_x[3], x[3].reshape(-1) / np.float32(255))
    assert split.test_y.tolist() == [6, 7, 8, 9] and split.train_x.dtype == np.float32
    with pytest.raises(MnistError, match="needs train-images"):
        load_split(tmp_path, "paper")


def test_paper_split_when_training_files_exist(tmp_path):
    x, y = tiny_set(10)
    tx, ty = tiny_set(30, seed=1)
    write_custom_set(tmp_path, x, y, tx, ty)
    split = load_split(tmp_path)
    assert split.name == "paper" and split.train_x.shape == (30, 784) and split.test_x.shape == (10, 784)
    assert load_split(tmp_path, "test-8k-2k").train_x.shape == (8, 784)


def test_md5_mismatch_and_missing_files_are_named(tmp_path, monkeypatch):
    x, y = tiny_set(10)
    write_custom_set(tmp_path, x, y)
    (tmp_path / "MD5SUMS").unlink()  # now the standard MNIST sums apply: these files are not MNIST
    with pytest.raises(MnistError, match="t10k-images-idx3-ubyte.gz: MD5 of the uncompressed data is"):
        load_split(tmp_path)
    # a corrupt (truncated) gzip
    write_custom_set(tmp_path, x, y)
    data = (tmp_path / "t10k-labels-idx1-ubyte.gz").read_bytes()
    (tmp_path / "t10k-labels-idx1-ubyte.gz").write_bytes(data[: len(data) // 2])
    with pytest.raises(MnistError, match="t10k-labels-idx1-ubyte.gz: cannot read"):
        load_split(tmp_path)
    (tmp_path / "t10k-labels-idx1-ubyte.gz").unlink()
    with pytest.raises(MnistError, match=r"t10k-labels-idx1-ubyte\[.gz\] is missing"):
        load_split(tmp_path)
    monkeypatch.delenv(mnist.ENV_DIR, raising=False)
    with pytest.raises(MnistError, match="pass --data DIR or set BPTSB_MNIST_DIR"):
        load_split(None)
    with pytest.raises(MnistError, match="does not exist"):
        load_split(tmp_path / "nowhere")


def test_labels_out_of_range_and_count_mismatch(tmp_path):
    x, y = tiny_set(10)
    y[3] = 12
    write_custom_set(tmp_path / "a", x, y)
    with pytest.raises(MnistError, match="digits 0-9, found 12"):
        load_split(tmp_path / "a")
    write_custom_set(tmp_path / "b", x, y[:9] % 10)
    with pytest.raises(MnistError, match="holds 10 images but"):
        load_split(tmp_path / "b")


def test_standard_checksums_verify_uncompressed_content(tmp_path, monkeypatch):
    """A file whose uncompressed bytes have the table's MD5 verifies, gzipped or not (table patched to a
    planted set so the test needs no real MNIST)."""
    x, y = tiny_set(10)
    write_custom_set(tmp_path, x, y, gz=False)
    sums = {line.split()[1]: line.split()[0] for line in (tmp_path / "MD5SUMS").read_text().splitlines()}
    (tmp_path / "MD5SUMS").unlink()
    monkeypatch.setattr(mnist, "RAW_MD5", {**mnist.RAW_MD5, **sums})
    for name in sums:  # gzip one of them: same uncompressed content, same verdict
        if "labels" in name:
            raw = (tmp_path / name).read_bytes()
            (tmp_path / name).unlink()
            with gzip.open(tmp_path / f"{name}.gz", "wb") as handle:
                handle.write(raw)
            assert hashlib.md5(raw).hexdigest() == sums[name]
    split = load_split(tmp_path)
    assert split.standard and split.test_y.tolist() == [8, 9]


def test_download_reports_every_mirror_when_offline(tmp_path):
    with pytest.raises(MnistError, match=r"cannot download t10k-images-idx3-ubyte.gz \(offline\?\)"):
        mnist.download(tmp_path, include_train=False, mirrors=("http://127.0.0.1:9/",), timeout=2)
    assert not list(tmp_path.glob("*.gz"))


def test_download_keeps_only_verified_archives(tmp_path, monkeypatch):
    """A mirror serving the right bytes is kept; a mirror serving other bytes is refused (urlopen planted)."""
    x, y = tiny_set(10)
    src = write_custom_set(tmp_path / "src", x, y)
    payload = {n: (src / f"{n}.gz").read_bytes() for n in (mnist.TEST_IMAGES, mnist.TEST_LABELS)}
    raw = {n: gzip.decompress(p) for n, p in payload.items()}

    class Response:
        def __init__(self, data):
            self.data = data

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def read(self):
            return self.data

    def fake_urlopen(url, timeout):
        name = url.rsplit("/", 1)[1].removesuffix(".gz")
        return Response(b"garbage" if url.startswith("http://bad/") else payload[name])

    monkeypatch.setattr(mnist.urllib.request, "urlopen", fake_urlopen)
    monkeypatch.setattr(mnist, "GZ_MD5", {n: hashlib.md5(p).hexdigest() for n, p in payload.items()})
    monkeypatch.setattr(mnist, "RAW_MD5", {n: hashlib.md5(r).hexdigest() for n, r in raw.items()})
    written = mnist.download(tmp_path / "dst", include_train=False, mirrors=("http://bad/", "http://good/"))
    assert [p.name for p in written] == ["t10k-images-idx3-ubyte.gz", "t10k-labels-idx1-ubyte.gz"]
    with pytest.raises(MnistError, match="http://bad/t10k-images-idx3-ubyte.gz: MD5"):
        mnist.download(tmp_path / "dst2", include_train=False, mirrors=("http://bad/",))


def test_data_cli_verifies(tmp_path, capsys):
    x, y = tiny_set(10)
    write_custom_set(tmp_path, x, y)
    assert main(["data", "mnist", "--dir", str(tmp_path), "--verify"]) == 0
    assert "custom IDX set" in capsys.readouterr().out
    (tmp_path / "MD5SUMS").write_text("not a checksum line\n")
    assert main(["data", "mnist", "--dir", str(tmp_path), "--verify"]) == 1
    assert "md5sum format" in capsys.readouterr().err


def _idx(dims: tuple[int, ...], data: bytes) -> bytes:
    return struct.pack(f">BBBB{len(dims)}i", 0, 0, 8, len(dims), *dims) + data


@pytest.mark.parametrize("dims, data, message", [
    ((-1, -1), bytes(1), r"shape \(-1, -1\); every size must be >= 1"),  # product 1: was a reshape ValueError
    ((0,), b"", r"shape \(0,\); every size must be >= 1"),
    ((65536, 65536, 65536, 65536), b"", "more than the maximum"),  # product 2**64 wrapped to 0 in int64
    ((1, 1, 1, 1, 1), bytes(1), "declares 5 dimensions"),
])
def test_forged_idx_dimensions_are_refused(tmp_path, dims, data, message):
    raw = _idx(dims, data)
    with pytest.raises(MnistError, match=message):
        parse_idx(raw, "x")
    for name, payload in (("x.idx", raw), ("x.idx.gz", gzip.compress(raw))):  # the file readers, too
        (tmp_path / name).write_bytes(payload)
        with pytest.raises(MnistError, match=message):
            mnist.read_idx(tmp_path / name)
    # the accepted edge: one of each size, four dimensions
    assert parse_idx(_idx((1, 1, 1, 1), bytes([7])), "x").tolist() == [[[[7]]]]


def test_idx_size_bound_both_sides(tmp_path, monkeypatch):
    monkeypatch.setattr(mnist, "MAX_IDX_BYTES", 100)
    assert parse_idx(_idx((4, 25), bytes(100)), "x").shape == (4, 25)
    (tmp_path / "ok.gz").write_bytes(gzip.compress(_idx((4, 25), bytes(100))))
    assert mnist.read_idx(tmp_path / "ok.gz").shape == (4, 25)
    with pytest.raises(MnistError, match=r"\(101 bytes\), more than the maximum of 100 bytes"):
        parse_idx(_idx((101,), bytes(101)), "x")


def _peak_bytes(fn) -> int:
    import tracemalloc

    tracemalloc.start()
    try:
        fn()
    finally:
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    return peak


@pytest.mark.parametrize("gz", [True, False])
def test_idx_reads_no_more_than_its_header_declares(tmp_path, gz):
    """A gzip bomb (64 MiB of zeros behind a 10-label header, 64 kB on disk) or a 64 MiB sparse file is
    refused after reading at most the declared size + 1 byte, not the whole file."""
    x, y = tiny_set(10)
    write_custom_set(tmp_path, x, y, gz=gz)
    name = "t10k-labels-idx1-ubyte" + (".gz" if gz else "")
    tail = bytes(64 * 2**20)
    if gz:
        (tmp_path / name).write_bytes(gzip.compress(mnist.encode_idx(y) + tail, compresslevel=1))
        assert (tmp_path / name).stat().st_size < 2**20
    else:
        with open(tmp_path / name, "ab") as handle:
            handle.truncate(len(mnist.encode_idx(y)) + len(tail))
    errors = []

    def load():
        try:
            load_split(tmp_path)
        except MnistError as err:
            errors.append(str(err))

    assert _peak_bytes(load) < 8 * 2**20
    expected = "more than 10 bytes of data" if gz else "holds 67108874 bytes of data"
    assert len(errors) == 1 and expected in errors[0] and name in errors[0]
    # one byte past the declared size is refused too; exactly the declared size verifies (the planted set)
    write_custom_set(tmp_path, x, y, gz=gz)
    raw = mnist.encode_idx(y) + b"\0"
    (tmp_path / name).write_bytes(gzip.compress(raw) if gz else raw)
    with pytest.raises(MnistError, match="more than 10 bytes" if gz else "holds 11 bytes"):
        load_split(tmp_path)
    write_custom_set(tmp_path, x, y, gz=gz)
    assert load_split(tmp_path).test_y.tolist() == [8, 9]


def test_data_cli_unwritable_dir_is_one_line(tmp_path, capsys, monkeypatch):
    def offline(url, timeout):
        raise mnist.urllib.error.URLError("offline (planted)")

    monkeypatch.setattr(mnist.urllib.request, "urlopen", offline)
    (tmp_path / "afile").write_text("x")
    for target in (tmp_path / "afile", tmp_path / "afile" / "sub"):
        assert main(["data", "mnist", "--dir", str(target), "--test-only"]) == 1
        err = capsys.readouterr().err
        assert f"{target}: not a writable directory" in err and len(err.strip().splitlines()) == 1
    assert (tmp_path / "afile").read_text() == "x"
    assert main(["data", "mnist", "--dir", str(tmp_path / "new"), "--test-only"]) == 1  # writable: offline
    assert "offline (planted)" in capsys.readouterr().err and (tmp_path / "new").is_dir()
