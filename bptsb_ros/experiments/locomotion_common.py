"""What the locomotion population experiments share: the forward-trained agents (one sweep job per seed, in
``OUT/agents``; a run reuses the agents of a sibling run of the same settings), their closed-loop evaluation with the
variants the paper's discussion suggests, and a batched simulation for populations of one agent under many
conditions (perturbations, wind values) that never aborts the batch for one diverging member.

Closed-loop success (paper, main text): closed-loop speed / open-loop speed ≥ :data:`SUCCESS_RATIO`.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import shutil
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from bptsb_ros.agent import Agent
from bptsb_ros.body.msdn import PROJECTIONS, BodyState
from bptsb_ros.brains import FeedbackLayer, SineWaveGenerator
from bptsb_ros.config import FeedbackConfig, override_mapping
from bptsb_ros.files.safe_write import atomic_writer
from bptsb_ros.jobs.sweep import Job, SweepResult
from bptsb_ros.sim.rollout import simulate_closed_loop, simulate_open_loop

#: closed-loop / open-loop speed at or above which a closed loop counts as autonomous locomotion (paper)
SUCCESS_RATIO = 0.7
#: the paper's count: 8 of 20 agents succeeded
PAPER_SUCCESSES, PAPER_AGENTS = 8, 20
#: steps between stored gait frames
GAIT_STRIDE = 5


@dataclass(frozen=True)
class AgentSettings:
    """Forward training and closed-loop evaluation of one locomotion agent.

    sim_time: training [s] (paper 1000); warmup_windows: untrained 200-step windows first (paper 100);
    fit_time: open-loop run for the FL fit [s] (paper 100, its middle 60 % used); eval_time: open- and
    closed-loop runs whose speeds are compared [s] (the original closed-loop config: 100);
    handover_time: the transition variant's blend from SWG to FL [s]; gait_time: stored gait [s]; projection: what
    the training does with a k, d or l below zero after an update (``training.projection``: clamp to 0, the paper;
    reset to 0.1, the authors' code); config_overrides: further ``key=value`` overrides of the agents' training
    config (``config/locomotion_forward.yaml``), e.g. ``body.integrator=published`` for the ablation of the
    authors' profile.
    """

    sim_time: float
    warmup_windows: int = 100
    fit_time: float = 100.0
    eval_time: float = 100.0
    handover_time: float = 5.0
    gait_time: float = 2.0
    projection: str = "clamp"
    config_overrides: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "config_overrides", tuple(self.config_overrides))
        owned = set(self.own_overrides())  # set by the fields themselves
        for item in self.config_overrides:
            if item.split("=", 1)[0].strip() in owned | {"seed"}:
                raise ValueError(f"locomotion agents: config_overrides may not set {item.split('=', 1)[0].strip()} "
                                 "(a setting of its own, or the run's seed)")
        if self.projection not in PROJECTIONS:
            raise ValueError(f"locomotion agents: projection must be one of {', '.join(PROJECTIONS)}, got "
                             f"{self.projection!r}")

    def own_overrides(self) -> dict[str, Any]:
        """The training config's keys these settings set themselves."""
        return {"sim_time": self.sim_time, "locomotion.warmup_windows": self.warmup_windows,
                "feedback.fit_time": self.fit_time, "locomotion.eval_time": self.eval_time,
                "training.projection": self.projection}

    def overrides(self) -> dict[str, Any]:
        """Overrides of ``config/locomotion_forward.yaml``: :meth:`own_overrides`, then ``config_overrides``."""
        return {**self.own_overrides(), **override_mapping(self.config_overrides)}

    def key(self) -> str:
        """Short stable name of these settings (agents of equal settings are shared between experiments); the
        default projection (clamp) and empty config overrides are left out of it, so agents trained before those
        options existed keep their key."""
        fields_ = asdict(self)
        if fields_["projection"] == "clamp":
            del fields_["projection"]
        if not fields_["config_overrides"]:
            del fields_["config_overrides"]
        else:
            fields_["config_overrides"] = list(fields_["config_overrides"])
        text = json.dumps(fields_, sort_keys=True)
        return hashlib.sha1(text.encode()).hexdigest()[:8]


#: the agents' sweep directory inside an experiment's ``--out``
AGENTS_DIR = "agents"


def agents_dir(out_dir: Path, settings: AgentSettings) -> Path:
    """Where the agents of a run live: ``OUT/agents`` (a sweep: ``jobs/seed-N/`` per agent; it resumes).
    ``settings`` name no directory: a run trains agents of one settings, and a job's key names them."""
    return Path(out_dir) / AGENTS_DIR


def train_agents(ctx: Any, settings: AgentSettings, seeds: list[int]) -> SweepResult:
    """Train (or reuse) one forward agent per seed as sweep jobs in ``OUT/agents``, where the run's
    ``--workers`` / ``--scheduler`` say (``ctx``: the experiment's ``Context``); returns the sweep's records.

    Agents another locomotion experiment finished with the same settings and seed, in a run beside this one
    (``OUT/../*/agents``: the default layout ``runs/reproduce/NAME``), are copied in first and kept (the sweep
    checks them as it checks its own records), so the experiments share their agents without writing outside
    their own ``--out``."""
    jobs = [Job(f"seed-{s}", functools.partial(forward_agent_job, settings, s)) for s in seeds]
    where = agents_dir(ctx.out_dir, settings)
    adopt_sibling_agents(jobs, where, ctx.out_dir, ctx.log)
    return ctx.sweep(jobs, where, what="locomotion agents")


def adopt_sibling_agents(jobs: list[Job], where: Path, out_dir: Path, log) -> list[str]:
    """Copy into ``where/jobs/`` every job of ``jobs`` not finished there that a sibling run
    (``out_dir/../*/agents``) finished (a valid record with this job's key); returns the names copied. Only
    siblings that are ``bptsb reproduce`` runs of this user are read (a shared parent such as ``/tmp`` may hold
    anyone's directories), and only regular files are copied (symbolic links are left behind)."""
    from bptsb_ros.experiments.registry import RUN_MARKER
    from bptsb_ros.experiments.seed_dirs import sibling_run_dirs
    from bptsb_ros.jobs.sweep import finished_record, job_key

    siblings = [p / AGENTS_DIR for p in sibling_run_dirs(Path(out_dir))
                if _own_run(p, RUN_MARKER) and (p / AGENTS_DIR / "jobs").is_dir()]
    copied = []
    for job in jobs:
        key = job_key(job)
        dest = where / "jobs" / job.name
        if finished_record(job, dest, key)[0] is not None:
            continue
        for sib in siblings:
            src = sib / "jobs" / job.name
            if src.is_symlink() or finished_record(job, src, key)[0] is None:
                continue
            if dest.exists():
                shutil.rmtree(dest)
            shutil.copytree(src, dest, ignore=lambda d, names: [n for n in names if Path(d, n).is_symlink()])
            log(f"locomotion agents: {job.name} reused from {sib.parent.name}")
            copied.append(job.name)
            break
    return copied


def _own_run(path: Path, marker: str) -> bool:
    """``path`` is a directory of an earlier ``bptsb reproduce`` run (it holds ``marker``) owned by this user."""
    try:
        st = path.stat()
    except OSError:
        return False
    owner = getattr(os, "getuid", None)
    return path.is_dir() and not path.is_symlink() and (path / marker).is_file() and (
        owner is None or st.st_uid == owner())


def forward_agent_job(settings: AgentSettings, seed: int, run_dir: Path) -> dict[str, Any]:
    """Sweep job: train one agent forward, fit its FL (spring lengths, σ 0.2), evaluate open and closed loop
    (the paper's method) and the two variants; store a short gait. Returns the numbers."""
    from bptsb_ros.experiments.common import packaged_config
    from bptsb_ros.training.checkpoint import load_agent, read_checkpoint
    from bptsb_ros.workflows.train import train

    cfg = packaged_config("locomotion_forward", settings.overrides(), seed=seed)
    res = train(cfg, run_dir, overwrite=True, progress=False)  # a sweep job owns run_dir (a rerun replaces it)
    ev = res.metrics["evaluation"]
    agent = load_agent(run_dir)
    state = task_state(read_checkpoint(run_dir))
    dt = agent.dt
    steps = int(round(settings.eval_time / dt))
    with torch.no_grad():
        open_roll = simulate_open_loop(agent, steps, state=state)
        v_open = centre_speed(open_roll.r[:, 0, :, 0], dt)
        start = open_roll.final  # every closed loop takes over where the open-loop evaluation ended
        closed = simulate_closed_loop(agent.body, agent.feedback, steps, state=start)
        v_closed = centre_speed(closed.r[:, 0, :, 0], dt)
        hand = int(round(settings.handover_time / dt))
        handed = simulate_closed_loop(agent.body, agent.feedback, hand + steps, state=start, handover=agent.brain,
                                      handover_steps=hand)
        v_hand = centre_speed(handed.r[hand:, 0, :, 0], dt)
        vel_fl = velocity_feedback(agent, cfg.feedback, state, seed)
        vel = simulate_closed_loop(agent.body, vel_fl, steps, state=start)
        v_vel = centre_speed(vel.r[:, 0, :, 0], dt)
    gait_steps = int(round(settings.gait_time / dt))
    with atomic_writer(run_dir / "gait.npz") as f:
        np.savez_compressed(f, r=open_roll.r[: gait_steps + 1 : GAIT_STRIDE, 0].double().numpy(),
                            dt=dt * GAIT_STRIDE, springs=np.asarray(agent.body.topology.springs))

    def ratio(v: float) -> float:
        return v / v_open if v_open > 0 else float("nan")

    return {
        "seed": seed, "loss_last": res.losses[-1], "train_seconds": res.metrics["train_seconds"],
        "open_speed": v_open, "closed_speed": v_closed, "ratio": ratio(v_closed),
        "success": bool(v_open > 0 and v_closed >= SUCCESS_RATIO * v_open),
        # the trainer's own evaluation of the same agent (same runs: a cross-check)
        "trainer_open_speed": ev["mean_forward_speed"], "trainer_ratio": ev.get("closed_over_open"),
        "handover_speed": v_hand, "handover_ratio": ratio(v_hand),
        "handover_success": bool(v_open > 0 and v_hand >= SUCCESS_RATIO * v_open),
        "velocity_fl_speed": v_vel, "velocity_fl_ratio": ratio(v_vel),
        "velocity_fl_success": bool(v_open > 0 and v_vel >= SUCCESS_RATIO * v_open),
    }


def velocity_feedback(agent: Agent, base: FeedbackConfig, state: BodyState, seed: int) -> FeedbackLayer:
    """An FL fitted on the mass velocities instead of the spring lengths (same noise, same fit run)."""
    from bptsb_ros.training.feedback_fit import fit_feedback

    fl = FeedbackLayer(2 * agent.body.n_movable, agent.body.topology.n_springs, state_type="velocity",
                       dtype=agent.dtype)
    other = Agent(agent.config, agent.body, agent.brain, fl)
    fit_feedback(other, base.model_copy(update={"state": "velocity"}), state, seed)
    return fl


def task_state(payload: dict[str, Any]) -> BodyState:
    """The body state a training ended in, from a checkpoint payload."""
    s = payload["extra"]["task_state"]
    return BodyState(s["r"], s["v"], s["a"], s["length"], int(s["step"]))


def centre_speed(x: torch.Tensor | np.ndarray, dt: float) -> float:
    """Mean forward speed [m/s] from x positions (T+1, M) of all masses over T steps of ``dt``."""
    x = np.asarray(x, dtype=np.float64)
    centre = x.mean(-1)
    return float((centre[-1] - centre[0]) / ((x.shape[0] - 1) * dt))


@torch.no_grad()
def batched_centre_x(agent: Agent, state: BodyState, steps: int, *, closed: FeedbackLayer | None = None,
                     wind_x: torch.Tensor | None = None) -> tuple[np.ndarray, BodyState]:
    """One batched simulation of ``steps`` steps from ``state`` (B members) → (centre x (steps+1, B) [m], the
    final state).

    Open loop (the SWG, clock from ``state.step``) unless ``closed`` (the FL drives from the first step);
    ``wind_x``: (B,) or (steps+1, B) force along x on every mass [N]. Members that diverge become NaN and the
    others go on (no divergence check aborts the batch).
    """
    body = agent.body
    b = state.r.shape[0]
    wind = None
    if wind_x is not None:
        w = torch.as_tensor(wind_x, dtype=body.l.dtype)
        w = w.expand(steps + 1, b) if w.dim() == 1 else w
        wind = torch.zeros(steps + 1, b, body.n_movable, 2, dtype=body.l.dtype)
        wind[..., 0] = w[:, :, None]
    swg = agent.brain if isinstance(agent.brain, SineWaveGenerator) else None
    if closed is None and swg is None:
        raise ValueError("an open loop needs an SWG agent")
    out = np.empty((steps + 1, b))
    out[0] = state.r[..., 0].double().mean(-1).numpy()
    rest_open = None
    if closed is None:
        rest_open = swg.rest_length_at_steps(body.l, torch.arange(state.step + 1, state.step + steps + 1), body.dt)
    for i in range(1, steps + 1):
        rest = rest_open[i - 1] if closed is None else closed.rest_length(body.l, state)
        state = body.step(state, rest, None if wind is None else wind[i])
        out[i] = state.r[..., 0].double().mean(-1).numpy()
    return out, state


def late_speed(x: np.ndarray, dt: float) -> np.ndarray:
    """Mean forward speed [m/s] over the second half of a run: x (T+1, B) centre positions → (B,); NaN where
    the member diverged."""
    half = (x.shape[0] - 1) // 2
    with np.errstate(invalid="ignore"):
        return (x[-1] - x[-1 - half]) / (half * dt)


#: the perturbation draws of locomotion-perturbation (:func:`perturbed`)
DRAWS = ("position", "authors")


def authors_scales(state: BodyState) -> tuple[torch.Tensor, torch.Tensor]:
    """(P, S) of the authors' draw for each member of ``state``: P [m] = the body's x-extent (max − min of the
    masses' x), S [m/s] = the range of their x-velocities at that moment; each (B,)."""
    x, vx = state.r[..., 0], state.v[..., 0]
    return x.amax(-1) - x.amin(-1), vx.amax(-1) - vx.amin(-1)


def perturbed(agent: Agent, state: BodyState, sigma: torch.Tensor, seeds: torch.Tensor,
              rest_length: torch.Tensor, draw: str = "position") -> BodyState:
    """Copies of a batch-1 ``state``, perturbed by seeded Gaussian noise.

    ``draw``: ``position`` (the paper's text) shifts every movable mass's position by N(0, σ²) [m] per coordinate,
    velocities kept; ``authors`` (their published code) shifts the positions by N(0, (σ·P/8)²) and the velocities
    by N(0, (σ·S)²) per coordinate, P and S from :func:`authors_scales` of ``state`` (σ dimensionless then).
    sigma, seeds: (B,); member b's noise comes from a generator seeded with seeds[b] (reproducible member by
    member; the position noise is its first M × 2 normals, the velocity noise the next M × 2). Accelerations and
    spring lengths are recomputed at the new state under ``rest_length``.
    """
    if draw not in DRAWS:
        raise ValueError(f"perturbation draw must be one of {', '.join(DRAWS)}, got {draw!r}")
    body = agent.body
    m = body.n_movable
    gens = [torch.Generator().manual_seed(int(s)) for s in seeds.tolist()]
    noise = torch.stack([torch.randn(m, 2, generator=g, dtype=torch.float64) for g in gens]).to(body.l.dtype)
    sig = sigma.to(body.l.dtype)[:, None, None]
    v = state.v.expand(len(seeds), m, 2).clone()
    if draw == "position":
        r = state.r.expand(len(seeds), m, 2) + sig * noise
    else:
        p_extent, s_range = (t.to(body.l.dtype) for t in authors_scales(state))
        v_noise = torch.stack([torch.randn(m, 2, generator=g, dtype=torch.float64) for g in gens]).to(body.l.dtype)
        r = state.r.expand(len(seeds), m, 2) + sig * p_extent / 8 * noise
        v = v + sig * s_range * v_noise
    a, length = body.acceleration(r, v, rest_length, None)
    return BodyState(r, v, a, length, state.step)
