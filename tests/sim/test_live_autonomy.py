"""Wind schedules and perturbations, offline and live (Lissajous autonomy in ROS 2): the schedules'
definitions, the perturbation draw and ``MSDN.displaced``, the offline perturbed simulation against an independent
step-by-step loop, the replay metrics on planted trajectories, and live ``lissajous_switching`` / perturbed runs
equal to their offline counterparts (1e-9, float64)."""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys

import numpy as np
import pytest
import torch
from ros_live import REPO, bag_positions, bptsb, fresh_agent, stamp_ns

DT = 0.01
DT_NS_DEFAULT = 10_000_000


# -- wind schedules ------------------------------------------------------------------------------------------
def test_constant_and_periodic_schedules_by_hand():
    from bptsb_ros.sim.wind_schedule import WindSchedule

    np.testing.assert_array_equal(WindSchedule("constant", force=(0.5, -2.0)).forces(3, DT), [[0.5, -2.0]] * 4)
    # period 0.4 s = 40 steps: calm for steps 0..19, blowing for 20..39, calm again from 40
    wind = WindSchedule("periodic", force=(-3.0, 1.0), period=0.4).forces(100, DT)
    expected = np.array([(-3.0, 1.0) if k % 40 >= 20 else (0.0, 0.0) for k in range(101)])
    np.testing.assert_array_equal(wind, expected)


def test_switching_schedule_switches_at_the_stated_phase_and_whole_periods():
    from bptsb_ros.sim.wind_schedule import WindSchedule

    period = 50  # steps (0.5 s at dt 0.01)
    for timing, phase in (("fixed", 0), ("37", round(period * 37 / 100))):
        s = WindSchedule("switching", force=(1.0, 0.0), period=0.5, hold_periods=(2, 3), timing=timing, seed=5)
        on = s.forces(2000, DT)[:, 0]
        assert set(np.unique(on)) == {0.0, 1.0} and on[0] == 0.0  # starts calm
        switches = np.flatnonzero(np.diff(on)) + 1
        assert len(switches) >= 10
        assert all(k % period == phase for k in switches)  # t_wind = t0 + (2π/ω)·n/100
        # each segment ends 2 or 3 whole periods after the start of the period it began in, plus the phase
        starts = np.concatenate([[0], switches[:-1]])
        held = (switches - phase) // period - starts // period
        assert set(held.tolist()) <= {2, 3} and len(set(held.tolist())) == 2
    rnd = WindSchedule("switching", force=(1.0, 0.0), period=0.5, hold_periods=(2, 3), seed=5).forces(4000, DT)
    phases = {int(k) % period for k in np.flatnonzero(np.diff(rnd[:, 0])) + 1}
    assert len(phases) > 5  # random n: many different switch phases


def test_force_at_equals_forces_and_the_draw_is_prefix_stable():
    from bptsb_ros.sim.wind_schedule import WindSchedule

    s = WindSchedule("switching", force=(15.0, 1.0), period=1.0, hold_periods=(1, 2), seed=3)
    step_by_step = np.array([s.force_at(k, DT) for k in range(3001)])  # grows its cached draw 1024 → 2048 → 4096
    fresh = WindSchedule("switching", force=(15.0, 1.0), period=1.0, hold_periods=(1, 2), seed=3)
    np.testing.assert_array_equal(step_by_step, fresh.forces(3000, DT))
    np.testing.assert_array_equal(fresh.forces(100, DT), step_by_step[:101])
    assert set(map(tuple, step_by_step)) == {(0.0, 0.0), (15.0, 1.0)}


def test_file_schedule_and_its_errors(tmp_path):
    from bptsb_ros.sim.wind_schedule import WindSchedule, WindScheduleError, read_table

    f = tmp_path / "wind.csv"
    f.write_text("# a gust\nt,fx,fy\n0.05,1.5,0\n0.1,0,-2\n0.13,0,0\n")
    s = WindSchedule("file", table=read_table(f))
    w = s.forces(20, DT)
    expected = np.zeros((21, 2))
    expected[5:10] = (1.5, 0.0)
    expected[10:13] = (0.0, -2.0)
    np.testing.assert_array_equal(w, expected)
    assert [s.force_at(k, DT) for k in (4, 5, 12, 13)] == [(0.0, 0.0), (1.5, 0.0), (0.0, -2.0), (0.0, 0.0)]
    for text, match in (("t,fx\n0,1\n", "header"), ("t,fx,fy\n0,1,nan\n", "row 2"), ("t,fx,fy\n1,0,0\n0.5,1,1\n",
                        "not after"), ("t,fx,fy\n", "no rows")):
        f.write_text(text)
        with pytest.raises(WindScheduleError, match=match):
            read_table(f)
    with pytest.raises(WindScheduleError, match="no such file"):
        read_table(tmp_path / "missing.csv")


@pytest.mark.ros
def test_agent_wind_and_node_parameters():
    from bptsb_ros.interface.params import ParameterError
    from bptsb_ros.ros.wind_source import PARAMS, schedule_from_parameters
    from bptsb_ros.sim.wind_schedule import for_agent

    liss = {"task": "lissajous", "brain": {"omega": math.pi}}
    s = for_agent(liss, {"curve_on": [2, 1, 1.57], "published_wind": True, "hold_periods": [4, 6],
                         "timing": "fixed"})
    assert (s.kind, s.force, s.calm, s.period, s.hold_periods, s.timing) == (
        "switching", (15.0, 1.0), (0.0, 1.0), 2.0, (4, 6), "fixed")
    # what the switching training fed the body: wind_vector(F_wind, published) = (15·F, 1), calm included
    from bptsb_ros.sim.inputs import wind_schedule
    from bptsb_ros.tasks.switching import wind_vector

    f_wind = wind_schedule(3000, 200, np.random.default_rng(0), hold_periods=(4, 6), timing="fixed")
    np.testing.assert_array_equal(s.forces(3000, DT), wind_vector(f_wind, published=True).numpy())
    loc = for_agent({"task": "locomotion", "locomotion": {"wind_force": -3.0, "wind_period": 4.0}})
    assert (loc.kind, loc.force, loc.period) == ("periodic", (-3.0, 0.0), 4.0)
    defaults = {p.name: p.default for p in PARAMS}
    force = next(p for p in PARAMS if p.name == "force")  # `-p force:=2.0` (a double) as well as '' or '2.5'
    assert (force.validate(2.0), force.validate(3), force.validate(""), force.validate("2.5")) == (2.0, 3.0, "", 2.5)
    for bad in ("strong", float("nan"), True):
        with pytest.raises(ParameterError, match="force"):
            force.validate(bad)
    s = schedule_from_parameters(liss, {}, {**defaults, "force": "2.5", "hold_periods": "1,2", "timing": "fixed"})
    assert (s.kind, s.force, s.hold_periods, s.timing, s.period) == ("switching", (2.5, 0.0), (1, 2), "fixed", 2.0)
    c = schedule_from_parameters(liss, {}, {**defaults, "schedule": "constant", "force_y": "-1"})
    assert (c.kind, c.force) == ("constant", (0.0, -1.0))
    with pytest.raises(ParameterError, match="hold_periods"):
        schedule_from_parameters(liss, {}, {**defaults, "hold_periods": "3"})
    with pytest.raises(ParameterError, match="timing"):
        schedule_from_parameters(liss, {}, {**defaults, "timing": "150"})
    with pytest.raises(ParameterError, match="schedule"):
        schedule_from_parameters({"task": "narma"}, {}, defaults)
    with pytest.raises(ParameterError, match="is at most half a time step"):
        schedule_from_parameters(liss, {}, {**defaults, "period": "0.004"}, 0.01)
    with pytest.raises(ParameterError, match="hold_periods"):
        schedule_from_parameters(liss, {}, {**defaults, "hold_periods": "²,3"})


# -- perturbations -------------------------------------------------------------------------------------------
def test_perturbation_draw_and_displaced_state():
    from bptsb_ros.sim.perturbation import perturbation, perturbation_batch

    z = torch.randn(5, 2, generator=torch.Generator().manual_seed(9), dtype=torch.float64).numpy()
    np.testing.assert_array_equal(perturbation(5, 0.3, 9), 0.3 * z)
    batch = perturbation_batch(5, 10, np.array([0.0, 0.3]), torch.float64)
    np.testing.assert_array_equal(batch[19].numpy(), 0.3 * z)  # row σ_1·seeds + 9
    assert not batch[:10].any()
    with pytest.raises(ValueError, match="sigma"):
        perturbation(5, -0.1, 0)
    # displacing the layout at rest = releasing the body from the displaced layout (two code paths)
    body = fresh_agent("lissajous").body
    d = torch.as_tensor(perturbation(body.n_movable, 0.2, 4)).unsqueeze(0)
    a = body.displaced(body.initial_state(1), d)
    b = body.initial_state(1, displacement=d)
    for x, y in zip((a.r, a.v, a.a, a.length), (b.r, b.v, b.a, b.length), strict=True):
        torch.testing.assert_close(x, y, rtol=0, atol=1e-13)


def _step_by_step(agent, steps: int, kicks: dict, wind: np.ndarray, closed_from: int | None = None) -> torch.Tensor:
    """Independent reference: one body.step per step; SWG rest lengths l(1 + A sin(ωt + φ)) written out, then the
    feedback layer; at a kicked step r += d and a, lengths recomputed from the spring model."""
    from bptsb_ros.body.msdn import BodyState

    body, swg = agent.body, agent.brain
    m = body.n_movable

    def rest_at(k: int, state) -> torch.Tensor:
        if closed_from is not None and k > closed_from:
            return agent.feedback.rest_length(body.l, state)[0]
        return body.l * (1 + swg.driven * swg.amplitude * torch.sin(swg.omega * k * body.dt + swg.phase))

    def force(k: int) -> torch.Tensor:
        return torch.as_tensor(wind[k]).expand(m, 2).clone()

    with torch.no_grad():
        rest = rest_at(0, None)
        s = body.initial_state(1, rest_length=rest, external_force=force(0))
        rows = []
        for k in range(steps + 1):
            if k:
                rest = rest_at(k, s)
                s = body.step(s, rest, force(k))
            if k in kicks:
                r = s.r + torch.as_tensor(kicks[k]).view(1, m, 2)
                acc, length = body.acceleration(r, s.v, rest.view(1, -1), force(k))
                s = BodyState(r, s.v, acc, length, s.step)
            rows.append(s.r[0])
    return torch.stack(rows)


def test_simulate_perturbed_equals_a_step_by_step_loop():
    from bptsb_ros.sim.perturbation import perturbation, simulate_perturbed
    from bptsb_ros.training.feedback_fit import fit_feedback

    agent = fresh_agent("lissajous", seed=2)
    m = agent.body.n_movable
    kicks = {0: perturbation(m, 0.05, 1), 33: perturbation(m, 0.3, 2)}
    wind = np.zeros((81, 2))
    wind[12:50] = (1.5, -0.5)
    ref = _step_by_step(agent, 80, kicks, wind)
    torch.testing.assert_close(simulate_perturbed(agent, 80, kicks, wind=wind), ref, rtol=0, atol=1e-12)
    assert (ref - _step_by_step(agent, 80, {}, wind)).abs().max() > 0.05  # the kicks matter
    # closed loop after 20 SWG steps, kicked before and after the handover
    from bptsb_ros.config import validate

    cfg = validate({"task": "lissajous", "seed": 2, "dtype": "float64", "feedback": {"fit_time": 5.0}})
    fit_feedback(agent, cfg.feedback, None, 2)
    kicks = {15: perturbation(m, 0.1, 3), 40: perturbation(m, 0.1, 4)}
    ref = _step_by_step(agent, 70, kicks, np.zeros((71, 2)), closed_from=20)
    torch.testing.assert_close(simulate_perturbed(agent, 70, kicks, feedback_from=20), ref, rtol=0, atol=1e-12)


# -- replay metrics on planted trajectories ------------------------------------------------------------------
def test_return_metrics_on_planted_offsets():
    from bptsb_ros.analysis.replay_lissajous import lissajous_target, return_metrics

    config = {"task": "lissajous", "brain": {"omega": 2 * math.pi}, "body": {"size": 4.0, "dt": DT},
              "lissajous": {"amplitude_fraction": 0.05, "alpha": 1, "beta": 2, "delta": 0.0}}
    target, period, amp, _ = lissajous_target(config)
    assert (period, amp) == (100, 0.2)
    t = np.arange(1001) * DT
    tgt = target(t)
    planted = {"unperturbed": tgt + 0.01, "live": tgt + 0.015, "offline": tgt + 0.012}
    out = return_metrics(planted, 0, 200, DT, config)
    # after the kick at step 200: 8 whole periods → the last 4 are measured; E = offset² (no shift does better)
    assert out["eval_periods"] == 4 and out["eval_steps"] == [600, 1000]
    assert out["E_orig"] == pytest.approx(1e-4) and out["E_live"] == pytest.approx(2.25e-4)
    assert (out["returned_live"], out["returned_offline"], out["returned_equal"]) == (False, True, False)
    short = return_metrics(planted, 0, 950, DT, config)
    assert "problem" in short and "returned_live" not in short
    # rows 700..1000 only (a bag with a gap before them), kicked at step 100: the window stays within the rows
    tail = {k: v[700:] for k, v in planted.items()}
    out = return_metrics(tail, 700, 100, DT, config)
    assert out["eval_periods"] == 3 and out["eval_steps"] == [700, 1000]


def test_switching_metrics_on_planted_drawings():
    from bptsb_ros.analysis.replay_lissajous import switching_metrics, wind_segments
    from bptsb_ros.tasks.switching import CURVE_1, Curve

    config = {"task": "lissajous", "brain": {"omega": 2 * math.pi}, "body": {"size": 4.0, "dt": DT},
              "lissajous": {"amplitude_fraction": 0.05, "alpha": 1, "beta": 2, "delta": 0.0}}
    extra = {"curve_on": [2, 1, math.pi / 2], "wind_shift_x": 0.3}
    wind = np.zeros((1201, 2))
    wind[400:800, 0] = 1.0
    assert wind_segments(wind) == [(0, 400, False), (400, 800, True), (800, 1201, False)]
    t = np.arange(1201) * DT
    good = np.where(wind[:, :1] > 0, Curve(2, 1, math.pi / 2).target(t, 0.2, 2 * math.pi, 0.3),
                    CURVE_1.target(t, 0.2, 2 * math.pi))
    out = switching_metrics({"live": good, "stuck": CURVE_1.target(t, 0.2, 2 * math.pi)}, wind, DT, config, extra)
    assert [s["steps"] for s in out["segments"]] == [[200, 399], [600, 799], [1000, 1200]]
    assert all(s["nmse_live"] < 1e-20 for s in out["segments"])
    assert out["both_curves_drawn_live"] and not out["both_curves_drawn_stuck"]
    assert out["segments"][1]["nmse_stuck"] > 1.0  # (1,2,0) is far from (2,1,π/2) shifted by 0.3 m


# -- live ----------------------------------------------------------------------------------------------------
def _save(run, agent, extra=None) -> None:
    from bptsb_ros.training.checkpoint import save_checkpoint

    save_checkpoint(run, agent, extra or {})


@pytest.mark.slow
def test_live_lissajous_switching_equals_offline(tmp_path, ros_env):
    """SWG + wind_source (the agent's switching wind: on and off at random phases) in lockstep: the live run
    equals the offline run under the schedule, and replay compares per wind segment."""
    from bptsb_ros.analysis.replay import replay
    from bptsb_ros.bags.reader import read_messages
    from bptsb_ros.sim.rollout import simulate_open_loop
    from bptsb_ros.sim.wind_schedule import WindSchedule

    run = tmp_path / "agent"
    agent = fresh_agent("lissajous", seed=1)
    _save(run, agent, {"curve_on": [2, 1, math.pi / 2], "wind_shift_x": 0.1, "hold_periods": [3, 3]})
    bag = tmp_path / "bag"
    # hold 3 periods, seed 4: calm for steps 0..371, blowing for 372..693, calm again from 694 (too short to count)
    out = bptsb(["launch", "lissajous_switching", "--agent", str(run), "--duration", "7", "--bag", str(bag),
                 "--param", "wind_source:schedule_seed:=4", "--perturb-at", "6.0", "--perturb-sigma", "0.1",
                 "--perturb-seed", "5"], ros_env)
    assert out.returncode == 0, out.stdout[-4000:]
    stamps, pos = bag_positions(bag)
    assert stamps.tolist() == [k * DT_NS_DEFAULT for k in range(701)]
    schedule = WindSchedule("switching", force=(1.0, 0.0), period=1.0, hold_periods=(3, 3), seed=4)
    wind = schedule.forces(700, DT)
    assert 0 < wind[:, 0].mean() < 1  # the wind switches within the run
    live_wind = {stamp_ns(m.header.stamp) // DT_NS_DEFAULT: (m.vector.x, m.vector.y)
                 for *_, m in read_messages(bag, ["/env/wind"])}
    np.testing.assert_array_equal(np.array([live_wind[k] for k in range(701)]), wind)
    assert wind[600, 0] == 1.0  # the kick lands while the wind blows: its force enters the new accelerations
    kick = {600: 0.1 * torch.randn(agent.body.n_movable, 2, generator=torch.Generator().manual_seed(5),
                                   dtype=torch.float64).numpy()}
    ref = agent.body.full_positions(_step_by_step(agent, 700, kick, wind)).numpy()
    calm = simulate_open_loop(agent, 700)
    assert np.abs(ref - agent.body.full_positions(calm.r[:, 0]).numpy()).max() > 1e-3
    assert np.abs(pos - ref).max() <= 1e-9
    metrics = replay(bag, tmp_path / "replay", run, gif=False)
    assert metrics["offline_comparison"]["max_abs_position_difference_m"] <= 1e-9
    assert metrics["offline_comparison"]["perturbed_steps"] == [600]
    summary = json.loads((tmp_path / "bag.launch" / "body_summary.json").read_text())
    assert summary["wind_accepted"] == 701 and summary["rejected_total"] == 0  # the wind of every step, counted
    seg = metrics["switching"]["segments"]
    assert [(s["steps"], s["wind"]) for s in seg] == [([200, 371], False), ([572, 693], True)]  # 2 periods skipped
    for s in seg:
        assert s["nmse_live"] == pytest.approx(s["nmse_offline"], rel=1e-9)
    assert (tmp_path / "replay" / "switching_curves.png").is_file()


@pytest.mark.slow
def test_live_perturbation_equals_offline_and_replay_reports_the_return(tmp_path, ros_env):
    """``bptsb launch --perturb-at T --perturb-sigma S``: the state of step T is displaced by S·z(seed); the run
    equals the independent offline loop; replay's return verdict is the offline one."""
    from bptsb_ros.analysis.replay import replay
    from bptsb_ros.bags.reader import read_messages

    run = tmp_path / "agent"
    agent = fresh_agent("lissajous", seed=4)
    _save(run, agent)
    bag = tmp_path / "bag"
    out = bptsb(["launch", "lissajous_open", "--agent", str(run), "--duration", "5", "--bag", str(bag),
                 "--perturb-at", "0.5", "--perturb-sigma", "0.2", "--perturb-seed", "3"], ros_env)
    assert out.returncode == 0, out.stdout[-4000:]
    z = torch.randn(agent.body.n_movable, 2, generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    kicks = [(stamp_ns(m.header.stamp) // DT_NS_DEFAULT, np.asarray(m.position).reshape(-1, 2))
             for *_, m in read_messages(bag, ["/body/perturbation"])]
    assert len(kicks) == 1 and kicks[0][0] == 50
    np.testing.assert_array_equal(kicks[0][1], 0.2 * z.numpy())
    _, pos = bag_positions(bag)
    ref = agent.body.full_positions(_step_by_step(agent, 500, {50: 0.2 * z.numpy()}, np.zeros((501, 2)))).numpy()
    assert np.abs(pos[50] - pos[49]).max() > 0.05  # the kick is in the recorded positions
    assert np.abs(pos - ref).max() <= 1e-9
    summary = json.loads((tmp_path / "bag.launch" / "body_summary.json").read_text())
    assert summary["perturbation_steps"] == [50] and summary["rejected_total"] == 0
    metrics = replay(bag, tmp_path / "replay", run, gif=False)
    assert metrics["offline_comparison"]["max_abs_position_difference_m"] <= 1e-9
    assert metrics["offline_comparison"]["perturbed_steps"] == [50]
    p = metrics["perturbation"]
    assert p["perturbed_at_step"] == 50 and p["eval_periods"] == 2
    assert p["E_live"] == pytest.approx(p["E_offline"], rel=1e-9) and p["returned_equal"]
    assert (tmp_path / "replay" / "perturbation.png").is_file()


def test_launch_refuses_a_perturbation_without_its_time(tmp_path, ros_env):
    from bptsb_ros.live.loops import LOOPS, LaunchArgumentError, resolve_arguments

    out = bptsb(["launch", "lissajous_open", "--duration", "1", "--perturb-sigma", "0.2"], ros_env)
    assert out.returncode == 2 and "--perturb-at" in out.stdout
    with pytest.raises(LaunchArgumentError, match="perturb_at"):  # the same rule for ros2 launch
        resolve_arguments(LOOPS["lissajous_open"], {"perturb_sigma": "0.2"})
    late = bptsb(["launch", "lissajous_open", "--duration", "1", "--perturb-at", "2", "--perturb-sigma", "0.2"],
                 ros_env)
    assert late.returncode != 0 and "after the run's last step" in late.stdout


def _read_table_in_subprocess(path, timeout: float = 30) -> subprocess.CompletedProcess:
    """read_table(path) in a child with a 2 GiB address-space limit and a timeout, so that a FIFO that blocks or a
    device that never ends fails the test instead of hanging it (or filling the memory)."""
    import resource

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (2 * 2**30, 2 * 2**30))

    code = ("import sys\nfrom bptsb_ros.sim.wind_schedule import WindScheduleError, read_table\n"
            "try:\n    read_table(sys.argv[1])\nexcept WindScheduleError as err:\n    print(err)\n    sys.exit(2)\n")
    return subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, timeout=timeout,
                          preexec_fn=limit, env={**os.environ, "PYTHONPATH": str(REPO)})


def test_wind_file_must_be_a_regular_file(tmp_path):
    fifo = tmp_path / "wind.fifo"
    os.mkfifo(fifo)
    for path, kind in ((fifo, "a FIFO (named pipe)"), ("/dev/zero", "a character device"), (tmp_path, "a directory")):
        out = _read_table_in_subprocess(path)
        assert out.returncode == 2 and "Traceback" not in out.stderr, out.stderr[-2000:]
        assert out.stdout.strip() == f"wind file {path} is {kind}, not a regular file"


def test_wind_file_size_bound_both_sides(tmp_path, monkeypatch):
    from bptsb_ros.sim import wind_schedule
    from bptsb_ros.sim.wind_schedule import WindScheduleError, read_table

    f = tmp_path / "wind.csv"
    text = "t,fx,fy\n0,1,2\n"
    f.write_text(text)
    monkeypatch.setattr(wind_schedule, "MAX_TABLE_BYTES", len(text))
    assert read_table(f) == ((0.0, 1.0, 2.0),)
    monkeypatch.setattr(wind_schedule, "MAX_TABLE_BYTES", len(text) - 1)
    with pytest.raises(WindScheduleError, match=f"holds {len(text)} bytes, more than the maximum of {len(text) - 1}"):
        read_table(f)


@pytest.mark.ros
def test_wind_table_beyond_max_wind_is_refused_at_startup(tmp_path, capsys):
    """A 1e30 N row made the body reject every wind (the run ended 'ok' with no wind at all): the table is
    checked against the body's max_wind by read_table, by wind_source and by `bptsb launch` before starting."""
    from bptsb_ros.cli import main
    from bptsb_ros.cli.launch_cmd import _wind_limit
    from bptsb_ros.interface.params import ParameterError
    from bptsb_ros.live.safety import DEFAULT_MAX_WIND
    from bptsb_ros.ros.wind_source import PARAMS, schedule_from_parameters
    from bptsb_ros.sim.wind_schedule import WindScheduleError, read_table

    assert DEFAULT_MAX_WIND == 1000.0
    f = tmp_path / "wind.csv"
    f.write_text("t,fx,fy\n0,1,0\n0.5,-1000,1000\n")  # exactly at the limit: accepted
    assert read_table(f, max_force=1000.0)[1] == (0.5, -1000.0, 1000.0)
    loc = {"task": "locomotion", "locomotion": {"wind_force": -3.0, "wind_period": 4.0}}
    defaults = {p.name: p.default for p in PARAMS}
    file_params = {**defaults, "schedule": "file", "file": str(f)}
    assert schedule_from_parameters(loc, {}, file_params).force_at(50, DT) == (-1000.0, 1000.0)
    extra = {"body_sim": [], "swg_brain": [], "wind_source": ["schedule:=file", f"file:='{f}'"]}
    assert _wind_limit(extra) == 1000.0
    f.write_text("t,fx,fy\n0,1,0\n# gusts\n0.5,-1000.001,0\n")  # just above
    message = f"wind file {f}, row 3: force (-1000, 0) N is beyond the body's max_wind of 1000 N per component"
    with pytest.raises(WindScheduleError, match=re.escape(message)):
        read_table(f, max_force=1000.0)
    with pytest.raises(ParameterError, match="row 3"):
        schedule_from_parameters(loc, {}, file_params)
    with pytest.raises(ValueError, match=re.escape(message)):
        _wind_limit(extra)
    assert _wind_limit({**extra, "body_sim": ["max_wind:=2000"]}) == 2000.0  # the body's own limit counts
    f.write_text("t,fx,fy\n0,0,1e30\n")
    args = ["launch", "locomotion_headwind", "--duration", "1", "--param", "wind_source:schedule:=file",
            "--param", f"wind_source:file:={f}", "--log-dir", str(tmp_path / "logs")]
    assert main(args) == 1  # the file's content: a runtime failure
    err = capsys.readouterr().err.strip()
    assert err == (f"bptsb launch: wind file {f}, row 2: force (0, 1e+30) N is beyond the body's max_wind of 1000 N "
                   "per component (every wind would be rejected)")
    assert not (tmp_path / "logs").exists()  # refused before any node started
    # the other schedules: a force or calm beyond the limit, both sides
    const = {**defaults, "schedule": "constant", "force": 1000.0, "force_y": -1000.0}
    assert schedule_from_parameters(loc, {}, const).force == (1000.0, -1000.0)
    with pytest.raises(ParameterError, match=r"force \(1000.01, -1000\) N is beyond the body's max_wind of 1000 N"):
        schedule_from_parameters(loc, {}, {**const, "force": 1000.01})
    with pytest.raises(ParameterError, match="max_wind of 5 N"):
        schedule_from_parameters(loc, {}, {**const, "max_wind": 5.0})
