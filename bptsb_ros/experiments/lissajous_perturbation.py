"""Perturbation return rates of the Lissajous agent, open loop (SWG) and closed loop (FL) (paper: Fig. 4(b,c);
Methods "Lissajous curve drawing task").

The trained single-curve agent runs on its limit cycle (open loop: the SWG; closed loop: the FL, first left
``settle`` periods to find its own cycle). The movable masses are displaced by N(0, σ²) per coordinate,
σ = 0.0, 0.1, …, 1.0, with ``seeds`` random seeds each (seed i draws the same standard-normal pattern for
every σ), and the system runs on for ``run`` periods. All 11 × seeds rows are ONE batched simulation per loop.

Error E: the paper's closed-loop error (per-period minimum over time shifts of the MSE to the target, mean over
the last ``eval_periods`` periods). Success (Methods): E / E_orig < 2. E_orig is read two ways:

* primary: the error of the same loop without perturbation (σ = 0), so a return means "back to what this loop
  drew before"; robustness of the open and the closed loop is compared on equal terms;
* literal: E_orig = the open-loop (SWG) error for the closed loop too ("E_orig was the error in the open loop").
  With a closed loop whose unperturbed error is already ≥ 2× the SWG's this rate is 0 at every σ; it is
  reported beside the primary one.

A row that blows up counts as not returned. The claims and their premises: :func:`claims`.

Two trials run side by side (the settings file's ``variants``), each with its own rows and claims: ``paper``
(the kick above) and ``authors`` (their published code, :func:`restart_errors`): every row restarts the trained
agent from its initial layout plus the same N(0, σ²) displacement, at rest, with the clock at t = 0; its error is
the mean of the training-window MSEs to the target (the training loss) over the last ``eval_windows`` windows of
the run, and it returns when that is < 2 × the same loop's unperturbed (σ = 0) error.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from bptsb_ros.experiments.claim_rules import (
    DRAWS_NMSE,
    SAME_RATE,
    almost_same_rates,
    draws,
    fmt,
)
from bptsb_ros.experiments.lissajous_agents import TrainedAgent, single_threaded, train_single_curve
from bptsb_ros.experiments.measured import judge, stored_calls
from bptsb_ros.experiments.registry import Context, experiment
from bptsb_ros.experiments.result import Claim, all_not_testable
from bptsb_ros.experiments.seeds import seed_figure
from bptsb_ros.sim.batched import run_population
from bptsb_ros.sim.perturbation import perturbation_batch
from bptsb_ros.tasks.lissajous import RETURN_RATIO, returned, windowed_shift_error_batch
from bptsb_ros.tasks.switching import CURVE_1

SIGMAS = np.round(np.arange(0.0, 1.0001, 0.1), 10)
#: each trial in words (claims of a variant after the first are prefixed with it); key: a restart trial
TRIAL_TEXT = {False: "a kick of the running cycle", True: "restarts from the displaced layout at rest, t = 0"}
#: Pearson r(σ, rate) below which a loop's return rate counts as "tending to decrease" with σ
FALL_R = -0.5
#: a run that did not return "converged" (to an attractor) when its error over the last evaluation periods differs
#: from its error over the as many periods before by at most this fraction of the former
SETTLED_REL = 0.2
#: the share of the runs that did not return which must have converged so (diverged runs count as not converged)
CONVERGED_SHARE = 0.9


@dataclass(frozen=True)
class PerturbationNumbers:
    """What the claims of lissajous-perturbation rest on.

    sigmas: (S,) perturbation σ [m], ascending; rate_open, rate_closed: (S,) return rates of the SWG and the FL
    (E_orig = the same loop unperturbed); open_nmse, closed_nmse: each loop's unperturbed error / target mean
    square; rate_literal_0: the FL's rate at σ = 0 with the literal E_orig (the SWG's error), for the evidence;
    variant: the trial's name (figures over seeds); diverged: why there is no trained agent ("": there is one)."""

    sigmas: np.ndarray
    rate_open: np.ndarray
    rate_closed: np.ndarray
    open_nmse: float
    closed_nmse: float
    rate_literal_0: float = float("nan")
    variant: str = ""
    diverged: str = ""


def _falls(sigmas: np.ndarray, rate: np.ndarray) -> tuple[bool, float]:
    """(rate at the largest σ < rate at the smallest and Pearson r(σ, rate) < FALL_R, r); r = 0 for a flat rate."""
    r = float(np.corrcoef(sigmas, rate)[0, 1]) if np.std(rate) > 0 else 0.0
    return bool(rate[-1] < rate[0] and r < FALL_R), r


@judge("lissajous-perturbation")
def claims(n: PerturbationNumbers) -> list[Claim]:
    """The paper (main text): "As the standard deviation of the perturbation increased, the return rates tended to
    decrease (Fig. 4(c)). However, the return rates of the sinusoidal drive and closed-loop control were almost the
    same, suggesting that the robustness was not impaired by the closed loop."

    * each loop's rate falls: rate(σ_max) < rate(σ_min) and Pearson r(σ, rate) < −0.5. Premise: the loop draws
      the trained curve unperturbed (error < :data:`DRAWS_NMSE` × target mean square): a return is a return "to
      the trained trajectory".
    * almost the same: |rate_SWG − rate_FL| ≤ :data:`~bptsb_ros.experiments.claim_rules.SAME_RATE` at every σ
      (:func:`~bptsb_ros.experiments.claim_rules.almost_same_rates`, the rule of locomotion-perturbation too).
      Premises: both loops draw the curve, and some σ gives a rate below 1 in one of them (if neither loop ever
      fails to return, the perturbations did not test robustness at all).

    A run whose agent's training diverged (``n.diverged``) has the same claims, not testable.
    """
    if n.diverged:
        return all_not_testable(claims(replace(n, diverged="")), n.diverged)
    sig, ro, rc = np.asarray(n.sigmas, float), np.asarray(n.rate_open, float), np.asarray(n.rate_closed, float)
    out = []
    for name, rate, nmse in (("SWG (open loop)", ro, n.open_nmse), ("closed loop (FL)", rc, n.closed_nmse)):
        text = (f"{name}: the return rate falls as σ grows (rate(σ={sig[-1]:.1f}) < rate(σ={sig[0]:.1f}) and "
                f"Pearson r(σ, rate) < {FALL_R})")
        if not draws(nmse):
            out.append(Claim.not_testable(text, f"the unperturbed {name} does not draw the trained curve (error / "
                                                f"target mean square {fmt(nmse)} ≥ {DRAWS_NMSE}): no trained "
                                                "trajectory to return to"))
            continue
        holds, r = _falls(sig, rate)
        out.append(Claim(text, holds, f"{rate[0]:.2f} → {rate[-1]:.2f}, r = {r:.2f}"))
    same = (f"the return rates of the SWG and the closed loop are almost the same (|difference| ≤ {SAME_RATE} at "
            "every σ; E_orig = the same loop unperturbed)")
    failing = [name for name, nmse in (("the SWG", n.open_nmse), ("the closed loop", n.closed_nmse))
               if not draws(nmse)]
    if failing:
        out.append(Claim.not_testable(same, f"{' and '.join(failing)} {'do' if len(failing) > 1 else 'does'} not "
                                            "draw the trained curve unperturbed "
                                            f"(error / target mean square: SWG {fmt(n.open_nmse)}, FL "
                                            f"{fmt(n.closed_nmse)}; drawn: < {DRAWS_NMSE})"))
    elif min(ro.min(), rc.min()) >= 1:
        out.append(Claim.not_testable(same, "both loops returned from every perturbation (rate 1 at every σ): no "
                                            "σ tested their robustness"))
    else:
        holds, gap, worst = almost_same_rates(ro, rc)
        literal = (f"; with the literal E_orig (SWG error) the FL rate at σ = {sig[0]:.1f} is {n.rate_literal_0:.2f}"
                   if np.isfinite(n.rate_literal_0) else "")
        out.append(Claim(same, holds, f"max |rate_SWG − rate_FL| = {gap:.2f} (at σ = {sig[worst]:.1f}){literal}"))
    return out


@dataclass(frozen=True)
class AttractorNumbers:
    """What the claim "systems that did not recover converged to untrained attractors" rests on, for one loop of one
    trial.

    loop: the loop's name; errors: (S, n) the error E of each perturbed run over the last evaluation periods [m²]
    (NaN: diverged), rows σ_j as in :data:`SIGMAS`; errors_before: (S, n) the same error over as many periods just
    before those; error_orig: the loop's unperturbed error E_orig [m²]; nmse_orig: E_orig / target mean square
    (the premise: the loop draws the trained curve); diverged: why there is no trained agent ("": there is one)."""

    loop: str
    errors: np.ndarray
    errors_before: np.ndarray
    error_orig: float
    nmse_orig: float
    diverged: str = ""


@judge("lissajous-perturbation-attractors")
def attractor_claims(n: AttractorNumbers) -> list[Claim]:
    """The paper (main text, on Fig. 4(b)): "In the Lissajous task, while there were systems that successfully
    returned to the trained trajectory, systems that did not recover finally converged to untrained attractors."

    A run did not recover when it did not return (E / E_orig ≥ 2, the paper's criterion, or diverged). It
    *converged* when its error stopped changing: |E_last − E_before| ≤ :data:`SETTLED_REL` × E_last, E_last over
    the last evaluation periods and E_before over as many periods just before. On a periodic orbit both are equal;
    on a chaotic or quasi-periodic attractor they fluctuate by less than that when averaged over 10 periods; a run
    still on its way back (or away) changes by more. The attractor is *untrained* because the run did not return
    (its error stays ≥ 2 × the trained cycle's). A diverged run converged to nothing.

    * the runs that did not return converged: at least :data:`CONVERGED_SHARE` of them ("finally converged" holds
      for the population, not necessarily for every run near the return threshold).

    Premises: the unperturbed loop draws the trained curve (< :data:`DRAWS_NMSE` × target mean square; there is a
    trained trajectory to fail to return to), and some run did not return. One claim per loop.
    """
    text = (f"{n.loop}: the perturbed runs that did not return converged to untrained attractors (at least "
            f"{CONVERGED_SHARE:.0%} of them with |E_last − E_before| ≤ {SETTLED_REL} × E_last over the last two "
            "evaluation windows, and finite)")
    if n.diverged:
        return [Claim.not_testable(text, n.diverged)]
    if not draws(n.nmse_orig):
        return [Claim.not_testable(text, f"the unperturbed {n.loop} does not draw the trained curve (error / target "
                                         f"mean square {fmt(n.nmse_orig)} ≥ {DRAWS_NMSE})")]
    e, e0 = np.asarray(n.errors, float).ravel(), np.asarray(n.errors_before, float).ravel()
    lost = ~returned(e, n.error_orig)
    if not lost.any():
        return [Claim.not_testable(text, f"every one of the {e.size} perturbed runs returned")]
    with np.errstate(invalid="ignore"):
        settled = np.isfinite(e) & np.isfinite(e0) & (np.abs(e - e0) <= SETTLED_REL * e)
    k, m = int(np.sum(settled & lost)), int(lost.sum())
    diverged = int(np.sum(lost & ~np.isfinite(e)))
    return [Claim(text, k >= CONVERGED_SHARE * m,
                  f"{k} of {m} runs that did not return converged ({diverged} diverged); of {e.size} runs")]


def perturbation_errors(trained: TrainedAgent, seeds: int, *, settle: int, run: int, eval_periods: int,
                        sigmas: np.ndarray = SIGMAS) -> dict[str, object]:
    """Errors E (len(sigmas)·seeds,) of the open and the closed loop after perturbation over the last
    ``eval_periods`` periods (``open``, ``closed``) and over as many periods before those (``open_before``,
    ``closed_before``; ``run`` must be at least twice ``eval_periods``); one CMP trajectory per row (for figures);
    the rollout throughput."""
    agent, body = trained.agent, trained.agent.body
    period = trained.period
    cmp = body.cmp_local
    steps = run * period
    disp = perturbation_batch(body.n_movable, seeds, sigmas, body.l.dtype)
    batch = disp.shape[0]
    out: dict[str, object] = {"batch": batch, "steps": steps}
    target_fn = CURVE_1.target
    # open loop: perturb the state where training ended
    s0 = trained.state
    rest0 = agent.brain.rest_length_at_steps(body.l, [s0.step], body.dt)[0]
    t0 = time.perf_counter()
    pop = run_population(body, steps, body.displaced(s0, disp, rest0), swg=agent.brain)
    out["open_wall_s"] = time.perf_counter() - t0
    traj = pop.tracked[:, :, 0].double().numpy()
    out["open"] = _errors(traj, s0.step, period, eval_periods, body.dt, trained, target_fn)
    out["open_before"] = _errors(traj[:-eval_periods * period], s0.step, period, eval_periods, body.dt, trained,
                                 target_fn)
    out["open_traj"] = pop.tracked[:, :, 0].numpy()
    out["open_diverged"] = pop.diverged.numpy()
    # closed loop: settle on its own cycle first; the rest length in force at the settled step is the FL's
    fb = agent.feedback
    settled = run_population(body, settle * period - 1, s0, feedback=fb, track=(cmp,)).final
    rest_c = fb.rest_length(body.l, settled)
    sc = body.step(settled, rest_c)
    t0 = time.perf_counter()
    popc = run_population(body, steps, body.displaced(sc, disp, rest_c), feedback=fb)
    out["closed_wall_s"] = time.perf_counter() - t0
    traj = popc.tracked[:, :, 0].double().numpy()
    out["closed"] = _errors(traj, sc.step, period, eval_periods, body.dt, trained, target_fn)
    out["closed_before"] = _errors(traj[:-eval_periods * period], sc.step, period, eval_periods, body.dt, trained,
                                   target_fn)
    out["closed_traj"] = popc.tracked[:, :, 0].numpy()
    out["closed_diverged"] = popc.diverged.numpy()
    out["t0_open"], out["t0_closed"] = s0.step * body.dt, sc.step * body.dt
    return out


def window_errors(traj: np.ndarray, target: np.ndarray, window: int, last: int) -> np.ndarray:
    """(T+1, B, 2) CMP trajectory from step 0 and its (T+1, 2) target → (B,) mean over the last ``last`` windows of
    ``window`` steps (of steps 1..T) of each window's MSE to the target (mean over the steps and both coordinates,
    the training loss) [m²]; NaN for a row with a NaN in those windows. T must hold ``last`` windows."""
    n = last * window
    if traj.shape[0] - 1 < n:
        raise ValueError(f"the run has {traj.shape[0] - 1} steps, fewer than {last} windows of {window}")
    sq = (traj[-n:] - target[-n:, None, :]) ** 2  # (n, B, 2)
    per_window = sq.reshape(last, window, *sq.shape[1:]).mean(axis=(1, 3))  # (last, B)
    return per_window.mean(0)


def restart_errors(trained: TrainedAgent, seeds: int, *, run: int, window: int, eval_windows: int,
                   sigmas: np.ndarray = SIGMAS) -> dict[str, object]:
    """The authors' trial: every row starts from the layout + σ·z (seed pattern z), at rest, at step 0, and runs
    ``run`` periods open loop (the SWG from t = 0) or closed loop (the FL from the displaced layout). Errors
    (len(sigmas)·seeds,) of each loop by :func:`window_errors` over the last ``eval_windows`` windows (``open``,
    ``closed``) and over as many windows before those (``open_before``, ``closed_before``), NaN for a diverged
    row."""
    agent, body = trained.agent, trained.agent.body
    disp = perturbation_batch(body.n_movable, seeds, sigmas, body.l.dtype)
    batch, steps = disp.shape[0], run * trained.period
    t = np.arange(steps + 1) * body.dt
    target = CURVE_1.target(t, trained.amplitude, trained.omega)
    rest0 = agent.brain.rest_length_at_steps(body.l, [0], body.dt)[0]
    pop = run_population(body, steps, body.initial_state(batch, rest_length=rest0, displacement=disp),
                         swg=agent.brain)
    fb = agent.feedback
    rest_c = fb.rest_length(body.l, body.initial_state(batch, displacement=disp))
    popc = run_population(body, steps, body.initial_state(batch, rest_length=rest_c, displacement=disp),
                          feedback=fb)
    out: dict[str, object] = {"batch": batch, "steps": steps}
    n = eval_windows * window
    for name, p in (("open", pop), ("closed", popc)):
        traj = p.tracked[:, :, 0].double().numpy()
        e = window_errors(traj, target, window, eval_windows)
        before = window_errors(traj[:-n], target[:-n], window, eval_windows)
        e[p.diverged.numpy()] = np.nan
        before[p.diverged.numpy()] = np.nan
        out[name], out[f"{name}_before"], out[f"{name}_diverged"] = e, before, p.diverged.numpy()
    return out


def _errors(traj: np.ndarray, k0: int, period: int, eval_periods: int, dt: float, trained: TrainedAgent,
            target_fn) -> np.ndarray:
    """(T+1, B, 2) CMP trajectory from step k0 → (B,) error over its last eval_periods periods."""
    tail = traj[-(eval_periods * period + 1):]
    k_first = k0 + traj.shape[0] - tail.shape[0]
    t = (k_first + np.arange(tail.shape[0] + period)) * dt
    return windowed_shift_error_batch(tail, target_fn(t, trained.amplitude, trained.omega), period)


@experiment(
    "lissajous-perturbation",
    paper_ref="Fig. 4(b,c); Methods 'Lissajous curve drawing task' (success E/E_orig < 2)",
    summary="displace the movable masses by N(0, σ²), σ = 0…1 step 0.1 × seeds, open loop (SWG) and closed loop "
            "(FL), one batched run each; return rate vs σ; variants paper (a kick of the running cycle) and authors "
            "(a restart from the displaced layout at t = 0)",
)
@single_threaded
def run(ctx: Context) -> None:
    from bptsb_ros.workflows.train import TrainingDiverged

    sim_time = ctx.settings["sim_time"]
    variants = ctx.settings.variants or {"paper": {"restart": False, "eval_windows": 0}}
    for name, variant in variants.items():
        if variant["restart"] and variant["eval_windows"] < 1:
            raise ValueError(f"lissajous-perturbation: variant {name} restarts its trials but compares "
                             f"{variant['eval_windows']} windows (eval_windows must be ≥ 1)")
        compared = variant["eval_windows"] if variant["restart"] else ctx.settings["eval_periods"]
        if ctx.settings["run_periods"] < 2 * compared:
            raise ValueError(f"lissajous-perturbation: variant {name} compares the last {compared} periods with the "
                             f"{compared} before them, so run_periods must be ≥ {2 * compared}, got "
                             f"{ctx.settings['run_periods']}")
    ctx.log(f"lissajous-perturbation: training the single-curve agent ({sim_time} s, seed {ctx.seed})")
    try:
        trained = train_single_curve(ctx.out_dir / "agent", sim_time=sim_time, seed=ctx.seed,
                                     progress=ctx.progress, fit_time=ctx.settings["fit_time"])
    except TrainingDiverged as err:  # a result of this seed (its claims ∅), not a failure of the run
        _diverged(ctx, variants, f"the single-curve agent's training diverged ({err})")
        return
    ctx.row("single-curve agent", "training diverged (1) or finished (0)", "1", 0.0, 0)
    target_ms = float(trained.metrics["evaluation"]["target_mean_square"])
    for vi, (name, variant) in enumerate(variants.items()):
        values = {**ctx.settings, **variant}
        trial = _restart_variant if variant["restart"] else _kick_variant
        trial(ctx, trained, name, TRIAL_TEXT[trial is _restart_variant], values, target_ms, first=vi == 0)


def _diverged(ctx: Context, variants, why: str) -> None:
    """The result of a seed whose agent could not be trained: the row that says so, every claim not testable."""
    ctx.log(f"lissajous-perturbation: {why}")
    ctx.row("single-curve agent", "training diverged (1) or finished (0)", "1", 1.0, 0)
    nothing = np.full(len(SIGMAS), np.nan)
    for vi, (name, variant) in enumerate(variants.items()):
        help_text = TRIAL_TEXT[bool(variant["restart"])]
        label = "" if vi == 0 else f"[{name}: {help_text}] "
        ctx.judge(claims, PerturbationNumbers(SIGMAS, nothing, nothing, np.nan, np.nan, variant=name, diverged=why),
                  label=label)
        _judge_attractors(ctx, {}, {}, {}, {}, label, why)
    ctx.result.details = {"seed": ctx.seed, "training_sim_time_s": ctx.settings["sim_time"], "diverged": why}


def _judge_attractors(ctx: Context, errors: dict, before: dict, orig: dict, nmse: dict, label: str,
                      diverged: str = "") -> None:
    """The "did not recover → converged to untrained attractors" claim of each loop (:func:`attractor_claims`);
    dicts keyed "open" and "closed"."""
    for loop, loop_name in (("open", "SWG (open loop)"), ("closed", "closed loop (FL)")):
        empty = np.full((len(SIGMAS), 0), np.nan)
        ctx.judge(attractor_claims, AttractorNumbers(loop_name, errors.get(loop, empty), before.get(loop, empty),
                                                     orig.get(loop, np.nan), nmse.get(loop, np.nan), diverged),
                  label=label)


def _kick_variant(ctx: Context, trained: TrainedAgent, name: str, help_text: str, values, target_ms: float, *,
                  first: bool) -> None:
    """Rows, claims, figure and details of the paper's trial: a kick of the running cycle
    (:func:`perturbation_errors`)."""
    sim_time, seeds, run_periods = values["sim_time"], values["n_seeds"], values["run_periods"]
    eval_periods, settle = values["eval_periods"], values["settle_periods"]
    n_s = len(SIGMAS)
    tag, label = ("", "") if first else (f"{name}: ", f"[{name}: {help_text}] ")
    ctx.log(f"lissajous-perturbation: {n_s} σ × {seeds} seeds, {run_periods} periods, open and closed loop (kick)")
    res = perturbation_errors(trained, seeds, settle=settle, run=run_periods, eval_periods=eval_periods)
    e_open = np.asarray(res["open"]).reshape(n_s, seeds)
    e_closed = np.asarray(res["closed"]).reshape(n_s, seeds)
    e_open_orig = float(np.median(e_open[0]))  # σ = 0: every row is the unperturbed run
    e_closed_orig = float(np.median(e_closed[0]))
    rate_open = returned(e_open, e_open_orig).mean(1)
    rate_closed = returned(e_closed, e_closed_orig).mean(1)
    rate_literal = returned(e_closed, e_open_orig).mean(1)
    for s, ro, rc, rl in zip(SIGMAS, rate_open, rate_closed, rate_literal, strict=True):
        ctx.row(f"{tag}SWG (open loop), σ = {s:.1f}", "return rate", "1", ro)
        ctx.row(f"{tag}FL (closed loop), σ = {s:.1f}", "return rate", "1", rc)
        ctx.row(f"{tag}FL, E_orig = SWG error (literal), σ = {s:.1f}", "return rate", "1", rl)
    ctx.row(f"{tag}SWG (open loop)", "unperturbed error E_orig", "m²", e_open_orig)
    ctx.row(f"{tag}FL (closed loop)", "unperturbed error E_orig", "m²", e_closed_orig)
    rows = res["batch"]
    steps = res["steps"]
    for loop in ("open", "closed"):
        wall = float(res[f"{loop}_wall_s"])
        ctx.row(f"{tag}{'SWG' if loop == 'open' else 'FL'} batched sweep", "rollouts per second", "1/s", rows / wall)
    ctx.row(f"{tag}SWG (open loop)", "unperturbed error / target mean square", "1", e_open_orig / target_ms)
    ctx.row(f"{tag}FL (closed loop)", "unperturbed error / target mean square", "1", e_closed_orig / target_ms)
    ctx.judge(claims, PerturbationNumbers(SIGMAS, rate_open, rate_closed, e_open_orig / target_ms,
                                          e_closed_orig / target_ms, float(rate_literal[0]), name), label=label)
    before = {k: np.asarray(res[f"{k}_before"]).reshape(n_s, seeds) for k in ("open", "closed")}
    _judge_attractors(ctx, {"open": e_open, "closed": e_closed}, before,
                      {"open": e_open_orig, "closed": e_closed_orig},
                      {"open": e_open_orig / target_ms, "closed": e_closed_orig / target_ms}, label)
    ctx.phase("plotting the return rates")
    from bptsb_ros.analysis.autonomy_plots import plot_perturbation

    path = plot_perturbation(ctx.out_dir / "perturbation.png", SIGMAS, {
        "SWG (open loop)": rate_open, "FL (closed loop)": rate_closed,
        "FL, E_orig = SWG error (literal)": rate_literal},
        closed_traj=np.asarray(res["closed_traj"]), closed_ok=returned(e_closed, e_closed_orig).reshape(-1),
        dt=trained.agent.dt, t0=float(res["t0_closed"]), target=lambda t: CURVE_1.target(t, trained.amplitude,
                                                                                          trained.omega),
        seeds=seeds, period=trained.period)
    ctx.figure(path)
    ctx.result.details.update({
        "seed": ctx.seed, "training_sim_time_s": sim_time, "seeds_per_sigma": seeds, "sigmas": SIGMAS,
        "run_periods_after_perturbation": run_periods, "eval_periods": eval_periods, "closed_settle_periods": settle,
        "success_criterion": f"E / E_orig < {RETURN_RATIO}",
        "errors_open": e_open, "errors_closed": e_closed,
        "errors_open_before": before["open"], "errors_closed_before": before["closed"],
        "diverged_open": int(np.sum(res["open_diverged"])), "diverged_closed": int(np.sum(res["closed_diverged"])),
        "batched_rows": rows, "steps_per_row": steps,
        "wall_s": {"open": res["open_wall_s"], "closed": res["closed_wall_s"]},
        "body_steps_per_second": {k: rows * steps / float(res[f"{k}_wall_s"]) for k in ("open", "closed")},
        "training_loss_last": trained.metrics["loss"][-1],
    })
    notes = []
    if rate_open.min() == 1.0:
        notes.append("The open loop returned from every perturbation: a damped body driven by a fixed periodic "
                     "rest-length signal forgets its initial condition (here no perturbation up to σ = 1 m pushed it "
                     "onto another attractor), so its return rate does not fall with σ as the paper's does.")
    if rate_literal[0] < 1.0:
        notes.append(f"With the literal E_orig (the SWG's error also for the closed loop) the unperturbed closed loop "
                     f"already fails (its error is {e_closed_orig / e_open_orig:.2f}× the SWG's, ≥ 2), hence the "
                     "primary reading E_orig = the same loop unperturbed.")
    ctx.result.details["notes"] = " ".join(notes)


def _restart_variant(ctx: Context, trained: TrainedAgent, name: str, help_text: str, values, target_ms: float, *,
                     first: bool) -> None:
    """Rows, claims and details of the authors' restart trial (:func:`restart_errors`)."""
    seeds, n_s = values["n_seeds"], len(SIGMAS)
    window = int(trained.agent.config["training"]["update_steps"])
    tag, label = ("", "") if first else (f"{name}: ", f"[{name}: {help_text}] ")
    ctx.log(f"lissajous-perturbation: {n_s} σ × {seeds} seeds restarted from the layout at t = 0, "
            f"{values['run_periods']} periods (the authors' trial)")
    res = restart_errors(trained, seeds, run=values["run_periods"], window=window,
                         eval_windows=values["eval_windows"])
    e_open = np.asarray(res["open"]).reshape(n_s, seeds)
    e_closed = np.asarray(res["closed"]).reshape(n_s, seeds)
    orig = {"open": float(np.median(e_open[0])), "closed": float(np.median(e_closed[0]))}  # σ = 0: unperturbed
    rate_open, rate_closed = returned(e_open, orig["open"]).mean(1), returned(e_closed, orig["closed"]).mean(1)
    for s, ro, rc in zip(SIGMAS, rate_open, rate_closed, strict=True):
        ctx.row(f"{tag}SWG (open loop), σ = {s:.1f}", "return rate", "1", ro)
        ctx.row(f"{tag}FL (closed loop), σ = {s:.1f}", "return rate", "1", rc)
    for loop, loop_name in (("open", "SWG (open loop)"), ("closed", "FL (closed loop)")):
        ctx.row(f"{tag}{loop_name}", "unperturbed error E_orig", "m²", orig[loop])
        ctx.row(f"{tag}{loop_name}", "unperturbed error / target mean square", "1", orig[loop] / target_ms)
    ctx.judge(claims, PerturbationNumbers(SIGMAS, rate_open, rate_closed, orig["open"] / target_ms,
                                          orig["closed"] / target_ms, variant=name), label=label)
    before = {k: np.asarray(res[f"{k}_before"]).reshape(n_s, seeds) for k in ("open", "closed")}
    _judge_attractors(ctx, {"open": e_open, "closed": e_closed}, before, orig,
                      {k: v / target_ms for k, v in orig.items()}, label)
    ctx.result.details.setdefault("variants", {})[name] = {
        "help": help_text, "trial": "restart", "window_steps": window, "eval_windows": values["eval_windows"],
        "run_periods": values["run_periods"], "errors_open": e_open, "errors_closed": e_closed,
        "errors_open_before": before["open"], "errors_closed_before": before["closed"],
        "unperturbed_error": orig, "rate_open": rate_open, "rate_closed": rate_closed,
        "success_criterion": f"mean error of the last {values['eval_windows']} windows < {RETURN_RATIO} × the same "
                             "loop's unperturbed one",
        "diverged_open": int(np.sum(res["open_diverged"])), "diverged_closed": int(np.sum(res["closed_diverged"]))}


@seed_figure("lissajous-perturbation")
def seed_figures(out_dir: Path, per_seed: Sequence[Mapping[str, Any]], seeds: Sequence[int]) -> list[Path]:
    """Across seeds: the return rate against σ of both loops, as the mean over seeds with the band of their min–max,
    one panel per trial (the numbers :func:`claims` read in each seed; a seed without a trained agent has none)."""
    from bptsb_ros.analysis.seed_plots import plot_band_panels

    panels: dict[str, dict[str, Any]] = {}
    for res in per_seed:
        for label, args, _ in stored_calls(res, claims):
            n = args[0]
            if n.diverged:
                continue
            name = label.strip().strip("[]") or f"{n.variant or 'paper'}: {TRIAL_TEXT[False]}"
            panel = panels.setdefault(name, {"x": np.asarray(n.sigmas, float),
                                             "curves": {"SWG (open loop)": [], "FL (closed loop)": []}})
            panel["curves"]["SWG (open loop)"].append(np.asarray(n.rate_open, float))
            panel["curves"]["FL (closed loop)"].append(np.asarray(n.rate_closed, float))
    if not panels:
        return []
    return [plot_band_panels(out_dir / "perturbation_seeds.png", panels, xlabel="perturbation σ [m]",
                             ylabel="return rate [-]", ylim=(-0.03, 1.03),
                             title=f"Return rate (E / E_orig < 2) over {len(seeds)} seeds, Lissajous")]
