"""The planted data of the live MNIST tests (``test_mnist_live.py``, and the launch file's episode in
``test_ros_launch_files.py``): a tiny IDX stream of stroke-like images and a small seeded, untrained float64
system."""

from __future__ import annotations

import gzip

import numpy as np

from bptsb_ros.data.mnist import encode_idx
from bptsb_ros.tasks.drawing import ImageToBody, SystemSpec, save_system

LABELS = np.array([3, 1, 7, 0], dtype=np.uint8)


def planted_images(n: int = 4, seed: int = 5) -> np.ndarray:
    """(n, 28, 28) uint8: a bright random stroke-like blob per image on a dark background."""
    rng = np.random.default_rng(seed)
    x = np.zeros((n, 28, 28), dtype=np.uint8)
    for i in range(n):
        r, c = rng.integers(4, 20, size=2)
        x[i, r: r + 8, c: c + 3] = rng.integers(100, 256, size=(8, 3))
    return x


def write_stream(tmp_path) -> tuple[str, str, np.ndarray]:
    """The planted images (gzipped IDX) and labels (plain IDX); returns both paths and the images."""
    x = planted_images()
    images, labels = tmp_path / "images-idx3-ubyte.gz", tmp_path / "labels-idx1-ubyte"
    with gzip.open(images, "wb") as out:
        out.write(encode_idx(x))
    labels.write_bytes(encode_idx(LABELS))
    return str(images), str(labels), x


def write_system(path, seed: int = 4) -> ImageToBody:
    system = ImageToBody(SystemSpec(brain="lil", nodes=17, dtype="float64"), seed)
    save_system(system, path)
    return system
