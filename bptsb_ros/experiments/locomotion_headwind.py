"""Locomotion switching under a headwind (paper: supplement "Behavioral switching", locomotion; Fig. S(a), (c), (e)).

1. A caterpillar agent is trained forward (the agents of ``locomotion-closed-loop-20``, reused when present);
   its open-loop speed is v_max.
2. Additional training (``config/locomotion_headwind.yaml``, the paper's switching learning rates): constant
   target v_tgt = v_max / 2 while a headwind F_wind = −1 N on every mass blows periodically (calm half a
   period, blowing half a period).
3. (c) the speed over time under the periodic wind; (e) the speed for F_wind ∈ [−2, 1] in steps of 0.05
   (ONE batched simulation of the 61 wind values).

Claims, each with its criterion and premise: :func:`claims`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from bptsb_ros.experiments.claim_rules import at_most
from bptsb_ros.experiments.common import derived_seeds, packaged_config
from bptsb_ros.experiments.locomotion_closed_loop import agent_settings
from bptsb_ros.experiments.locomotion_common import batched_centre_x, late_speed, task_state, train_agents
from bptsb_ros.experiments.measured import judge, stored_calls
from bptsb_ros.experiments.registry import Context, experiment
from bptsb_ros.experiments.result import Claim, all_not_testable
from bptsb_ros.experiments.seeds import seed_figure
from bptsb_ros.sim.inputs import wind_blowing

#: relative distance to the target within which the speed "is maintained"
NEAR = 0.25
#: relative distance to the target within which an untrained wind value counts as "somewhat close"
INTERP = 0.5


PHASES = ("calm", "windy_early", "windy_late")


def _phase_masks(t_block: np.ndarray, period: float) -> dict[str, np.ndarray]:
    phase = np.mod(np.round(t_block, 6), period)
    phase[phase == 0] = period  # a block ending exactly at a period's end belongs to that period
    q = period / 4
    return {"calm": (phase > q) & (phase <= 2 * q), "windy_early": (phase > 2 * q) & (phase <= 3 * q),
            "windy_late": phase > 3 * q}


def phase_speeds(t_block: np.ndarray, v_block: np.ndarray, period: float) -> dict[str, float]:
    """Mean block speeds [m/s] by wind phase (the wind blows in the second half of each period): calm = the
    second half of the calm half-period, windy_early / windy_late = the first / second half of the windy
    half-period. ``t_block``: (K,) block end times [s]; ``v_block``: (K,) block speeds. NaN if a phase is empty."""
    parts = _phase_masks(t_block, period)
    return {k: float(v_block[m].mean()) if m.any() else float("nan") for k, m in parts.items()}


def phase_blocks(t_block: np.ndarray, period: float) -> dict[str, int]:
    """How many blocks :func:`phase_speeds` averages in each phase."""
    return {k: int(m.sum()) for k, m in _phase_masks(t_block, period).items()}


@dataclass(frozen=True)
class HeadwindNumbers:
    """What the claims of locomotion-headwind rest on (all of the agent after the switching training).

    target: v_tgt = v_max / 2 [m/s]; phases: mean speed [m/s] per wind phase (:data:`PHASES`, see
    :func:`phase_speeds`; NaN: empty or diverged); blocks: how many 1-s blocks each phase holds; winds: (W,) the
    constant F_wind of the sweep [N]; speeds: (W,) the speed at each [m/s] (NaN: diverged)."""

    target: float
    phases: dict[str, float]
    blocks: dict[str, int]
    winds: np.ndarray
    speeds: np.ndarray
    force: float = -1.0
    """the trained headwind F [N] (< 0): the sweep's regions are read relative to it (the paper: −1)"""
    variant: str = ""
    """the switching protocol's variant name (figures over seeds)"""
    diverged: str = ""
    """why there is no agent after the switching training ("": there is one)"""


@judge("locomotion-headwind")
def claims(n: HeadwindNumbers) -> list[Claim]:
    """The paper (supplement, "Behavioral switching", locomotion):

    1. "we obtained an agent that maintained constant locomotion regardless of the absence or presence of wind
       (F_wind = 0, −1)": calm and late-windy speeds within :data:`NEAR` × v_tgt of the target (inclusive).
       Premise: the periodic-wind run has blocks in both phases.
    2. "the locomotion speed began to slow down immediately after the wind started blowing, but it progressively
       increased and returned to locomotion equivalent to windless conditions": early-windy speed < calm speed,
       early < late-windy, and |late − calm| ≤ :data:`NEAR` × v_tgt. Premise: blocks in all three phases.
    3. "With the wind (−1.0 < F_wind < 1.0), which was unknown to it, the agent accomplished locomotion at a speed
       somewhat close to the target": every untrained F_wind in (−1, 1) within :data:`INTERP` × v_tgt (inclusive).
    4. "the locomotion speed was far from the target speed when F_wind < −1.0": the mean relative error over
       F_wind < −1 exceeds :data:`INTERP` (farther than "somewhat close"; a diverged speed is infinitely far).
       Premise of 3 and 4: at the trained F_wind = 0 and −1 of the same sweep the speed is within :data:`NEAR` ×
       v_tgt ("interpolation was performed in an unlearned parameter region" presumes the learned one).

    A variant whose training diverged, or a seed whose forward agent could not be trained (``n.diverged``), has the
    same claims, not testable.
    """
    if n.diverged:
        return all_not_testable(claims(replace(n, diverged="")), n.diverged)
    tgt, ph, blocks = n.target, n.phases, n.blocks
    winds = np.asarray(n.winds, float)
    if not n.force < 0:
        raise ValueError(f"locomotion-headwind claims: the trained headwind must be < 0 N, got {n.force}")
    scale, fw = -n.force, f"−{-n.force:g}"
    rel_w = winds / scale  # −1: the trained headwind
    trained = (0.0, n.force)
    with np.errstate(invalid="ignore"):
        err = np.abs(np.asarray(n.speeds, float) - tgt) / tgt
    out = []
    text1 = (f"after switching training the speed stays near the target with and without wind (within {NEAR:.0%} "
             f"of v_tgt, F = 0 and F = {fw})")
    empty = [k for k in PHASES if blocks.get(k, 0) == 0]
    no_blocks = f"the periodic-wind run has no 1-s block in the phase(s) {', '.join(empty)}"
    rel = {k: abs(ph[k] - tgt) / tgt for k in ("calm", "windy_late")}
    if set(empty) & {"calm", "windy_late"}:
        out.append(Claim.not_testable(text1, no_blocks))
    else:
        out.append(Claim(text1, all(at_most(v, NEAR) for v in rel.values()),
                         f"|v − v_tgt|/v_tgt: calm {rel['calm']:.2f}, headwind {rel['windy_late']:.2f}"))
    text2 = ("the speed drops right after the wind starts and recovers to the windless speed (first half of each "
             f"windy phase slower than the calm phase and than its second half; second half within {NEAR:.0%} of "
             "v_tgt of the calm speed)")
    if empty:
        out.append(Claim.not_testable(text2, no_blocks))
    else:
        calm, early, late = ph["calm"], ph["windy_early"], ph["windy_late"]
        holds = early < calm and early < late and at_most(abs(late - calm) / tgt, NEAR)
        out.append(Claim(text2, holds, f"calm {calm:.3f}, windy first half {early:.3f}, second half {late:.3f} m/s"))
    trained_err = {f: float(err[np.isclose(winds, f)][0]) for f in trained}
    learned = all(at_most(e, NEAR) for e in trained_err.values())
    not_learned = ("at the trained F_wind the sweep's speed is not near the target (|v − v_tgt|/v_tgt: "
                   + ", ".join(f"F = {f:g}: {e:.2f}" for f, e in trained_err.items()) + f"; near: ≤ {NEAR:.0%})")
    text3 = (f"for unlearned {fw} < F_wind < {scale:g} the speed is somewhat close to the target (every value within "
             f"{INTERP:.0%} of v_tgt)")
    inside = (rel_w > -1) & (rel_w < 1) & ~np.isclose(winds, trained[0]) & ~np.isclose(winds, trained[1])
    if not learned:
        out.append(Claim.not_testable(text3, not_learned))
    else:
        worst = float(np.max(np.where(np.isfinite(err[inside]), err[inside], np.inf)))
        out.append(Claim(text3, at_most(worst, INTERP), f"largest |v − v_tgt|/v_tgt = {worst:.2f}"))
    text4 = (f"the speed is far from the target when F_wind < {fw} (mean |v − v_tgt|/v_tgt over F_wind < {fw} > "
             f"{INTERP:.0%}, farther than 'somewhat close')")
    strong = rel_w < -1 - 1e-9
    if not learned:
        out.append(Claim.not_testable(text4, not_learned))
    else:
        e_strong = float(np.mean(np.where(np.isfinite(err[strong]), err[strong], np.inf)))
        e_mid = float(np.nanmean(err[(rel_w >= -1 - 1e-9) & (rel_w <= 1 + 1e-9)]))
        out.append(Claim(text4, e_strong > INTERP,
                         f"mean |v − v_tgt|/v_tgt: F < {fw} {e_strong:.2f}, [{fw}, {scale:g}] {e_mid:.2f}"))
    return out


@experiment(
    "locomotion-headwind",
    paper_ref="supplement 'Behavioral switching' (locomotion), Fig. S(a), (c), (e)",
    summary="forward agent → additional training at v_max/2 under a periodic headwind F = −1; speed under the "
            "switching wind (c) and speed vs F_wind ∈ [−2, 1] (e, one batched simulation); variants paper and "
            "authors (−15 N in 100 s / 100 s phases, their rates, ÷10 at 80 % / 90 %)",
)
def run(ctx: Context) -> None:
    from bptsb_ros.training.checkpoint import load_agent, read_checkpoint

    settings = agent_settings(ctx)
    agent_seed = derived_seeds(ctx.seed, 1)[0]
    sweep = train_agents(ctx, settings, [agent_seed])
    variants = ctx.settings.variants or {"paper": {"wind_force": -1.0, "wind_period": None,
                                                   "lr": (1.0, 1e-2, 1e-3, 1e-5, 1e-4), "lr_decay": False}}
    forward_dir = sweep.out_dir / "jobs" / f"seed-{agent_seed}"
    why = None
    if sweep.failed:
        why = f"the forward agent's training failed ({str(sweep.failed[0].get('error'))[:300]})"
    else:
        v_max = float(sweep.results()[f"seed-{agent_seed}"]["open_speed"])
        if not v_max > 0:
            why = f"the forward agent does not move forward (speed {v_max:.3g} m/s): no target v_max/2"
    ctx.row("forward agent", "training failed or no forward motion (1) or usable (0)", "1", 1.0 if why else 0.0, 0)
    if why:  # a result of this seed (every claim ∅), not a failure of the run
        ctx.log(f"locomotion-headwind: {why}")
        for vi, (name, variant) in enumerate(variants.items()):
            _judge_diverged(ctx, name, variant, vi == 0, why)
        ctx.result.details = {"seed": ctx.seed, "forward_settings": settings.__dict__, "diverged": why}
        return
    target = v_max / 2
    forward = (load_agent(forward_dir), task_state(read_checkpoint(forward_dir)))
    for vi, (name, variant) in enumerate(variants.items()):
        _switching_variant(ctx, name, variant, vi == 0, forward, forward_dir, settings, v_max, target)


def _judge_diverged(ctx: Context, variant_name: str, variant, first: bool, why: str) -> None:
    """The claims of a variant with no agent to test (its training diverged, or the forward agent is missing), all
    not testable because ``why``; the same texts as a tested variant's."""
    force = float(variant["wind_force"])
    winds = np.round(np.arange(-2.0, 1.0 + 1e-9, 0.05), 2) * -force
    phases = dict.fromkeys(PHASES, float("nan"))
    ctx.judge(claims, HeadwindNumbers(float("nan"), phases, dict.fromkeys(PHASES, 0), winds,
                                      np.full(len(winds), np.nan), force, variant_name, why),
              label="" if first else f"[{variant_name}] ")


def _switching_variant(ctx: Context, variant_name: str, variant, first: bool, forward, forward_dir, settings,
                       v_max: float, target: float) -> None:
    """One switching protocol (a settings variant): its additional training, rows, claims, figures and details
    (the first variant's at the top level and unprefixed, every one also under ``details["variants"]``)."""
    from bptsb_ros.training.checkpoint import load_agent, read_checkpoint
    from bptsb_ros.workflows.train import TrainingDiverged, train

    tag, label, suffix = ("", "", "") if first else (f"{variant_name}: ", f"[{variant_name}] ", f"-{variant_name}")
    sim_time = ctx.settings["switching_time"]
    period = ctx.settings["wind_period"] if variant["wind_period"] is None else variant["wind_period"]
    eval_periods, sweep_time = ctx.settings["eval_periods"], ctx.settings["sweep_time"]
    force = float(variant["wind_force"])
    lr = dict(zip(("k", "d", "l", "amplitude", "phase"), variant["lr"], strict=True))
    cfg = packaged_config("locomotion_headwind", {"sim_time": sim_time, "locomotion.target_speed": target,
                                                  "locomotion.wind_period": period, "locomotion.wind_force": force,
                                                  **{f"training.lr.{k}": v for k, v in lr.items()},
                                                  "training.lr_decay": variant["lr_decay"]}, seed=ctx.seed)
    ctx.log(f"locomotion-headwind ({variant_name}): v_max {v_max:.3f} m/s → target {target:.3f} m/s; {sim_time} s "
            f"switching training, F = {force:g} N, period {period:g} s")
    run_dir = ctx.out_dir / f"switching{suffix}"
    try:
        res = train(cfg, run_dir, overwrite=True, init_from=forward_dir, progress=ctx.progress)
    except TrainingDiverged as err:  # a result of this variant (its claims ∅); the other variants go on
        why = f"the switching training diverged ({err})"
        ctx.log(f"locomotion-headwind ({variant_name}): {why}")
        ctx.row(f"{tag}switching training", "diverged (1) or finished (0)", "1", 1.0, 0)
        _judge_diverged(ctx, variant_name, variant, first, why)
        details = {"seed": ctx.seed, "v_max": v_max, "target": target, "switching_sim_time_s": sim_time,
                   "wind_force": force, "wind_period_s": period, "diverged": why}
        if first:
            ctx.result.details = dict(details)
        ctx.result.details.setdefault("variants", {})[variant_name] = details
        return
    ctx.row(f"{tag}switching training", "diverged (1) or finished (0)", "1", 0.0, 0)
    agents = {"switching": (load_agent(run_dir), task_state(read_checkpoint(run_dir))), "forward": forward}
    dt = agents["switching"][0].dt

    ctx.phase(f"the periodic-wind test of the switching and forward agents ({eval_periods} periods)")
    # (c) periodic wind; each agent continues from where its training ended, the wind clock = absolute time
    steps = int(round(eval_periods * period / dt))
    block = int(round(1.0 / dt))
    traces = {}
    for name, (agent, state) in agents.items():
        k = np.arange(state.step, state.step + steps + 1)
        wind = torch.as_tensor(np.where(wind_blowing(k, dt, period), force, 0.0))[:, None]
        x, _ = batched_centre_x(agent, state, steps, wind_x=wind)
        xb = x[::block, 0]
        t_end = (state.step + np.arange(block, steps + 1, block)) * dt
        v_block = np.diff(xb) / (block * dt)
        traces[name] = {"t": t_end, "v": v_block, "on": wind_blowing(k, dt, period), "t0": state.step * dt,
                        "dt": dt, "phases": phase_speeds(t_end, v_block, period)}
    sw = traces["switching"]["phases"]
    fw = traces["forward"]["phases"]
    if first:
        ctx.row("target", "v_tgt = v_max / 2", "m/s", target)
    fw_text = f"−{-force:g}"
    for who, ph in (("after switching training", sw), ("forward agent (before)", fw)):
        ctx.row(f"{tag}{who}", "speed, calm (F = 0)", "m/s", ph["calm"])
        ctx.row(f"{tag}{who}", "speed, first half of each headwind phase", "m/s", ph["windy_early"])
        ctx.row(f"{tag}{who}", f"speed, second half of each headwind phase (F = {fw_text})", "m/s", ph["windy_late"])
    # (e) speed vs F_wind: one batched simulation per agent over all wind values (relative to the trained wind)
    winds = np.round(np.arange(-2.0, 1.0 + 1e-9, 0.05), 2) * -force
    n_sweep = int(round(sweep_time / dt))
    curves = {}
    for name, (agent, state) in agents.items():
        batch = state.__class__(state.r.expand(len(winds), -1, -1), state.v.expand(len(winds), -1, -1),
                                state.a.expand(len(winds), -1, -1), state.length.expand(len(winds), -1), state.step)
        x, _ = batched_centre_x(agent, batch, n_sweep, wind_x=torch.as_tensor(winds))
        curves[name] = late_speed(x, dt)
    v = curves["switching"]
    for f in (-2.0, -1.0, -0.5, 0.0, 1.0):
        fv = f * -force
        ctx.row(f"{tag}after switching training", f"speed at F_wind = {fv:g}", "m/s",
                float(v[np.isclose(winds, fv)][0]))
    blocks = phase_blocks(traces["switching"]["t"], period)
    ctx.judge(claims, HeadwindNumbers(target, sw, blocks, winds, v, force, variant_name), label=label)
    ctx.phase("plotting the speeds")
    from bptsb_ros.analysis.locomotion_plots import plot_headwind_speed, plot_speed_vs_wind
    ctx.figure(plot_headwind_speed(ctx.out_dir / f"headwind_speed{suffix}.png", traces, target, force, period))
    ctx.figure(plot_speed_vs_wind(ctx.out_dir / f"speed_vs_wind{suffix}.png", winds, curves, target, (0.0, force)))
    ctx.figure(run_dir / "loss.png")
    details = {
        "seed": ctx.seed, "v_max": v_max, "target": target, "switching_sim_time_s": sim_time, "wind_force": force,
        "wind_period_s": period, "eval_periods": eval_periods, "wind_sweep_time_s": sweep_time,
        "forward_settings": settings.__dict__, "forward_dir": str(forward_dir),
        "loss_first": res.losses[0], "loss_last": res.losses[-1],
        "phase_speeds": {"switching": sw, "forward": fw}, "phase_blocks": blocks,
        "speed_vs_wind": {"F_wind": winds.tolist(), **{k: [None if not np.isfinite(u) else float(u) for u in c]
                                                        for k, c in curves.items()}},
        "lr": lr, "lr_decay": bool(variant["lr_decay"]),
        "notes": ("v_max is the forward agent's mean open-loop speed. The wind's period is ours (the paper: "
                  "'periodically'); the published code used −15 N plus a constant +1 N upward (the authors' variant "
                  "has the −15 N along x, not the upward 1 N)."),
    }
    if first:
        ctx.result.details = dict(details)
    ctx.result.details.setdefault("variants", {})[variant_name] = details


@seed_figure("locomotion-headwind")
def seed_figures(out_dir: Path, per_seed: Sequence[Mapping[str, Any]], seeds: Sequence[int]) -> list[Path]:
    """Across seeds: the speed after the switching training against the constant F_wind, relative to each seed's
    own target v_tgt = v_max / 2 (seeds differ in v_max), as the mean over seeds with the band of their min–max,
    one panel per switching protocol (what :func:`claims` read; a seed whose variant diverged has none)."""
    from bptsb_ros.analysis.seed_plots import plot_band_panels

    panels: dict[str, dict[str, Any]] = {}
    for res in per_seed:
        for _, args, _ in stored_calls(res, claims):
            n = args[0]
            if n.diverged:
                continue
            half = 0.025 * abs(n.force)  # half a grid step: the sweep steps by 0.05 × |trained F|
            panel = panels.setdefault(n.variant or "paper", {
                "x": np.asarray(n.winds, float), "curves": {"after switching training": []},
                "spans": [(n.force - half, n.force + half, f"trained: F = {n.force:g} N"),
                          (-half, half, "trained: F = 0")]})
            panel["curves"]["after switching training"].append(np.asarray(n.speeds, float) / n.target)
    if not panels:
        return []
    return [plot_band_panels(out_dir / "speed_vs_wind_seeds.png", panels, xlabel="F_wind [N]",
                             ylabel="speed / target speed v_tgt [-]", hline=1.0,
                             title=f"Speed against the wind after the switching training, over {len(seeds)} seeds")]
