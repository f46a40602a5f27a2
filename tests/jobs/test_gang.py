"""Independent trainings as one batched simulation (``bptsb_ros/jobs/gang.py``, ``body/held_window_kernel.py``): each
lane of a window run together with others equals that body's window run alone (``held_force_readout``'s solo
path, itself checked against the per-step rollout in tests/body/test_held_window.py) bit for bit, in float64 and
float32; whole trainings in a gang (memory and NARMA targets, the guard rejecting updates, two topologies in one
gang) equal the same trainings run one by one, bit for bit; a failing training is returned in its place while
the others finish; sweeps in gangs; the gang's arguments."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from bptsb_ros.body.held_window import as_lanes, held_force_readout
from bptsb_ros.body.msdn import MSDN, SimulationDiverged
from bptsb_ros.body.shapes import double_circle, multiple_circle
from bptsb_ros.config import validate
from bptsb_ros.jobs.gang import Gang, run_gang
from bptsb_ros.jobs.sweep import SweepError, gangs_of, run_sweep, train_jobs
from bptsb_ros.workflows.train import train

TAU, BLOCKS = 4, 6


def _body(seed: int, dtype: torch.dtype, topology=None) -> MSDN:
    body = MSDN(topology or double_circle(13), dt=0.01, dtype=dtype, backend="numba",
                generator=torch.Generator().manual_seed(seed))
    g = torch.Generator().manual_seed(100 + seed)
    with torch.no_grad():  # every body its own parameters
        for t in (body.k, body.d, body.l):
            t.mul_(1 + 0.2 * (torch.rand(t.shape, generator=g, dtype=torch.float64).to(dtype) - 0.5))
    return body


def _window(body: MSDN, seed: int, row: int, coord: int):
    """Readout of a held window and the gradients of a weighted sum of it w.r.t. k, d, l and the forces (through
    the start state too: its acceleration sees the first block's force and the springs)."""
    g = torch.Generator().manual_seed(seed)
    blocks = (0.5 * torch.randn((BLOCKS, body.n_movable, 2), generator=g, dtype=torch.float64)).to(
        body.k.dtype).requires_grad_(True)
    # a displaced, moving start whose displacement and velocity take gradients: the lanes' λ_r, λ_v reach them
    disp = (0.05 * torch.randn((1, body.n_movable, 2), generator=g, dtype=torch.float64)).to(
        body.k.dtype).requires_grad_(True)
    vel = (0.1 * torch.randn((1, body.n_movable, 2), generator=g, dtype=torch.float64)).to(
        body.k.dtype).requires_grad_(True)
    state = body.initial_state(1, external_force=blocks[0], displacement=disp, velocity=vel)
    y = held_force_readout(body, state, blocks, TAU, row, coord)
    body.zero_grad()
    weights = torch.linspace(-1.0, 2.0, BLOCKS, dtype=body.k.dtype) + seed
    (weights * y).sum().backward()
    return [y.detach().clone()] + [t.grad.clone() for t in (body.k, body.d, body.l, blocks, disp, vel)]


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_each_lane_equals_its_window_alone_bit_for_bit(dtype):
    specs = [(seed, 0 if seed % 2 else None, seed % 2) for seed in range(5)]

    def case(seed, row, coord):
        body = _body(seed, dtype)
        return _window(body, seed, body.cmp_local if row is None else row, coord)

    alone = [case(*s) for s in specs]
    gang = Gang()
    together = gang.run([lambda s=s: case(*s) for s in specs])
    # two read coordinates: the CMP's y (3 lanes), mass 0's x (2 lanes): two groups in each of the two rounds
    assert gang.lanes == 5 and gang.rounds == 2
    for a, b in zip(alone, together, strict=True):
        assert not isinstance(b, BaseException), b
        for name, x, y in zip(("readout", "k", "d", "l", "forces", "start position", "start velocity"), a, b,
                              strict=True):
            assert float(x.abs().max()) > 0, name
            assert torch.equal(x, y), (name, float((x - y).abs().max()))


def _narma_raw(seed: int, **over) -> dict:
    narma = {"tau": 5, "n_inputs": 14, "washout": 2, "train_end": 10, "brain_input": "symmetric",
             **over.pop("narma", {})}
    return {"task": "narma", "dtype": "float32", "epochs": 5, "seed": seed,
            "body": {"shape": "double_circle", "nodes": 13}, "brain": {"type": "lil"},
            "training": {"optimizer": "sgd", "backend": "fused", "lr": {"k": 1e3, "d": 1e2, "l": 1.0, "brain": 1e-2},
                         **over.pop("training", {})},
            "narma": narma, **over}


def _narma_cfg(seed: int, **over):
    return validate(_narma_raw(seed, **over))


#: memory targets at three delays, a NARMA target, rates 10× the config's (the guard rejects updates there), and a
#: multiple circle (another topology: a second group in every round)
TRAININGS = [
    (0, {"narma": {"target": "memory", "delay": 1}}),
    (1, {"narma": {"target": "memory", "delay": 3}}),
    (2, {"narma": {"target": "memory", "delay": 5}}),
    (3, {}),
    (4, {"training": {"lr": {"k": 1e5, "d": 1e4, "l": 1e2, "brain": 1.0}}, "narma": {"target": "memory", "delay": 2}}),
    (5, {"body": {"shape": "multiple_circle", "nodes": 17}, "narma": {"target": "memory", "delay": 2}}),
]


def _summary(res):
    return (res.losses, [float(x) for x in res.metrics["evaluation"].values() if isinstance(x, float)],
            res.metrics["guard"]["rejections"])


@pytest.mark.slow
def test_trainings_in_a_gang_equal_the_same_trainings_one_by_one(tmp_path):
    alone = [_summary(train(_narma_cfg(s, **o), tmp_path / f"alone{s}", progress=False)) for s, o in TRAININGS]
    gang = Gang()
    together = gang.run([lambda s=s, o=o: train(_narma_cfg(s, **o), tmp_path / f"gang{s}", progress=False)
                         for s, o in TRAININGS])
    assert gang.lanes == 6 * len(TRAININGS)  # 5 updates and the evaluation, all in lanes
    assert alone[4][2] > 0  # the guard rejected updates: the lockstep survives them
    for i, (a, b) in enumerate(zip(alone, together, strict=True)):
        assert not isinstance(b, BaseException), b
        assert a == _summary(b), i
    for s, _ in TRAININGS:
        for name in ("checkpoint.pt", "metrics.json", "loss.png"):
            assert (tmp_path / f"gang{s}" / name).is_file()
        a = torch.load(tmp_path / f"alone{s}" / "checkpoint.pt", weights_only=True)["modules"]
        b = torch.load(tmp_path / f"gang{s}" / "checkpoint.pt", weights_only=True)["modules"]
        assert a.keys() == b.keys() and a
        for module in a:
            for key in a[module]:
                assert torch.equal(a[module][key], b[module][key]), (s, module, key)


def test_a_failing_member_is_returned_in_its_place_and_the_others_finish():
    def good(seed):
        body = _body(seed, torch.float64)
        return float(_window(body, seed, body.cmp_local, 1)[0].sum())

    def bad():
        raise ValueError("planted")

    def blows_up():
        body = _body(9, torch.float64)
        blocks = torch.full((BLOCKS, body.n_movable, 2), 1e12, dtype=torch.float64)
        held_force_readout(body, body.initial_state(1), blocks, TAU, 0, 1)

    out = run_gang([lambda: good(1), bad, lambda: good(2), blows_up, lambda: 7])
    assert out[0] == good(1) and out[2] == good(2) and out[4] == 7
    assert isinstance(out[1], ValueError) and str(out[1]) == "planted"
    assert isinstance(out[3], SimulationDiverged)


def test_threads_start_one_at_a_time():
    """Member i starts only once members 0 … i−1 wait for the gang: it sees all of them at their first window."""
    submitted, seen_at_start = [0], {}

    def member(seed):
        seen_at_start[seed] = submitted[0]
        torch.manual_seed(seed)  # the trainer's way: seed the global generator, then draw from it
        draw = torch.rand(3)
        body = _body(seed, torch.float64)
        submitted[0] += 1  # the next line hands the first window to the gang
        _window(body, seed, 0, 0)
        return draw

    out = run_gang([lambda s=s: member(s) for s in range(6)])
    assert seen_at_start == {s: s for s in range(6)}
    for s, draw in enumerate(out):
        torch.manual_seed(s)
        assert torch.equal(draw, torch.rand(3))


def test_windows_with_a_ground_run_alone_inside_a_gang():
    from bptsb_ros.body.msdn import Environment

    class Refuses:
        def forward(self, lane):
            raise AssertionError("a window with a ground went to the lane kernel")

        backward = forward

    body = MSDN(double_circle(13), dt=0.01, dtype=torch.float64, backend="numba",
                environment=Environment(gravity=9.8, ground_c=5.0), generator=torch.Generator().manual_seed(0))
    blocks = torch.zeros((BLOCKS, body.n_movable, 2), dtype=torch.float64)
    with as_lanes(Refuses()):
        y = held_force_readout(body, body.initial_state(1), blocks, TAU, 0, 1)
    assert y.shape == (BLOCKS,)


def test_a_second_backward_through_a_lane_is_refused():
    def member():
        body = _body(0, torch.float64)
        blocks = torch.zeros((BLOCKS, body.n_movable, 2), dtype=torch.float64, requires_grad=True)
        y = held_force_readout(body, body.initial_state(1), blocks, TAU, 0, 1)
        y.sum().backward(retain_graph=True)
        with pytest.raises(RuntimeError, match="a second time"):
            y.sum().backward()
        return True

    assert run_gang([member]) == [True]


def test_multiple_circle_lanes_too():
    topo = multiple_circle(17)
    alone = _window(_body(0, torch.float64, topo), 0, 2, 1)
    (together,) = run_gang([lambda: _window(_body(0, torch.float64, topo), 0, 2, 1)])
    for x, y in zip(alone, together, strict=True):
        assert torch.equal(x, y)


def test_a_sweep_in_gangs_records_every_job_as_one_by_one(tmp_path):
    import yaml

    cfg = tmp_path / "memory.yaml"
    cfg.write_text(yaml.safe_dump(_narma_raw(0, narma={"target": "memory", "delay": 2})))
    jobs = train_jobs(cfg, [0, 1, 2])
    one = run_sweep(jobs, tmp_path / "one", workers=0)
    gangs = run_sweep(jobs, tmp_path / "gangs", workers=0, gang=2)
    assert [r["status"] for r in gangs.records] == ["done"] * 3

    def numbers(res):
        return {name: {k: v for k, v in r.items() if k != "train_seconds"} for name, r in res.results().items()}

    assert numbers(gangs) == numbers(one)
    assert len(numbers(one)) == 3 and len({r["loss_last"] for r in numbers(one).values()}) == 3


@pytest.mark.parametrize("bad", [0, -1, 1.5, True, "2"])
def test_a_gang_is_a_whole_number_of_jobs(bad):
    with pytest.raises(SweepError, match="whole number of jobs"):
        gangs_of(3, bad)


def test_gangs_cover_the_jobs_in_order():
    assert gangs_of(5, None) == [range(i, i + 1) for i in range(5)] == gangs_of(5, 1)
    assert gangs_of(5, 2) == [range(0, 2), range(2, 4), range(4, 5)]
    assert gangs_of(4, 9) == [range(0, 4)]
    assert gangs_of(0, 3) == []


def test_bptsb_sweep_gang(tmp_path, capsys):
    import yaml

    from bptsb_ros.cli import main

    cfg = tmp_path / "memory.yaml"
    cfg.write_text(yaml.safe_dump({**_narma_raw(0, narma={"target": "memory", "delay": 2}), "epochs": 2}))
    assert main(["sweep", str(cfg), "--seeds", "0-2", "--gang", "2", "--workers", "0", "--out",
                 str(tmp_path / "s")]) == 0
    assert "3 done, 0 failed" in capsys.readouterr().out
    for seed in range(3):
        assert (tmp_path / "s" / "jobs" / f"seed-{seed}" / "checkpoint.pt").is_file()


def test_a_gang_reports_how_far_it_is(capsys):
    def member(seed):
        body = _body(seed, torch.float64)
        for _ in range(3):
            _window(body, seed, 0, 1)

    run_gang([lambda s=s: member(s) for s in range(2)], report_every_s=0.0)
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 6 and lines[-1].startswith("gang of 2 trainings")
    assert "6 windows in 6 rounds" in lines[-1] and "0 running" not in lines[0]
    run_gang([lambda: member(0)])
    assert capsys.readouterr().err == ""


def test_the_gang_benchmark_and_its_paper_estimate():
    from bptsb_ros.bench import gang_speed as bench_gang

    # 170 trainings × 40,000 updates on 2 workers = 3.4e6 updates each; at 6 ms and 2 ms per update
    assert bench_gang.paper_estimate({"alone_ms_per_update": 6.0, "gang_ms_per_member_update": 2.0}) == {
        "workers": 2, "alone_h": round(3.4e6 * 6e-3 / 3600, 2), "gangs_h": round(3.4e6 * 2e-3 / 3600, 2)}
    entry = bench_gang.measure(members=2, updates=1)
    assert entry["members"] == 2 and entry["updates_timed"] == 1 and entry["alone_ms_per_update"] > 0
    assert entry["gang_ms_per_member_update"] > 0 and entry["gang_windows"] == 2 * (1 + 1)
    assert "error" in bench_gang.measure(members=0, updates=1)
    # as populations too, where measured: at 0.5 ms per member-update
    assert bench_gang.paper_estimate({"alone_ms_per_update": 6.0, "gang_ms_per_member_update": 2.0,
                                      "population_ms_per_member_update": 0.5})["populations_h"] == \
        round(3.4e6 * 0.5e-3 / 3600, 2)
    pop = bench_gang.measure_population(members=2, updates=2)
    assert pop["population_members"] == 2 and pop["population_updates_timed"] == 2
    assert pop["population_ms_per_member_update"] > 0


def test_the_lanes_divergence_test_is_the_bodys():
    from bptsb_ros.body.msdn import DIVERGENCE_LIMIT, BodyState, state_is_sound

    body = _body(0, torch.float64)

    def body_says(r, v, a, dtype=None):
        """check_finite's verdict: float64 on CPU takes the numpy test, float16 torch's reductions."""
        parts = [torch.from_numpy(x) if dtype is None else torch.from_numpy(x).to(dtype) for x in (r, v, a)]
        try:
            body.check_finite(BodyState(*parts, torch.zeros(1), 0))
        except SimulationDiverged:
            return False
        return True

    ok = np.zeros((3, 2))
    cases = [((ok, ok, ok), True)]
    edge = ok.copy()
    edge[1, 0] = -DIVERGENCE_LIMIT
    cases.append(((edge, ok, ok), True))
    beyond = ok.copy()
    beyond[1, 0] = -np.nextafter(DIVERGENCE_LIMIT, np.inf)
    cases.append(((beyond, ok, ok), False))
    for i in range(3):
        bad = [ok, ok, ok]
        bad[i] = np.array([[0.0, np.nan], [np.inf, 0.0], [0.0, 0.0]])
        cases.append((tuple(bad), False))
    for arrays, sound in cases:
        assert state_is_sound(*arrays) is sound
        assert body_says(*arrays) is sound
    # the torch branch (a dtype numpy views do not take), with limits float16 can hold
    small = ok.copy()
    small[0, 1] = 60.0
    assert body_says(small, ok, ok, torch.float16)
    with pytest.raises(SimulationDiverged):
        body.check_finite(BodyState(*(torch.from_numpy(x).to(torch.float16) for x in (small, ok, ok)),
                                    torch.zeros(1), 0), limit=50.0)
    for i in range(3):
        bad = [ok, ok, ok]
        bad[i] = np.array([[0.0, np.nan], [np.inf, 0.0], [0.0, 0.0]])
        assert not body_says(*bad, torch.float16)


def test_a_resumed_sweep_splits_the_jobs_left_into_the_gangs_asked_for(tmp_path):
    import yaml

    cfg = tmp_path / "memory.yaml"
    cfg.write_text(yaml.safe_dump({**_narma_raw(0, narma={"target": "memory", "delay": 2}), "epochs": 1}))
    jobs = train_jobs(cfg, [0, 1, 2])
    run_sweep(jobs[:1], tmp_path / "s", workers=0)
    res = run_sweep(jobs, tmp_path / "s", workers=0, n_gangs=2)  # 2 left: a gang of one each, not one of 2
    assert res.skipped == ["seed-0"] and res.provenance()["jobs"] == 2
    assert [r["status"] for r in res.records] == ["done"] * 3
    with pytest.raises(SweepError, match="not both"):
        run_sweep(jobs, tmp_path / "t", workers=0, gang=2, n_gangs=2)


def test_a_backward_after_the_gang_ended_is_refused_not_left_waiting():
    kept = {}

    def member():
        body = _body(0, torch.float64)
        blocks = torch.zeros((BLOCKS, body.n_movable, 2), dtype=torch.float64, requires_grad=True)
        kept["y"] = held_force_readout(body, body.initial_state(1), blocks, TAU, 0, 1)

    assert run_gang([member]) == [None]
    with pytest.raises(RuntimeError, match="this gang has ended"):
        kept["y"].sum().backward()


def test_a_failing_kernel_call_reaches_every_member_as_its_own_error(monkeypatch):
    import bptsb_ros.jobs.gang as gang_module

    def fails(lanes):
        raise ValueError("planted kernel failure")

    monkeypatch.setattr(gang_module, "run_lanes_forward", fails)
    out = run_gang([lambda s=s: _window(_body(s, torch.float64), s, 0, 1) for s in range(3)])
    assert all(isinstance(e, RuntimeError) and isinstance(e.__cause__, ValueError) for e in out)
    assert "planted kernel failure" in str(out[0]) and len({id(e) for e in out}) == 3
