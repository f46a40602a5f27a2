"""The update guard (bptsb_ros.training.guard): planted tiny trainings whose expected behaviour is known by hand,
and one planted failure per trainer family showing that the trainer goes through the guard."""

from __future__ import annotations

import copy
import json
import math

import numpy as np
import pytest
import torch
from conftest import REPO_ROOT
from torch import nn

from bptsb_ros.training.guard import UpdateGuard

CONFIG = REPO_ROOT / "config"
NAN = float("nan")


# -- a tiny training: two parameter groups, SGD with momentum (so the optimiser has a state) ----------------------
def _tiny():
    a = nn.Parameter(torch.tensor([1.0, -2.0], dtype=torch.float64))
    b = nn.Parameter(torch.tensor([0.5], dtype=torch.float64))
    opt = torch.optim.SGD([{"params": [a], "lr": 0.1, "name": "a"}, {"params": [b], "lr": 0.01, "name": "b"}],
                          lr=0.1, momentum=0.9)
    return [a, b], opt


def _update(guard: UpdateGuard, params, opt, i: int, planted: float | None, *, nan_grad: bool = False):
    """One update: gradients of a real loss, the planted loss value judged, the step if accepted."""
    opt.zero_grad()
    sum((p**2).sum() for p in params).backward()
    if nan_grad:
        params[1].grad[0] = NAN
    decision = guard.review(i, planted, grads_finite=guard.gradients_finite())
    if decision.accepted:
        opt.step()
    return decision


def _copy(params, opt):
    return [p.detach().clone() for p in params], copy.deepcopy(opt.state_dict())


def _same(params, opt, saved) -> bool:
    values, state = saved
    if not all(torch.equal(p.detach(), v) for p, v in zip(params, values)):
        return False
    now = opt.state_dict()["state"]
    return now.keys() == state["state"].keys() and all(
        torch.equal(now[k]["momentum_buffer"], state["state"][k]["momentum_buffer"]) for k in now)


def _rates(opt) -> list[float]:
    return [g["lr"] for g in opt.param_groups]


def test_a_spike_restores_parameters_and_optimiser_state_exactly():
    params, opt = _tiny()
    guard = UpdateGuard(opt)
    assert _update(guard, params, opt, 0, 1.0).accepted
    before = _copy(params, opt)  # θ1 and the momentum before update 1's step
    assert _update(guard, params, opt, 1, 1.0).accepted
    assert not _same(params, opt, before)  # the step changed both
    d = _update(guard, params, opt, 2, 10.5)  # > 10 × 1.0: update 1 made it, so update 1 is undone
    assert not d.accepted and d.reason == "loss spike" and not d.stop
    assert _same(params, opt, before)
    assert guard.count == 1 and guard.history == [1.0, 1.0, 1.0]  # the rejected loss repeats the previous entry
    assert guard.events[0]["update"] == 2 and guard.events[0]["loss"] == 10.5
    assert guard.events[0]["reference"] == 1.0 and guard.events[0]["rates"] == {"a": 0.1, "b": 0.01}


def test_five_rejections_divide_every_rate_by_ten():
    params, opt = _tiny()
    guard = UpdateGuard(opt)
    _update(guard, params, opt, 0, 1.0)
    for i in range(1, 5):
        assert not _update(guard, params, opt, i, 100.0).accepted
    assert _rates(opt) == [0.1, 0.01]  # four: not yet
    d = _update(guard, params, opt, 5, 100.0)
    assert d.divided and _rates(opt) == pytest.approx([0.01, 0.001], rel=1e-15)
    assert guard.count == 0 and guard.events[-1]["divided"] and guard.events[-1]["rates"]["b"] == pytest.approx(1e-3)
    _update(guard, params, opt, 6, 100.0)  # the restore after a division keeps the divided rates
    assert _rates(opt) == pytest.approx([0.01, 0.001], rel=1e-15)


def test_two_good_updates_in_a_row_reset_the_count_and_one_does_not():
    params, opt = _tiny()
    guard = UpdateGuard(opt)
    plan = [1.0] + [100.0] * 4 + [1.0, 1.0] + [100.0] * 4  # 4 rejections, 2 good, 4 rejections
    decisions = [_update(guard, params, opt, i, v) for i, v in enumerate(plan)]
    assert [d.accepted for d in decisions] == [v == 1.0 for v in plan]
    assert not any(d.divided for d in decisions) and _rates(opt) == [0.1, 0.01] and guard.count == 4

    params, opt = _tiny()
    guard = UpdateGuard(opt)
    plan = [1.0] + [100.0] * 4 + [1.0] + [100.0]  # 4 rejections, 1 good, 1 rejection: five without a reset
    decisions = [_update(guard, params, opt, i, v) for i, v in enumerate(plan)]
    assert decisions[-1].divided and _rates(opt) == pytest.approx([0.01, 0.001], rel=1e-15)


@pytest.mark.parametrize("kind", ["nan loss", "inf loss", "nan gradient", "diverged"])
def test_non_finite_loss_gradient_or_divergence_restores(kind):
    params, opt = _tiny()
    guard = UpdateGuard(opt, factor=0.0)  # no spike rule: numerical failures are rejected all the same
    _update(guard, params, opt, 0, 1.0)
    before = _copy(params, opt)
    _update(guard, params, opt, 1, 0.5)
    if kind == "diverged":
        opt.zero_grad()
        d = guard.review(2, None, diverged="simulation diverged at step 7")
    else:
        d = _update(guard, params, opt, 2, {"nan loss": NAN, "inf loss": math.inf}.get(kind, 0.4),
                    nan_grad=kind == "nan gradient")
    reason = {"nan loss": "non-finite loss", "inf loss": "non-finite loss", "nan gradient": "non-finite gradient",
              "diverged": "diverged"}[kind]
    assert not d.accepted and d.reason == reason and not d.stop
    assert _same(params, opt, before) and guard.history == [1.0, 0.5, 0.5]
    assert guard.events[0]["loss"] == (0.4 if kind == "nan gradient" else None)
    # the same failure again, with nothing applied since the restore: nothing to undo, the training stops
    d = _update(guard, params, opt, 3, NAN)
    assert d.stop and d.reason == "non-finite loss" and len(guard.events) == 1


def test_a_failure_of_the_initial_parameters_cannot_be_undone():
    params, opt = _tiny()
    guard = UpdateGuard(opt)
    d = _update(guard, params, opt, 0, NAN)
    assert d.stop and not d.accepted and guard.events == [] and guard.history == []


@pytest.mark.parametrize(("history", "reference"), [([1.0], 1.0), ([1.0, 4.0], 4.0), ([1.0, 2.0, 3.0, 4.0, 5.0], 3.0),
                                                    ([9.0, 1.0, 2.0, 3.0, 4.0, 5.0], 3.0)])
def test_exactly_ten_times_the_reference_is_accepted_just_past_it_rejected(history, reference):
    """The reference: the previous loss while there are fewer than 5, then the mean of the last 5 (hand values)."""
    for loss, accepted in ((10 * reference, True), (math.nextafter(10 * reference, math.inf), False)):
        params, opt = _tiny()
        guard = UpdateGuard(opt)
        for i, v in enumerate(history):
            assert _update(guard, params, opt, i, v).accepted
        assert guard.reference() == reference
        assert _update(guard, params, opt, len(history), loss).accepted is accepted, loss


@pytest.mark.parametrize(("window", "history", "reference"), [(3, [1.0, 2.0], 2.0), (3, [9.0, 1.0, 2.0, 6.0], 3.0),
                                                              (1, [5.0, 1.0], 1.0), (8, [2.0] * 7 + [10.0], 3.0)])
def test_a_guard_of_another_window_means_that_many_last_losses(window, history, reference):
    """The reference: the previous loss while there are fewer than ``window``, then the mean of the last ``window``
    (hand values); the summary names the window."""
    params, opt = _tiny()
    guard = UpdateGuard(opt, window=window)
    for i, v in enumerate(history):
        assert _update(guard, params, opt, i, v).accepted
    assert guard.reference() == reference and guard.summary()["window"] == window
    assert not _update(guard, params, opt, len(history), math.nextafter(10 * reference, math.inf)).accepted


@pytest.mark.parametrize("window", [0, -3])
def test_a_window_below_one_is_refused(window):
    _, opt = _tiny()
    with pytest.raises(ValueError, match="window must be >= 1"):
        UpdateGuard(opt, window=window)
    assert UpdateGuard(opt, window=1).window == 1


def test_resume_state_round_trips_through_a_weights_only_checkpoint(tmp_path):
    params, opt = _tiny()
    guard = UpdateGuard(opt)
    for i, v in enumerate([1.0, 1.0, 50.0, 1.0]):
        _update(guard, params, opt, i, v)
    torch.save({"guard": guard.state_dict()}, tmp_path / "g.pt")
    state = torch.load(tmp_path / "g.pt", weights_only=True)["guard"]
    twin_params, twin_opt = _tiny()
    with torch.no_grad():
        for p, q in zip(twin_params, params):
            p.copy_(q)
    twin_opt.load_state_dict(opt.state_dict())
    twin = UpdateGuard(twin_opt)
    twin.load_state_dict(state)
    # every entry comes back (history, events, counters, stepped, the saved parameters and optimiser state)
    assert _same_state(twin.state_dict(), guard.state_dict()) and guard.good_in_a_row == 1 and guard.stepped
    for g, ps, o in ((guard, params, opt), (twin, twin_params, twin_opt)):
        assert _update(g, ps, o, 4, 100.0).reason == "loss spike"  # both undo update 3 the same way
    assert all(torch.equal(p, q) for p, q in zip(params, twin_params)) and twin.history == guard.history
    assert twin.count == guard.count == 2  # one good update after the first rejection does not reset the count


def _same_state(a: dict, b: dict) -> bool:
    tensors = lambda st: [*st["saved"]["params"], *(v for s in st["saved"]["optimizer"]["state"].values()  # noqa: E731
                                                   for v in s.values())]
    plain = ("history", "events", "count", "good_in_a_row", "stepped")
    return all(a[k] == b[k] for k in plain) and _equal(tensors(a), tensors(b)) and \
        a["saved"]["optimizer"]["param_groups"] == b["saved"]["optimizer"]["param_groups"]


@pytest.mark.parametrize("marked_after", [2, 3, 5])
def test_a_mark_gives_the_state_of_its_moment_after_later_updates(marked_after):
    """A trainer marks the guard every update and saves the marked state later: :meth:`state_at` of a mark is the
    :meth:`state_dict` of the mark's moment, with rejections, a division and accepted updates after it."""
    params, opt = _tiny()
    guard = UpdateGuard(opt)
    losses = [1.0, 1.0, 50.0, 1.0, 60.0, 70.0, 80.0, 90.0, 95.0, 1.0, 1.0]  # 5 spikes in a row: one division
    for i, v in enumerate(losses[:marked_after]):
        _update(guard, params, opt, i, v)
    mark, then = guard.mark(), guard.state_dict()
    for i, v in enumerate(losses[marked_after:], start=marked_after):
        _update(guard, params, opt, i, v)
    assert guard.summary()["divisions"] == 1 and not _same_state(guard.state_dict(), then)
    assert _same_state(guard.state_at(mark), then)


def test_a_mark_from_a_longer_history_is_refused():
    params, opt = _tiny()
    guard = UpdateGuard(opt)
    for i in range(3):
        _update(guard, params, opt, i, 1.0)
    mark = guard.mark()
    guard.load_state_dict({**guard.state_dict(), "history": [1.0]})
    with pytest.raises(ValueError, match="longer history"):
        guard.state_at(mark)


# -- every trainer goes through the guard: one planted failure per trainer family ------------------------------
def _values(tensors) -> list[torch.Tensor]:
    return [t.detach().clone() for t in tensors]


def _equal(a, b) -> bool:
    return all(torch.equal(x, y) for x, y in zip(a, b, strict=True))


def _plant_narma(monkeypatch, seen: list) -> None:
    """NarmaTask.update_loss records the parameters it runs with; update 2's loss is NaN, update 4's ×1000."""
    from bptsb_ros.tasks.narma import NarmaTask

    original = NarmaTask.update_loss

    def planted(self, index):
        seen.append(_values([self.agent.body.k, self.agent.body.l, *self.agent.brain.parameters()]))
        loss, info = original(self, index)
        return loss * {2: NAN, 4: 1000.0}.get(index, 1.0), info

    monkeypatch.setattr(NarmaTask, "update_loss", planted)


SHORT_NARMA = ["narma.n_inputs=40", "narma.washout=10", "narma.train_end=30"]


def test_trainer_undoes_a_planted_nan_and_spike_and_writes_the_events(tmp_path, monkeypatch):
    """NARMA (the main trainer): update 2's loss is NaN, update 4's 1000× its value. Update 2 evaluated θ2, made by
    update 1 from θ1: update 3 must run θ1 again; update 4 evaluated the step of update 3 from θ1: update 5 runs
    θ1 once more. metrics.json lists both events."""
    from bptsb_ros.config import load_config
    from bptsb_ros.workflows.train import train

    seen: list[list[torch.Tensor]] = []
    _plant_narma(monkeypatch, seen)
    res = train(load_config(CONFIG / "narma.yaml", ["epochs=6", *SHORT_NARMA]), tmp_path / "run", progress=False)
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    events = metrics["guard"]["events"]
    assert [(e["update"], e["reason"]) for e in events] == [(2, "non-finite loss"), (4, "loss spike")]
    assert events[1]["loss"] > 10 * events[1]["reference"] and events[0]["loss"] is None
    assert not _equal(seen[2], seen[1]) and _equal(seen[3], seen[1]) and _equal(seen[5], seen[1])
    assert not _equal(seen[4], seen[1])
    assert res.losses[2] == res.losses[1] and res.losses[4] == res.losses[3] and len(metrics["loss"]) == 6
    assert metrics["guard"]["factor"] == 10 and metrics["guard"]["rates"]["k"] == 1000.0


def test_a_resumed_run_continues_the_guard_bit_for_bit(tmp_path, monkeypatch):
    """Stopped after update 3 (accepted: the guard holds θ1, from before its step) and resumed: update 4's spike
    must restore θ1 from the checkpoint; the same losses, events and parameters as one run of 6 epochs."""
    from bptsb_ros.config import load_config
    from bptsb_ros.training.checkpoint import load_agent
    from bptsb_ros.workflows.train import train

    _plant_narma(monkeypatch, [])
    full = train(load_config(CONFIG / "narma.yaml", ["epochs=6", *SHORT_NARMA]), tmp_path / "a", progress=False)
    train(load_config(CONFIG / "narma.yaml", ["epochs=4", *SHORT_NARMA]), tmp_path / "b", progress=False)
    resumed = train(load_config(CONFIG / "narma.yaml", ["epochs=6", *SHORT_NARMA]), tmp_path / "b", resume=True,
                    progress=False)
    assert resumed.losses == full.losses and resumed.metrics["guard"] == full.metrics["guard"]
    a, b = load_agent(tmp_path / "a"), load_agent(tmp_path / "b")
    assert all(torch.equal(x, y) for x, y in zip(a.brain.state_dict().values(), b.brain.state_dict().values()))
    assert torch.equal(a.body.k, b.body.k) and torch.equal(a.body.l, b.body.l)


def _lissajous_agent():
    from bptsb_ros.agent import build_agent
    from bptsb_ros.experiments.common import packaged_config

    agent = build_agent(packaged_config("lissajous_single", ["dtype=float64"], seed=3))
    with torch.no_grad():
        agent.feedback.weight.normal_(0, 0.02, generator=torch.Generator().manual_seed(0))
    body, swg = agent.body, agent.brain
    state = body.initial_state(1, rest_length=swg.rest_length(body.l, torch.zeros(1, dtype=torch.float64))[0])
    return agent, state


def _planted_target(agent, seen, bad: int, wind: bool = False):
    """A zero target that records the parameters it is evaluated with and is NaN at call ``bad``."""

    def target(t, *_wind):
        seen.append(_values([agent.body.k, agent.body.l, agent.brain.phase, agent.feedback.weight]))
        out = torch.zeros(t.shape[0], 2, dtype=torch.float64)
        return out * NAN if len(seen) - 1 == bad else out

    return target


@pytest.mark.parametrize("scheme", [1, 2, 3])
def test_closed_loop_schemes_undo_a_planted_nan(scheme, monkeypatch):
    from bptsb_ros.config import LearningRates
    from bptsb_ros.tasks import feedback_schemes as cls

    # rates 1000x below the paper's: no update of its own is rejected (scheme 1 at the paper's rates diverges)
    monkeypatch.setattr(cls, "FL_LR", 1e-3)
    lr = LearningRates(k=10.0, d=1.0, l=1e-3, amplitude=1e-3, phase=1e-2)
    agent, state = _lissajous_agent()
    seen: list[list[torch.Tensor]] = []
    target = _planted_target(agent, seen, bad=2)
    if scheme == 1:
        res = cls.train_scheme1(agent, target, 4, lr=lr)
    else:
        res = getattr(cls, f"train_scheme{scheme}")(agent, state, target, 4, lr=lr)
    assert res.diverged is None and len(res.losses) == 4 and res.losses[2] == res.losses[1]
    assert [(e["update"], e["reason"]) for e in res.guard["events"]] == [(2, "non-finite loss")]
    assert not _equal(seen[2], seen[1]) and _equal(seen[3], seen[1])  # update 1 undone (the FL too, scheme 3)


@pytest.mark.parametrize("backend", ["numba", "fused"])
def test_switching_training_undoes_a_planted_nan(backend):
    from bptsb_ros.tasks.switching import train_switching

    agent, state = _lissajous_agent()
    seen: list[list[torch.Tensor]] = []
    schedule = np.zeros(401)
    schedule[150:] = 1.0
    res = train_switching(agent, state, schedule, _planted_target(agent, seen, bad=2), backend=backend)
    assert len(res.losses) == 4 and res.losses[2] == res.losses[1]
    assert [(e["update"], e["reason"]) for e in res.guard["events"]] == [(2, "non-finite loss")]
    assert not _equal(seen[2], seen[1]) and _equal(seen[3], seen[1])


def _images(n: int, bad: int, batch: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """n random images, one NaN pixel in the first image of batch ``bad`` (the batches: a permutation by ``seed``)."""
    x = np.random.default_rng(1).uniform(0, 1, (n, 784))
    order = np.random.default_rng(seed).permutation(n)
    x[order[bad * batch], 400] = NAN
    return x, np.arange(n) % 10


def test_mnist_drawing_undoes_a_planted_bad_batch():
    from bptsb_ros.tasks.drawing import ImageToBody, SystemSpec, train_drawing

    system = ImageToBody(SystemSpec(brain="lil", nodes=17, dtype="float64"), 0)
    x, y = _images(8, bad=2, batch=2, seed=5)
    log = train_drawing(system, x, y, epochs=1, batch=2, seed=5)
    assert [(e["update"], e["reason"]) for e in log.guard["events"]] == [(2, "non-finite loss")]
    assert len(log.losses) == 4 and log.losses[2] == log.losses[1] and np.isfinite(log.epoch_losses).all()


def test_mnist_readout_undoes_a_planted_bad_batch():
    from bptsb_ros.tasks.readout import ReadoutSpec, ReadoutSystem, train_readout

    model = ReadoutSystem(ReadoutSpec(shape="double_circle", nodes=33), seed=0)
    x, y = _images(8, bad=1, batch=2, seed=4)
    log = train_readout(model, x, y, epochs=1, batch=2, seed=4)
    assert [(e["update"], e["reason"]) for e in log.guard["events"]] == [(1, "non-finite loss")]
    assert len(log.losses) == 4 and log.losses[1] == log.losses[0]


def test_copy_state_is_a_deep_copy_that_keeps_types_and_metadata():
    from collections import OrderedDict

    from bptsb_ros.training.guard import copy_state

    module = nn.Linear(3, 2)
    params, opt = _tiny()
    _update(UpdateGuard(opt), params, opt, 0, 1.0)  # a momentum buffer in the optimiser's state
    tree = {"module": module.state_dict(), "optimizer": opt.state_dict(), "array": np.arange(3.0),
            "nested": [(1, "x", None, 2.5), {"t": torch.ones(2)}], "step": 7}
    copied, reference = copy_state(tree), copy.deepcopy(tree)
    assert type(copied["module"]) is OrderedDict and copied["module"]._metadata == reference["module"]._metadata
    assert isinstance(copied["nested"][0], tuple) and copied["nested"][0] == (1, "x", None, 2.5)
    with torch.no_grad():  # the originals change in place, as an optimiser step changes them
        for t in (*tree["module"].values(), tree["nested"][1]["t"],
                  *(s["momentum_buffer"] for s in tree["optimizer"]["state"].values())):
            t.add_(1.0)
    tree["array"] += 1
    tree["optimizer"]["param_groups"][0]["lr"] = 99.0
    flat = lambda d: [(k, v.tolist() if hasattr(v, "tolist") else v) for k, v in d.items()]  # noqa: E731
    assert flat(copied["module"]) == flat(reference["module"]) and copied["array"].tolist() == [0.0, 1.0, 2.0]
    assert copied["nested"][1]["t"].tolist() == [1.0, 1.0] and copied["optimizer"]["param_groups"][0]["lr"] == 0.1
    assert [s["momentum_buffer"].tolist() for s in copied["optimizer"]["state"].values()] == \
        [s["momentum_buffer"].tolist() for s in reference["optimizer"]["state"].values()]
    nn.Linear(3, 2).load_state_dict(copied["module"])  # loadable as the module's own


def test_the_update_loop_calls_its_callbacks_in_order_around_the_verdict():
    """Planted losses 1, 1, 50 (a spike: rejected), 1: each callback hears on_measured before the guard's verdict
    (the loss curve has no entry for the update yet) and on_update after it, in the order given; the SimSteps and
    LossCallback objects count and report what the loop did."""
    import torch

    from bptsb_ros.training.callbacks import LossCallback, SimSteps
    from bptsb_ros.training.loop import Callback, GuardRules, Measured, UpdateLoop

    w = torch.nn.Parameter(torch.tensor([1.0]))
    opt = torch.optim.SGD([w], lr=0.1)
    planted = [1.0, 1.0, 50.0, 1.0]

    class Planted:
        def measure(self, update: int) -> Measured:
            return Measured(loss=(w * 0 + planted[update]).sum())

        def step(self) -> None:
            opt.step()

        def advance(self, finite: bool) -> None:
            pass

    loop = UpdateLoop(opt, GuardRules(factor=10.0, window=2))
    events: list[tuple] = []

    class Recorder(Callback):
        def __init__(self, name: str) -> None:
            self.name = name

        def on_measured(self, update: int, measured: Measured) -> None:
            events.append((self.name, "measured", update, len(loop.losses)))

        def on_update(self, update: int) -> None:
            events.append((self.name, "update", update, len(loop.losses)))

    steps, seen = SimSteps(7), []
    loop.run(Planted(), range(4), callbacks=[Recorder("a"), Recorder("b"), steps,
                                             LossCallback(lambda i, loss: seen.append((i, loss)), loop.losses)])
    expected = []
    for i in range(4):
        expected += [("a", "measured", i, i), ("b", "measured", i, i), ("a", "update", i, i + 1),
                     ("b", "update", i, i + 1)]
    assert events == expected
    assert steps.steps == 28
    assert seen == [(0, 1.0), (1, 1.0), (2, 1.0), (3, 1.0)]  # the rejected spike repeats the previous entry
