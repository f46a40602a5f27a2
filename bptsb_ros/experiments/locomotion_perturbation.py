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

from dataclasses import dataclass

import numpy as np
import torch

from bptsb_ros.experiments.claim_rules import at_most
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
from bptsb_ros.experiments.measured import judge
from bptsb_ros.experiments.registry import Context, experiment
from bptsb_ros.experiments.result import Claim

SIGMAS = tuple(round(0.1 * i, 1) for i in range(11))
#: |open − closed| return rate, averaged over σ, below which the two count as "almost the same"
SAME_RATE = 0.15
#: each perturbation draw in words (claims of a variant after the first are prefixed with it)
DRAW_TEXT = {"position": "positions shifted by N(0, σ²) [m]",
             "authors": "the authors' draw: positions N(0, (σ·P/8)²), velocities N(0, (σ·S)²)"}
#: the σ [m] at or below which a perturbation counts as weak, and at or above which as strong
WEAK_SIGMA, STRONG_SIGMA = 0.4, 0.6


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


@judge("locomotion-perturbation")
def claims(n: PerturbationRates) -> list[Claim]:
    """The paper (main text): "As the standard deviation of the perturbation increased, the return rates tended to
    decrease (Fig. 4(c)). However, the return rates of the sinusoidal drive and closed-loop control were almost the
    same, suggesting that the robustness was not impaired by the closed loop." The paper perturbs the closed loops
    that succeeded ("We then analyzed the stability of the closed-loop systems").

    * each loop's rate falls: mean rate over σ ≥ 0.6 < mean over σ ≤ 0.4. Premise: the loop locomotes before the
      perturbation (open loop: it moves forward; closed loop: it is one that succeeded).
    * almost the same: mean |rate_open − rate_closed| over σ ≤ :data:`SAME_RATE` (inclusive). Premises: both
      loops locomote, and some σ gives a rate below 1 (otherwise no perturbation tested their robustness).
    """
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
    same = (f"return rates of the SWG and the closed loop are almost the same (mean |difference| over σ "
            f"≤ {SAME_RATE})")
    failed = [p for p in premise.values() if p]
    if failed:
        out.append(Claim.not_testable(same, "; ".join(failed)))
    elif min(rates["open"].min(), rates["closed"].min()) >= 1:
        out.append(Claim.not_testable(same, "both loops returned from every perturbation (rate 1 at every σ): no σ "
                                            "tested their robustness"))
    else:
        gap = float(np.mean(np.abs(rates["open"] - rates["closed"])))
        out.append(Claim(same, at_most(gap, SAME_RATE), f"mean |open − closed| = {gap:.3f}"))
    return out


def return_rates(agent, state, closed, sigmas: np.ndarray, n_noise: int, before: int, after: int,
                 noise_seed0: int = 0, draw: str = "position") -> dict[str, np.ndarray]:
    """One agent, one loop type (``closed``: its FL, or None for the SWG); ``draw``: see :func:`perturbed`.

    Runs ``before`` steps (batch 1), then ONE batched run of len(sigmas) × n_noise perturbed copies for ``after``
    steps. Returns v_before (scalar array), v_after (S, n), success (S, n) and the centre x traces.
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
    with np.errstate(invalid="ignore"):
        success = np.isfinite(v_after) & (v_after >= SUCCESS_RATIO * v_before) & (v_before > 0)
    return {"v_before": np.asarray(v_before), "v_after": v_after, "success": success, "x_before": x0[:, 0],
            "x_after": x1}


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
    agents = {}
    for s in chosen:
        run_dir = sweep.out_dir / "jobs" / f"seed-{s}"
        agents[s] = (load_agent(run_dir), task_state(read_checkpoint(run_dir)))
    variants = ctx.settings.variants or {"paper": {"authors_draw": False}}
    per_variant = {}
    for vi, (name, variant) in enumerate(variants.items()):
        draw = "authors" if variant["authors_draw"] else "position"
        tag, label = ("", "") if vi == 0 else (f"{name}: ", f"[{name}: {DRAW_TEXT[draw]}] ")
        unit = " m" if draw == "position" else ""
        rates, v_before_open, example = _variant_rates(ctx, agents, sigmas, n_noise, before_s, after_s, draw, name)
        mean = {k: np.mean(v, 0) for k, v in rates.items()}
        for loop, loop_name in (("open", "SWG (open loop)"), ("closed", "FL (closed loop)")):
            for sg in (0.0, 0.3, 0.5, 1.0):
                i = int(np.argmin(np.abs(sigmas - sg)))
                ctx.row(f"{tag}{loop_name}", f"return rate at σ = {sg:.1f}{unit}", "1", float(mean[loop][i]))
        ctx.judge(claims, PerturbationRates(sigmas, mean["open"], mean["closed"], all(v > 0 for v in v_before_open),
                                            not fallback), label=label)
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


def _variant_rates(ctx: Context, agents: dict, sigmas: np.ndarray, n_noise: int, before_s: float, after_s: float,
                   draw: str, name: str) -> tuple[dict[str, list[np.ndarray]], list[float], dict]:
    """Return rates (S,) per agent and loop under one perturbation ``draw``; the open loops' speeds before; the
    first agent's traces (for the figure)."""
    rates: dict[str, list[np.ndarray]] = {"open": [], "closed": []}
    v_before_open, example = [], {}
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
    return rates, v_before_open, example
