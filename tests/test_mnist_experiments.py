"""The five MNIST experiments at smoke scale on a tiny planted IDX set, each checked against an independent
recomputation from what it saved (rows ↔ claims, rows ↔ saved systems)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from bptsb_ros.cli import main
from bptsb_ros.data.mnist import write_custom_set
from bptsb_ros.experiments import read_result
from bptsb_ros.tasks.digits import load_targets

N_IMAGES = 150  # split test-8k-2k: 120 for training, the last 30 (3 of every digit) for testing


@pytest.fixture(scope="module")
def tiny_mnist(tmp_path_factory):
    """Planted digits: label d lights rows 2+2d..3+2d of a 28×28 image, plus noise; labels cycle 0..9."""
    rng = np.random.default_rng(0)
    labels = (np.arange(N_IMAGES) % 10).astype(np.uint8)
    images = rng.integers(0, 40, (N_IMAGES, 28, 28)).astype(np.uint8)
    for i, d in enumerate(labels):
        images[i, 2 + 2 * d: 4 + 2 * d, 4:24] = 255
    return write_custom_set(tmp_path_factory.mktemp("mnist"), images, labels), images, labels


def reproduce(name: str, data, out, *extra: str) -> dict:
    assert main(["reproduce", name, "--scale", "smoke", "--data", str(data), "--out", str(out), "--no-progress",
                 *extra]) == 0
    result = read_result(out / "result.json")
    assert all((out / f).is_file() for f in result["figures"]) and result["figures"]
    assert "test-8k-2k" in result["provenance"]["data"] and "custom IDX set" in result["provenance"]["data"]
    return result


def rows_of(result: dict) -> dict[tuple[str, str], float]:
    return {(r["system"], r["metric"]): r["ours"] for r in result["rows"]}


def test_every_mnist_experiment_is_listed(capsys):
    assert main(["reproduce", "--list"]) == 0
    out = capsys.readouterr().out
    for name in ("mnist-drawing", "mnist-pca", "mnist-labelmap", "mnist-specific100", "mnist-readout"):
        assert name in out


def test_missing_data_is_one_clear_error(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("BPTSB_MNIST_DIR", raising=False)
    assert main(["reproduce", "mnist-drawing", "--scale", "smoke", "--out", str(tmp_path / "x")]) == 2
    assert "pass --data DIR or set BPTSB_MNIST_DIR" in capsys.readouterr().err
    assert not (tmp_path / "x" / "result.json").exists()


def test_mnist_drawing_smoke(tiny_mnist, tmp_path):
    """Trains in the process pool; the saved systems redraw the test images with the reported errors."""
    from bptsb_ros.tasks.mnist_drawing import load_system

    data, images, labels = tiny_mnist
    out = tmp_path / "draw"
    result = reproduce("mnist-drawing", data, out)
    rows = rows_of(result)
    test_x = torch.as_tensor(images[120:150].reshape(30, -1) / 255.0, dtype=torch.float32)
    test_y = labels[120:150]
    targets = load_targets()
    mean = {}
    for brain in ("lil", "mlp"):
        for nodes in (17, 65):
            system, extra = load_system(out / "systems" / f"{brain}-multiple_circle-{nodes}.pt")
            assert extra["scale"] == "smoke" and extra["epochs"] == 1
            with torch.no_grad():
                drawing = system.draw(test_x, 160, adjoint=False).double().numpy()
            errs = [np.mean((drawing[i, : len(targets[d])] - targets[d]) ** 2) for i, d in enumerate(test_y)]
            mean[(brain, nodes)] = rows[(f"{brain.upper()} + MC {nodes}", "test drawing MSE (mean)")]
            assert mean[(brain, nodes)] == pytest.approx(np.mean(errs), rel=1e-4)
    claims = {c["claim"]: c["holds"] for c in result["claims"]}
    assert claims["the MLP brain draws with a smaller error than the LIL (both bodies)"] == all(
        mean[("mlp", n)] < mean[("lil", n)] for n in (17, 65))
    assert claims["more mass points give a smaller error (65 < 17, both brains)"] == all(
        mean[(b, 65)] < mean[(b, 17)] for b in ("lil", "mlp"))


def _silhouette(points: np.ndarray, labels: np.ndarray) -> float:
    dist = np.linalg.norm(points[:, None] - points[None], axis=-1)
    out = []
    for i in range(len(points)):
        same = (labels == labels[i]) & (np.arange(len(points)) != i)
        if not same.any():
            out.append(0.0)
            continue
        a = dist[i, same].mean()
        b = min(dist[i, labels == other].mean() for other in np.unique(labels) if other != labels[i])
        out.append((b - a) / max(a, b))
    return float(np.mean(out))


def test_mnist_pca_smoke(tiny_mnist, tmp_path, monkeypatch):
    """Silhouettes recomputed with numpy (SVD for PCA, the silhouette by its definition) from the saved system."""
    from bptsb_ros.tasks.mnist_drawing import load_system

    monkeypatch.setenv("BPTSB_WORKERS", "1")
    data, images, labels = tiny_mnist
    out = tmp_path / "pca"
    result = reproduce("mnist-pca", data, out)
    rows = rows_of(result)
    system, _ = load_system(out / "systems" / "mlp-multiple_circle-17.pt")
    x = torch.as_tensor(images[120:150].reshape(30, -1) / 255.0, dtype=torch.float32)
    y = labels[120:150]
    with torch.no_grad():
        brain = system.displacement(x)[:, system.driven].reshape(30, -1).double().numpy()
        body = system.draw(x, 157, adjoint=False).reshape(30, -1).double().numpy()
    got = {}
    for part, feats in (("brain output (initial positions)", brain), ("body output (CMP trajectory)", body)):
        centred = feats - feats.mean(0)
        _, _, vt = np.linalg.svd(centred, full_matrices=False)
        got[part] = _silhouette(centred @ vt[:2].T, y)
        assert rows[(f"MLP + MC 17: {part}", "silhouette of the labels, 2-D PCA")] == pytest.approx(got[part],
                                                                                                    abs=2e-3)
    body_s, brain_s = got["body output (CMP trajectory)"], got["brain output (initial positions)"]
    assert result["claims"][0]["holds"] == (body_s > brain_s)


def test_mnist_labelmap_smoke(tiny_mnist, tmp_path, monkeypatch):
    monkeypatch.setenv("BPTSB_WORKERS", "1")
    data, _, _ = tiny_mnist
    result = reproduce("mnist-labelmap", data, tmp_path / "lm")
    sizes = {r["system"]: r["ours"] for r in result["rows"] if r["metric"].startswith("label-map size")}
    # multiple-circle 37: movable masses 20..35 are placed; 32..35 (the innermost ring) hold springs to the CMP
    assert len(sizes) == 16
    joined = {k: v for k, v in sizes.items() if "joined" in k}
    assert sorted(int(k.split("mass ")[1].split()[0]) for k in joined) == [32, 33, 34, 35]
    grid = result["details"]["label_maps"]["grid"]
    for v in sizes.values():  # a size is a share of the 10 maps' grid² cells
        assert v * 10 * grid * grid == pytest.approx(round(v * 10 * grid * grid))
    others = [v for k, v in sizes.items() if "joined" not in k]
    assert result["claims"][0]["holds"] == (np.mean(list(joined.values())) < np.mean(others))
    hi = max(sizes, key=sizes.get)
    lo = min(sizes, key=sizes.get)
    assert result["claims"][1]["holds"] == ("joined" not in hi and "joined" in lo)


def test_mnist_specific100_smoke(tiny_mnist, tmp_path, monkeypatch):
    monkeypatch.setenv("BPTSB_WORKERS", "1")
    data, _, _ = tiny_mnist
    result = reproduce("mnist-specific100", data, tmp_path / "sp")
    assert "20 images (2 per digit" in result["provenance"]["data"]
    mse = {r["system"]: r["ours"] for r in result["rows"] if r["metric"].startswith("drawing MSE")}
    claims = {c["claim"]: c["holds"] for c in result["claims"]}
    bodies = ("DC N_mov 17", "DC N_mov 65", "MC N_mov 17", "MC N_mov 65")
    assert claims["the MLP yields less error than the LIL (every body)"] == all(
        mse[f"MLP + {b}"] < mse[f"LIL + {b}"] for b in bodies)
    assert claims["bodies with more mass points perform better (65 < 17, every brain and shape)"] == all(
        mse[f"{br} + {s} N_mov 65"] < mse[f"{br} + {s} N_mov 17"] for br in ("LIL", "MLP") for s in ("DC", "MC"))


def test_mnist_readout_smoke(tiny_mnist, tmp_path, monkeypatch):
    monkeypatch.setenv("BPTSB_WORKERS", "1")
    data, _, _ = tiny_mnist
    result = reproduce("mnist-readout", data, tmp_path / "ro")
    acc = {r["system"]: r["ours"] for r in result["rows"]}
    paper = {r["system"]: r["paper"] for r in result["rows"]}
    assert paper == {"only brain": 91.18, "double-circle N_mov 17": 95.69, "double-circle N_mov 65": 96.77,
                     "multiple-circle 17": 95.36, "multiple-circle 65": 96.22}
    for v in acc.values():  # accuracies on 30 test images: multiples of 1/30
        assert v * 30 / 100 == pytest.approx(round(v * 30 / 100))
    brain = acc.pop("only brain")
    assert result["claims"][0]["holds"] == all(v > brain for v in acc.values())
    assert result["claims"][1]["holds"] == (acc["double-circle N_mov 65"] > acc["double-circle N_mov 17"]
                                           and acc["multiple-circle 65"] > acc["multiple-circle 17"])
    assert result["details"]["systems"]["double-circle N_mov 17"]["n_features"] == 20 * 17
