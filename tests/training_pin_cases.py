"""Tiny fixed-seed trainings of every training family, and their fingerprints (the training pins).

``CASES``: name → function() returning a :class:`Trained` (the loss curve, every trained tensor — parameters,
buffers and the state the training ends in —, and the numbers it reports). Each runs a few updates on small data
in seconds, through the code path the experiments use (the packaged configs' backends and dtypes).

:func:`fingerprint` turns a :class:`Trained` into plain JSON: the losses and reported numbers as exact floats
(JSON floats written by Python read back to the same bits), every tensor's dtype, shape and SHA-256 of its raw
bytes plus its first values and its sum, so that a difference says what moved. ``tests/training/test_training_pins.py``
compares them with ``tests/data/training_pins.json``; ``scripts/record_training_pins.py`` writes that file from the
code as it is.

The imports of the package's training functions are the only lines here that may change when modules move: what
each case computes must not.
"""

from __future__ import annotations

import copy
import functools
import hashlib
import json
import platform
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

import bptsb_ros as bp

DATA = "tests/data/training_pins.json"


@dataclass
class Trained:
    """losses: the loss curve (one entry per update); tensors: name → every trained parameter and buffer and the
    carried state; numbers: scalars the training reports (evaluation, guard summary as canonical JSON)."""

    losses: list[float]
    tensors: dict[str, torch.Tensor | np.ndarray]
    numbers: dict[str, Any] = field(default_factory=dict)


def _modules(prefix: str, modules: dict[str, torch.nn.Module]) -> dict[str, torch.Tensor]:
    return {f"{prefix}{name}.{key}": t for name, m in modules.items() for key, t in m.state_dict().items()}


def _state(prefix: str, state) -> dict[str, torch.Tensor]:
    if state is None:
        return {}
    return {f"{prefix}{k}": getattr(state, k) for k in ("r", "v", "a", "length")} | {
        f"{prefix}step": torch.tensor(state.step)}


def _guard(summary: dict[str, Any]) -> str:
    return json.dumps(summary, sort_keys=True, default=float)


def _floats(metrics: dict[str, Any]) -> dict[str, float]:
    """The scalar float entries of an evaluation dict (nested dicts flattened with dots)."""
    out: dict[str, float] = {}
    for k, v in metrics.items():
        if isinstance(v, dict):
            out.update({f"{k}.{kk}": vv for kk, vv in _floats(v).items()})
        elif isinstance(v, float | int) and not isinstance(v, bool):
            out[k] = float(v)
    return out


def _from_result(res) -> Trained:
    """A :func:`bptsb_ros.train` result: losses, the agent's modules, the final state, evaluation and guard."""
    numbers = {f"evaluation.{k}": v for k, v in _floats(res.metrics.get("evaluation", {})).items()}
    numbers |= {f"feedback_fit.{k}": v for k, v in _floats(res.metrics.get("feedback_fit", {})).items()}
    numbers["guard"] = _guard(res.metrics["guard"])
    numbers["backend"] = res.metrics["backend"]
    return Trained(list(res.losses), _modules("", res.agent.modules()) | _state("state.", res.state), numbers)


# -- the trainer (bptsb train): Lissajous, locomotion forward and headwind, NARMA and memory -----------------------
def _lissajous_cfg(backend: str, dtype: str = "float32"):
    """3 windows of 25 steps, the feedback layer fitted on 1 s, evaluated over one period."""
    return bp.load_config("lissajous_single", {
        "dtype": dtype, "training.backend": backend, "training.update_steps": 25, "sim_time": 0.75,
        "feedback.fit_time": 1.0, "lissajous.eval_periods": 1})


def lissajous_fused() -> Trained:
    return _from_result(bp.train(_lissajous_cfg("fused"), progress=False))


def lissajous_numba() -> Trained:
    return _from_result(bp.train(_lissajous_cfg("numba"), progress=False))


def lissajous_fused_float64() -> Trained:
    return _from_result(bp.train(_lissajous_cfg("fused", "float64"), progress=False))


def lissajous_run_dir() -> Trained:
    """With a run directory: what ``checkpoint.pt`` holds (modules, the task's carried state, losses, update)."""
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as tmp:
        run = Path(tmp) / "run"
        res = bp.train(_lissajous_cfg("numba"), out=run, progress=False)
        saved = torch.load(run / "checkpoint.pt", weights_only=True)
    out = _from_result(res)
    out.tensors |= {f"checkpoint.{name}.{key}": t for name, sd in saved["modules"].items() for key, t in sd.items()}
    task_state = saved["extra"]["task_state"]
    out.tensors |= {f"checkpoint.task_state.{k}": v for k, v in task_state.items() if isinstance(v, torch.Tensor)}
    out.numbers |= {"checkpoint.update": saved["extra"]["update"],
                    "checkpoint.losses": [float(x) for x in saved["extra"]["losses"]]}
    return out


def _locomotion(name: str, extra: dict[str, Any]):
    return bp.load_config(name, {"training.update_steps": 40, "locomotion.speed_block": 20, "sim_time": 1.2,
                                 "locomotion.eval_time": 0.4, **extra})


def locomotion_forward() -> Trained:
    """Two warm-up windows, three updates, the feedback layer fitted on 1 s."""
    cfg = _locomotion("locomotion_forward", {"locomotion.warmup_windows": 2, "feedback.fit_time": 1.0})
    return _from_result(bp.train(cfg, progress=False))


def locomotion_headwind() -> Trained:
    """The periodic headwind (calm 0.15 s, blowing 0.15 s) against a constant target speed."""
    cfg = _locomotion("locomotion_headwind", {"locomotion.wind_period": 0.3, "locomotion.target_speed": 0.5})
    return _from_result(bp.train(cfg, progress=False))


#: tiny held-window episodes: 14 inputs of 5 steps, washout 3, training samples up to 10
_NARMA = {"narma.n_inputs": 14, "narma.tau": 5, "narma.washout": 3, "narma.train_end": 10,
          "narma.brain_input": "symmetric", "narma.eval_seed": 99}


def _narma_cfg(name: str, seed: int, extra: dict[str, Any]):
    """8 epochs; a low spike factor so that the guard rejects updates (and, with Adam, divides rates)."""
    return bp.load_config(name, {"epochs": 8, "body.nodes": 13, **_NARMA, **extra}, seed=seed)


#: the NARMA-family trainings of the population and gang cases: (packaged config, seed, overrides)
_LIL_MEMBERS = (
    ("narma", 0, {"brain.type": "lil", "narma.target": "memory", "narma.delay": 2, "training.reject_factor": 1.2}),
    ("narma", 1, {"brain.type": "lil", "narma.target": "expanded", "training.reject_factor": 1.2}),
    ("narma", 2, {"brain.type": "lil", "narma.target": "memory", "narma.delay": 4, "training.reject_factor": 1.2}),
)


def narma_mlp() -> Trained:
    """The packaged NARMA config's MLP brain, its fused held-window path."""
    cfg = _narma_cfg("narma", 0, {"narma.target": "expanded", "training.reject_factor": 1.2})
    return _from_result(bp.train(cfg, progress=False))


def memory_lil() -> Trained:
    name, seed, extra = _LIL_MEMBERS[0]
    return _from_result(bp.train(_narma_cfg(name, seed, extra), progress=False))


def narma_adam() -> Trained:
    cfg = _narma_cfg("narma_adam", 3, {"brain.type": "lil", "narma.target": "memory", "narma.delay": 3,
                                        "training.reject_factor": 1.25, "training.lr.d": 0.3, "training.lr.k": 3})
    return _from_result(bp.train(cfg, progress=False))


def _joined(results: list[Trained]) -> Trained:
    out = Trained([], {}, {})
    for b, r in enumerate(results):
        out.losses += r.losses
        out.tensors |= {f"member{b}.{k}": v for k, v in r.tensors.items()}
        out.numbers |= {f"member{b}.{k}": v for k, v in r.numbers.items()}
    return out


def narma_population() -> Trained:
    """Three LIL members (memory at two delays, NARMA) as one population."""
    from bptsb_ros.workflows.population import train_population

    cfgs = [_narma_cfg(*m) for m in _LIL_MEMBERS]
    results, failures = train_population(cfgs, [None] * len(cfgs), progress=False)
    assert failures == [], failures
    return _joined([_from_result(r) for r in results])


def narma_gang() -> Trained:
    """The same three trainings and the MLP one, each in a thread of one gang (their windows run as lanes)."""
    from bptsb_ros.jobs.gang import Gang

    cfgs = [_narma_cfg(*m) for m in _LIL_MEMBERS]
    cfgs.append(_narma_cfg("narma", 0, {"narma.target": "expanded", "training.reject_factor": 1.2}))
    out = Gang().run([functools.partial(bp.train, cfg, progress=False) for cfg in cfgs])
    for r in out:
        assert not isinstance(r, BaseException), r
    return _joined([_from_result(r) for r in out])


# -- the additional trainings of the experiments: switching, closed-loop schemes ---------------------------------
@functools.cache
def _preliminary():
    """The preliminary Lissajous training the switching and scheme experiments start from (its agent with the
    feedback layer fitted, and the state on its cycle)."""
    res = bp.train(_lissajous_cfg("fused"), progress=False)
    return res.agent, res.state


def _start():
    agent, state = _preliminary()
    return copy.deepcopy(agent), copy.deepcopy(state.detach())


def _agent_trained(agent, losses, state, guard) -> Trained:
    return Trained(list(losses), _modules("", agent.modules()) | _state("state.", state), {"guard": _guard(guard)})


def _switching(backend: str, lr_decay: bool, reject_factor: float) -> Trained:
    from bptsb_ros.sim.inputs import wind_schedule
    from bptsb_ros.tasks.switching import CURVE_1, CURVE_SWITCH, switch_targets, train_switching

    agent, state = _start()
    schedule = wind_schedule(100, 25, np.random.default_rng(5), hold_periods=(1, 2))
    target = switch_targets(CURVE_1, CURVE_SWITCH, 0.2, agent.brain.omega, 0.05)
    res = train_switching(agent, state, schedule, target, window=25, backend=backend, lr_decay=lr_decay,
                          lr_decay_min_updates=1, reject_factor=reject_factor)
    out = _agent_trained(agent, res.losses, res.state, res.guard)
    out.numbers["lr_k"] = [float(x) for x in res.lr_k]
    out.tensors["schedule"] = np.asarray(schedule)
    return out


def switching_fused() -> Trained:
    """Four windows of 25 steps under a wind schedule, the published ÷10 schedule (both divisions at update 3)."""
    return _switching("fused", True, 0.0)


def switching_numba() -> Trained:
    """The autograd path, with a spike rule that rejects the window where the wind switches the curve."""
    return _switching("numba", False, 1.2)


def _liss_target(t: torch.Tensor) -> torch.Tensor:
    return torch.stack([0.2 * torch.cos(2 * np.pi * t), 0.2 * torch.sin(4 * np.pi * t)], -1)


def scheme1() -> Trained:
    """Closed loop from rest, FL from the seeded N(0, 0.1²) draw, the paper's closed-loop rates (the loss grows:
    a spike rule rejects and restores)."""
    from bptsb_ros.tasks.feedback_schemes import train_scheme1

    agent, _ = _start()
    res = train_scheme1(agent, _liss_target, 4, window=25, seed=4, reject_factor=1.5)
    out = _agent_trained(agent, res.losses, res.state, res.guard)
    out.numbers["diverged"] = res.diverged
    return out


def scheme2() -> Trained:
    from bptsb_ros.tasks.feedback_schemes import train_scheme2

    agent, state = _start()
    res = train_scheme2(agent, state, _liss_target, 3, window=25)
    out = _agent_trained(agent, res.losses, res.state, res.guard)
    out.numbers["diverged"] = res.diverged
    return out


def scheme3() -> Trained:
    from bptsb_ros.tasks.feedback_schemes import train_scheme3

    agent, state = _start()
    res = train_scheme3(agent, state, _liss_target, 3, window=25, fit_windows=2, seed=6)
    out = _agent_trained(agent, res.losses, res.state, res.guard)
    out.numbers["diverged"] = res.diverged
    return out


# -- MNIST: drawing and readout ---------------------------------------------------------------------------------
def _images(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Planted sparse 'images' in [0, 1] (float32, as the MNIST loader gives them) and labels."""
    rng = np.random.default_rng(11)
    x = (rng.uniform(0, 1, (n, 784)) * (rng.uniform(0, 1, (n, 784)) > 0.8)).astype(np.float32)
    return x, np.array([1, 7, 0, 4, 1, 9][:n])


def _drawing(brain: str) -> Trained:
    from bptsb_ros.tasks.drawing import ImageToBody, SystemSpec, train_drawing

    torch.set_num_threads(1)
    x, y = _images(5)
    system = ImageToBody(SystemSpec(brain=brain, shape="multiple_circle", nodes=17, hidden=8), seed=2)
    log = train_drawing(system, x, y, epochs=2, batch=2, seed=3)
    return Trained(list(log.losses), _modules("", {"system": system}),
                   {"epoch_losses": [float(v) for v in log.epoch_losses], "guard": _guard(log.guard)})


def drawing_lil() -> Trained:
    """Five images in batches of 2, 2, 1 over two epochs (six SGD updates at the paper's rates)."""
    return _drawing("lil")


def drawing_mlp() -> Trained:
    return _drawing("mlp")


def _readout(shape: str | None) -> Trained:
    from bptsb_ros.tasks.readout import ReadoutSpec, ReadoutSystem, train_readout

    torch.set_num_threads(1)
    x, y = _images(4)
    model = ReadoutSystem(ReadoutSpec(shape=shape, nodes=9, hidden=8, transient_s=0.3), seed=1)
    log = train_readout(model, x, y, epochs=2, batch=2, seed=0, test=(x, y))
    return Trained(list(log.losses), _modules("", {"model": model}),
                   {"epoch_accuracy": [float(v) for v in log.epoch_accuracy], "guard": _guard(log.guard)})


def readout_body() -> Trained:
    """Four images in batches of 2 over two epochs (four Adam updates), a 0.3 s release."""
    return _readout("double_circle")


def readout_brain_only() -> Trained:
    return _readout(None)


CASES: dict[str, Callable[[], Trained]] = {
    "lissajous-fused": lissajous_fused,
    "lissajous-numba": lissajous_numba,
    "lissajous-fused-float64": lissajous_fused_float64,
    "lissajous-run-dir": lissajous_run_dir,
    "locomotion-forward": locomotion_forward,
    "locomotion-headwind": locomotion_headwind,
    "narma-mlp": narma_mlp,
    "memory-lil": memory_lil,
    "narma-adam": narma_adam,
    "narma-population": narma_population,
    "narma-gang": narma_gang,
    "switching-fused": switching_fused,
    "switching-numba": switching_numba,
    "scheme1": scheme1,
    "scheme2": scheme2,
    "scheme3": scheme3,
    "drawing-lil": drawing_lil,
    "drawing-mlp": drawing_mlp,
    "readout-body": readout_body,
    "readout-brain-only": readout_brain_only,
}


# -- fingerprints -------------------------------------------------------------------------------------------------
def _array(t: torch.Tensor | np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(t.detach().cpu().numpy() if isinstance(t, torch.Tensor) else t)


def tensor_print(t: torch.Tensor | np.ndarray) -> dict[str, Any]:
    """dtype, shape, SHA-256 of the raw little-endian bytes (its first 16 hex digits), the first 3 values and the
    float64 sum (JSON floats: Python writes the shortest text that reads back to the same float, so exact)."""
    a = _array(t)
    a = a.astype(a.dtype.newbyteorder("<"), copy=False)
    flat = a.reshape(-1)
    return {"dtype": str(a.dtype), "shape": list(a.shape), "sha256": hashlib.sha256(a.tobytes()).hexdigest()[:16],
            "head": [float(v) for v in flat[:3]], "sum": float(flat.astype(np.float64).sum())}


def fingerprint(trained: Trained) -> dict[str, Any]:
    """The JSON-able pin of one case: exact floats (the loss curve, the reported numbers) and tensor prints."""
    return {"losses": [float(v) for v in trained.losses],
            "tensors": {k: tensor_print(v) for k, v in sorted(trained.tensors.items())},
            "numbers": dict(sorted(trained.numbers.items()))}


def environment() -> dict[str, str]:
    """What decides the floating-point results besides the code: the numeric libraries and the CPU the compiled
    kernels target. Pins recorded in another environment are compared to a tolerance, not bit for bit."""
    import llvmlite.binding
    import numba

    return {"torch": torch.__version__, "numpy": np.__version__, "numba": numba.__version__,
            "machine": platform.machine(), "cpu": llvmlite.binding.get_host_cpu_name(),
            "cpu_capability": torch.backends.cpu.get_cpu_capability()}


def dumps(pins: dict[str, Any]) -> str:
    """The pins file's text: JSON, one line per tensor and per number, so a diff shows what moved."""
    def line(v: Any) -> str:
        return json.dumps(v, separators=(",", ":"))

    out = ["{", f' "environment": {line(pins["environment"])},', ' "cases": {']
    names = list(pins["cases"])
    for i, name in enumerate(names):
        case = pins["cases"][name]
        out.append(f"  {line(name)}: {{")
        out.append(f'   "losses": {line(case["losses"])},')
        for key in ("tensors", "numbers"):
            items = list(case[key].items())
            out.append(f'   "{key}": {{' + ("" if items else "}" + ("," if key == "tensors" else "")))
            for j, (k, v) in enumerate(items):
                out.append(f"    {line(k)}: {line(v)}" + ("," if j < len(items) - 1 else ""))
            if items:
                out.append("   }" + ("," if key == "tensors" else ""))
        out.append("  }" + ("," if i < len(names) - 1 else ""))
    out += [" }", "}"]
    return "\n".join(out) + "\n"
