"""The held-force window (``bptsb_ros/body/held_window.py``, the NARMA and memory tasks' episode under
``training.backend: fused``) against the per-step path: the readout and the gradients of k, d, l and the block
forces (the first also through the start acceleration) equal ``rollout_window`` on the same forces held per step
(float64, 1e-12); central finite differences of a loss of the readout; a NARMA update's loss and every
parameter's gradient equal between the two backends (LIL and MLP brains); whole trainings through the guard give
the same loss curve and parameters; the trainer names the backend; divergence and bad arguments."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from bptsb_ros.agent import build_agent
from bptsb_ros.body.adjoint import rollout_window
from bptsb_ros.body.held_window import held_force_readout, held_window_unsupported
from bptsb_ros.body.msdn import MSDN, SimulationDiverged
from bptsb_ros.body.shapes import double_circle
from bptsb_ros.config import validate
from bptsb_ros.tasks import get_task
from bptsb_ros.workflows.train import train

F64 = torch.float64
TAU, BLOCKS = 5, 7
#: a small NARMA system: double circle of 13 masses, 12 inputs held 5 steps
NARMA = {"task": "narma", "dtype": "float64", "epochs": 3, "body": {"shape": "double_circle", "nodes": 13},
         "brain": {"type": "lil"}, "training": {"optimizer": "sgd", "backend": "fused"},
         "narma": {"tau": 5, "n_inputs": 12, "washout": 2, "train_end": 9, "brain_input": "symmetric"}}


def _body() -> MSDN:
    body = MSDN(double_circle(13), dt=0.01, dtype=F64, backend="numba", generator=torch.Generator().manual_seed(3))
    with torch.no_grad():  # spread the parameters so that every spring's terms differ
        body.k.mul_(torch.linspace(0.5, 1.5, body.k.numel(), dtype=F64))
        body.d.mul_(torch.linspace(1.5, 0.5, body.d.numel(), dtype=F64))
        body.l.mul_(torch.linspace(0.9, 1.1, body.l.numel(), dtype=F64))
    return body


def _forces(body: MSDN, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return (0.5 * torch.randn((BLOCKS, body.n_movable, 2), generator=g, dtype=F64)).requires_grad_(True)


def _per_step_readout(body: MSDN, blocks: torch.Tensor, row: int, coord: int) -> torch.Tensor:
    """The same readout through ``rollout_window``: block j's force repeated over its τ steps by hand."""
    state = body.initial_state(1, external_force=blocks[0])
    per_step = blocks.repeat_interleave(TAU, dim=0)  # (K·τ, M, 2): steps 1..K·τ
    win = rollout_window(body, state, body.l.expand(BLOCKS * TAU, -1), per_step)
    return win.r[TAU - 1:: TAU, 0, row, coord]


def _held_readout(body: MSDN, blocks: torch.Tensor, row: int, coord: int) -> torch.Tensor:
    state = body.initial_state(1, external_force=blocks[0])
    return held_force_readout(body, state, blocks, TAU, row, coord)


def _grads(body: MSDN, blocks: torch.Tensor, out: torch.Tensor, weights: torch.Tensor):
    body.zero_grad()
    blocks.grad = None
    (weights * out).sum().backward()
    return [t.grad.clone() for t in (body.k, body.d, body.l, blocks)]


@pytest.mark.parametrize(("row", "coord"), [(None, 1), (0, 0)])
def test_readout_and_gradients_equal_the_per_step_window(row, coord):
    body = _body()
    row = body.cmp_local if row is None else row
    blocks = _forces(body)
    weights = torch.linspace(-1.0, 2.0, BLOCKS, dtype=F64)
    held = _held_readout(body, blocks, row, coord)
    g_held = _grads(body, blocks, held, weights)
    step = _per_step_readout(body, blocks, row, coord)
    g_step = _grads(body, blocks, step, weights)
    assert held.shape == (BLOCKS,)
    torch.testing.assert_close(held, step.detach(), rtol=1e-12, atol=1e-14)
    for name, a, b in zip(("k", "d", "l", "block forces"), g_held, g_step, strict=True):
        assert float(b.abs().max()) > 0, name  # the loss reads every parameter
        torch.testing.assert_close(a, b, rtol=1e-12, atol=1e-14, msg=name)


def test_gradients_match_central_finite_differences():
    body = _body()
    blocks = _forces(body, seed=1)
    row = body.cmp_local
    weights = torch.linspace(1.0, 2.0, BLOCKS, dtype=F64)

    def loss() -> float:
        with torch.no_grad():
            return float((weights * _held_readout(body, blocks, row, 1)).sum())

    g_k, _, g_l, g_f = _grads(body, blocks, _held_readout(body, blocks, row, 1), weights)
    eps = 1e-6
    for tensor, grad, index in ((body.k, g_k, 3), (body.l, g_l, 5), (blocks, g_f, (0, 2, 1)), (blocks, g_f, (4, 1, 0))):
        with torch.no_grad():
            tensor[index] += eps
            up = loss()
            tensor[index] -= 2 * eps
            down = loss()
            tensor[index] += eps
        fd = (up - down) / (2 * eps)
        assert abs(float(grad[index]) - fd) <= 1e-6 * max(1.0, abs(fd)), (index, float(grad[index]), fd)


def _narma_cfg(brain: str, backend: str, **narma):
    data = {key: (dict(value) if isinstance(value, dict) else value) for key, value in NARMA.items()}
    data["brain"] = {"type": brain, "hidden": 8}
    data["training"] = {**data["training"], "backend": backend}
    data["narma"] = {**data["narma"], **narma}
    return validate(data)


def _update(cfg):
    torch.manual_seed(cfg.seed)
    agent = build_agent(cfg)
    task = get_task("narma")(agent, cfg)
    loss, _ = task.update_loss(0)
    loss.backward()
    params = {f"{m}.{n}": p for m, module in agent.modules().items() for n, p in module.named_parameters()}
    return task, float(loss.detach()), {n: p.grad.clone() for n, p in params.items()}


@pytest.mark.parametrize("brain", ["lil", "mlp"])
@pytest.mark.parametrize("target", ["narma", "memory"])
def test_a_narma_update_equals_the_numba_path(brain, target):
    extra = {"target": "memory", "delay": 2} if target == "memory" else {}
    fused_task, fused_loss, fused_grads = _update(_narma_cfg(brain, "fused", **extra))
    numba_task, numba_loss, numba_grads = _update(_narma_cfg(brain, "numba", **extra))
    assert fused_task.fused_episodes and not numba_task.fused_episodes
    assert fused_loss == pytest.approx(numba_loss, rel=1e-12)
    assert fused_grads.keys() == numba_grads.keys()
    assert {"body.k", "body.d", "body.l"} <= fused_grads.keys() and len(fused_grads) > 3  # the brain's too
    for name, grad in fused_grads.items():
        assert float(numba_grads[name].abs().max()) > 0, name
        torch.testing.assert_close(grad, numba_grads[name], rtol=1e-10, atol=1e-13, msg=name)


def test_trainings_through_the_guard_agree_and_the_trainer_names_the_backend(capsys):
    # rates high enough that the guard rejects updates and divides the rates: both paths must take the same ones
    over = {"epochs": 12, "training": {"optimizer": "sgd", "backend": "fused", "reject_factor": 1.05,
                                       "reject_patience": 2, "lr": {"k": 3e3, "d": 3e2, "l": 3.0, "brain": 3e-2}}}
    results = {}
    for backend in ("fused", "numba"):
        cfg = validate({**NARMA, **over, "training": {**over["training"], "backend": backend}})
        results[backend] = train(cfg, None, progress=False)
    fused, numba = results["fused"], results["numba"]
    assert fused.metrics["backend"] == "fused" and "backend_fallback" not in fused.metrics
    assert numba.metrics["backend"] == "numba"
    assert "numba path instead" not in capsys.readouterr().err
    assert fused.metrics["guard"]["rejections"] == numba.metrics["guard"]["rejections"] > 0
    np.testing.assert_allclose(fused.losses, numba.losses, rtol=1e-9)
    for (name, a), (_, b) in zip(fused.agent.body.named_parameters(), numba.agent.body.named_parameters(),
                                 strict=True):
        torch.testing.assert_close(a, b, rtol=1e-9, atol=1e-12, msg=name)


def test_without_the_adjoint_the_narma_task_trains_on_autograd_and_says_why(capsys):
    cfg = validate({**NARMA, "epochs": 1, "training": {**NARMA["training"], "adjoint": False}})
    res = train(cfg, None, progress=False)
    assert res.metrics["backend"] == "numba"
    assert "adjoint" in res.metrics["backend_fallback"]
    assert "training.backend fused:" in capsys.readouterr().err


def test_a_diverging_window_raises():
    body = _body()
    blocks = torch.full((BLOCKS, body.n_movable, 2), 1e12, dtype=F64)
    with pytest.raises(SimulationDiverged, match="diverged"):
        _held_readout(body, blocks, body.cmp_local, 1)


def test_bad_arguments_are_refused_and_good_ones_pass():
    body = _body()
    m = body.n_movable
    state = body.initial_state(1)
    good = torch.zeros((BLOCKS, m, 2), dtype=F64)
    assert held_force_readout(body, state, good, TAU, 0, 1).shape == (BLOCKS,)
    assert held_window_unsupported(body) is None
    assert "adjoint" in held_window_unsupported(body, adjoint=False)
    for blocks, tau, row, coord, match in (
            (torch.zeros((BLOCKS, m + 1, 2), dtype=F64), TAU, 0, 1, "block_forces"),
            (torch.zeros((0, m, 2), dtype=F64), TAU, 0, 1, "block_forces"),
            (good, 0, 0, 1, "tau"),
            (good, TAU, m, 1, "movable mass"),
            (good, TAU, 0, 2, "coordinate")):
        with pytest.raises(ValueError, match=match):
            held_force_readout(body, state, blocks, tau, row, coord)
    with pytest.raises(ValueError, match="batch"):
        held_force_readout(body, body.initial_state(2), good, TAU, 0, 1)


def test_the_bench_measures_the_narma_task_on_both_paths():
    from bptsb_ros.bench.suite import _measure_narma_task

    fused, numba = (_measure_narma_task(backend, 0.01) for backend in ("fused", "numba"))
    assert fused["fused_episodes"] is True and numba["fused_episodes"] is False
    for row in (fused, numba):
        assert row["train_steps_per_s"] > 0 and row["ms_per_update"] > 0
        # steps/s and ms/update describe the same updates: 3,000 steps per update (150 inputs × τ 20)
        assert row["train_steps_per_s"] * row["ms_per_update"] / 1e3 == pytest.approx(3000, rel=0.02)


def test_the_bench_table_shows_the_narma_task_rows():
    from bptsb_ros.bench.suite import workload_table

    def m(train):
        return {"forward_steps_per_s": 10.0, "train_steps_per_s": train, "peak_rss_mib": 1.0}

    report = {"workloads": {"narma": {"batch": 1, "torch": m(1.0), "numba": m(2.0), "numba_over_torch": 2.0,
                                      "task_numba": {"train_steps_per_s": 3.0, "peak_rss_mib": 2.0},
                                      "task_fused": {"train_steps_per_s": 9.0, "peak_rss_mib": 2.0},
                                      "task_fused_over_numba": 3.0}}}
    rows = workload_table(report).splitlines()
    assert rows[-2:] == ["| narma | 1 | task_numba | – | 3.0 | – |  | 2.0 |",
                         "| narma | 1 | task_fused | – | 9.0 | – | task fused / task numba 3.0 | 2.0 |"]


def test_a_second_backward_through_one_window_says_so():
    body = _body()
    blocks = torch.zeros(3, body.n_movable, 2, dtype=F64, requires_grad=True)
    out = held_force_readout(body, body.initial_state(1), blocks, TAU, 0, 1).sum()
    out.backward(retain_graph=True)
    with pytest.raises(RuntimeError, match="second time"):
        out.backward()
