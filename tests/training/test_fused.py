"""The fused training path (``training.backend: fused``, bptsb_ros/training/fused.py) against the autograd paths:
one Lissajous window's loss and gradients equal plain autograd through ``MSDN.step`` (torch backend) and the numba
path to 1e-12 in float64, with the exact clock of a whole-step period and of a fractional one; central finite
differences of the fused loss; whole trainings (guard rejections and rate divisions included) give the numba
path's parameters and loss curve; the projection of k, d, l; divergence; the fallback line."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from bptsb_ros.agent import build_agent
from bptsb_ros.body.msdn import SimulationDiverged
from bptsb_ros.config import ConfigError, ExperimentConfig, validate
from bptsb_ros.tasks import get_task
from bptsb_ros.training.fused import PARAMETERS, FusedSwgWindow, LissajousLoss, fused_training, fused_unsupported
from bptsb_ros.training.optim import make_optimizer
from bptsb_ros.workflows.train import train

F64 = torch.float64
#: a small double circle (13 masses, 24 springs), 40-step windows
SMALL = {"task": "lissajous", "dtype": "float64", "body": {"nodes": 13},
         "training": {"update_steps": 40}, "feedback": {"enabled": False}, "lissajous": {"eval_periods": 1}}


def _cfg(**changes) -> ExperimentConfig:
    data = {key: (dict(value) if isinstance(value, dict) else value) for key, value in SMALL.items()}
    for dotted, value in changes.items():
        *head, last = dotted.split("__")
        node = data
        for part in head:
            node = node.setdefault(part, {})
        node[last] = value
    return validate(data)


def _build(cfg: ExperimentConfig):
    torch.manual_seed(cfg.seed)
    agent = build_agent(cfg)
    return agent, get_task(cfg.task)(agent, cfg), make_optimizer(agent, cfg.training)


def _params(agent) -> dict[str, torch.Tensor]:
    b, s = agent.body, agent.brain
    return {"k": b.k, "d": b.d, "l": b.l, "amplitude": s.amplitude, "phase": s.phase}


def _autograd_window(cfg: ExperimentConfig, windows: int = 1):
    """Loss and gradients of the last of ``windows`` windows through the task's own autograd path."""
    agent, task, _ = _build(cfg)
    for _ in range(windows):
        for p in _params(agent).values():
            p.grad = None
        loss, _ = task.update_loss(0)
        loss.backward()
    return float(loss.detach()), {n: p.grad.clone() for n, p in _params(agent).items()}, task.state


def _fused_window(cfg: ExperimentConfig, windows: int = 1):
    agent, task, opt = _build(cfg)
    fused, why = fused_training(task, opt)
    assert why is None
    for _ in range(windows):
        loss, ok = fused.update_loss(0)
    assert ok
    return loss, fused.fused.gradients(), task.state


@pytest.mark.parametrize(("reference", "omega"), [("torch", 2 * math.pi), ("numba", 2 * math.pi), ("torch", 5.0)],
                         ids=["torch-autograd", "numba", "torch-autograd-fractional-period"])
def test_one_window_loss_and_gradients_equal_the_autograd_paths(reference, omega):
    # omega 5 rad/s: the period is 125.66 steps, the clock's fractional branch (2π·frac(k·c)); three windows, so
    # the clock runs past the start and the carried state is used
    ref_cfg = _cfg(training__backend=reference, training__adjoint=reference != "torch", brain__omega=omega)
    loss_ref, grads_ref, state_ref = _autograd_window(ref_cfg, windows=3)
    loss, grads, state = _fused_window(_cfg(training__backend="fused", brain__omega=omega), windows=3)
    assert loss == pytest.approx(loss_ref, rel=1e-12, abs=0)
    for name in PARAMETERS:
        scale = float(grads_ref[name].abs().max())
        assert scale > 0, name
        assert float((grads[name] - grads_ref[name]).abs().max()) <= 1e-12 * scale, name
    for a, b in ((state.r, state_ref.r), (state.v, state_ref.v), (state.a, state_ref.a),
                 (state.length, state_ref.length)):
        assert torch.allclose(a, b, rtol=0, atol=1e-12)
    assert state.step == state_ref.step == 3 * 40


def _partial_swg(backend: str):
    """The small Lissajous system with an SWG that drives every spring but 2, 6, 10, … (set before the task takes
    its start state, so that the start's rest length is the masked one too)."""
    cfg = _cfg(training__backend=backend, training__adjoint=backend != "torch")
    torch.manual_seed(cfg.seed)
    agent = build_agent(cfg)
    agent.brain.driven.copy_(torch.arange(agent.body.topology.n_springs) % 4 != 2)
    return agent, get_task(cfg.task)(agent, cfg), make_optimizer(agent, cfg.training)


def test_an_swg_driving_only_some_springs_gives_the_autograd_paths_window():
    agent, task, _ = _partial_swg("torch")
    params = _params(agent)
    for _ in range(2):
        for p in params.values():
            p.grad = None
        loss_ref, _ = task.update_loss(0)
        loss_ref.backward()
    fagent, ftask, opt = _partial_swg("fused")
    fused, why = fused_training(ftask, opt)
    assert why is None
    for _ in range(2):
        loss, ok = fused.update_loss(0)
    assert ok and loss == pytest.approx(float(loss_ref.detach()), rel=1e-12, abs=0)
    grads = fused.fused.gradients()
    undriven = ~agent.brain.driven
    for name in PARAMETERS:
        scale = float(params[name].grad.abs().max())
        assert scale > 0, name
        assert float((grads[name] - params[name].grad).abs().max()) <= 1e-12 * scale, name
    for name in ("amplitude", "phase"):  # an undriven spring's A and φ change nothing
        assert float(params[name].grad[undriven].abs().max()) == 0.0
        assert float(grads[name][undriven].abs().max()) == 0.0
    assert torch.allclose(ftask.state.r, task.state.r, rtol=0, atol=1e-12)


def test_gradients_match_central_finite_differences():
    agent, task, opt = _build(_cfg(training__backend="fused"))
    fused = FusedSwgWindow(agent.body, agent.brain, opt, 40,
                           LissajousLoss(0.2, 0.2, 1.0, 2.0, 0.0, 2 * math.pi, agent.body.cmp_local))
    state = task.state
    fused.window(state)
    grads = fused.gradients()
    for name, index, h in (("k", 3, 1e-4), ("phase", 5, 1e-6), ("l", 0, 1e-7), ("amplitude", 7, 1e-6)):
        p = _params(agent)[name]
        with torch.no_grad():
            p[index] += h
            up = fused.window(state)[0]
            p[index] -= 2 * h
            down = fused.window(state)[0]
            p[index] += h
        fd = (up - down) / (2 * h)
        assert abs(float(grads[name][index])) > 1e-6, name
        assert float(grads[name][index]) == pytest.approx(fd, rel=1e-5), name


@pytest.mark.parametrize("backend", ["numba", "torch"])
def test_training_gives_the_same_parameters_and_losses(backend):
    # 25 updates at rates high enough that d hits its bound 0 (the projection acts) and the guard rejects loss
    # spikes (reject_factor 2) and divides the rates (patience 2): 6 rejections, 2 divisions
    changes = dict(sim_time=10.0, training__lr={"k": 3e4, "d": 1e4, "l": 10.0, "amplitude": 10.0, "phase": 100.0},
                   training__reject_factor=2.0, training__reject_patience=2)
    ref = train(_cfg(training__backend=backend, **changes), None, progress=False)
    res = train(_cfg(training__backend="fused", **changes), None, progress=False)
    assert res.metrics["backend"] == "fused" and "backend_fallback" not in res.metrics
    assert len(res.losses) == 25
    events = [(e["update"], e["reason"], e["divided"]) for e in res.metrics["guard"]["events"]]
    assert events == [(e["update"], e["reason"], e["divided"]) for e in ref.metrics["guard"]["events"]]
    assert len(events) >= 3 and any(divided for _, _, divided in events)
    np.testing.assert_allclose(res.losses, ref.losses, rtol=1e-10, atol=0)
    assert res.metrics["guard"]["rates"] == pytest.approx(ref.metrics["guard"]["rates"], rel=1e-15)
    for name, p in _params(res.agent).items():
        p, q = p.detach(), _params(ref.agent)[name].detach()
        assert float((p - q).abs().max()) <= 1e-10 * max(1.0, float(q.abs().max())), name
    body = res.agent.body
    assert float(body.d.detach().min()) == 0.0  # the projection acted
    assert float(torch.cat([body.k, body.d, body.l]).detach().min()) >= 0.0


def test_one_update_is_sgd_per_group_then_the_projection():
    agent, task, opt = _build(_cfg(training__backend="fused", training__lr__l=0.0, training__lr__k=1e7))
    fused, _ = fused_training(task, opt)
    before = {n: p.detach().clone() for n, p in _params(agent).items()}
    fused.update_loss(0)
    grads = fused.fused.gradients()
    opt.param_groups[1]["lr"] *= 0.1  # a division by the guard is read at the step
    fused.step()
    rates = {"k": 1e7, "d": 1e2, "l": 0.0, "amplitude": 1e1, "phase": 1e2}
    for name, p in _params(agent).items():
        expected = before[name] - rates[name] * grads[name]
        if name in ("k", "d", "l"):
            expected = expected.clamp(min=0)
        assert torch.equal(p.detach(), expected), name
    assert float(agent.body.k.detach().min()) == 0.0 and float((before["k"] - 1e7 * grads["k"]).min()) < 0
    assert torch.equal(agent.body.l, before["l"])  # lr 0: not in the optimiser, not trained


def test_a_diverged_window_raises_as_the_numba_path_does_and_keeps_the_state():
    messages = []
    for backend in ("numba", "fused"):
        agent, task, opt = _build(_cfg(training__backend=backend))
        with torch.no_grad():
            agent.body.k.mul_(1e6)  # ω·Δt ≫ 2: the integrator explodes within the window
        start = task.state
        with pytest.raises(SimulationDiverged) as err:
            if backend == "fused":
                fused_training(task, opt)[0].update_loss(0)
            else:
                task.update_loss(0)
        assert task.state is start
        messages.append(str(err.value))
    assert messages[0] == messages[1]


def test_unsupported_configs_fall_back_with_one_line(capsys, monkeypatch):
    from bptsb_ros.body.msdn import MSDN

    projections = []  # what the numba path projects with after each accepted update
    project = MSDN.clamp_parameters_
    monkeypatch.setattr(MSDN, "clamp_parameters_",
                        lambda self, projection="clamp": (projections.append(projection), project(self, projection))[1])
    res = train(_cfg(training__backend="fused", training__optimizer="adam", sim_time=0.8), None, progress=False)
    lines = [line for line in capsys.readouterr().err.splitlines() if "training.backend fused" in line]
    assert lines == ["training.backend fused: it implements plain SGD, the optimiser is Adam; training on the numba "
                     "path instead"]
    assert res.metrics["backend"] == "numba" and "Adam" in res.metrics["backend_fallback"]
    res = train(_cfg(training__backend="fused", training__projection="reset", sim_time=0.8), None, progress=False)
    lines = [line for line in capsys.readouterr().err.splitlines() if "training.backend fused" in line]
    assert lines == ["training.backend fused: the projection reset is not in the fused kernel (clamp only); training "
                     "on the numba path instead"]
    assert res.metrics["backend"] == "numba"
    assert projections and set(projections[-res.metrics["updates"]:]) == {"reset"}
    loco = validate({"task": "locomotion", "body": {"shape": "caterpillar", "nodes": 10},
                     "training": {"update_steps": 200, "backend": "fused"}})
    _, task, opt = _build(loco)
    assert fused_unsupported(task, opt) is None  # locomotion is covered
    _, task, opt = _build(validate({"task": "narma", "brain": {"type": "lil"}, "training": {"backend": "fused"}}))
    assert task.fused_episodes  # NARMA fuses its own episodes (tests/body/test_held_window.py), never this path
    assert fused_unsupported(task, opt) == "the NARMA task fuses its own episodes"
    assert "adjoint" in fused_unsupported(task, opt, adjoint=False)

    class Drawing:  # a task the fused path does not cover
        name = "mnist-drawing"
    assert "not 'mnist-drawing'" in fused_unsupported(Drawing(), opt)
    _, task, opt = _build(_cfg(training__backend="fused"))
    assert fused_unsupported(task, opt) is None
    assert "adjoint" in fused_unsupported(task, opt, adjoint=False)


def test_the_backend_key_is_validated():
    with pytest.raises(ConfigError, match="training.backend"):
        validate({"task": "lissajous", "training": {"backend": "fuse"}})
    assert build_agent(_cfg(training__backend="fused")).body.backend == "numba"  # the body simulates on numba


def test_float32_window_agrees_with_the_numba_path_to_float32_rounding():
    loss_ref, grads_ref, _ = _autograd_window(_cfg(dtype="float32", training__backend="numba"))
    loss, grads, _ = _fused_window(_cfg(dtype="float32", training__backend="fused"))
    assert grads["k"].dtype == torch.float32
    assert loss == pytest.approx(loss_ref, rel=1e-5)
    for name in PARAMETERS:
        scale = float(grads_ref[name].abs().max())
        assert float((grads[name] - grads_ref[name]).abs().max()) <= 1e-4 * scale, name


def test_the_bench_runner_times_the_bench_workload():
    from bptsb_ros.bench.suite import WORKLOADS, _setup, fused_runner

    w = WORKLOADS["lissajous"]
    _, _, state, run_window = _setup(w, True, F64, "numba")
    window, _, state0 = fused_runner(w, F64)
    loss_ref, final_ref = run_window(state)
    loss, final = window(state0)
    assert loss == pytest.approx(float(loss_ref.detach()), rel=1e-12)
    assert torch.allclose(final.r, final_ref.r, rtol=0, atol=1e-12)


def test_the_bench_table_has_a_fused_row_with_its_ratios():
    from bptsb_ros.bench.suite import workload_table

    def m(train):
        return {"forward_steps_per_s": 10.0, "train_steps_per_s": train, "peak_rss_mib": 1.0}

    report = {"workloads": {"lissajous": {"batch": 1, "torch": m(100.0), "numba": m(1000.0), "fused": m(8000.0),
                                          "numba_over_torch": 10.0, "fused_over_numba": 8.0, "fused_over_torch": 80.0},
                            "narma": {"batch": 1, "torch": m(1.0), "numba": m(2.0), "numba_over_torch": 2.0}}}
    rows = workload_table(report).splitlines()
    assert [r for r in rows if "fused" in r] == ["| lissajous | 1 | fused | 10.0 | 8000.0 | – | 80.0 (fused / numba "
                                                 "8.0) | 1.0 |"]
    assert len(rows) == 2 + 5


def test_a_resumed_fused_run_equals_the_uninterrupted_one(tmp_path):
    from bptsb_ros.training.checkpoint import read_checkpoint

    changes = dict(training__reject_factor=2.0, training__lr__k=3e4)
    full = train(_cfg(training__backend="fused", sim_time=4.0, **changes), tmp_path / "a", progress=False)
    train(_cfg(training__backend="fused", sim_time=2.0, **changes), tmp_path / "b", progress=False)
    resumed = train(_cfg(training__backend="fused", sim_time=4.0, **changes), tmp_path / "b", resume=True,
                    progress=False)
    assert len(full.losses) == 10 and np.array_equal(resumed.losses, full.losses)  # bit for bit
    for name, p in _params(full.agent).items():
        assert torch.equal(p, _params(resumed.agent)[name]), name
    a, b = (read_checkpoint(tmp_path / x)["extra"]["task_state"] for x in ("a", "b"))
    assert a["step"] == b["step"] == 400
    for key in ("r", "v", "a", "length"):
        assert torch.equal(a[key], b[key]), key


def test_the_feedback_layer_is_fitted_after_fused_training_as_after_numba_training():
    # the FL is fitted outside every training window: the fused path applies with it enabled
    runs = {b: train(_cfg(training__backend=b, sim_time=2.0, feedback__enabled=True, feedback__fit_time=5.0), None,
                     progress=False) for b in ("numba", "fused")}
    assert runs["fused"].metrics["backend"] == "fused" and "feedback_fit" in runs["fused"].metrics
    w_ref, w = (runs[b].agent.feedback.weight.detach() for b in ("numba", "fused"))
    assert float(w_ref.abs().max()) > 0
    assert torch.allclose(w, w_ref, rtol=1e-9, atol=1e-12)
    closed = [runs[b].metrics["evaluation"]["closed_loop_shift_min_mse"] for b in ("numba", "fused")]
    assert closed[1] == pytest.approx(closed[0], rel=1e-9)


@pytest.mark.slow
def test_the_bench_report_holds_the_fused_ratios_and_target(monkeypatch):
    from bptsb_ros.bench import mnist_speed as bench_mnist
    from bptsb_ros.bench import suite as bench

    planted = {"torch": 100.0, "numba": 1000.0, "fused": 4000.0}  # train steps/s: fused / numba 4 < 5

    def fake(w, adjoint, dtype="float32", min_seconds=3.0, backend="torch", numba_cache=None):
        rate = planted[backend] if adjoint else 50.0
        return {"forward_steps_per_s": 1.0, "forward_body_steps_per_s": float(w.batch), "train_steps_per_s": rate,
                "train_body_steps_per_s": rate * w.batch, "peak_rss_mib": 1.0, "first_call_s": 0.0}

    monkeypatch.setattr(bench, "measure_isolated", fake)
    monkeypatch.setattr(bench, "measure_compile", lambda min_seconds: {})
    monkeypatch.setattr(bench, "_ipc_entry", lambda quick, progress: {})
    monkeypatch.setattr(bench_mnist, "run_isolated", lambda quick: {"systems": {}})
    report = bench.run_benchmarks(quick=True, progress=lambda _: None)
    liss = report["workloads"]["lissajous"]
    assert liss["fused"]["train_steps_per_s"] == 4000.0
    assert liss["fused_over_numba"] == 4.0 and liss["fused_over_torch"] == 40.0
    assert all("fused" not in e for n, e in report["workloads"].items() if n != "lissajous")
    assert report["targets"]["lissajous_fused_over_numba_train"] == {"target": 5.0, "measured": 4.0, "met": False}


#: a small locomotion run as config/locomotion_forward.yaml (caterpillar, environment, the floor that gives traction,
#: its rates) with 40-step windows of two 20-step speed blocks and two warm-up windows
LOCO = {"task": "locomotion", "dtype": "float64",
        "body": {"shape": "caterpillar", "nodes": 10, "environment": "locomotion", "ground_clamp": True},
        "brain": {"amplitude": 0.4}, "training": {"update_steps": 40}, "feedback": {"enabled": False},
        "locomotion": {"speed_block": 20, "warmup_windows": 2, "eval_time": 0.5}}
LOCO_LR = {"k": 1e2, "d": 1.0, "l": 0.1, "amplitude": 1e-3, "phase": 1e-2}
LOCO_CASES = {  # name: overrides — the ramp (ours), the published velocity, headwind blowing half of every 0.3 s
    "ramp": {},
    "before_velocity": {"locomotion": {"loss_velocity": "before", "target_slope": 0.002}},
    "periodic_headwind": {"locomotion": {"wind_force": -0.7, "wind_period": 0.3, "target_speed": 0.05}},
}


def _loco(name: str, **top) -> ExperimentConfig:
    data = {key: (dict(value) if isinstance(value, dict) else value) for key, value in LOCO.items()}
    for section, values in {**LOCO_CASES[name], **top}.items():
        if isinstance(values, dict):
            data[section] = {**data.get(section, {}), **values}
        else:
            data[section] = values
    return validate(data)


@pytest.mark.parametrize("case", list(LOCO_CASES))
def test_locomotion_window_loss_and_gradients_equal_the_autograd_paths(case):
    loss, grads, state = _fused_window(_loco(case, training={"update_steps": 40, "backend": "fused"}), windows=2)
    for reference in ("torch", "numba"):
        cfg = _loco(case, training={"update_steps": 40, "backend": reference, "adjoint": reference != "torch"})
        loss_ref, grads_ref, state_ref = _autograd_window(cfg, windows=2)
        assert loss == pytest.approx(loss_ref, rel=1e-12, abs=0), reference
        for name in PARAMETERS:
            scale = float(grads_ref[name].abs().max())
            assert scale > 0, (reference, name)
            assert float((grads[name] - grads_ref[name]).abs().max()) <= 1e-12 * scale, (reference, name)
        assert torch.allclose(state.v, state_ref.v, rtol=0, atol=1e-12) and state.step == state_ref.step == 160


def test_locomotion_training_gives_the_numba_paths_parameters():
    changes = {"sim_time": 4.0, "training": {"update_steps": 40, "reject_factor": 3.0, "lr": LOCO_LR}}
    runs = {b: train(_loco("periodic_headwind", **{**changes, "training": {**changes["training"], "backend": b}}),
                     None, progress=False) for b in ("numba", "fused")}
    assert runs["fused"].metrics["backend"] == "fused" and len(runs["fused"].losses) == 10
    np.testing.assert_allclose(runs["fused"].losses, runs["numba"].losses, rtol=1e-10, atol=0)
    for name, p in _params(runs["fused"].agent).items():
        p, q = p.detach(), _params(runs["numba"].agent)[name].detach()
        assert float((p - q).abs().max()) <= 1e-10 * max(1.0, float(q.abs().max())), name


def test_only_the_trained_parameters_gradients_must_be_finite():
    # as UpdateGuard.gradients_finite: a parameter outside the optimiser (lr 0) does not count
    _, task, opt = _build(_cfg(training__backend="fused", training__lr__amplitude=0.0))
    fused, _ = fused_training(task, opt)
    _, ok = fused.update_loss(0)
    assert ok and fused.fused.gradients_finite()
    rows = {name: i for i, name in enumerate(PARAMETERS)}
    fused.fused.grads[rows["amplitude"], 2] = math.nan  # planted: not trained
    assert fused.fused.gradients_finite()
    fused.fused.grads[rows["phase"], 2] = math.inf  # planted: trained
    assert not fused.fused.gradients_finite()


@pytest.mark.parametrize("published", [False, True], ids=["wind", "published-wind"])
def test_switching_training_gives_the_numba_paths_losses_and_parameters(published):
    from bptsb_ros.sim.inputs import wind_schedule
    from bptsb_ros.tasks.switching import CURVE_1, CURVE_SWITCH, switch_targets, train_switching

    schedule = wind_schedule(400, 100, np.random.default_rng(3), hold_periods=(1, 1))
    assert 0 < schedule.mean() < 1  # the wind blows part of the time
    target = switch_targets(CURVE_1, CURVE_SWITCH, 0.2, 2 * math.pi, 0.1)
    runs = {}
    for backend in ("numba", "fused"):
        agent, task, _ = _build(_cfg(training__backend=backend))
        runs[backend] = (agent, train_switching(agent, task.state, schedule, target, window=40, reject_factor=2.0,
                                                published_wind=published))
    (ref_agent, ref), (agent, res) = runs["numba"], runs["fused"]
    assert len(res.losses) == 10
    np.testing.assert_allclose(res.losses, ref.losses, rtol=1e-10, atol=0)
    assert [e["update"] for e in res.guard["events"]] == [e["update"] for e in ref.guard["events"]]
    for name, p in _params(agent).items():
        p, q = p.detach(), _params(ref_agent)[name].detach()
        assert not torch.equal(q, _params(_build(_cfg())[0])[name].detach()), name  # trained
        assert float((p - q).abs().max()) <= 1e-10 * max(1.0, float(q.abs().max())), name
    assert res.state.step == ref.state.step == 400
    assert torch.allclose(res.state.r, ref.state.r, rtol=0, atol=1e-10)


def test_lr_decay_divides_every_rate_by_100_after_90_percent_of_more_than_1000_updates(tmp_path):
    from bptsb_ros.training.checkpoint import read_checkpoint

    n = 1001  # the schedule applies only above 1,000 updates (its boundary: step_decay_updates' own test)
    cfg = _cfg(training__update_steps=1, training__lr_decay=True, sim_time=n * _cfg().body.dt)
    res = train(cfg, tmp_path, progress=False)
    assert res.metrics["updates"] == n
    rates = {g["name"]: g["lr"] for g in read_checkpoint(tmp_path)["extra"]["optimizer"]["param_groups"]}
    base = {"k": 1e4, "d": 1e3, "l": 1e1, "amplitude": 1e1, "phase": 1e2}  # LearningRates' defaults
    assert rates == pytest.approx({k: v / 100 for k, v in base.items()}, rel=1e-12)
