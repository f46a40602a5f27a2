"""The training pins: a tiny fixed-seed training of every training family gives, bit for bit, the losses and
trained tensors recorded from the code in ``tests/data/training_pins.json``.

The families (``tests/training_pin_cases.py``): the trainer of ``bptsb train`` on Lissajous (fused and numba
backends, float32 and float64, with a run directory: the checkpoint's content), locomotion forward and headwind,
NARMA and the memory task (MLP and LIL brains, SGD and Adam, the update guard rejecting and dividing rates) alone,
as one population and in a gang; Lissajous switching (fused and autograd paths); the closed-loop schemes 1–3; MNIST
drawing (LIL and MLP) and readout (with a body and the brain alone).

These tests hold refactorings to "behaviour unchanged". A change MEANT to change trainings re-records the file
with ``scripts/record_training_pins.py`` and says why in its commit. Where the numeric environment differs from
the one recorded (torch, numpy, numba versions; the CPU the kernels target), bits may differ by rounding: the
tensors' hashes are then not compared, and the losses, reported numbers and the tensors' first values and sums
must agree to a relative 1e-3 (a real change of a training moves them far more).
"""

from __future__ import annotations

import json
import math
from typing import Any

import pytest
import torch
import training_pin_cases as cases
from conftest import REPO_ROOT

PINS = json.loads((REPO_ROOT / cases.DATA).read_text())
#: rounding may differ in another numeric environment: compare to this relative tolerance there
RTOL = 1e-3


@pytest.fixture(autouse=True)
def _keep_torch_threads():
    threads = torch.get_num_threads()
    yield
    torch.set_num_threads(threads)


def _close(a: Any, b: Any) -> bool:
    """``a`` equals ``b`` up to RTOL in every float (recursively through lists, dicts and JSON texts)."""
    if isinstance(a, str) and isinstance(b, str) and a.startswith(("{", "[")):
        return _close(json.loads(a), json.loads(b))
    if isinstance(a, float | int) and isinstance(b, float | int) and not isinstance(a, bool):
        return a == b or math.isclose(a, b, rel_tol=RTOL, abs_tol=1e-12)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_close(x, y) for x, y in zip(a, b))
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_close(a[k], b[k]) for k in a)
    return a == b


def differences(want: dict[str, Any], got: dict[str, Any], *, exact: bool) -> list[str]:
    """One line per thing that moved: the loss curve, a tensor (its print before → after), a reported number."""
    same = (lambda a, b: a == b) if exact else _close
    out = []
    if not same(want["losses"], got["losses"]):
        moved = [(i, a, b) for i, (a, b) in enumerate(zip(want["losses"], got["losses"])) if not same(a, b)]
        first = f"first at update {moved[0][0]}: {moved[0][1]!r} → {moved[0][2]!r}" if moved else ""
        out.append(f"losses: {len(want['losses'])} → {len(got['losses'])} updates; {len(moved)} differ {first}")
    for name in sorted(want["tensors"].keys() | got["tensors"].keys()):
        a, b = want["tensors"].get(name), got["tensors"].get(name)
        if a is None or b is None:
            out.append(f"tensor {name}: {'new' if a is None else 'gone'}")
            continue
        keys = ("dtype", "shape", "sha256", "head", "sum") if exact else ("dtype", "shape", "head", "sum")
        if not all(same(a[k], b[k]) for k in keys):
            out.append(f"tensor {name}: {a['dtype']}{a['shape']} head {a['head']} sum {a['sum']!r} → "
                       f"{b['dtype']}{b['shape']} head {b['head']} sum {b['sum']!r}")
    for name in sorted(want["numbers"].keys() | got["numbers"].keys()):
        a, b = want["numbers"].get(name), got["numbers"].get(name)
        if not same(a, b):
            out.append(f"number {name}: {a!r} → {b!r}")
    return out


def test_every_family_has_its_pin():
    assert list(PINS["cases"]) == list(cases.CASES)


@pytest.mark.parametrize("name", list(cases.CASES))
def test_training_is_bit_identical_to_its_pin(name):
    exact = PINS["environment"] == cases.environment()
    problems = differences(PINS["cases"][name], cases.fingerprint(cases.CASES[name]()), exact=exact)
    where = "" if exact else f" (recorded in {PINS['environment']}, compared to rel. {RTOL})"
    assert not problems, (f"training {name!r} moved{where}:\n  " + "\n  ".join(problems[:12]) +
                          "\nIf the change is meant to change trainings: scripts/record_training_pins.py, and say why "
                          "in the commit.")


# -- the comparison itself ---------------------------------------------------------------------------------------
PLANTED = {"losses": [0.5, 0.25],
           "tensors": {"w": {"dtype": "float32", "shape": [2], "sha256": "00ff", "head": [1.0, 2.0], "sum": 3.0}},
           "numbers": {"guard": '{"events": [{"loss": 0.5, "update": 1}]}', "evaluation.mse": 0.125}}


def _planted(**change: Any) -> dict[str, Any]:
    out = json.loads(json.dumps(PLANTED))
    for path, value in change.items():
        *outer, last = path.split("__")
        node = out
        for key in outer:
            node = node[key]
        node[last] = value
    return out


def test_equal_pins_show_no_difference_exactly_and_to_the_tolerance():
    assert differences(PLANTED, _planted(), exact=True) == []
    assert differences(PLANTED, _planted(), exact=False) == []


@pytest.mark.parametrize(("change", "what"), [
    ({"losses": [0.5, 0.25 + 2 ** -40]}, "losses: 2 → 2 updates; 1 differ first at update 1"),
    ({"tensors__w__sha256": "00fe"}, "tensor w: float32[2]"),
    ({"numbers__evaluation.mse": 0.125 * (1 + 1e-12)}, "number evaluation.mse"),
    ({"numbers__guard": '{"events": [{"loss": 0.5000001, "update": 1}]}'}, "number guard"),
])
def test_one_bit_anywhere_is_a_difference_where_the_environment_is_the_recorded_one(change, what):
    moved = differences(PLANTED, _planted(**change), exact=True)
    assert len(moved) == 1 and moved[0].startswith(what), moved


def test_in_another_environment_rounding_passes_and_a_real_change_does_not():
    rounding = _planted(losses=[0.5 * (1 + 1e-6), 0.25], tensors__w__sha256="00fe", tensors__w__sum=3.0 * (1 - 1e-5),
                        **{"numbers__evaluation.mse": 0.125 * (1 + 1e-5)})
    assert differences(PLANTED, rounding, exact=False) == []
    assert len(differences(PLANTED, rounding, exact=True)) == 3
    moved = _planted(losses=[0.5, 0.26], tensors__w__head=[1.0, 2.01],
                     numbers__guard='{"events": [{"loss": 0.5, "update": 2}]}')
    assert [m.split(":")[0] for m in differences(PLANTED, moved, exact=False)] == ["losses", "tensor w", "number guard"]
    assert differences(PLANTED, _planted(tensors__w__shape=[3]), exact=False)[0].startswith("tensor w")
    extra = _planted()
    extra["tensors"]["v"] = extra["tensors"]["w"]
    assert differences(PLANTED, extra, exact=False) == ["tensor v: new"]
