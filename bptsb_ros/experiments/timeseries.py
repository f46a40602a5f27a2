"""Helpers shared by the time-series experiments (NARMA emulation, memory task, IPC): the 1-D chain
counter-example, thread settings, parallel jobs."""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from bptsb_ros.body.shapes import Topology, nodes_for_movable
from bptsb_ros.config import Overrides, override_mapping


def chain_topology(n_movable: int = 8, spacing: float = 0.5) -> Topology:
    """Masses on the x-axis joined to their nearest and next-nearest neighbours, both ends fixed: the
    supplement's counter-example of a body that stays linear when forces act along the line only."""
    n = n_movable + 2
    positions = np.stack([spacing * np.arange(n), np.zeros(n)], axis=1)
    springs = [(i, i + 1) for i in range(n - 1)] + [(i, i + 2) for i in range(n - 2)]
    fixed = np.zeros(n, dtype=bool)
    fixed[[0, -1]] = True
    return Topology("chain", positions, np.array(springs), fixed, -1)


def one_torch_thread() -> None:
    """Run torch on one thread: the bodies are tiny (tens of masses), so per-op overhead dominates and a second
    thread only adds synchronisation (measured here: ~3,000 vs ~100 batched steps/s on a busy 2-core machine).
    Parallelism comes from independent jobs instead (see :func:`run_jobs`)."""
    torch.set_num_threads(1)


#: the time-series experiments' bodies: N_mov = 17 movable masses each. Double circle: 33 masses (16 fixed);
#: multiple circle: 37 masses (3 rings, the outer 20 fixed), whose 17 movable masses match the paper's N_mov = 17
#: and its per-mass IPC figure (IDs 0…16, the innermost ring joined to the CMP).
N_MOV = 17
BODIES = {"double-circle": ("double_circle", nodes_for_movable("double_circle", N_MOV)),
          "multiple-circle": ("multiple_circle", nodes_for_movable("multiple_circle", N_MOV))}


#: the brain sees 20·(2u − 1) as in the published code, not 20·u: a zero-bias ReLU MLP is exactly linear on a
#: non-negative input, so with the paper's literal (0, 20) the MLP brain adds no nonlinearity (measured: the
#: trained MLP system's output had 3rd-order capacity < 1e-6); the target still uses u in [0, 1]
BRAIN_INPUT = "symmetric"


def narma_overrides(scale: str, epochs: int, body: str, brain: str, extra: Overrides = ()) -> dict[str, Any]:
    """Overrides of the packaged NARMA config for one system of the time-series experiments, ``extra`` (``--set``
    texts of the settings or a mapping) last."""
    shape, nodes = BODIES[body]
    return {"epochs": epochs, "body.shape": shape, "body.nodes": nodes, "brain.type": brain,
            "narma.brain_input": BRAIN_INPUT, **override_mapping(extra)}


@dataclass(frozen=True)
class NarmaJob:
    """Train one time-series system (a sweep job) and record its block-end states on a long held-out input.

    After each epoch count in ``stages`` (0 = untrained) the agent runs, in float64, on ``eval_inputs`` inputs
    u ~ U(0, 1) from ``eval_seed``; the movable masses' positions at every block end are saved to
    ``run_dir/states_<epochs>.npz`` (``u``, ``positions`` (K, M, 2), ``movable``, ``cmp_index``, ``target``).
    Returns the NMSE of the CMP's y against the task's target after ``washout`` inputs, per stage.
    """

    config: str
    overrides: Mapping[str, Any]
    seed: int
    stages: tuple[int, ...]
    eval_inputs: int
    eval_seed: int = 777
    washout: int = 100

    def __call__(self, run_dir: Path) -> dict[str, Any]:
        from bptsb_ros.agent import build_agent
        from bptsb_ros.training.checkpoint import load_agent
        from bptsb_ros.workflows.train import train

        one_torch_thread()
        out: dict[str, Any] = {"seed": self.seed}
        trained = 0
        for epochs in self.stages:
            cfg = self.stage_config(epochs)
            if epochs == 0:  # the initial agent train() builds (same seed), in float64
                torch.manual_seed(cfg.seed)
                agent = build_agent(cfg)
            else:
                # a rerun of a killed job starts its first stage afresh (the job owns run_dir)
                res = train(cfg, run_dir / "agent", resume=trained > 0, overwrite=trained == 0, progress=False)
                trained = epochs
                out[f"loss_last_{epochs}"] = res.losses[-1]
                out["train_seconds"] = res.metrics["train_seconds"]
                agent = load_agent(run_dir / "agent", dtype=torch.float64)
            self.record(agent, cfg, run_dir, epochs, out)
        out["nmse"] = out[f"nmse_{self.stages[-1]}"]
        return out

    def result_problem(self, result: dict[str, Any]) -> str | None:
        """Why a recorded result cannot be this job's (the sweep asks before reusing it): its NMSEs, losses and
        training time are numbers ≥ 0 (``"nan"`` or ``"inf"`` as the record writes a non-finite one)."""
        for key, value in result.items():
            if not key.startswith(("nmse", "loss_last", "train_seconds")) or value in ("nan", "inf"):
                continue
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not value >= 0:
                return f"its {key} is {str(value)[:40]}, not a number ≥ 0"
        return None

    def stage_config(self, epochs: int) -> Any:
        """The config trained up to ``epochs`` (0: the untrained agent's, in float64)."""
        from bptsb_ros.experiments.common import packaged_config

        if epochs == 0:
            return packaged_config(self.config, {**self.overrides, "dtype": "float64"}, seed=self.seed)
        return packaged_config(self.config, {**self.overrides, "epochs": epochs}, seed=self.seed)

    def record(self, agent: Any, cfg: Any, run_dir: Path, epochs: int, out: dict[str, Any]) -> None:
        """Run ``agent`` (trained ``epochs``) on the held-out input: ``out["nmse_<epochs>"]`` and
        ``run_dir/states_<epochs>.npz``."""
        from bptsb_ros.sim.inputs import narma_inputs
        from bptsb_ros.tasks.narma import NarmaTask, nmse

        u = narma_inputs(self.eval_seed, self.eval_inputs)
        task = NarmaTask(agent, cfg)
        pos = task.block_positions(u)
        target = task.target(u)
        cmp_y = pos[:, agent.body.cmp_local, 1]
        out[f"nmse_{epochs}"] = nmse(cmp_y[self.washout:], target[self.washout:])
        from bptsb_ros.files.safe_write import atomic_writer

        with atomic_writer(run_dir / f"states_{epochs}.npz") as f:
            np.savez(f, u=u, positions=pos, target=target, movable=agent.body.topology.movable,
                     cmp_index=agent.body.topology.cmp_index)


@dataclass(frozen=True)
class NarmaPopulationJob:
    """Train :class:`NarmaJob` s of one topology (one training stage each) as one population
    (:mod:`bptsb_ros.workflows.population`: their episodes one batched simulation, each member's numbers its solo
    training's to rounding). Member ``name`` gets the directory ``run_dir/name`` a :class:`NarmaJob` writes;
    returns ``{name: that job's result}``, for a member that diverged ``{"diverged": "TrainingDiverged: …"}``
    (:func:`run_jobs` treats it as a failed training)."""

    members: tuple[tuple[str, NarmaJob], ...]

    def __call__(self, run_dir: Path) -> dict[str, Any]:
        from bptsb_ros.training.checkpoint import load_agent
        from bptsb_ros.workflows.population import train_population

        one_torch_thread()
        for name, job in self.members:
            if len(job.stages) != 1 or job.stages[0] < 1:
                raise ValueError(f"{name}: a population member trains one stage of >= 1 epochs, got {job.stages}")
        cfgs = [job.stage_config(job.stages[0]) for _, job in self.members]
        dirs = [run_dir / name / "agent" for name, _ in self.members]
        # a rerun of a killed population goes on from its last saved state (every 10 minutes); the job owns
        # run_dir, so a state of other trainings left there is discarded
        results, failures = train_population(cfgs, dirs, overwrite=True, desc=run_dir.name,
                                             state_path=run_dir / "population.pt", stale_state="discard")
        out: dict[str, Any] = {self.members[f.index][0]: {"diverged": f"TrainingDiverged: {f.error}"}
                               for f in failures}
        for (name, job), cfg, res in zip(self.members, cfgs, results):
            if res is None:
                continue
            epochs = job.stages[0]
            member = {"seed": job.seed, f"loss_last_{epochs}": res.losses[-1],
                      "train_seconds": res.metrics["train_seconds"], "population": len(self.members)}
            job.record(load_agent(run_dir / name / "agent", dtype=torch.float64), cfg, run_dir / name, epochs, member)
            member["nmse"] = member[f"nmse_{epochs}"]
            out[name] = member
        return out


def population_jobs(jobs: list[Any], chunks: int) -> tuple[list[Any], dict[str, str]]:
    """Group ``NarmaJob`` sweep jobs of equal body (config, overrides other than the delay and target) into
    ``chunks`` :class:`NarmaPopulationJob` s per body, of consecutive jobs. Returns the new jobs and each
    member's job name (member → population), for :func:`job_dir`."""
    from bptsb_ros.jobs.sweep import Job

    by_body: dict[tuple, list[Any]] = {}
    for job in jobs:
        key = (job.fn.config, tuple((k, repr(v)) for k, v in job.fn.overrides.items()
                                    if k not in ("narma.delay", "narma.target")))
        by_body.setdefault(key, []).append(job)
    out, where = [], {}
    for i, members in enumerate(by_body.values()):
        n = max(1, min(chunks, len(members)))
        size = -(-len(members) // n)
        for c in range(0, len(members), size):
            part = members[c: c + size]
            name = f"population{i}_{c // size}"
            out.append(Job(name, NarmaPopulationJob(tuple((j.name, j.fn) for j in part))))
            where.update({j.name: name for j in part})
    return out, where


def job_dir(sweep_dir: Path, name: str, populations: dict[str, str] | None = None) -> Path:
    """The directory of sweep job ``name`` (a :class:`NarmaJob`'s ``run_dir``), also as a population member."""
    if populations and name in populations:
        return sweep_dir / "jobs" / populations[name] / name
    return sweep_dir / "jobs" / name


def run_jobs(ctx: Any, jobs: list[Any], out_dir: Path, diverged_ok: bool = False,
             gangs: bool = False) -> dict[str, dict[str, Any]]:
    """Run independent jobs (``bptsb_ros.jobs.sweep.Job``) as a resumable sweep in ``out_dir``, where the run's
    ``--workers`` / ``--scheduler`` say (``ctx``: the experiment's ``Context``, :meth:`Context.sweep`; ``gangs``:
    one gang of trainings per worker, their episodes one batched simulation). Every failure is an error, except,
    with ``diverged_ok``, a training that diverged: its result is ``{"diverged": message}`` (SGD can blow a system
    up beyond what the update guard can undo; that is a result). A :class:`NarmaPopulationJob`'s result is
    unpacked: each member's under its own name."""
    res = ctx.sweep(jobs, out_dir, what="trainings", gangs=gangs)
    diverged = {f["name"]: {"diverged": str(f.get("error")).split(";")[0]} for f in res.failed
                if diverged_ok and str(f.get("error", "")).startswith("TrainingDiverged")}
    failed = [f for f in res.failed if f["name"] not in diverged]
    if failed:
        first = failed[0]
        raise RuntimeError(f"{len(failed)} of {len(jobs)} jobs failed; first: {first['name']}: "
                           f"{first.get('error')} (records in {out_dir / 'sweep.json'})")
    done = res.results()
    results: dict[str, dict[str, Any]] = {}
    for job in jobs:
        if job.name in done:
            results.update(done[job.name] if isinstance(job.fn, NarmaPopulationJob) else {job.name: done[job.name]})
    lost = {name: r["diverged"] for name, r in results.items() if isinstance(r.get("diverged"), str)
            and name not in diverged}
    if lost and not diverged_ok:  # population members that diverged: failed trainings, as a job's failure is
        first = next(iter(lost))
        raise RuntimeError(f"{len(lost)} of {len(results)} population trainings diverged; first: {first}: "
                           f"{lost[first]} (records in {out_dir / 'jobs'})")
    results.update({name: {"diverged": msg.removeprefix("TrainingDiverged: ").split(";")[0]}
                    for name, msg in lost.items()})
    return {**results, **diverged}


def guard_record(run_dir: Path) -> dict[str, Any] | None:
    """What the update guard did in the training of the job in ``run_dir`` (from its ``agent/metrics.json``):
    ``rejections``, ``divisions``, ``tenth_division_update`` (the update of the 10th division of every rate, by
    then 10⁻¹⁰ of the start; None if fewer) and ``final_rates``. None where the training left no metrics (it
    diverged)."""
    path = run_dir / "agent" / "metrics.json"
    if not path.is_file():
        return None
    guard = json.loads(path.read_text())["guard"]
    divided = [e["update"] for e in guard["events"] if e["divided"]]
    return {"rejections": guard["rejections"], "divisions": guard["divisions"],
            "tenth_division_update": divided[9] if len(divided) >= 10 else None, "final_rates": guard["rates"]}


def load_states(run_dir: Path, epochs: int) -> dict[str, np.ndarray]:
    with np.load(run_dir / f"states_{epochs}.npz", allow_pickle=False) as data:
        return {k: data[k] for k in data.files}


def ablation_variants(ctx: Any) -> dict[str, dict]:
    """The variants this run trains: the first (the package's defaults) always, the ablations after it when the
    ``ablations`` setting is on. Each: ``help`` (what it changes), ``brains`` (which brains it retrains; the other
    systems are the first variant's) and ``variant_overrides`` (``--set`` overrides of the training config)."""
    variants = ctx.settings.variants
    names = list(variants)
    chosen = names if ctx.settings["ablations"] else names[:1]
    return {name: dict(variants[name]) for name in chosen}
