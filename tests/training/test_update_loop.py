"""The update loop (bptsb_ros.training.loop) over a batched objective: planted members whose losses per update are
known, so that every member's verdicts, parameters, rates and loss curve are known by hand — one member restored,
one stopped and masked, one whose rates are divided, the others advancing as alone — and the callbacks a
population's training uses (progress with a shown loss of its own, a periodic save)."""

from __future__ import annotations

import pytest
import torch

from bptsb_ros.training.loop import Callback, GuardRules, LoopStopped, Measured, UpdateLoop

DIVERGE = "diverge"
NAN = float("nan")


class Planted:
    """B members, member b one float64 parameter w_b = 1 and its own SGD (rate ``lr``); the loss of member b at
    update i is ``losses[b][i]`` (DIVERGE: its simulation diverged), its gradient 1, so an accepted step takes
    ``lr`` off w_b. Records what the loop asks of it."""

    def __init__(self, losses: list[list], lr: float = 0.1) -> None:
        self.losses = losses
        self.w = [torch.nn.Parameter(torch.tensor([1.0], dtype=torch.float64)) for _ in losses]
        self.opts = [torch.optim.SGD([{"params": [w], "lr": lr, "name": "w"}]) for w in self.w]
        self.active_seen: list[list[bool]] = []
        self.accepted: list[list[bool]] = []
        self.finite: list[list[bool]] = []

    def measure(self, update: int, active) -> list[Measured]:
        self.active_seen.append(list(active))
        out = []
        for b, (w, row) in enumerate(zip(self.w, self.losses)):
            w.grad = torch.ones_like(w)
            loss = row[update]
            out.append(Measured(failure=f"member {b} blew up", fused=True) if loss == DIVERGE
                       else Measured(value=loss, fused=True))
        return out

    def step(self, accepted) -> None:
        self.accepted.append(list(accepted))
        for opt, yes in zip(self.opts, accepted):
            if yes:
                opt.step()

    def advance(self, finite) -> None:
        self.finite.append(list(finite))

    def values(self) -> list[float]:
        return [float(w.detach()) for w in self.w]


class Recorder(Callback):
    def __init__(self) -> None:
        self.events: list[tuple] = []

    def on_measured(self, update: int, measured) -> None:
        self.events.append(("measured", update, len(measured)))

    def on_stopped(self, stop: LoopStopped) -> None:
        self.events.append(("stopped", stop.update, stop.member, stop.decision.reason))

    def on_update(self, update: int) -> None:
        self.events.append(("update", update))


#: member 0: two spikes in a row (patience 2: its rate divided by 10); member 1: a diverged window with an update to
#: undo (restored); member 2: diverges at once (nothing to undo: stopped); member 3: never rejected
LOSSES = [[1.0, 1.0, 100.0, 100.0, 1.0, 1.0],
          [2.0, 2.0, DIVERGE, 2.0, 2.0, 2.0],
          [DIVERGE, 3.0, 3.0, 3.0, 3.0, 3.0],
          [4.0, 4.0, 4.0, 4.0, 4.0, 4.0]]


def _run(losses=LOSSES, **kwargs):
    objective = Planted(losses)
    logged: list[tuple[int, str]] = []
    loop = UpdateLoop.batched(objective.opts, GuardRules(factor=10.0, patience=2),
                              log=lambda b, line: logged.append((b, line)))
    recorder = Recorder()
    loop.run(objective, range(len(losses[0])), callbacks=[recorder], **kwargs)
    return loop, objective, recorder, logged


def test_each_member_is_judged_by_its_own_guard():
    loop, objective, recorder, logged = _run()
    # w by hand (steps of 0.1, 0.01 after member 0's division):
    #   member 0: 1 → 0.9 → 0.8, spike at 2 restores 0.9, spike at 3 restores 0.9 again (rate → 0.01), 0.89, 0.88
    #   member 1: 1 → 0.9 → 0.8, diverged at 2 restores 0.9, then 0.8, 0.7, 0.6
    #   member 2: stopped at update 0, never stepped: 1
    #   member 3: six steps: 0.4
    assert objective.values() == pytest.approx([0.88, 0.6, 1.0, 0.4], abs=1e-12)
    assert [g.history for g in loop.guards] == [[1.0] * 6, [2.0] * 6, [], [4.0] * 6]
    assert [g.rates() for g in loop.guards] == [{"w": pytest.approx(0.01)}, {"w": 0.1}, {"w": 0.1}, {"w": 0.1}]
    assert [[(e["update"], e["reason"], e["count"], e["divided"]) for e in g.events] for g in loop.guards] == [
        [(2, "loss spike", 1, False), (3, "loss spike", 2, True)], [(2, "diverged", 1, False)], [], []]
    assert loop.active == [True, True, False, True]
    assert [b for b, _ in logged] == [0, 1, 0]  # one line per rejection, by its member's guard


def test_a_stopped_member_is_masked_and_the_others_advance():
    loop, objective, recorder, _ = _run()
    live = [True, True, False, True]
    assert objective.active_seen == [[True] * 4] + [live] * 5
    assert objective.accepted == [[True, True, False, True], [True, True, False, True],
                                  [False, False, False, True], [False, True, False, True],
                                  [True, True, False, True], [True, True, False, True]]
    assert objective.finite == [[True, True, False, True], live, [True, False, False, True], live, live, live]
    # the stop is heard once, between the measurement and the end of its update
    assert recorder.events[:3] == [("measured", 0, 4), ("stopped", 0, 2, "diverged"), ("update", 0)]
    assert sum(e[0] == "stopped" for e in recorder.events) == 1
    assert [e[1] for e in recorder.events if e[0] == "update"] == list(range(6))


def test_a_non_finite_loss_or_gradient_with_something_to_undo_restores_that_member_alone():
    objective = Planted([[1.0, 1.0, NAN, 1.0], [1.0, 1.0, 1.0, 1.0]])
    loop = UpdateLoop.batched(objective.opts, GuardRules(factor=0.0))
    real = objective.measure

    def measure(update, active):
        out = real(update, active)
        if update == 3:
            out[1].grads_finite = False
        return out

    objective.measure = measure
    loop.run(objective, range(4))
    assert [[(e["update"], e["reason"]) for e in g.events] for g in loop.guards] == [
        [(2, "non-finite loss")], [(3, "non-finite gradient")]]
    assert objective.values() == pytest.approx([0.8, 0.8], abs=1e-12)  # 0.9 restored then one step; 0.7 restored 0.8
    assert loop.active == [True, True]


def test_every_member_stopped_and_the_loop_goes_on_to_the_end():
    """Member 0 stops on a diverged window, member 1 on a non-finite loss (its window did not diverge): neither
    is carried on from the update it stopped at."""
    loop, objective, recorder, _ = _run([[DIVERGE, 1.0, 1.0], [NAN, 1.0, 1.0]])
    assert loop.active == [False, False]
    assert objective.accepted == [[False, False]] * 3 and objective.values() == [1.0, 1.0]
    assert objective.finite == [[False, False]] * 3
    assert [e[2:] for e in recorder.events if e[0] == "stopped"] == [(0, "diverged"), (1, "non-finite loss")]


def test_scheduled_divisions_divide_every_members_rates():
    loop, objective, _, _ = _run([[1.0] * 3, [1.0] * 3], decay_at=[1, 1])
    assert [g.rates()["w"] for g in loop.guards] == pytest.approx([0.001, 0.001])
    assert objective.values() == pytest.approx([0.898, 0.898], abs=1e-12)  # 1 − 0.1 − 0.001 − 0.001


def test_a_training_alone_still_raises_and_its_guard_is_the_loops():
    w = torch.nn.Parameter(torch.tensor([1.0]))
    opt = torch.optim.SGD([w], lr=0.1)

    class Alone:
        def measure(self, update):
            return Measured(failure="blew up", fused=True)

        def step(self):
            raise AssertionError("no step after a stop")

        def advance(self, finite):
            raise AssertionError("no advance after a stop")

    loop = UpdateLoop(opt)
    with pytest.raises(LoopStopped, match="^update 0: blew up") as stop:
        loop.run(Alone(), range(3))
    assert stop.value.member is None and loop.guard is loop.guards[0] and loop.losses is loop.guard.history


def test_the_progress_bar_shows_a_loss_of_its_own_and_none_without_one(monkeypatch):
    from bptsb_ros.training.callbacks import ProgressBar

    shown = [0.5, None]
    bar = ProgressBar(4, "pop", lambda: shown[0], enabled=False, log_every=2, refresh=False)
    posted = []
    monkeypatch.setattr(bar.bar, "set_postfix", lambda **kw: posted.append(kw))
    for i in range(4):
        if i == 2:
            shown[0] = None
        bar.on_update(i)
    assert posted == [{"loss": "0.5", "refresh": False}]


def test_periodically_calls_once_the_interval_passed_since_the_last_call(monkeypatch):
    from types import SimpleNamespace

    import bptsb_ros.training.callbacks as callbacks

    clock = iter([0.0, 3.0, 5.0, 5.5, 9.0, 10.5, 11.0])  # readings: the start, then one per update (and per call)
    monkeypatch.setattr(callbacks, "time", SimpleNamespace(perf_counter=lambda: next(clock)))
    calls = []
    periodic = callbacks.Periodically(5.0, calls.append)
    for i in range(4):
        periodic.on_update(i)
    # update 0 at 3 s: no; update 1 at 5 s: call (then 5.5 s); update 2 at 9 s: no (3.5 s); update 3 at 10.5 s: call
    assert calls == [1, 3]


def test_a_stop_reports_the_simulations_message_or_the_loss_with_the_ranges():
    from bptsb_ros.training.guard import GuardDecision

    tail = "; the guard has nothing to undo (no update since the start or the last restore)"
    diverged = LoopStopped(3, Measured(failure="blew up at step 8", fused=True), GuardDecision(False, "diverged"))
    nan = LoopStopped(3, Measured(value=NAN, fused=True), GuardDecision(False, "non-finite loss"), member=1)
    grad = LoopStopped(3, Measured(value=0.5, fused=True), GuardDecision(False, "non-finite gradient"))
    assert diverged.report("k in [1, 2]") == "blew up at step 8" + tail
    assert nan.report("k in [1, 2]") == "loss is nan; k in [1, 2]" + tail
    assert grad.report("k in [1, 2]") == "non-finite gradient; k in [1, 2]" + tail
    assert str(nan) == "member 1, update 3: non-finite loss; nothing to undo"


def test_a_loop_and_an_objective_that_do_not_fit_are_one_line_each():
    planted = Planted([[1.0], [1.0]])

    class Alone:
        def measure(self, update):
            raise AssertionError("never measured")

    with pytest.raises(TypeError, match=r"^UpdateLoop.run: this loop runs a BatchedObjective, measure\(update, "
                                        r"active\); Alone.measure takes 1 arguments$"):
        UpdateLoop.batched(planted.opts).run(Alone(), range(1))
    with pytest.raises(TypeError, match=r"^UpdateLoop.run: this loop runs an Objective, measure\(update\); "
                                        r"Planted.measure takes 2 arguments$"):
        UpdateLoop(planted.opts[0]).run(planted, range(1))
    assert planted.active_seen == []  # refused before any update
    with pytest.raises(ValueError, match="a population needs at least one member"):
        UpdateLoop.batched([])
    loop = UpdateLoop.batched(planted.opts)
    for name in ("guard", "losses"):  # a training alone's: a population has one per member
        with pytest.raises(AttributeError, match=rf"^UpdateLoop.{name} is a training alone's"):
            getattr(loop, name)
    assert len(loop.guards) == 2 and UpdateLoop(planted.opts[0]).losses == []
