"""Return rates of locomotion after perturbations (paper: Fig. 4(b), (c); Methods "Locomotion task"): the
positions of the movable masses are shifted by Gaussian noise of standard deviation σ ∈ {0.0, 0.1, …, 1.0} [m],
100 noise seeds per σ; a return succeeds when the speed afterwards is ≥ 0.7 × the speed before. Open loop (SWG)
and closed loop (FL), for the agents whose closed loop succeeded in ``locomotion-closed-loop-20`` (their sweep
is reused when it exists beside this run, trained otherwise).

Per agent and loop type the 11 × 100 perturbed copies are ONE batched simulation. Speed before: the last half
of a ``before`` run of the loop; speed after: the last half of the ``after`` run that starts at the perturbation
(time to regain speed, as the paper's successful cases "gradually regained their speed"). Claims: :func:`claims`.

Two perturbation protocols run side by side (the settings file's ``variants``), each with its own rows and
claims: ``paper`` (the text: positions shifted by N(0, σ²) [m]) and ``authors`` (their published code: positions
by N(0, (σ·P/8)²), velocities by N(0, (σ·S)²), P the body's x-extent, S the range of its x-velocities at that
moment; σ dimensionless). See :func:`bptsb_ros.experiments.locomotion_common.perturbed`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from bptsb_ros.experiments.claim_rules import EPS, SAME_RATE, almost_same_rates
from bptsb_ros.experiments.common import derived_seeds
from bptsb_ros.experiments.locomotion_closed_loop import settings_for
from bptsb_ros.experiments.locomotion_common import (
    SUCCESS_RATIO,
    batched_centre_x,
    late_speed,
    perturbed,
    task_state,
    train_agents,
)
from bptsb_ros.experiments.measured import judge, stored_calls
from bptsb_ros.experiments.registry import Context, experiment
from bptsb_ros.experiments.result import Claim, all_not_testable
from bptsb_ros.experiments.seeds import seed_figure

SIGMAS = tuple(round(0.1 * i, 1) for i in range(11))
#: each perturbation draw in words (claims of a variant after the first are prefixed with it)
DRAW_TEXT = {"position": "positions shifted by N(0, σ²) [m]",
             "authors": "the authors' draw: positions N(0, (σ·P/8)²), velocities N(0, (σ·S)²)"}
#: the σ [m] at or below which a perturbation counts as weak, and at or above which as strong
WEAK_SIGMA, STRONG_SIGMA = 0.4, 0.6
#: a perturbed run "came to a standstill" when |its speed over the last half of the run| ≤ this × the speed before
STANDSTILL = 0.1
#: ... and "suddenly slowed down" when its speed over the first EARLY_SHARE of the run is < SUDDEN × the speed before
SUDDEN = 0.5
EARLY_SHARE = 0.1


@dataclass(frozen=True)
class PerturbationRates:
    """What the claims of locomotion-perturbation rest on: sigmas (S,) [m]; rate_open, rate_closed (S,): the
    return rates, mean over the perturbed agents; open_moves: every perturbed agent's open loop moved forward
    before the perturbation; closed_succeeded: the perturbed agents are ones whose closed loop succeeded in
    locomotion-closed-loop-20 (False: none did, the best one was perturbed)."""

    sigmas: np.ndarray
    rate_open: np.ndarray
    rate_closed: np.ndarray
    open_moves: bool
    closed_succeeded: bool
    variant: str = ""
    """the perturbation draw's variant name (figures over seeds)"""
    diverged: str = ""
    """why there is no agent to perturb ("": there is one)"""


@judge("locomotion-perturbation")
def claims(n: PerturbationRates) -> list[Claim]:
    """The paper (main text): "As the standard deviation of the perturbation increased, the return rates tended to
    decrease (Fig. 4(c)). However, the return rates of the sinusoidal drive and closed-loop control were almost the
    same, suggesting that the robustness was not impaired by the closed loop." The paper perturbs the closed loops
    that succeeded ("We then analyzed the stability of the closed-loop systems").

    * each loop's rate falls: mean rate over σ ≥ 0.6 < mean over σ ≤ 0.4. Premise: the loop locomotes before the
      perturbation (open loop: it moves forward; closed loop: it is one that succeeded).
    * almost the same: |rate_open − rate_closed| ≤ :data:`~bptsb_ros.experiments.claim_rules.SAME_RATE` at every σ
      (:func:`~bptsb_ros.experiments.claim_rules.almost_same_rates`, the rule of lissajous-perturbation too).
      Premises: both loops locomote, and some σ gives a rate below 1 (otherwise no perturbation tested their
      robustness).

    A seed with no agent to perturb (every forward training failed: ``n.diverged``) has the same claims, not
    testable.
    """
    if n.diverged:
        return all_not_testable(claims(replace(n, diverged="")), n.diverged)
    sig = np.asarray(n.sigmas, float)
    rates = {"open": np.asarray(n.rate_open, float), "closed": np.asarray(n.rate_closed, float)}
    low, high = sig <= WEAK_SIGMA + 1e-9, sig >= STRONG_SIGMA - 1e-9
    premise = {"open": None if n.open_moves else "an open loop perturbed here does not move forward before the "
                                                 "perturbation",
               "closed": None if n.closed_succeeded else "no agent's closed loop succeeded (closed/open speed ≥ 0.7), "
                                                         "so the closed loop perturbed here does not locomote"}
    out = []
    for loop in ("open", "closed"):
        text = (f"{loop} loop: the return rate falls as σ grows (mean over σ ≥ {STRONG_SIGMA} < mean over "
                f"σ ≤ {WEAK_SIGMA})")
        if premise[loop]:
            out.append(Claim.not_testable(text, premise[loop]))
            continue
        lo_rate, hi_rate = float(rates[loop][low].mean()), float(rates[loop][high].mean())
        out.append(Claim(text, hi_rate < lo_rate, f"{hi_rate:.3f} vs {lo_rate:.3f}"))
    same = (f"return rates of the SWG and the closed loop are almost the same (|difference| ≤ {SAME_RATE} at every "
            "σ)")
    failed = [p for p in premise.values() if p]
    if failed:
        out.append(Claim.not_testable(same, "; ".join(failed)))
    elif min(rates["open"].min(), rates["closed"].min()) >= 1:
        out.append(Claim.not_testable(same, "both loops returned from every perturbation (rate 1 at every σ): no σ "
                                            "tested their robustness"))
    else:
        holds, gap, worst = almost_same_rates(rates["open"], rates["closed"])
        out.append(Claim(same, holds, f"max |open − closed| = {gap:.3f} (at σ = {sig[worst]:.1f})"))
    return out


@dataclass(frozen=True)
class StandstillNumbers:
    """What the claim "some agents suddenly slowed down and came to a standstill" rests on, for one loop of one
    perturbation draw: the perturbed runs that did not return (speed after < 0.7 × the speed before, or diverged),
    pooled over the perturbed agents and σ.

    loop: the loop's name; early, late: (K,) each run's speed over the first :data:`EARLY_SHARE` and over the last
    half of the run after the perturbation, / its agent's speed before [1] (NaN: diverged); runs: how many runs
    were perturbed in all (K of them did not return); moving: the agents of this loop move forward before the
    perturbation (the premise); diverged: why there is no agent ("": there is one)."""

    loop: str
    early: np.ndarray
    late: np.ndarray
    runs: int
    moving: bool
    diverged: str = ""


@judge("locomotion-perturbation-standstill")
def standstill_claims(n: StandstillNumbers) -> list[Claim]:
    """The paper (main text, on the perturbations): "In the locomotion task, cases successfully returned by
    gradually regaining their speed. On the other hand, there were some agents that suddenly slowed down and came to
    a standstill."

    * some runs that did not return suddenly slowed down and came to a standstill: at least one with |late speed| ≤
      :data:`STANDSTILL` × the speed before (a standstill: the centre moves less than a tenth as fast as before,
      neither forward nor backward) whose early speed (the first :data:`EARLY_SHARE` of the run) was already below
      :data:`SUDDEN` × the speed before (the slow-down came with the perturbation, not gradually). A diverged run
      came to no standstill.

    Premises: the loop moves forward before the perturbation, and some run did not return. One claim per loop.
    """
    text = (f"{n.loop}: some perturbed runs that did not return suddenly slowed down and came to a standstill (speed "
            f"over the first {EARLY_SHARE:.0%} of the run < {SUDDEN} × the speed before, |speed| over its last half "
            f"≤ {STANDSTILL} × the speed before)")
    if n.diverged:
        return [Claim.not_testable(text, n.diverged)]
    if not n.moving:
        return [Claim.not_testable(text, "an agent perturbed here does not move forward before the perturbation")]
    early, late = np.asarray(n.early, float), np.asarray(n.late, float)
    with np.errstate(invalid="ignore"):
        lost = ~(late >= SUCCESS_RATIO)
        still = lost & (np.abs(late) <= STANDSTILL + EPS) & (early < SUDDEN)
        stopped = lost & (np.abs(late) <= STANDSTILL + EPS)
    if not lost.any():
        return [Claim.not_testable(text, f"every one of the {n.runs} perturbed runs returned")]
    return [Claim(text, bool(still.any()),
                  f"{int(still.sum())} of {int(lost.sum())} runs that did not return (of {n.runs}) stopped suddenly; "
                  f"{int(stopped.sum())} came to a standstill at all; {int(np.sum(lost & ~np.isfinite(late)))} "
                  "diverged")]


def return_rates(agent, state, closed, sigmas: np.ndarray, n_noise: int, before: int, after: int,
                 noise_seed0: int = 0, draw: str = "position") -> dict[str, np.ndarray]:
    """One agent, one loop type (``closed``: its FL, or None for the SWG); ``draw``: see :func:`perturbed`.

    Runs ``before`` steps (batch 1), then ONE batched run of len(sigmas) × n_noise perturbed copies for ``after``
    steps. Returns v_before (scalar array), v_after (S, n; over the last half of the ``after`` run), v_early (S, n;
    over its first :data:`EARLY_SHARE`, at least one step), success (S, n) and the centre x traces.
    """
    body = agent.body
    dt = body.dt
    x0, s0 = batched_centre_x(agent, state, before, closed=closed)
    v_before = late_speed(x0, dt)[0]
    sig = torch.as_tensor(np.repeat(sigmas, n_noise))
    seeds = torch.arange(noise_seed0, noise_seed0 + len(sig))
    if closed is None:
        rest = agent.brain.rest_length_at_steps(body.l, [s0.step], dt)[0]
    else:
        rest = closed.rest_length(body.l, s0)[0]
    start = perturbed(agent, s0, sig, seeds, rest, draw)
    x1, _ = batched_centre_x(agent, start, after, closed=closed)
    v_after = late_speed(x1, dt).reshape(len(sigmas), n_noise)
    k = max(1, int(round(EARLY_SHARE * after)))
    v_early = ((x1[k] - x1[0]) / (k * dt)).reshape(len(sigmas), n_noise)
    with np.errstate(invalid="ignore"):
        success = np.isfinite(v_after) & (v_after >= SUCCESS_RATIO * v_before) & (v_before > 0)
    return {"v_before": np.asarray(v_before), "v_after": v_after, "v_early": v_early, "success": success,
            "x_before": x0[:, 0], "x_after": x1}


@experiment(
    "locomotion-perturbation",
    parallel=True,
    paper_ref="Fig. 4(b), (c); Methods 'Locomotion task' (perturbation)",
    summary="return rate vs perturbation σ 0.0…1.0 × 100 seeds (one batched simulation per agent and loop), open "
            "(SWG) and closed (FL) loop, for the agents whose closed loop succeeded; variants paper (positions "
            "N(0, σ²)) and authors (positions N(0, (σP/8)²), velocities N(0, (σS)²))",
)
def run(ctx: Context) -> None:
    from bptsb_ros.training.checkpoint import load_agent, read_checkpoint

    settings, n_agents = settings_for(ctx)
    seeds = derived_seeds(ctx.seed, n_agents)
    n_noise, max_agents = ctx.settings["n_noise"], ctx.settings["max_agents"]
    before_s, after_s = ctx.settings["before_time"], ctx.settings["after_time"]
    sweep = train_agents(ctx, settings, seeds)
    results = sweep.results()
    ok = [s for s in seeds if f"seed-{s}" in results and results[f"seed-{s}"]["success"]]
    fallback = not ok
    if fallback:  # no closed loop succeeded: perturb the best one, and say so
        ranked = sorted((s for s in seeds if f"seed-{s}" in results),
                        key=lambda s: -np.nan_to_num(results[f"seed-{s}"]["ratio"], nan=-np.inf))
        ok = ranked[:1]
    chosen = ok[:max_agents]
    sigmas = np.array(SIGMAS)
    variants = ctx.settings.variants or {"paper": {"authors_draw": False}}
    ctx.row("forward agents", "agents whose training finished", "agents", len(results), n_agents)
    if not chosen:  # a result of this seed (every claim ∅), not a failure of the run
        _no_agent(ctx, variants, sigmas, f"no agent finished its forward training ({len(sweep.failed)} of "
                                         f"{n_agents} failed, e.g. {str(sweep.failed[0].get('error'))[:200]})"
                  if sweep.failed else "no agent to perturb")
        ctx.result.details = {"agents": [], "settings": settings.__dict__,
                              "failed_jobs": {r["name"]: r.get("error") for r in sweep.failed}}
        return
    agents = {}
    for s in chosen:
        run_dir = sweep.out_dir / "jobs" / f"seed-{s}"
        agents[s] = (load_agent(run_dir), task_state(read_checkpoint(run_dir)))
    per_variant = {}
    for vi, (name, variant) in enumerate(variants.items()):
        draw = "authors" if variant["authors_draw"] else "position"
        tag, label = ("", "") if vi == 0 else (f"{name}: ", f"[{name}: {DRAW_TEXT[draw]}] ")
        unit = " m" if draw == "position" else ""
        rates, v_before_open, example, lost = _variant_rates(ctx, agents, sigmas, n_noise, before_s, after_s, draw,
                                                             name)
        mean = {k: np.mean(v, 0) for k, v in rates.items()}
        for loop, loop_name in (("open", "SWG (open loop)"), ("closed", "FL (closed loop)")):
            for sg in (0.0, 0.3, 0.5, 1.0):
                i = int(np.argmin(np.abs(sigmas - sg)))
                ctx.row(f"{tag}{loop_name}", f"return rate at σ = {sg:.1f}{unit}", "1", float(mean[loop][i]))
        ctx.judge(claims, PerturbationRates(sigmas, mean["open"], mean["closed"], all(v > 0 for v in v_before_open),
                                            not fallback, name), label=label)
        for loop in ("open", "closed"):
            ctx.judge(standstill_claims, lost[loop], label=label)
        per_variant[name] = {"help": DRAW_TEXT[draw], "draw": draw, "rates": rates, "mean": mean,
                             "v_before_open": v_before_open, "example": example}
    first = per_variant[next(iter(per_variant))]
    rates, mean, example, dt = first["rates"], first["mean"], first["example"], agents[chosen[0]][0].dt
    ctx.phase("plotting the return rates")
    from bptsb_ros.analysis.locomotion_plots import plot_return_rate
    ctx.figure(plot_return_rate(ctx.out_dir / "return_rate.png", sigmas, rates, mean, example, chosen[0], before_s,
                                dt))
    ctx.result.details = {
        "agents": chosen, "successful_agents": [] if fallback else ok, "settings": settings.__dict__,
        "fallback_best_agent": fallback, "noise_seeds_per_sigma": n_noise, "before_s": before_s, "after_s": after_s,
        "sigmas": sigmas.tolist(),
        "return_rate_mean": {k: v.tolist() for k, v in mean.items()},
        "return_rate_per_agent": {k: [r.tolist() for r in v] for k, v in rates.items()},
        "open_speed_before": first["v_before_open"],
        "variants": {name: {"help": v["help"], "draw": v["draw"],
                            "return_rate_mean": {k: r.tolist() for k, r in v["mean"].items()},
                            "return_rate_per_agent": {k: [r.tolist() for r in x] for k, x in v["rates"].items()},
                            "open_speed_before": v["v_before_open"]} for name, v in per_variant.items()},
        "notes": ("No agent's closed loop succeeded; the agent with the best closed/open ratio was perturbed instead."
                  if fallback else ""),
    }


LOOP_NAMES = {"open": "SWG (open loop)", "closed": "FL (closed loop)"}


def _no_agent(ctx: Context, variants, sigmas: np.ndarray, why: str) -> None:
    """Every claim of a seed with no agent to perturb, not testable because ``why``."""
    ctx.log(f"locomotion-perturbation: {why}")
    nothing = np.full(len(sigmas), np.nan)
    for vi, (name, variant) in enumerate(variants.items()):
        draw = "authors" if variant["authors_draw"] else "position"
        label = "" if vi == 0 else f"[{name}: {DRAW_TEXT[draw]}] "
        ctx.judge(claims, PerturbationRates(sigmas, nothing, nothing, False, False, name, why), label=label)
        for loop in ("open", "closed"):
            ctx.judge(standstill_claims, StandstillNumbers(LOOP_NAMES[loop], np.zeros(0), np.zeros(0), 0, False, why),
                      label=label)


def _variant_rates(ctx: Context, agents: dict, sigmas: np.ndarray, n_noise: int, before_s: float, after_s: float,
                   draw: str, name: str) -> tuple[dict[str, list[np.ndarray]], list[float], dict,
                                                  dict[str, StandstillNumbers]]:
    """Return rates (S,) per agent and loop under one perturbation ``draw``; the open loops' speeds before; the
    first agent's traces (for the figure); per loop the runs that did not return (:class:`StandstillNumbers`, speeds
    / the speed before rounded to 1e-4, pooled over the agents that moved forward before)."""
    rates: dict[str, list[np.ndarray]] = {"open": [], "closed": []}
    v_before_open, example = [], {}
    early: dict[str, list[np.ndarray]] = {"open": [], "closed": []}
    late: dict[str, list[np.ndarray]] = {"open": [], "closed": []}
    runs = {"open": 0, "closed": 0}
    for i, (s, (agent, state)) in enumerate(agents.items()):
        dt = agent.dt
        for loop, fl in (("open", None), ("closed", agent.feedback)):
            ctx.log(f"locomotion-perturbation ({name}): agent {s}, {loop} loop, {len(sigmas)} σ "
                    f"× {n_noise} seeds batched, {draw} draw")
            out = return_rates(agent, state, fl, sigmas, n_noise, int(round(before_s / dt)), int(round(after_s / dt)),
                               draw=draw)
            rates[loop].append(out["success"].mean(1))
            if loop == "open":
                v_before_open.append(float(out["v_before"]))
            if i == 0:
                example[loop] = out
            v0 = float(out["v_before"])
            if v0 > 0:
                lost = ~out["success"]
                early[loop].append(np.round(out["v_early"][lost] / v0, 4))
                late[loop].append(np.round(out["v_after"][lost] / v0, 4))
                runs[loop] += out["success"].size
    lost_runs = {loop: StandstillNumbers(LOOP_NAMES[loop], np.concatenate(early[loop] or [np.zeros(0)]),
                                         np.concatenate(late[loop] or [np.zeros(0)]), runs[loop], runs[loop] > 0)
                 for loop in ("open", "closed")}
    return rates, v_before_open, example, lost_runs


@seed_figure("locomotion-perturbation")
def seed_figures(out_dir: Path, per_seed: Sequence[Mapping[str, Any]], seeds: Sequence[int]) -> list[Path]:
    """Across seeds: the return rate against σ of both loops (mean over each seed's perturbed agents), as the mean
    over seeds with the band of their min–max, one panel per perturbation draw (what :func:`claims` read; a seed
    without an agent has none)."""
    from bptsb_ros.analysis.seed_plots import plot_band_panels

    panels: dict[str, dict[str, Any]] = {}
    for res in per_seed:
        for _, args, _ in stored_calls(res, claims):
            n = args[0]
            if n.diverged:
                continue
            authors = n.variant == "authors"
            panel = panels.setdefault(n.variant or "paper", {
                "x": np.asarray(n.sigmas, float), "curves": {"SWG (open loop)": [], "FL (closed loop)": []},
                "xlabel": "perturbation σ [-] (× P/8 for positions, × S for velocities)" if authors else
                          "perturbation σ [m]"})
            panel["curves"]["SWG (open loop)"].append(np.asarray(n.rate_open, float))
            panel["curves"]["FL (closed loop)"].append(np.asarray(n.rate_closed, float))
    if not panels:
        return []
    return [plot_band_panels(out_dir / "return_rate_seeds.png", panels, xlabel="perturbation σ [m]",
                             ylabel="return rate [-]", ylim=(-0.03, 1.03),
                             title=f"Return rate (speed after ≥ 0.7 × before) over {len(seeds)} seeds, locomotion")]
