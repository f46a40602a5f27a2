"""Population training (bptsb_ros/workflows/population.py): every member is its solo training bit for bit —
losses, parameters, the guard's events, the evaluation — under SGD and Adam, float32 and float64, with rejections
and rate divisions; a diverging member stops alone (or, with something to undo, is restored as alone); the
checkpoints resume in the solo trainer; an interrupted population goes on from its state; the sweep's population
jobs give the solo jobs' results."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from bptsb_ros.experiments.common import packaged_config
from bptsb_ros.experiments.timeseries import narma_overrides

SMALL = ("narma.n_inputs=40", "narma.washout=10", "narma.train_end=30")


def configs(name: str, epochs: int, *extra: str, members=((0, 1), (1, 8), (2, 3)), body: str = "double-circle",
            dtype: str = "float64"):
    return [packaged_config(name, narma_overrides("paper", epochs, body, "lil", (
        "narma.target=memory", f"narma.delay={dt}", *SMALL, f"dtype={dtype}", *extra)), seed=seed)
            for seed, dt in members]


def parameters(agent) -> list[torch.Tensor]:
    return [t.detach() for t in (agent.body.k, agent.body.d, agent.body.l, agent.brain.weight, agent.brain.bias)]


def assert_same_training(solo, member) -> None:
    """Bit for bit: the population's step is torch's SGD / Adam arithmetic, its window the solo window's."""
    assert solo.losses == member.losses
    for x, y in zip(parameters(solo.agent), parameters(member.agent)):
        assert torch.equal(x, y), float((x - y).abs().max())
    events = [[(e["update"], e["reason"], e["count"], e["divided"]) for e in r.metrics["guard"]["events"]]
              for r in (solo, member)]
    assert events[0] == events[1]
    assert solo.metrics["guard"]["rates"] == member.metrics["guard"]["rates"]
    assert member.metrics["evaluation"]["nmse_test"] == solo.metrics["evaluation"]["nmse_test"]


# a low spike factor makes the guard reject often; with Adam and these rates it also divides the members' rates at
# different updates (then accepts again), and the clamp holds some k and d at 0
GUARDED = {"narma": (12, ("training.reject_factor=1.2",)),
           "narma_adam": (20, ("training.reject_factor=1.25", "training.lr.d=0.3", "training.lr.k=3"))}


@pytest.mark.parametrize("dtype", ["float64", "float32"])
@pytest.mark.parametrize("name", ["narma", "narma_adam"])
def test_every_member_is_its_solo_training_with_rejections_and_divisions(name, dtype):
    from bptsb_ros.workflows.population import train_population
    from bptsb_ros.workflows.train import train

    epochs, extra = GUARDED[name]
    cfgs = configs(name, epochs, *extra, dtype=dtype)
    results, failures = train_population(cfgs, [None] * len(cfgs), progress=False)
    assert failures == []
    events, divided_at, zeros = 0, set(), 0
    for cfg, member in zip(cfgs, results):
        solo = train(cfg, None, progress=False)
        assert_same_training(solo, member)
        events += len(solo.metrics["guard"]["events"])
        divided_at |= {e["update"] for e in solo.metrics["guard"]["events"] if e["divided"]}
        zeros += sum(int((t == 0).sum()) for t in (solo.agent.body.k, solo.agent.body.d))
    assert events >= 3  # the restore path ran (the test covers the guard's views of the stacked parameters)
    if name == "narma_adam" and dtype == "float64":  # rates divided at different updates; the clamp acted
        assert len(divided_at) >= 2 and zeros >= 1, (divided_at, zeros)


def test_members_differ_from_each_other():
    """Stacking keeps members apart: equal configs give equal members, another seed another training."""
    from bptsb_ros.workflows.population import train_population

    cfgs = configs("narma_adam", 4, members=((0, 3), (0, 3), (5, 3)))
    results, _ = train_population(cfgs, [None] * 3, progress=False)
    a, b, c = (parameters(r.agent) for r in results)
    assert all(torch.equal(x, y) for x, y in zip(a, b))
    assert not torch.allclose(a[0], c[0])


def test_a_diverging_member_stops_alone(monkeypatch, tmp_path):
    import bptsb_ros.workflows.population as population
    from bptsb_ros.workflows.train import TrainingDiverged, train

    real = population.population_readout

    def second_member_blows_up(*args, **kwargs):
        win = real(*args, **kwargs)
        win.sound[1] = False  # as if member 1's state had left the sensible range in this window
        return win

    monkeypatch.setattr(population, "population_readout", second_member_blows_up)
    cfgs = configs("narma_adam", 3)
    dirs = [tmp_path / f"m{i}" for i in range(3)]
    results, failures = population.train_population(cfgs, dirs, progress=False)
    assert [f.index for f in failures] == [1] and results[1] is None
    assert isinstance(failures[0].error, TrainingDiverged)
    assert "update 0: simulation diverged at step 800" in str(failures[0].error)
    assert "nothing to undo" in str(failures[0].error)
    report = json.loads((dirs[1] / "diverged.json").read_text())
    assert report["update"] == 0 and not (dirs[1] / "checkpoint.pt").exists()
    monkeypatch.setattr(population, "population_readout", real)
    for i in (0, 2):  # the others trained on, as alone
        assert_same_training(train(cfgs[i], None, progress=False), results[i])


def test_a_member_that_diverges_with_something_to_undo_is_restored_as_alone(monkeypatch):
    """Member 1's window of update 2 diverges (planted); its guard restores the parameters from before update 1's
    step, as the solo trainer's does when the same window diverges there; every member equals its solo run."""
    import bptsb_ros.workflows.population as population
    from bptsb_ros.body.msdn import MSDN, SimulationDiverged
    from bptsb_ros.workflows.train import train

    real, calls = population.population_readout, []

    def diverges_at_update_2(*args, **kwargs):
        win = real(*args, **kwargs)
        calls.append(1)
        if len(calls) == 3:
            win.sound[1] = False
        return win

    monkeypatch.setattr(population, "population_readout", diverges_at_update_2)
    cfgs = configs("narma_adam", 6)
    results, failures = population.train_population(cfgs, [None] * 3, progress=False)
    monkeypatch.setattr(population, "population_readout", real)
    assert failures == []
    events = results[1].metrics["guard"]["events"]
    assert [(e["update"], e["reason"]) for e in events] == [(2, "diverged")]
    assert "simulation diverged at step 800" in events[0]["detail"]
    check, seen = MSDN.check_finite, []

    def solo_diverges_at_update_2(self, state, *args, **kwargs):  # the solo window's divergence test, planted
        seen.append(1)
        if len(seen) == 3:
            raise SimulationDiverged("planted")
        return check(self, state, *args, **kwargs)

    for i, cfg in enumerate(cfgs):
        seen.clear()
        if i == 1:
            monkeypatch.setattr(MSDN, "check_finite", solo_diverges_at_update_2)
        solo = train(cfg, None, progress=False)
        monkeypatch.setattr(MSDN, "check_finite", check)
        assert_same_training(solo, results[i])


def test_a_member_whose_evaluation_diverges_fails_alone(monkeypatch, tmp_path):
    from bptsb_ros.body.msdn import SimulationDiverged
    from bptsb_ros.tasks.narma import NarmaTask
    from bptsb_ros.workflows.population import train_population

    evaluate = NarmaTask.evaluate

    def second_seed_diverges(self):
        if self.cfg.seed == 1:
            raise SimulationDiverged("planted evaluation divergence")
        return evaluate(self)

    monkeypatch.setattr(NarmaTask, "evaluate", second_seed_diverges)
    dirs = [tmp_path / f"m{i}" for i in range(3)]
    results, failures = train_population(configs("narma_adam", 2), dirs, progress=False)
    assert [f.index for f in failures] == [1] and results[1] is None
    assert "evaluation: planted evaluation divergence" in str(failures[0].error)
    assert (dirs[1] / "diverged.json").is_file() and not (dirs[1] / "checkpoint.pt").exists()
    assert all((dirs[i] / "checkpoint.pt").is_file() for i in (0, 2))


@pytest.mark.parametrize("extra", [(), GUARDED["narma_adam"][1]], ids=["plain", "guarded"])
def test_member_checkpoints_resume_in_the_solo_trainer(tmp_path, extra):
    """Plain: every update accepted, so the resumed steps depend on Adam's moments and step count in the
    checkpoint; guarded: rejections before and after the resume restore the guard's saved state."""
    from bptsb_ros.workflows.population import train_population
    from bptsb_ros.workflows.train import train

    short = configs("narma_adam", 5, *extra, members=((1, 8),))
    train_population(short, [tmp_path / "run"], progress=False)
    assert (tmp_path / "run" / "metrics.json").is_file() and (tmp_path / "run" / "loss.png").is_file()
    long = configs("narma_adam", 10, *extra, members=((1, 8),))[0]
    resumed = train(long, tmp_path / "run", resume=True, progress=False)
    assert_same_training(train(long, None, progress=False), resumed)


def test_population_readout_is_each_bodys_held_window():
    """B bodies with their own k, d, l and forces: each lane's output and every gradient equal the solo
    held_force_readout's (float64)."""
    from bptsb_ros.agent import build_agent
    from bptsb_ros.body.held_window import held_force_readout, population_readout

    body = build_agent(configs("narma", 1)[0]).body
    gen = torch.Generator().manual_seed(3)
    b, n_blocks, m = 3, 6, body.n_movable
    k = (body.k.detach() * (1 + 0.3 * torch.rand(b, body.k.shape[0], generator=gen, dtype=torch.float64)))
    d = (body.d.detach() * (1 + 0.3 * torch.rand(b, body.d.shape[0], generator=gen, dtype=torch.float64)))
    l = (body.l.detach() * (1 + 0.05 * torch.rand(b, body.l.shape[0], generator=gen, dtype=torch.float64)))  # noqa: E741
    blocks = torch.randn(b, n_blocks, m, 2, generator=gen, dtype=torch.float64)
    weights = torch.randn(b, n_blocks, generator=gen, dtype=torch.float64)
    leaves = [t.clone().requires_grad_(True) for t in (k, d, l, blocks)]
    r0 = body.positions0[body.movable_index].expand(b, -1, -1)
    v0 = torch.zeros_like(r0)
    a0, _ = body.acceleration(r0, v0, leaves[2], leaves[3][:, 0], k=leaves[0], d=leaves[1])
    win = population_readout(body, r0, v0, a0, *leaves[:3], leaves[3], 5, body.cmp_local, 1)
    (win.y * weights).sum().backward()
    assert win.sound.all() and win.y.shape == (b, n_blocks)
    for i in range(b):
        with torch.no_grad():
            body.k.copy_(k[i]), body.d.copy_(d[i]), body.l.copy_(l[i])
        f = blocks[i].clone().requires_grad_(True)
        state = body.initial_state(1, external_force=f[0])
        y = held_force_readout(body, state, f, 5, body.cmp_local, 1)
        for p in (body.k, body.d, body.l):
            p.grad = None
        (y * weights[i]).sum().backward()
        assert torch.equal(y.detach(), win.y[i].detach())
        for solo, stacked in ((body.k.grad, leaves[0].grad[i]), (body.d.grad, leaves[1].grad[i]),
                              (body.l.grad, leaves[2].grad[i]), (f.grad, leaves[3].grad[i])):
            assert torch.allclose(solo, stacked, rtol=1e-12, atol=1e-12 * float(solo.abs().max()))


def test_what_can_train_as_one_population():
    from bptsb_ros.workflows.population import population_unsupported

    cfgs = configs("narma", 2)
    assert population_unsupported(cfgs) is None  # seeds and delays differ: fine
    assert population_unsupported([]) == "there are no trainings"
    mlp = packaged_config("narma", narma_overrides("paper", 2, "double-circle", "mlp", SMALL), seed=0)
    assert population_unsupported([mlp]) == "brain 'mlp' is not an LIL"
    other_rate = configs("narma", 2, "training.lr.k=5")[0]
    assert population_unsupported([cfgs[0], other_rate]) == "training 1 differs from the first in training.lr.k"
    other_body = configs("narma", 2, body="multiple-circle")[0]
    assert "body.nodes" in population_unsupported([cfgs[0], other_body])
    assert population_unsupported(configs("narma", 2, "training.backend=numba")) == \
        "training.backend is not fused with the adjoint"
    assert population_unsupported(configs("narma", 2, "training.optimizer=adam")) is None


def test_population_jobs_give_the_solo_jobs_results(tmp_path):
    from bptsb_ros.experiments.timeseries import NarmaJob, job_dir, population_jobs
    from bptsb_ros.jobs.sweep import Job

    jobs = []
    for body in ("double-circle", "multiple-circle"):
        for seed, dt in ((0, 1), (1, 4), (2, 2)):
            over = narma_overrides("smoke", 3, body, "lil", ("narma.target=memory", f"narma.delay={dt}", *SMALL[:3]))
            jobs.append(Job(f"{body}_{dt}_{seed}", NarmaJob("narma_adam", over, seed, (3,), 60, washout=10)))
    grouped, where = population_jobs(jobs, 2)
    assert [len(j.fn.members) for j in grouped] == [2, 1, 2, 1]  # two per body, of consecutive jobs
    assert [m for j in grouped for m, _ in j.fn.members] == [j.name for j in jobs]
    assert job_dir(tmp_path, jobs[4].name, where) == tmp_path / "jobs" / where[jobs[4].name] / jobs[4].name
    assert job_dir(tmp_path, "solo") == tmp_path / "jobs" / "solo"
    pop = grouped[0]
    out = pop.fn(tmp_path / pop.name)
    for name, job in pop.fn.members:
        solo = job(tmp_path / "solo" / name)
        assert out[name]["nmse"] == pytest.approx(solo["nmse"], rel=1e-6)
        assert out[name]["loss_last_3"] == pytest.approx(solo["loss_last_3"], rel=1e-6)
        with np.load(tmp_path / pop.name / name / "states_3.npz") as a, \
                np.load(tmp_path / "solo" / name / "states_3.npz") as b:
            assert np.allclose(a["positions"], b["positions"], rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("extra", [(), GUARDED["narma_adam"][1],
                                   ("training.reject_factor=1.01", "training.reject_patience=1", "STOP")],
                         ids=["plain", "guarded", "divided-and-stopped"])
def test_an_interrupted_population_goes_on_from_its_saved_state(monkeypatch, tmp_path, extra):
    """Killed after its third update (the state saved after every update), the population started again goes on
    from update 3 to the numbers of an uninterrupted run, bit for bit (plain: every step counts, Adam's moments
    included; guarded: with rejections; divided-and-stopped: rates divided and a member stopped before the
    interruption); the state file is removed at the end; a state of other trainings is refused, with one line."""
    import bptsb_ros.workflows.population as population
    from bptsb_ros.config import ConfigError

    stop = "STOP" in extra  # member 2 cannot go on from update 0 (planted divergence, nothing to undo)
    cfgs = configs("narma_adam", 6, *(e for e in extra if e != "STOP"))
    real, calls = population.population_readout, []

    def planted(*args, **kwargs):
        win = real(*args, **kwargs)
        if stop and not calls:
            win.sound[2] = False
        return win

    monkeypatch.setattr(population, "population_readout", planted)
    whole, whole_failures = population.train_population(cfgs, [None] * 3, progress=False)
    assert len(whole_failures) == int(stop)
    calls.clear()

    def killed_at_the_fourth_window(*args, **kwargs):
        if len(calls) == 3:
            raise KeyboardInterrupt
        win = planted(*args, **kwargs)
        calls.append(1)
        return win

    state = tmp_path / "population.pt"
    dirs = [tmp_path / f"m{i}" for i in range(3)]
    monkeypatch.setattr(population, "population_readout", killed_at_the_fourth_window)
    with pytest.raises(KeyboardInterrupt):
        population.train_population(cfgs, dirs, progress=False, state_path=state, save_every_s=0)
    assert torch.load(state, weights_only=True)["update"] == 3
    monkeypatch.setattr(population, "population_readout", real)  # (a stopped member stays stopped: the state)
    with pytest.raises(ConfigError, match="state of another population"):
        population.train_population(configs("narma_adam", 6, members=((0, 1), (1, 8), (2, 4))), dirs,
                                    overwrite=True, progress=False, state_path=state)
    resumed, failures = population.train_population(cfgs, dirs, progress=False, state_path=state)
    assert not state.exists()
    def stopped(fs):  # the error without its last part (where the member's files are: here a directory)
        return [(f.index, str(f.error).rsplit(" (", 1)[0]) for f in fs]

    assert stopped(failures) == stopped(whole_failures)
    if stop:
        assert whole[2] is None and resumed[2] is None
        divided = [e for r in whole[:2] for e in r.metrics["guard"]["events"] if e["divided"] and e["update"] < 3]
        assert divided  # rates divided before the interruption: the resumed rates are the saved ones
    for a, b in zip(whole, resumed):
        if a is None:
            continue
        assert a.losses == b.losses
        assert all(torch.equal(x, y) for x, y in zip(parameters(a.agent), parameters(b.agent)))
        assert a.metrics["guard"]["events"] == b.metrics["guard"]["events"]


def test_run_jobs_treats_a_diverged_population_member_as_a_failed_training(tmp_path):
    from bptsb_ros.experiments.timeseries import NarmaPopulationJob, run_jobs
    from bptsb_ros.jobs.sweep import Job

    class Done:  # what the sweep returns for one population job, one member diverged
        failed: list = []

        def results(self):
            return {"population0_0": {"a": {"nmse": 0.5}, "b": {"diverged": "TrainingDiverged: update 3: boom; x"}}}

    class Ctx:
        def sweep(self, jobs, out_dir, what, gangs):
            return Done()

    jobs = [Job("population0_0", NarmaPopulationJob(()))]
    with pytest.raises(RuntimeError, match="1 of 2 population trainings diverged; first: b: TrainingDiverged: "
                                           "update 3: boom"):
        run_jobs(Ctx(), jobs, tmp_path)
    assert run_jobs(Ctx(), jobs, tmp_path, diverged_ok=True) == {"a": {"nmse": 0.5},
                                                                 "b": {"diverged": "update 3: boom"}}
