"""The five MNIST experiments at smoke scale on a tiny planted IDX set, each checked against an independent
recomputation from what it saved (rows ↔ claims, rows ↔ saved systems)."""

from __future__ import annotations

import json
import math

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


def learned(percent: float, n: int, chance: float = 0.1) -> bool:
    """The claims' premise, by its definition: accuracy above chance by more than 3 binomial standard errors (the
    planted test images hold every digit equally often: chance 1/10)."""
    return percent / 100 > chance + 3 * math.sqrt(chance * (1 - chance) / n) + 1e-9


def every(checks: list[tuple[bool, bool]]) -> bool | None:
    """A claim over (holds, testable) comparisons: False if a testable one fails, else None if one is not
    testable, else True."""
    if any(t and not h for h, t in checks):
        return False
    return None if not all(t for _, t in checks) else True


def verdict(result: dict, start: str) -> bool | None:
    """The verdict of the one claim whose text starts with ``start``."""
    found = [c["holds"] for c in result["claims"] if c["claim"].startswith(start)]
    assert len(found) == 1, (start, [c["claim"] for c in result["claims"]])
    return found[0]


#: the paper's bodies by N_mov (movable masses) → masses, by hand (published-code facts: a multiple circle of 37
#: masses has 17 movable, of 101 masses 65; a double circle of 33 has 17, of 129 has 65)
MASSES = {("multiple_circle", 17): 37, ("multiple_circle", 65): 101, ("double_circle", 17): 33,
          ("double_circle", 65): 129}


def assert_paper_body(system, n_mov: int) -> None:
    """The built body has ``n_mov`` movable masses (counted from its fixed mask) and the brain places the
    2(N_mov − 1) coordinates of the movable masses other than the CMP (paper, "MNIST classification and drawing")."""
    fixed = np.asarray(system.body.topology.fixed, dtype=bool)
    assert int(np.count_nonzero(~fixed)) == n_mov and fixed.size == MASSES[(system.spec.shape, n_mov)]
    out = system.brain_output(torch.zeros(2, 784, dtype=system.body.k.dtype))
    assert out.shape == (2, 2 * (n_mov - 1))


def test_every_mnist_system_has_the_papers_movable_masses():
    """The systems each MNIST experiment trains: N_mov 17 / 65 movable masses, brain outputs 2(N_mov − 1), readout
    states 20·N_mov (supplement, "reading states out")."""
    from bptsb_ros.experiments import mnist_drawing, mnist_readout, mnist_specific100
    from bptsb_ros.tasks.drawing import ImageToBody
    from bptsb_ros.tasks.readout import ReadoutSpec, ReadoutSystem

    drawing = [(n, spec) for _, n, spec in mnist_drawing.systems()]
    drawing += [(n, spec) for _, _, n, spec in mnist_specific100.systems()]
    assert sorted({(spec.shape, n) for n, spec in drawing}) == sorted(MASSES)
    for n, spec in drawing:
        assert_paper_body(ImageToBody(spec), n)
    bodies = [(shape, n, nodes) for shape, n, nodes, *_ in mnist_readout.systems() if shape is not None]
    assert sorted((shape, n) for shape, n, _ in bodies) == sorted(MASSES)
    for shape, n, nodes in bodies:
        model = ReadoutSystem(ReadoutSpec(shape=shape, nodes=nodes))
        assert int(np.count_nonzero(~np.asarray(model.system.body.topology.fixed))) == n
        assert model.n_features == 20 * n and model.readout.in_features == 20 * n


def test_every_mnist_experiment_is_listed(capsys):
    assert main(["reproduce", "--list"]) == 0
    out = capsys.readouterr().out
    for name in ("mnist-drawing", "mnist-pca", "mnist-labelmap", "mnist-specific100", "mnist-readout"):
        assert name in out


def test_missing_data_is_one_clear_error(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("BPTSB_MNIST_DIR", raising=False)
    assert main(["reproduce", "mnist-drawing", "--scale", "smoke", "--out", str(tmp_path / "x")]) == 1
    assert "pass --data DIR or set BPTSB_MNIST_DIR" in capsys.readouterr().err
    assert not (tmp_path / "x" / "result.json").exists()


def _context(scale: str, split: str, data):
    from bptsb_ros.experiments.registry import Context
    from bptsb_ros.experiments.result import ExperimentResult

    return Context(scale, 0, data, ExperimentResult("mnist-x", "", scale, 0), log=lambda _: None, data_dir=data,
                   split=split)


def test_paper_scale_means_the_papers_split(tmp_path, capsys):
    """--scale paper with --split auto trains on the training set and tests on the test set; without the training
    files it is one clear error (not a quiet fall-back to test-8k-2k); an explicit --split is honoured."""
    from bptsb_ros.data.mnist import MnistError
    from bptsb_ros.experiments.mnist_common import load_data

    rng = np.random.default_rng(1)
    digits = lambda n: (rng.integers(0, 256, (n, 28, 28)).astype(np.uint8), (np.arange(n) % 10).astype(np.uint8))  # noqa: E731
    (test_x, test_y), (train_x, train_y) = digits(20), digits(30)
    full = write_custom_set(tmp_path / "full", test_x, test_y, train_x, train_y)
    test_only = write_custom_set(tmp_path / "test_only", test_x, test_y)
    data = load_data(_context("paper", "auto", full), None, None)
    assert (len(data.train_y), len(data.test_y)) == (30, 20)
    np.testing.assert_array_equal(data.train_x, train_x.reshape(30, -1) / np.float32(255))
    with pytest.raises(MnistError, match="train-images-idx3-ubyte"):
        load_data(_context("paper", "auto", test_only), None, None)
    data = load_data(_context("paper", "test-8k-2k", full), None, None)  # asked for: the first 16 / last 4 test images
    assert (len(data.train_y), len(data.test_y)) == (16, 4)
    data = load_data(_context("short", "auto", test_only), None, None)  # below paper scale auto may fall back
    assert (len(data.train_y), len(data.test_y)) == (16, 4)
    out = tmp_path / "run"
    assert main(["reproduce", "mnist-readout", "--scale", "paper", "--data", str(test_only), "--out", str(out),
                 "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert "split 'paper' needs train-images-idx3-ubyte" in err and len(err.strip().splitlines()) == 1
    assert not (out / "result.json").exists()


@pytest.mark.slow
def test_mnist_drawing_smoke(tiny_mnist, tmp_path):
    """Trains in the process pool; the saved systems redraw the test images with the reported errors."""
    from bptsb_ros.tasks.drawing import load_system

    data, images, labels = tiny_mnist
    out = tmp_path / "draw"
    result = reproduce("mnist-drawing", data, out)
    rows = rows_of(result)
    test_x = torch.as_tensor(images[120:150].reshape(30, -1) / 255.0, dtype=torch.float32)
    test_y = labels[120:150]
    targets = load_targets()
    mean, acc = {}, {}
    for brain in ("lil", "mlp"):
        for n_mov in (17, 65):
            masses = MASSES[("multiple_circle", n_mov)]
            system, extra = load_system(out / "systems" / f"{brain}-multiple_circle-{masses}.pt")
            assert extra["scale"] == "smoke" and extra["epochs"] == 1
            assert_paper_body(system, n_mov)
            with torch.no_grad():
                drawing = system.draw(test_x, 160, adjoint=False).double().numpy()
            errs = [np.mean((drawing[i, : len(targets[d])] - targets[d]) ** 2) for i, d in enumerate(test_y)]
            label = f"{brain.upper()} + multiple-circle (N_mov {n_mov})"
            mean[(brain, n_mov)] = rows[(label, "test drawing MSE (mean)")]
            assert mean[(brain, n_mov)] == pytest.approx(np.mean(errs), rel=1e-4)
            nearest = [int(np.argmin([np.mean((drawing[i, : len(t)] - t) ** 2) for t in targets])) == d
                       for i, d in enumerate(test_y)]
            acc[(brain, n_mov)] = rows[(label, "test drawings nearest to their own target")]
            assert acc[(brain, n_mov)] == pytest.approx(100 * np.mean(nearest))
    ok = {k: learned(v, 30) for k, v in acc.items()}
    assert verdict(result, "the MLP brain draws with a smaller error") == every(
        [(mean[("mlp", n)] < mean[("lil", n)], ok[("mlp", n)] and ok[("lil", n)]) for n in (17, 65)])
    assert verdict(result, "more mass points give a smaller error") == every(
        [(mean[(b, 65)] < mean[(b, 17)], ok[(b, 65)] and ok[(b, 17)]) for b in ("lil", "mlp")])


def _silhouettes(points: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Per-point silhouette by its definition: (b − a) / max(a, b), a lone point of its label 0."""
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
    return np.asarray(out)


def _redraw(system, images: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(brain output without the CMP, CMP drawings, errors against every target (n, 10)) of the saved system for
    ``images`` (n, 784) in [0, 1]."""
    x = torch.as_tensor(np.asarray(images).reshape(len(labels), -1), dtype=torch.float32)
    targets = load_targets()
    with torch.no_grad():
        brain = system.displacement(x)[:, system.driven].reshape(len(labels), -1).double().numpy()
        drawing = system.draw(x, max(len(t) for t in targets) - 1, adjoint=False).double().numpy()
    errs = np.array([[np.mean((d[: len(t)] - t) ** 2) for t in targets] for d in drawing])
    return brain, drawing, errs


#: the PCA probe's held-out half of the 30 planted test images (3 of every digit), stratified: 15 images, five
#: digits twice and five once, so always answering one digit scores 2/15
PROBE_N, PROBE_CHANCE = 15, 2 / 15


def test_mnist_pca_smoke(tiny_mnist, tmp_path):
    """Silhouettes recomputed with numpy (SVD for PCA, the silhouette by its definition) from the saved system;
    the claims' verdicts recomputed from them and the rows."""
    from bptsb_ros.tasks.drawing import load_system

    data, images, labels = tiny_mnist
    out = tmp_path / "pca"
    result = reproduce("mnist-pca", data, out)
    rows = rows_of(result)
    system, _ = load_system(out / "systems" / "mlp-multiple_circle-37.pt")
    assert_paper_body(system, 17)
    y = labels[120:150]
    brain, drawing, errs = _redraw(system, images[120:150].reshape(30, -1) / np.float32(255), y)
    name = "MLP + multiple-circle (N_mov 17)"
    acc = rows[(name, "test drawings nearest to their own target")]
    assert acc == pytest.approx(100 * np.mean(errs.argmin(1) == y))
    ok = learned(acc, 30)
    got, per, probe = {}, {}, {}
    for part, feats in (("brain", brain), ("body", drawing.reshape(30, -1))):
        what = "brain output (initial positions)" if part == "brain" else "body output (CMP trajectory)"
        centred = feats - feats.mean(0)
        _, _, vt = np.linalg.svd(centred, full_matrices=False)
        sil = _silhouettes(centred @ vt[:2].T, y)
        got[part], per[part] = sil.mean(), [sil[y == d].mean() for d in range(10)]
        assert rows[(f"{name}: {what}", "silhouette of the labels, 2-D PCA")] == pytest.approx(got[part], abs=2e-3)
        probe[part] = rows[(f"{name}: {what}", "linear-probe accuracy in the 2-D PCA plane (held-out half)")]
        assert probe[part] * PROBE_N / 100 == pytest.approx(round(probe[part] * PROBE_N / 100))
    assert verdict(result, f"{name}: each output classifies") == every(
        [(learned(probe[p], PROBE_N, PROBE_CHANCE), ok) for p in ("brain", "body")])
    assert verdict(result, f"{name}: the body's output separates") == every([(got["body"] > got["brain"], ok)])
    assert verdict(result, f"{name}: especially digits 5, 7 and 8") == every(
        [(per["body"][d] > per["brain"][d], ok) for d in (5, 7, 8)])


def labelmap_verdicts(sizes: dict[str, float], centre_ok: bool) -> list[bool | None]:
    """[joined smaller, largest not joined / smallest joined, others mostly original] from the size rows."""
    if not centre_ok:
        return [None, None, None]
    joined = [v for k, v in sizes.items() if "joined" in k]
    others = [v for k, v in sizes.items() if "joined" not in k]
    top = [k for k, v in sizes.items() if v >= max(sizes.values()) - 1e-9]
    bottom = [k for k, v in sizes.items() if v <= min(sizes.values()) + 1e-9]
    return [bool(np.mean(joined) < np.mean(others) - 1e-9),
            all("joined" not in k for k in top) and all("joined" in k for k in bottom),
            bool(min(others) > 0.5 + 1e-9)]


def best_draw_own_digit(errs: np.ndarray, labels: np.ndarray) -> bool:
    """Each digit's lowest-error image (the label maps' start) draws nearest to its own digit's target."""
    best = [np.flatnonzero(labels == d)[np.argmin(errs[labels == d, d])] for d in range(10)]
    return all(int(errs[i].argmin()) == d for d, i in enumerate(best))


@pytest.mark.slow
def test_mnist_labelmap_smoke(tiny_mnist, tmp_path):
    from bptsb_ros.tasks.drawing import load_system

    data, images, labels = tiny_mnist
    result = reproduce("mnist-labelmap", data, tmp_path / "lm")
    system = load_system(tmp_path / "lm" / "systems" / "mlp-multiple_circle-37.pt")[0]
    assert_paper_body(system, 17)
    sizes = {r["system"]: r["ours"] for r in result["rows"] if r["metric"].startswith("label-map size")}
    # multiple-circle 37: movable masses 20..35 are placed; 32..35 (the innermost ring) hold springs to the CMP
    assert len(sizes) == 16 and all(k.startswith("MLP + multiple-circle (N_mov 17): mass ") for k in sizes)
    joined = {k: v for k, v in sizes.items() if "joined" in k}
    assert sorted(int(k.split("mass ")[1].split()[0]) for k in joined) == [32, 33, 34, 35]
    grid = result["details"]["label_maps"]["grid"]
    assert result["details"]["label_maps"]["half_width_m"] == pytest.approx(0.8)  # ±size/5 for size 4
    for v in sizes.values():  # a size is a share of the 10 maps' grid² cells
        assert v * 10 * grid * grid == pytest.approx(round(v * 10 * grid * grid))
    _, _, errs = _redraw(system, images[120:150].reshape(30, -1) / np.float32(255), labels[120:150])
    starts = best_draw_own_digit(errs, labels[120:150])
    # the maps' intricacy per mass (mean over its 10 maps): shares of the 2G(G − 1) neighbour pairs, region counts
    details = result["details"]["label_maps"]
    joined_mask = np.asarray(details["joined_to_cmp"], bool)
    intricate = []
    for key, unit in (("boundary_per_mass", 10 * 2 * grid * (grid - 1)), ("regions_per_mass", 10)):
        v = np.asarray(details[key])
        assert v.shape == (16,) and np.allclose(v * unit, np.round(v * unit))
        intricate.append(v[joined_mask].mean() > v[~joined_mask].mean() + 1e-9)
    assert verdicts_of(result) == labelmap_verdicts(sizes, starts) + [all(intricate) if starts else None]


def verdicts_of(result: dict) -> list[bool | None]:
    return [c["holds"] for c in result["claims"]]


@pytest.mark.slow
def test_mnist_specific100_smoke(tiny_mnist, tmp_path):
    from bptsb_ros.tasks.drawing import load_system

    data, images, labels = tiny_mnist
    result = reproduce("mnist-specific100", data, tmp_path / "sp")
    assert "20 images (2 per digit" in result["provenance"]["data"]
    for (shape, n_mov), masses in MASSES.items():
        for brain in ("lil", "mlp"):
            assert_paper_body(load_system(tmp_path / "sp" / "systems" / f"{brain}-{shape}-{masses}.pt")[0], n_mov)
    assert len(list((tmp_path / "sp" / "systems").glob("*.pt"))) == 8
    mse = {r["system"]: r["ours"] for r in result["rows"] if r["metric"].startswith("drawing MSE")}
    acc = {r["system"]: r["ours"] for r in result["rows"] if r["metric"].startswith("drawings nearest")}
    ok = {k: learned(v, 20) for k, v in acc.items()}  # 20 images, 2 of every digit: chance 1/10
    bodies = [f"{s} (N_mov {n})" for s in ("double-circle", "multiple-circle") for n in (17, 65)]
    assert sorted(mse) == sorted(acc) == sorted(f"{br} + {b}" for br in ("LIL", "MLP") for b in bodies)
    got = verdicts_of(result)
    assert got[0] is all(v >= 90 for v in acc.values())
    assert got[1] == every([(mse[f"MLP + {b}"] < mse[f"LIL + {b}"], ok[f"MLP + {b}"] and ok[f"LIL + {b}"])
                            for b in bodies])
    pairs = [(f"{br} + {s} (N_mov 65)", f"{br} + {s} (N_mov 17)") for br in ("LIL", "MLP")
             for s in ("double-circle", "multiple-circle")]
    assert got[2] == every([(mse[big] < mse[small], ok[big] and ok[small]) for big, small in pairs])
    name = "MLP + multiple-circle (N_mov 17), specific 100"
    rows = rows_of(result)
    analysed = ok["MLP + multiple-circle (N_mov 17)"]
    probe = rows[(f"{name}: brain output (initial positions)",
                  "linear-probe accuracy in the 2-D PCA plane (held-out half)")]
    # the probe's held-out half of 20 images (2 per digit), stratified: one of every digit, chance 1/10
    assert got[3] == every([(learned(probe, 10), analysed)])
    body_2d = rows[(f"{name}: body output (CMP trajectory)", "silhouette of the labels, 2-D PCA")]
    brain_2d = rows[(f"{name}: brain output (initial positions)", "silhouette of the labels, 2-D PCA")]
    system = load_system(tmp_path / "sp" / "systems" / "mlp-multiple_circle-37.pt")[0]
    from bptsb_ros.data.mnist import load_split
    from bptsb_ros.experiments.mnist_common import specific_images

    split = load_split(data, "test-8k-2k")  # the 20 images: 2 per digit from its training part, seed 0
    x, y = specific_images(split.train_x, split.train_y, 2, 0)
    _, drawing, errs = _redraw(system, x, y)
    centred = drawing.reshape(20, -1) - drawing.reshape(20, -1).mean(0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    sil = _silhouettes(centred @ vt[:2].T, y)
    assert body_2d == pytest.approx(sil.mean(), abs=2e-3)
    assert got[4] == every([(sil[y == d].mean() > 0, analysed) for d in range(10)])
    assert got[5] == every([(body_2d > brain_2d, analysed)])
    sizes = {r["system"]: r["ours"] for r in result["rows"]
             if r["metric"].startswith("label-map size") and r["system"].startswith(f"{name}: ")}
    assert len(sizes) == 16
    chosen = result["details"]["label_maps"]["best_sample_per_digit"]
    assert chosen == [int(np.flatnonzero(y == d)[np.argmin(errs[y == d, d])]) for d in range(10)]
    assert got[6:8] == labelmap_verdicts(sizes, best_draw_own_digit(errs, y))[:2]
    # the brain's outputs per label: RMS radius against the distance to the nearest other label's mean, by hand
    brain = _redraw(system, x, y)[0]
    means = np.stack([brain[y == d].mean(0) for d in range(10)])
    radius = np.array([np.sqrt(((brain[y == d] - means[d]) ** 2).sum(1).mean()) for d in range(10)])
    between = np.linalg.norm(means[:, None] - means[None], axis=-1) + np.diag(np.full(10, np.inf))
    median = np.median(radius / between.min(1))
    assert rows[(f"{name}: brain output (initial positions)", "RMS radius of a label's outputs / distance to the "
                 "nearest other label's mean (median over the labels)")] == pytest.approx(median, rel=1e-4)
    assert got[8] == every([(median > 0.1, analysed)])

    # the same system trained on all data (mnist-drawing's smoke settings: 50 images, 1 epoch), trained here
    full_name = "MLP + multiple-circle (N_mov 17), all data"
    full, extra = load_system(tmp_path / "sp" / "systems" / "all-data" / "mlp-multiple_circle-37.pt")
    assert_paper_body(full, 17)
    assert (extra["experiment"], extra["scale"], extra["seed"], extra["epochs"]) == ("mnist-drawing", "smoke", 0, 1)
    assert "trained here" in result["details"]["all_data"]["system"]
    assert "n_train 50; n_test 30" in extra["data"]
    test_x, test_y = images[120:150].reshape(30, -1) / np.float32(255), labels[120:150]
    _, full_drawing, full_errs = _redraw(full, test_x, test_y)
    full_acc = rows[(full_name, "test drawings nearest to their own target")]
    assert full_acc == pytest.approx(100 * np.mean(full_errs.argmin(1) == test_y))
    centred = full_drawing.reshape(30, -1) - full_drawing.reshape(30, -1).mean(0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    full_body = rows[(f"{full_name}: body output (CMP trajectory)", "silhouette of the labels, 2-D PCA")]
    assert full_body == pytest.approx(_silhouettes(centred @ vt[:2].T, test_y).mean(), abs=2e-3)
    full_brain = rows[(f"{full_name}: brain output (initial positions)", "silhouette of the labels, 2-D PCA")]
    assert got[9] == every([(body_2d - brain_2d > full_body - full_brain, analysed and learned(full_acc, 30))])
    intricacy = {(who, what): rows[(who, f"label maps: {what}")] for who in (name, full_name)
                 for what in ("share of adjacent cells with different labels (mean over the maps)",
                              "single-label regions per map (mean)")}
    grid = result["details"]["label_maps"]["grid"]
    for (_, what), v in intricacy.items():  # a mean over 16 masses × 10 maps of shares of 2G(G − 1) pairs / counts
        unit = 16 * 10 * (2 * grid * (grid - 1) if what.startswith("share") else 1)
        assert v * unit == pytest.approx(round(v * unit))
    starts = best_draw_own_digit(errs, y) and best_draw_own_digit(full_errs, test_y)
    assert got[10] == every([(intricacy[(name, w)] > intricacy[(full_name, w)] + 1e-9, starts)
                             for w in {w for _, w in intricacy}])

    # an mnist-drawing run beside a later run holds that system (same scale, seed, data, epochs): reused, not trained
    import shutil

    (tmp_path / "mnist-drawing" / "systems").mkdir(parents=True)
    shutil.copy(tmp_path / "sp" / "systems" / "all-data" / "mlp-multiple_circle-37.pt",
                tmp_path / "mnist-drawing" / "systems")
    again = reproduce("mnist-specific100", data, tmp_path / "sp2")
    assert again["details"]["all_data"]["system"].startswith("reused ")
    assert not (tmp_path / "sp2" / "systems" / "all-data").exists()
    full_rows = [r for r in result["rows"] if r["system"].startswith(full_name)]
    assert full_rows and full_rows == [r for r in again["rows"] if r["system"].startswith(full_name)]


def test_mnist_readout_smoke(tiny_mnist, tmp_path):
    data, _, _ = tiny_mnist
    result = reproduce("mnist-readout", data, tmp_path / "ro")
    acc = {r["system"]: r["ours"] for r in result["rows"]}
    paper = {r["system"]: r["paper"] for r in result["rows"]}
    assert paper == {"only brain": 91.18, "double-circle (N_mov 17)": 95.69, "double-circle (N_mov 65)": 96.77,
                     "multiple-circle (N_mov 17)": 95.36, "multiple-circle (N_mov 65)": 96.22}
    for v in acc.values():  # accuracies on 30 test images: multiples of 1/30
        assert v * 30 / 100 == pytest.approx(round(v * 30 / 100))
    ok = {k: learned(v, 30) for k, v in acc.items()}  # 30 test images, 3 of every digit: chance 1/10
    brain = acc.pop("only brain")
    got = verdicts_of(result)
    assert got[0] is all(v > 95 for v in acc.values())
    assert got[1] == every([(v > brain, ok[k] and ok["only brain"]) for k, v in acc.items()])
    assert got[2] == every([(acc[f"{s} (N_mov 65)"] > acc[f"{s} (N_mov 17)"],
                             ok[f"{s} (N_mov 65)"] and ok[f"{s} (N_mov 17)"]) for s in ("double-circle",
                                                                                      "multiple-circle")])
    assert got[3] == every([(abs(acc[f"double-circle (N_mov {n})"] - acc[f"multiple-circle (N_mov {n})"]) <= 1 + 1e-9,
                             ok[f"double-circle (N_mov {n})"] and ok[f"multiple-circle (N_mov {n})"])
                            for n in (17, 65)])
    from bptsb_ros.body.shapes import build_shape

    systems = result["details"]["systems"]
    for (shape, n_mov), masses in MASSES.items():
        entry = systems[f"{shape.replace('_', '-')} (N_mov {n_mov})"]
        assert entry["n_features"] == 20 * n_mov and entry["nodes"] == masses  # 20·N_mov stored states
        assert int(np.count_nonzero(~build_shape(shape, entry["nodes"]).fixed)) == n_mov


def test_an_interrupted_readout_run_resumes_each_training_from_its_epoch_checkpoint(tiny_mnist, tmp_path, capfd):
    """Every readout training leaves its state after each epoch in RUN_DIR/training; a run that stopped before its
    result (planted: the result removed, the run marked unfinished) continues with --resume from those states,
    trains no epoch again, and comes to the same rows."""
    import torch

    from bptsb_ros.experiments.mnist_readout import systems, training_checkpoint

    data, _, _ = tiny_mnist
    out = tmp_path / "ro"
    args = ["reproduce", "mnist-readout", "--scale", "smoke", "--data", str(data), "--workers", "0", "--out", str(out)]
    assert main(args) == 0
    first = read_result(out / "result.json")
    for *_, name, _ in systems():
        state = torch.load(training_checkpoint(out, name), weights_only=True)
        assert state["epochs_done"] == 1 and state["identity"]["seed"] == 0
        assert state["identity"]["data"] == f"{first['provenance']['data']}; n_train 50; n_test 30"
    (out / "result.json").unlink()
    capfd.readouterr()
    assert main([*args, "--resume"]) == 0
    err = capfd.readouterr().err
    for name in ("only brain", "double-circle (N_mov 17)", "multiple-circle (N_mov 65)"):
        assert f"{name}: continuing after epoch 1/1 from" in err
        assert f"{name}: epoch 1/1 test accuracy" not in err
    again = read_result(out / "result.json")
    assert again["rows"] == first["rows"]
    assert [c["holds"] for c in again["claims"]] == [c["holds"] for c in first["claims"]]


def test_a_run_with_progress_prints_each_trainings_epochs(tiny_mnist, tmp_path, capfd):
    """Without --no-progress every training says which epoch it finished (from inside its job); with it, not."""
    data, _, _ = tiny_mnist
    args = ["reproduce", "mnist-readout", "--scale", "smoke", "--data", str(data), "--workers", "0"]
    assert main([*args, "--out", str(tmp_path / "quiet"), "--no-progress"]) == 0
    assert "epoch 1/1" not in capfd.readouterr().err
    assert main([*args, "--out", str(tmp_path / "shown")]) == 0
    err = capfd.readouterr().err
    for name in ("only brain", "double-circle (N_mov 17)", "multiple-circle (N_mov 65)"):
        assert f"{name}: epoch 1/1 test accuracy" in err


def test_epoch_lines_are_thinned_but_the_last_and_every_other_line_pass(monkeypatch, capsys):
    from bptsb_ros.experiments import mnist_common

    clock = iter([0.0, 10.0, 31.0, 40.0, 41.0, 100.0])
    monkeypatch.setattr(mnist_common.time, "monotonic", lambda: next(clock))
    log = mnist_common.EpochLines(every_s=30.0)
    for line in ("a: epoch 1/5 x", "a: epoch 2/5 x", "rejected update 7", "a: epoch 3/5 x", "a: epoch 4/5 x",
                 "a: epoch 5/5 x"):
        log(line)
    # t = 0 shown (first), 10 s dropped, 31 s shown, 40 s dropped, the last epoch shown
    assert capsys.readouterr().err.splitlines() == ["a: epoch 1/5 x", "rejected update 7", "a: epoch 3/5 x",
                                                    "a: epoch 5/5 x"]
    assert mnist_common.job_log(False) is None and isinstance(mnist_common.job_log(True), mnist_common.EpochLines)
    named = mnist_common.EpochLines(rename=("mlp-multiple_circle-37", "MLP + multiple-circle (N_mov 17)"))
    named("mlp-multiple_circle-37: epoch 1/1 train MSE 2 m²")
    named("guard: mlp-multiple_circle-37")
    assert capsys.readouterr().err.splitlines() == ["MLP + multiple-circle (N_mov 17): epoch 1/1 train MSE 2 m²",
                                                    "guard: mlp-multiple_circle-37"]


def test_jobs_with_costs_are_handed_out_costliest_first_and_come_back_in_job_order():
    from bptsb_ros.experiments import mnist_common

    class Ctx:
        progress = False

        def run_jobs(self, fn, jobs, *, names, what):
            self.names = list(names)
            return [fn(*job) for job in jobs]

    ctx = Ctx()
    jobs = [{"x": 1}, {"x": 2}, {"x": 3}, {"x": 4}]
    out = mnist_common.run_jobs(ctx, lambda x, progress: 10 * x, jobs, costs=[5, 129, 0, 37])
    assert out == [10, 20, 30, 40]
    assert ctx.names == ["training 1", "training 3", "training 0", "training 2"]
    assert mnist_common.run_jobs(ctx, lambda x, progress: x, jobs) == [1, 2, 3, 4]
    assert ctx.names == [f"training {i}" for i in range(4)]


def test_a_readout_job_runs_the_guard_it_is_given():
    from bptsb_ros.experiments.mnist_readout import train_readout_job

    rng = np.random.default_rng(0)
    x, y = rng.random((20, 784), dtype=np.float32), rng.integers(0, 10, 20)
    for factor, window in ((10.0, 5), (0.0, 7)):
        res = train_readout_job(None, 0, 0, x, y, x[:10], y[:10], epochs=1, guard_factor=factor, guard_window=window)
        assert (res["guard"]["factor"], res["guard"]["window"]) == (factor, window)


@pytest.mark.slow
def test_mnist_analyses_share_one_seeds_all_data_system_in_a_multi_seed_layout(tiny_mnist, tmp_path):
    """mnist-pca of seed 1 trains the all-data system (no mnist-drawing run beside it); mnist-labelmap and
    mnist-specific100 of seed 1 reuse it, and seed 0 of mnist-labelmap (another seed) does not."""
    from bptsb_ros.experiments.seeds import run_seeds

    data, _, _ = tiny_mnist
    quiet = {"workers": 0, "data_dir": data, "split": "test-8k-2k", "log": lambda m: None}
    run_seeds("mnist-pca", [1], out_dir=tmp_path / "mnist-pca", **quiet)
    trained = tmp_path / "mnist-pca" / "seed-1" / "systems" / "mlp-multiple_circle-37.pt"
    assert trained.is_file()
    run_seeds("mnist-labelmap", [0, 1], out_dir=tmp_path / "mnist-labelmap", **quiet)
    seeds = {s: json.loads((tmp_path / "mnist-labelmap" / f"seed-{s}" / "result.json").read_text()) for s in (0, 1)}
    assert seeds[1]["details"]["system"] == f"reused {trained}"
    assert not seeds[0]["details"]["system"].startswith("reused")
    run_seeds("mnist-specific100", [1], out_dir=tmp_path / "mnist-specific100", **quiet)
    one = json.loads((tmp_path / "mnist-specific100" / "seed-1" / "result.json").read_text())
    assert one["details"]["all_data"]["system"].startswith("reused ")
