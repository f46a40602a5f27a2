"""The MNIST benchmark: which systems it times, the paper-schedule arithmetic (planted rates, hand values), and one
real (tiny) measurement."""

from __future__ import annotations

import pytest

from bptsb_ros.bench import mnist_speed as bench_mnist


def planted_rates() -> dict[str, dict[str, float]]:
    """Drawing systems train 1,000 and evaluate 10,000 images/s; readout systems 2,000 and 20,000."""
    return {e["label"]: ({"train_images_per_s": 1000.0, "forward_images_per_s": 10000.0} if e["kind"] == "drawing"
                         else {"train_images_per_s": 2000.0, "forward_images_per_s": 20000.0})
            for e in bench_mnist.systems()}


def test_the_benchmark_times_every_system_of_the_mnist_experiments():
    entries = bench_mnist.systems()
    drawing = {e["label"]: (e["masses"], e["n_movable"]) for e in entries if e["kind"] == "drawing"}
    readout = {e["label"]: (e["masses"], e["n_movable"]) for e in entries if e["kind"] == "readout"}
    masses = {("double-circle", 17): 33, ("double-circle", 65): 129, ("multiple-circle", 17): 37,
              ("multiple-circle", 65): 101}
    assert drawing == {f"{b} + {s} (N_mov {n})": (m, n) for (s, n), m in masses.items() for b in ("LIL", "MLP")}
    assert readout == {"readout: only brain": (0, 0), **{f"readout: {s} (N_mov {n})": (m, n)
                                                         for (s, n), m in masses.items()}}


def test_paper_schedule_estimate_by_hand():
    """Per drawing system 50 epochs × 60,000 / 1,000 + 10,000 / 10,000 = 3,001 s; label maps 16·10·41² / 10,000 =
    26.896 s; specific-100 system 1,000 × 100 / 1,000 + 100 / 10,000 = 100.01 s; readout system 100 × 60,000 /
    2,000 + (100 × 10,000 + 60,000 + 10,000) / 20,000 = 3,053.5 s."""
    est = bench_mnist.paper_estimates(planted_rates(), workers=2)
    h = 3600.0
    assert est["mnist-drawing"] == {"systems": 4, "one_core_h": round(4 * 3001 / h, 3),
                                    "pool_h": round(2 * 3001 / h, 3)}
    assert est["mnist-pca"]["one_core_h"] == round(3001 / h, 3) and est["mnist-pca"]["after_mnist_drawing_h"] == 0
    assert est["mnist-labelmap"]["pool_h"] == round((3001 + 26.896) / h, 3)
    assert est["mnist-labelmap"]["after_mnist_drawing_h"] == round(26.896 / h, 3)
    assert est["mnist-specific100"] == {"systems": 8, "one_core_h": round((8 * 100.01 + 26.896) / h, 3),
                                        "pool_h": round((4 * 100.01 + 26.896) / h, 3)}
    # five equal readout trainings on two workers: three on one of them
    assert est["mnist-readout"] == {"systems": 5, "one_core_h": round(5 * 3053.5 / h, 3),
                                    "pool_h": round(3 * 3053.5 / h, 3)}
    one = bench_mnist.paper_estimates(planted_rates(), workers=1)
    assert one["mnist-readout"]["pool_h"] == one["mnist-readout"]["one_core_h"]


def test_run_reports_every_system_and_the_slowest_against_its_target():
    calls = []

    def fake(entry, **settings):
        calls.append(settings)
        rate = planted_rates()[entry["label"]]
        return {"updates": 2, "ms_per_update": 50e3 / rate["train_images_per_s"], **rate}

    out = bench_mnist.run_mnist_benchmarks(True, progress=lambda _: None, measure=fake)
    assert len(out["systems"]) == 13 and all(c == {"min_seconds": 0.3, "min_updates": 2, "eval_images": 500,
                                                   "repeats": 1} for c in calls)
    assert out["paper_schedule"]["hours"]["mnist-drawing"]["systems"] == 4
    assert bench_mnist.TARGET_TRAIN_IMAGES_PER_S == pytest.approx(50 * 60000 / 3600)
    assert "| readout: multiple-circle (N_mov 65) | 101 / 65 | 2000.0 |" in bench_mnist.mnist_table(out)


@pytest.mark.parametrize("label", ["readout: only brain", "LIL + multiple-circle (N_mov 17)"])
def test_one_real_measurement(label):
    entry = next(e for e in bench_mnist.systems() if e["label"] == label)
    res = bench_mnist.measure_system(entry, min_seconds=0.0, min_updates=2, eval_images=300, repeats=2)
    assert res["updates"] == 2 and res["train_images_per_s"] > 0 and res["forward_images_per_s"] > 0
    assert res["train_images_per_s"] == max(res["train_images_per_s_repeats"])
    assert res["train_images_per_s"] == pytest.approx(50 * 1000 / res["ms_per_update"], rel=0.01)
