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
    assert main(["data", "mnist", "--dir", str(tmp_path), "--verify"]) == 2
    assert "md5sum format" in capsys.readouterr().err
