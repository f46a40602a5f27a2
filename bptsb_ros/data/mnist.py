"""MNIST: the four IDX files, checked against their published MD5 sums, and the train/test splits we use.

Files (in one directory, each either gzipped ``NAME.gz`` as the mirrors serve them, or uncompressed ``NAME``)::

    train-images-idx3-ubyte   60,000 × 28 × 28 uint8     train-labels-idx1-ubyte   60,000 uint8
    t10k-images-idx3-ubyte    10,000 × 28 × 28 uint8     t10k-labels-idx1-ubyte    10,000 uint8

Verification: the MD5 of each file's *uncompressed* IDX bytes must equal :data:`RAW_MD5` (so a gzipped and
an uncompressed copy verify alike); a downloaded archive is also checked against :data:`GZ_MD5` before it
is kept. A directory may declare a custom IDX set instead (the tests' tiny planted sets, a subset you made):
an ``MD5SUMS`` file in ``md5sum`` format over the uncompressed names; then those sums are checked and the
set is reported as not the standard MNIST.

Splits (:func:`load_split`):

* ``paper``: train on the 60,000 training images, test on the 10,000 test images (the paper's split);
* ``test-8k-2k``: only the 10,000 test images: train on the first 8,000, test on the last 2,000;
* ``auto`` (default): ``paper`` when the training files are present, else ``test-8k-2k``.

Images are returned as float32 in [0, 1] (pixel / 255), shape (n, 784) row-major, as the paper's brains read
them ("vectorized by simply reshaping them into one dimension"); labels as int64 (n,).
"""

from __future__ import annotations

import gzip
import hashlib
import math
import os
import tempfile
import urllib.error
import urllib.request
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bptsb_ros.files.safe_write import atomic_writer, write_atomic

TRAIN_IMAGES = "train-images-idx3-ubyte"
TRAIN_LABELS = "train-labels-idx1-ubyte"
TEST_IMAGES = "t10k-images-idx3-ubyte"
TEST_LABELS = "t10k-labels-idx1-ubyte"
FILES = (TRAIN_IMAGES, TRAIN_LABELS, TEST_IMAGES, TEST_LABELS)

#: MD5 of the uncompressed IDX files of the standard MNIST distribution
RAW_MD5 = {
    TRAIN_IMAGES: "6bbc9ace898e44ae57da46a324031adb",
    TRAIN_LABELS: "a25bea736e30d166cdddb491f175f624",
    TEST_IMAGES: "2646ac647ad5339dbf082846283269ea",
    TEST_LABELS: "27ae3e4e09519cfbb04c329615203637",
}
#: MD5 of the gzipped files as the mirrors serve them
GZ_MD5 = {
    TRAIN_IMAGES: "f68b3c2dcbeaaa9fbdd348bbdeb94873",
    TRAIN_LABELS: "d53e105ee54ea40749a09fcbcd1e9432",
    TEST_IMAGES: "9fb629c4189551a2d022fa330f9573f3",
    TEST_LABELS: "ec29112dd5afa0611ce80d1b7f02629c",
}
#: mirrors tried in order by :func:`download`
MIRRORS = (
    "https://ossci-datasets.s3.amazonaws.com/mnist/",
    "https://storage.googleapis.com/cvdf-datasets/mnist/",
    "http://yann.lecun.com/exdb/mnist/",
)
SPLITS = ("auto", "paper", "test-8k-2k")
CHECKSUM_FILE = "MD5SUMS"
#: environment variable naming the MNIST directory when no --data is given
ENV_DIR = "BPTSB_MNIST_DIR"

_IDX_DTYPES = {0x08: np.uint8}
#: most dimensions an IDX header may declare (MNIST uses 1 and 3)
MAX_IDX_DIMS = 4
#: most data bytes an IDX header may declare: 512 MiB (the MNIST training images are 47 MB)
MAX_IDX_BYTES = 512 * 2**20


class MnistError(RuntimeError):
    """Missing, corrupt or unverifiable MNIST files; the message names the file and the problem."""


@dataclass(frozen=True)
class Split:
    """Images (n, 784) float32 in [0, 1] and labels (n,) int64 for training and testing.

    ``name`` is the split actually used (``paper`` or ``test-8k-2k``); ``standard`` is False for a custom
    IDX set declared by an ``MD5SUMS`` file; ``description`` is one line to print beside every number.
    """

    name: str
    train_x: np.ndarray
    train_y: np.ndarray
    test_x: np.ndarray
    test_y: np.ndarray
    standard: bool
    description: str


def _idx_header(head: bytes, what: str) -> tuple[int, tuple[int, ...]]:
    """Check the first bytes of an IDX file; returns (header length in bytes, shape).

    Refused before anything is allocated: a bad magic number or element type, 0 or more than
    :data:`MAX_IDX_DIMS` dimensions, a size below 1, or more than :data:`MAX_IDX_BYTES` bytes of data.
    """
    if len(head) < 4 or head[0] != 0 or head[1] != 0:
        raise MnistError(f"{what}: not an IDX file (bad magic number)")
    dtype_code, ndim = head[2], head[3]
    if dtype_code not in _IDX_DTYPES:
        raise MnistError(f"{what}: IDX element type 0x{dtype_code:02x} is not unsigned bytes (0x08)")
    if ndim == 0 or ndim > MAX_IDX_DIMS:
        raise MnistError(f"{what}: IDX header declares {ndim} dimensions (1 to {MAX_IDX_DIMS} allowed)")
    header = 4 + 4 * ndim
    if len(head) < header:
        raise MnistError(f"{what}: truncated IDX header")
    shape = tuple(int(s) for s in np.frombuffer(head, dtype=">i4", count=ndim, offset=4))
    if min(shape) < 1:
        raise MnistError(f"{what}: IDX header declares shape {shape}; every size must be >= 1")
    size = math.prod(shape)  # Python integers: no int64 wrap-around
    if size > MAX_IDX_BYTES:
        raise MnistError(f"{what}: IDX header declares shape {shape} ({size} bytes), more than the maximum of "
                         f"{MAX_IDX_BYTES} bytes")
    return header, shape


def parse_idx(data: bytes, what: str) -> np.ndarray:
    """Decode IDX bytes (magic 0x0000TTDD: type TT, DD dimensions, big-endian int32 sizes) to an array."""
    header, shape = _idx_header(data[:4 + 4 * MAX_IDX_DIMS], what)
    expected = math.prod(shape)
    if len(data) - header != expected:
        raise MnistError(f"{what}: IDX header says {shape} ({expected} bytes) but the file holds "
                         f"{len(data) - header} bytes of data (truncated or corrupt)")
    return np.frombuffer(data, dtype=np.uint8, offset=header).reshape(shape)


def encode_idx(array: np.ndarray) -> bytes:
    """IDX bytes of a uint8 array (the inverse of :func:`parse_idx`; used to write small custom sets)."""
    array = np.ascontiguousarray(array, dtype=np.uint8)
    head = bytes([0, 0, 0x08, array.ndim]) + np.asarray(array.shape, dtype=">i4").tobytes()
    return head + array.tobytes()


def _find(directory: Path, name: str) -> Path | None:
    for candidate in (directory / f"{name}.gz", directory / name):
        if candidate.is_file():
            return candidate
    return None


def _read_bytes(path: Path) -> bytes:
    """The uncompressed bytes of one IDX file, header included, read no further than its header declares.

    The header is checked first (:func:`_idx_header`); an uncompressed file's size must then match it before
    its data are read, and a gzipped one is decompressed to at most the declared size + 1 byte, so neither a
    forged header nor a gzip bomb makes this allocate more than :data:`MAX_IDX_BYTES`.
    """
    what = str(path)
    try:
        with (gzip.open(path, "rb") if path.suffix == ".gz" else path.open("rb")) as handle:
            head = handle.read(4)
            if len(head) == 4:
                head += handle.read(4 * min(head[3], MAX_IDX_DIMS))
            header, shape = _idx_header(head, what)
            expected = math.prod(shape)
            if path.suffix != ".gz":
                held = os.fstat(handle.fileno()).st_size - header
                if held != expected:
                    raise MnistError(f"{what}: IDX header says {shape} ({expected} bytes) but the file holds "
                                     f"{held} bytes of data (truncated or corrupt)")
            data = handle.read(expected + 1)
    except (OSError, EOFError, gzip.BadGzipFile, zlib.error) as err:
        raise MnistError(f"{path}: cannot read ({err})") from None
    if len(data) != expected:
        held = f"more than {expected}" if len(data) > expected else str(len(data))
        raise MnistError(f"{what}: IDX header says {shape} ({expected} bytes) but the file holds {held} "
                         "bytes of data (truncated or corrupt)")
    return head + data


def read_idx(path: str | Path) -> np.ndarray:
    """One IDX file (gzipped when its name ends in ``.gz``) as a uint8 array, unverified (a stream of your own
    images for the live loop); raises MnistError naming the file."""
    path = Path(path)
    if not path.is_file():
        raise MnistError(f"{path}: no such file")
    return parse_idx(_read_bytes(path), str(path))


def _custom_checksums(directory: Path) -> dict[str, str] | None:
    path = directory / CHECKSUM_FILE
    if not path.is_file():
        return None
    sums: dict[str, str] = {}
    for n, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip():
            continue
        parts = line.split()
        if len(parts) != 2 or len(parts[0]) != 32:
            raise MnistError(f"{path}:{n}: expected 'MD5  NAME' (md5sum format), got {line!r}")
        sums[parts[1].lstrip("*").removesuffix(".gz")] = parts[0].lower()
    return sums


def read_pair(directory: str | Path, images: str, labels: str) -> tuple[np.ndarray, np.ndarray, bool]:
    """Read and verify one images/labels pair; returns (uint8 (n, 28, 28), uint8 (n,), standard)."""
    directory = Path(directory)
    custom = _custom_checksums(directory)
    sums = RAW_MD5 if custom is None else custom
    arrays = []
    for name in (images, labels):
        path = _find(directory, name)
        if path is None:
            raise MnistError(f"{directory}: {name}[.gz] is missing")
        data = _read_bytes(path)
        if name not in sums:
            raise MnistError(f"{directory / CHECKSUM_FILE}: no checksum for {name}")
        digest = hashlib.md5(data).hexdigest()  # integrity, not security: the published sums are MD5
        if digest != sums[name]:
            origin = "the standard MNIST" if custom is None else CHECKSUM_FILE
            raise MnistError(f"{path}: MD5 of the uncompressed data is {digest}, {origin} says {sums[name]} "
                             "(a corrupt or different file; delete it and run `bptsb data mnist --dir DIR`)")
        arrays.append(parse_idx(data, str(path)))
    x, y = arrays
    if x.ndim != 3 or x.shape[1:] != (28, 28):
        raise MnistError(f"{directory / images}: expected images of shape (n, 28, 28), got {x.shape}")
    if y.ndim != 1 or y.shape[0] != x.shape[0]:
        raise MnistError(f"{directory}: {images} holds {x.shape[0]} images but {labels} has shape {y.shape}")
    if y.size and int(y.max()) > 9:
        raise MnistError(f"{directory / labels}: labels must be digits 0-9, found {int(y.max())}")
    return x, y, custom is None


def resolve_dir(data: str | Path | None) -> Path:
    """The MNIST directory: ``data`` if given, else ``$BPTSB_MNIST_DIR``; a clear error when neither exists."""
    chosen = data if data is not None else os.environ.get(ENV_DIR)
    if not chosen:
        raise MnistError(f"no MNIST directory: pass --data DIR or set {ENV_DIR} "
                         "(`bptsb data mnist --dir DIR` downloads the files)")
    path = Path(chosen).expanduser()
    if not path.is_dir():
        raise MnistError(f"MNIST directory {path} does not exist (`bptsb data mnist --dir {path}` downloads it)")
    return path


def _as_float(x: np.ndarray) -> np.ndarray:
    return (x.reshape(x.shape[0], -1).astype(np.float32) / 255.0)


def load_split(data: str | Path | None = None, split: str = "auto") -> Split:
    """Load MNIST from ``data`` (or ``$BPTSB_MNIST_DIR``) with the chosen split (see the module doc)."""
    if split not in SPLITS:
        raise MnistError(f"split must be one of {', '.join(SPLITS)}, got {split!r}")
    directory = resolve_dir(data)
    has_train = _find(directory, TRAIN_IMAGES) is not None and _find(directory, TRAIN_LABELS) is not None
    if split == "auto":
        split = "paper" if has_train else "test-8k-2k"
    test_x, test_y, standard = read_pair(directory, TEST_IMAGES, TEST_LABELS)
    if split == "paper":
        if not has_train:
            raise MnistError(f"{directory}: split 'paper' needs {TRAIN_IMAGES} and {TRAIN_LABELS}; "
                             "use --split test-8k-2k with the test set alone")
        train_x, train_y, standard_train = read_pair(directory, TRAIN_IMAGES, TRAIN_LABELS)
        standard = standard and standard_train
        desc = f"train {len(train_y)} (MNIST training set), test {len(test_y)} (MNIST test set)"
        return Split(split, _as_float(train_x), train_y.astype(np.int64), _as_float(test_x),
                     test_y.astype(np.int64), standard, desc + ("" if standard else "; custom IDX set"))
    n = len(test_y)
    cut = round(0.8 * n)
    desc = (f"train on the first {cut} and test on the last {n - cut} images of the MNIST test set "
            f"(split test-8k-2k){'' if standard else '; custom IDX set'}")
    return Split(split, _as_float(test_x[:cut]), test_y[:cut].astype(np.int64), _as_float(test_x[cut:]),
                 test_y[cut:].astype(np.int64), standard, desc)


def _writable_dir(directory: Path) -> None:
    """Create ``directory`` if needed and check a file can be created in it (before anything is fetched)."""
    try:
        directory.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=directory):
            pass
    except OSError as err:
        raise MnistError(f"{directory}: not a writable directory ({err.strerror or err})") from None


def download(directory: str | Path, *, include_train: bool = True, mirrors: tuple[str, ...] = MIRRORS,
             timeout: float = 30.0) -> list[Path]:
    """Download the gzipped files into ``directory`` (kept only when their MD5 matches); verify all.

    Files already present and verified are not fetched again. Raises :class:`MnistError` naming every
    mirror tried when a file cannot be fetched (e.g. offline).
    """
    directory = Path(directory)
    _writable_dir(directory)
    names = FILES if include_train else (TEST_IMAGES, TEST_LABELS)
    written = []
    for name in names:
        existing = _find(directory, name)
        if existing is not None and hashlib.md5(_read_bytes(existing)).hexdigest() == RAW_MD5[name]:
            written.append(existing)
            continue
        errors = []
        for mirror in mirrors:
            url = f"{mirror}{name}.gz"
            try:
                with urllib.request.urlopen(url, timeout=timeout) as response:
                    payload = response.read()
            except (urllib.error.URLError, OSError, TimeoutError) as err:
                errors.append(f"{url}: {getattr(err, 'reason', err)}")
                continue
            digest = hashlib.md5(payload).hexdigest()
            if digest != GZ_MD5[name]:
                errors.append(f"{url}: MD5 {digest}, expected {GZ_MD5[name]}")
                continue
            target = directory / f"{name}.gz"
            try:
                write_atomic(target, payload)
            except OSError as err:
                raise MnistError(f"{target}: cannot write ({err.strerror or err})") from None
            written.append(target)
            break
        else:
            raise MnistError(f"cannot download {name}.gz (offline?); tried:\n  " + "\n  ".join(errors))
    for images, labels in ((TEST_IMAGES, TEST_LABELS), (TRAIN_IMAGES, TRAIN_LABELS)):
        if images in names:
            read_pair(directory, images, labels)
    return written


def write_custom_set(directory: str | Path, test_x: np.ndarray, test_y: np.ndarray,
                     train_x: np.ndarray | None = None, train_y: np.ndarray | None = None,
                     *, gz: bool = True) -> Path:
    """Write a custom IDX set (uint8 images (n, 28, 28), labels (n,)) with its ``MD5SUMS``; returns the dir."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    items = [(TEST_IMAGES, test_x), (TEST_LABELS, test_y)]
    if train_x is not None and train_y is not None:
        items += [(TRAIN_IMAGES, train_x), (TRAIN_LABELS, train_y)]
    lines = []
    for name, array in items:
        data = encode_idx(array)
        if gz:
            with atomic_writer(directory / f"{name}.gz") as raw, gzip.GzipFile(fileobj=raw, mode="wb") as handle:
                handle.write(data)
        else:
            write_atomic(directory / name, data)
        lines.append(f"{hashlib.md5(data).hexdigest()}  {name}")
    write_atomic(directory / CHECKSUM_FILE, "\n".join(lines) + "\n")
    return directory
