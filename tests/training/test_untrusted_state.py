"""Resumed states are untrusted data, checked like a checkpoint before any of them is used: a solo training's
checkpoint (``train --resume``), a population's saved state, and the sweep records a resumed sweep (or gang) reuses.
Each hostile state below is planted by editing a real one; each is refused with one line naming the entry, the
file is left as it was, and the untouched state still resumes."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import REPO_ROOT as REPO

from bptsb_ros.cli import main
from bptsb_ros.config import ConfigError, load_config
from bptsb_ros.experiments.common import packaged_config
from bptsb_ros.experiments.timeseries import narma_overrides
from bptsb_ros.training.checkpoint import CheckpointError
from bptsb_ros.workflows.train import train

SMALL = ["narma.n_inputs=30", "narma.washout=5", "narma.train_end=20"]


# -- a solo training's checkpoint -------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def solo_run(tmp_path_factory) -> Path:
    """A 3-update Adam NARMA training (its checkpoint resumable to 5 updates)."""
    run = tmp_path_factory.mktemp("solo") / "run"
    train(load_config(REPO / "config" / "narma_adam.yaml", [*SMALL, "epochs=3"]), run, overwrite=True, progress=False)
    return run


def _scale_lr(p, factor):
    for g in p["extra"]["optimizer"]["param_groups"]:
        g["lr"] *= factor


def _first_moment(p):
    state = p["extra"]["optimizer"]["state"]
    state[0]["exp_avg"] = state[0]["exp_avg"][:3]


SOLO = {  # what is planted -> what the refusal names
    "update 1e9": (lambda p: p["extra"].update(update=10**9), r"extra\.update is 1000000000, outside 0 … 5"),
    "update -20": (lambda p: p["extra"].update(update=-20), r"extra\.update is -20, outside 0 … 5"),
    "k NaN": (lambda p: p["modules"]["body"]["k"].__setitem__(0, float("nan")), r"modules\.body\.k holds a value "
                                                                              "that is not finite"),
    "k cut": (lambda p: p["modules"]["body"].update(k=p["modules"]["body"]["k"][:1]),
              r"modules\.body\.k has shape \(1,\), not \(64,\)"),
    "k negative": (lambda p: p["modules"]["body"]["k"].__setitem__(3, -1.0), r"modules\.body\.k has a negative"),
    "mass changed": (lambda p: p["modules"]["body"]["mass"].mul_(2), r"modules\.body\.mass differs from the one "
                                                                     "the config builds"),
    "rates x -100": (lambda p: _scale_lr(p, -100), r"extra\.optimizer\.param_groups\[0\]\.lr \(k\) is -10\.0; a "
                                                   "learning rate is a finite number > 0"),
    "rates x 100": (lambda p: _scale_lr(p, 100), r"lr \(k\) is 10, above the config's 0\.1"),
    "betas": (lambda p: p["extra"]["optimizer"]["param_groups"][1].update(betas=(0.0, 0.0)),
              r"param_groups\[1\]\.betas is \(0\.0, 0\.0\), not the config's \(0\.9, 0\.999\)"),
    "moment cut": (_first_moment, r"extra\.optimizer\.state\[0\]\.exp_avg has shape \(3,\), not \(64,\)"),
    "adam step": (lambda p: p["extra"]["optimizer"]["state"][1].update(step=torch.tensor(50.0)),
                  r"state\[1\]\.step is 50, outside 0 … 3"),
    "history": (lambda p: p["extra"]["guard"]["history"].append(0.5), r"extra\.guard\.history holds 4 losses, not "
                                                                      "one per update \\(3\\)"),
    "guard count": (lambda p: p["extra"]["guard"].update(count=99), r"extra\.guard\.count is 99, outside 0 … 4"),
    "rng": (lambda p: p["extra"]["task_state"]["rng"].update(bit_generator="MT19937"),
            r"extra\.task_state\.rng\.bit_generator is 'MT19937', not 'PCG64'"),
}


@pytest.mark.parametrize("case", list(SOLO))
def test_a_tampered_checkpoint_does_not_resume(solo_run, tmp_path, case):
    plant, why = SOLO[case]
    run = tmp_path / "run"
    run.mkdir()
    payload = torch.load(solo_run / "checkpoint.pt", weights_only=True)
    plant(payload)
    torch.save(payload, run / "checkpoint.pt")
    before = (run / "checkpoint.pt").read_bytes()
    cfg = load_config(REPO / "config" / "narma_adam.yaml", [*SMALL, "epochs=5"])
    with pytest.raises(CheckpointError, match=why):
        train(cfg, run, resume=True, progress=False)
    assert (run / "checkpoint.pt").read_bytes() == before and [p.name for p in run.iterdir()] == ["checkpoint.pt"]


def test_the_cli_refuses_a_tampered_checkpoint_in_one_line_and_resumes_a_sound_one(solo_run, tmp_path, capsys):
    import shutil

    run = tmp_path / "run"
    shutil.copytree(solo_run, run)
    argv = ["train", str(REPO / "config" / "narma_adam.yaml"), *[a for s in SMALL for a in ("--set", s)],
            "--set", "epochs=5", "--resume", "--out", str(run), "--no-progress"]
    sound = (run / "checkpoint.pt").read_bytes()
    payload = torch.load(run / "checkpoint.pt", weights_only=True)
    payload["extra"]["update"] = -20
    torch.save(payload, run / "checkpoint.pt")
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "extra.update is -20, outside 0 … 5" in err, err
    (run / "checkpoint.pt").write_bytes(sound)
    assert main(argv) == 0
    assert len(json.loads((run / "metrics.json").read_text())["loss"]) == 5


# -- a population's saved state ---------------------------------------------------------------------------------

def _members(epochs: int):
    return [packaged_config("narma_adam", narma_overrides("paper", epochs, "double-circle", "lil", (
        "narma.target=memory", f"narma.delay={dt}", "narma.n_inputs=40", "narma.washout=10", "narma.train_end=30",
        "dtype=float64")), seed=seed) for seed, dt in ((0, 1), (1, 8))]


@pytest.fixture(scope="module")
def population_state(tmp_path_factory):
    """The state of a 2-member population killed after its third update, and the uninterrupted run's losses."""
    import bptsb_ros.workflows.population as population

    mp = pytest.MonkeyPatch()
    where = tmp_path_factory.mktemp("population")
    cfgs = _members(5)
    whole, _ = population.train_population(cfgs, [None, None], progress=False)
    real, calls = population.population_readout, []

    def killed_at_the_fourth_window(*args, **kwargs):
        if len(calls) == 3:
            raise KeyboardInterrupt
        calls.append(1)
        return real(*args, **kwargs)

    mp.setattr(population, "population_readout", killed_at_the_fourth_window)
    try:
        with pytest.raises(KeyboardInterrupt):
            population.train_population(cfgs, [where / "m0", where / "m1"], progress=False,
                                        state_path=where / "population.pt", save_every_s=0)
    finally:
        mp.undo()
    return torch.load(where / "population.pt", weights_only=True), [r.losses for r in whole]


def _cut_first_row(s):
    s["params"]["k"] = s["params"]["k"][:1]


def _scale_rates(s, factor):
    s["rates"] = [[r * factor for r in rates] for rates in s["rates"]]


POPULATION = {
    "k cut to one row": (_cut_first_row, r"params\.k has shape \(1, 64\), not \(2, 64\)"),
    "k NaN": (lambda s: s["params"]["k"].__setitem__((1, 0), float("nan")), r"params\.k holds a value that is not"),
    "update 1e9": (lambda s: s.update(update=10**9), r"update is 1000000000, outside 0 … 5"),
    "update -20": (lambda s: s.update(update=-20), r"update is -20, outside 0 … 5"),
    "rates x -100": (lambda s: _scale_rates(s, -100), r"rates\[0\] \(k\) is -10\.0; a learning rate is a finite"),
    "rates x 100": (lambda s: _scale_rates(s, 100), r"rates\[0\] \(k\) is 10, above the config's 0\.1"),
    "steps": (lambda s: s["steps"].fill_(1e9), r"steps\[0\] is 1000000000, outside 0 … 3"),
    "moment shape": (lambda s: s["moments"][0].__setitem__(0, s["moments"][0][0][:, :2]),
                     r"moments\[0\]\[0\] has shape \(2, 2\), not \(2, 64\)"),
    "second moment negative": (lambda s: s["moments"][0][1].fill_(-1.0), r"moments\[0\]\[1\] \(Adam's second"),
    "every member inactive": (lambda s: s.update(active=[False, False]), r"the stopped members \[0, 1\] are not "
                                                                         r"those with a recorded failure \[\]"),
    "a member too many": (lambda s: s["rates"].append(s["rates"][0]), r"rates is not a list of one entry per "
                                                                      r"member \(2\)"),
    "history NaN": (lambda s: s["guards"][1]["history"].__setitem__(0, float("nan")), r"guards\[1\]\.history\[0\] "
                                                                                       "is nan, not a finite number"),
    "guard rate": (lambda s: s["guards"][0]["saved"]["optimizer"]["param_groups"][2].update(lr=-1.0),
                   r"guards\[0\]\.saved\.optimizer \(l\) is -1"),
    "rng": (lambda s: s["rngs"].__setitem__(0, {"bit_generator": "PCG64", "state": "x"}),
            r"rngs\[0\] is not a state of the member's random generator"),
    "failure index": (lambda s: s.update(failures=[[7, "x"]]), r"stopped members \[\] are not those with a"),
}


@pytest.mark.parametrize("case", list(POPULATION))
def test_a_tampered_population_state_does_not_resume(population_state, tmp_path, case):
    from bptsb_ros.workflows.population import train_population

    state, _ = population_state
    plant, why = POPULATION[case]
    tampered = copy.deepcopy(state)
    plant(tampered)
    path = tmp_path / "population.pt"
    torch.save(tampered, path)
    before = path.read_bytes()
    with pytest.raises(ConfigError, match=why) as err:
        train_population(_members(5), [tmp_path / "m0", tmp_path / "m1"], progress=False, state_path=path)
    assert "\n" not in str(err.value) and "is not a state this population could have saved" in str(err.value)
    assert path.read_bytes() == before  # refused, not removed: nothing is lost


def test_the_sound_population_state_resumes_to_the_uninterrupted_numbers(population_state, tmp_path):
    from bptsb_ros.workflows.population import train_population

    state, losses = population_state
    path = tmp_path / "population.pt"
    torch.save(state, path)
    resumed, failures = train_population(_members(5), [tmp_path / "m0", tmp_path / "m1"], progress=False,
                                         state_path=path)
    assert not failures and [r.losses for r in resumed] == losses and not path.exists()


# -- the records a resumed sweep (or gang) reuses -------------------------------------------------------------------

def _population_result(members, seeds):
    return {name: {"seed": seed, "nmse": 0.5, "loss_last_1": 0.1, "train_seconds": 1.0}
            for name, seed in zip(members, seeds)}


def test_a_sweep_reuses_only_records_that_fit_the_job(tmp_path):
    """A finished record whose result names another job's trainings (a population job's result maps member names
    to results, merged into one table by the experiments), lacks a member, gives another seed or a negative NMSE,
    is not trusted: the job runs again."""
    from bptsb_ros.experiments.timeseries import NarmaJob, NarmaPopulationJob
    from bptsb_ros.jobs.sweep import Job, job_key, result_problem

    members = tuple((f"lil_dt{d}_s{s}", NarmaJob("narma_adam", {}, s, (1,), 50)) for d, s in ((1, 0), (8, 1)))
    job = Job("population0_0", NarmaPopulationJob(members))
    names = [m[0] for m in members]
    good = _population_result(names, (0, 1))
    assert result_problem(job, good) is None
    assert "names 'lil_dt17_s0', not a member" in result_problem(job, {**good, "lil_dt17_s0": good[names[0]]})
    assert "lacks a member's result" in result_problem(job, {names[0]: good[names[0]]})
    assert "of seed 5, not 1" in result_problem(job, {**good, names[1]: {**good[names[1]], "seed": 5}})
    assert "its nmse is -3.0, not a number ≥ 0" in result_problem(job, {**good, names[1]: {**good[names[1]],
                                                                                           "nmse": -3.0}})
    assert result_problem(job, {**good, names[1]: {"diverged": "TrainingDiverged: update 3"}}) is None
    solo = Job("lil_dt1_s0", members[0][1])
    assert "of seed 7, not 0" in result_problem(solo, {"seed": 7, "nmse": 0.2})
    # in a sweep directory: the record is not trusted, with one line, and the job would run again
    from bptsb_ros.jobs.sweep import _manifest, finished_record

    run_dir = tmp_path / "jobs" / job.name
    run_dir.mkdir(parents=True)
    record = {"name": job.name, "key": job_key(job), "status": "done", "wall_s": 1.0, "files": _manifest(run_dir),
              "result": {**good, "lil_dt17_s0": good[names[0]]}}
    (run_dir / "job.json").write_text(json.dumps(record))
    assert finished_record(job, run_dir, job_key(job)) == (None, "its result names 'lil_dt17_s0', not a member of "
                                                                 "this job (2 members)")
    record["result"] = good
    (run_dir / "job.json").write_text(json.dumps(record))
    assert finished_record(job, run_dir, job_key(job))[0] == record
    assert np.isclose(record["result"][names[0]]["nmse"], 0.5)


# -- strict JSON -------------------------------------------------------------------------------------------------

def _strict(text: str):
    def refuse(constant):
        raise ValueError(f"{constant} is not JSON")

    return json.loads(text, parse_constant=refuse)


def test_metrics_json_is_strict_json_whatever_the_numbers(tmp_path, monkeypatch):
    """A training time or an evaluation that is not finite is written as null (JSON has no NaN), not as the
    invalid NaN that json.dumps writes by default."""
    import bptsb_ros.workflows.train as trainer

    real = trainer.training_metrics

    def nan_time(*args, **kwargs):
        metrics = real(*args, **kwargs)
        metrics["train_seconds"] = float("nan")
        metrics["guard"]["rates"]["k"] = float("inf")
        return metrics

    monkeypatch.setattr(trainer, "training_metrics", nan_time)
    res = train(load_config(REPO / "config" / "narma_adam.yaml", [*SMALL, "epochs=2"]), tmp_path / "run",
                progress=False)
    assert np.isnan(res.metrics["train_seconds"])  # the result in memory keeps the number
    written = _strict((tmp_path / "run" / "metrics.json").read_text())
    assert written["train_seconds"] is None and written["guard"]["rates"]["k"] is None
    assert written["evaluation"]["nmse_test"] == res.metrics["evaluation"]["nmse_test"]


def test_a_population_state_with_an_impossible_time_or_all_members_stopped(population_state, tmp_path):
    """seconds NaN is refused; every member stopped, each with its recorded failure, is a state a population can
    reach (all diverged): it resumes to no result and every failure, without a KeyError."""
    from bptsb_ros.workflows.population import train_population

    state, _ = population_state
    path = tmp_path / "population.pt"
    bad = copy.deepcopy(state)
    bad["seconds"] = float("nan")
    torch.save(bad, path)
    with pytest.raises(ConfigError, match="seconds is nan, not a time ≥ 0"):
        train_population(_members(5), [tmp_path / "m0", tmp_path / "m1"], progress=False, state_path=path)
    stopped = copy.deepcopy(state)
    stopped["active"] = [False, False]
    stopped["failures"] = [[0, "update 1: loss is nan"], [1, "update 2: diverged"]]
    torch.save(stopped, path)
    results, failures = train_population(_members(5), [tmp_path / "m0", tmp_path / "m1"], progress=False,
                                         state_path=path)
    assert results == [None, None] and [(f.index, str(f.error)) for f in failures] == [
        (0, "update 1: loss is nan"), (1, "update 2: diverged")]


def test_a_full_disk_during_a_periodic_checkpoint_is_one_line_and_keeps_the_last_one(tmp_path, monkeypatch, capsys):
    import errno

    import bptsb_ros.files.safe_write as safe_files

    real, written = safe_files.temp_file_beside, []

    class Full:
        """A file whose writes fail as on a full disk (after the first checkpoint)."""

        def __init__(self, f):
            self.f, self.name = f, f.name

        def write(self, data):
            raise OSError(errno.ENOSPC, "No space left on device")

        def __getattr__(self, name):
            return getattr(self.f, name)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.f.close()

    def full_after_one(path, mode="wb", suffix=".tmp"):
        f, tmp = real(path, mode, suffix)
        if Path(path).name == "checkpoint.pt":
            written.append(path)
            if len(written) > 1:
                return Full(f), tmp
        return f, tmp

    monkeypatch.setattr(safe_files, "temp_file_beside", full_after_one)
    run = tmp_path / "run"
    argv = ["train", str(REPO / "config" / "narma_adam.yaml"), *[a for s in SMALL for a in ("--set", s)],
            "--set", "epochs=4", "--set", "training.checkpoint_every=1", "--out", str(run), "--no-progress"]
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert err.strip().splitlines()[-1] == f"bptsb train: cannot write {run / 'checkpoint.pt'}: No space left on device"
    assert "Traceback" not in err and len(written) == 2
    kept = torch.load(run / "checkpoint.pt", weights_only=True)
    assert kept["extra"]["update"] == 1  # the last checkpoint that was written, whole
    assert not [p.name for p in run.iterdir() if p.name.endswith(".tmp")]
