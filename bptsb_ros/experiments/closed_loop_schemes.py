"""Simultaneous training for a closed loop, schemes 1–3 (paper: supplement "Simultaneous training for a closed
loop" and its table): 3 Lissajous curves × 5 seeds, each an independent job.

Per (curve, seed): the preliminary SWG training (config/lissajous_single.yaml with the curve), the FL fitted by
regression, its closed-loop error E_before; then from that agent scheme 2 and scheme 3
(:mod:`bptsb_ros.tasks.feedback_schemes`), each closed afterwards (E_after); and scheme 1 from scratch.
The closed-loop error is the paper's: per-period minimum over time shifts of the MSE, mean over
``eval_periods`` periods after as many periods of settling in the closed loop.

Claims (:func:`claims`): scheme 1 draws no curve (closed-loop error < :data:`DRAWS_NMSE` × target mean square
counts as drawing) and its closed loops come to rest (the CMP's motion over the evaluation periods below
:data:`STATIONARY_MS` × the target mean square); schemes 2 and 3 improve only some systems, at most half of them
(ratio E_after / E_before < 1: paper "only 7" and "a mere 6" of 15).
"""

from __future__ import annotations

import copy
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bptsb_ros.experiments.claim_rules import DRAWS_NMSE
from bptsb_ros.experiments.common import derived_seeds
from bptsb_ros.experiments.lissajous_agents import TrainedAgent, single_threaded, train_single_curve
from bptsb_ros.experiments.measured import judge
from bptsb_ros.experiments.registry import Context, experiment
from bptsb_ros.experiments.result import Claim
from bptsb_ros.files.safe_write import write_atomic
from bptsb_ros.sim.batched import run_population
from bptsb_ros.tasks.lissajous import windowed_shift_error_batch
from bptsb_ros.tasks.switching import CURVE_1, CURVE_SWITCH, CURVE_TIMING, Curve

__all__ = ["DRAWS_NMSE", "SchemeNumbers", "claims", "run", "scheme_job"]

CURVES = (CURVE_1, CURVE_SWITCH, CURVE_TIMING)
#: a closed loop is in a stationary state when the CMP's motion (mean square about its mean) is below this ×
#: the target's mean square: an RMS motion under a tenth of the figure's
STATIONARY_MS = 0.01
#: the paper's table: E_after / E_before per curve (rows as CURVES) and seed 0..4
PAPER_SCHEME2 = ((1.00, 1.15, 0.87, 1.09, 0.59), (2.11, 1.24, 0.99, 0.68, 1.04), (0.97, 1.26, 0.94, 1.18, 0.82))
PAPER_SCHEME3 = ((0.83, 1.68, 1.11, 1.89, 1.62), (0.58, 1.56, 0.34, 0.67, 1.33), (0.65, 1.03, 1.33, 1.08, 0.66))


@dataclass(frozen=True)
class SchemeNumbers:
    """What the claims of closed-loop-schemes rest on, each (curves, seeds): the closed-loop errors [m²] of the
    preliminary agent (``before``, NaN: its training diverged) and after each scheme (NaN: diverged);
    ``target_mean_square`` [m²]; ``scheme1_trained``: scheme 1's training finished without diverging;
    ``note``: which preliminary trainings diverged (for the evidence); ``scheme1_motion``: the mean square [m²] of
    the CMP about its mean over the evaluation periods of scheme 1's closed loop (NaN: diverged; None: a run made
    before it was measured)."""

    before: np.ndarray
    scheme1: np.ndarray
    scheme2: np.ndarray
    scheme3: np.ndarray
    target_mean_square: np.ndarray
    scheme1_trained: np.ndarray
    note: str = ""
    scheme1_motion: np.ndarray | None = None


@judge("closed-loop-schemes")
def claims(n: SchemeNumbers) -> list[Claim]:
    """The paper (supplement, "Simultaneous training for a closed loop"): "We trained 15 systems and Scheme 1 could
    not make any systems draw the desired trajectory, even after repeated parameter updates." and "In regard to the
    second and third schemes, we compared the error before and after applying them. Only 7 systems out of 15 were
    improved in terms of the error with Scheme 2, and Scheme 3 enhanced the trajectory accuracy of a mere 6
    systems."

    * scheme 1 draws nothing: no system's closed-loop error < :data:`DRAWS_NMSE` × target mean square. Premise: some
      scheme-1 training finished (a training that diverged made no attempt to draw).
    * "All the systems transitioned into a stationary state quickly after the body started moving due to the
      distribution of the initial values of the feedback weights": every scheme-1 system whose training finished
      has a closed loop at rest — the CMP's motion (mean square about its mean over the evaluation periods, after
      as many periods of settling) below :data:`STATIONARY_MS` × the target mean square. A closed loop that blew
      up is not at rest. "Quickly" is not tested: the state is measured after the training and the settling.
      Premises: some scheme-1 training finished, and the motion was measured.
    * schemes 2 and 3 improve only some systems: 0 < improved ≤ half of the systems with a preliminary agent
      ("only 7", "a mere 6" of 15: fewer than half). Improved: E_after / E_before < 1 (a diverged scheme is not).
      Premise: at least two systems with a preliminary agent (with one, "some but not most" cannot happen).
    """
    before = np.asarray(n.before, float)
    total = before.size
    out = []
    text1 = (f"scheme 1 (closed loop from scratch) makes no system draw the curve (closed-loop error < "
             f"{DRAWS_NMSE} × target mean square counts as drawing)")
    trained1 = np.asarray(n.scheme1_trained, bool)
    if not trained1.any():
        out.append(Claim.not_testable(text1, f"every scheme-1 training diverged ({total} of {total})"))
    else:
        with np.errstate(invalid="ignore"):
            drawn1 = int(np.sum(np.asarray(n.scheme1, float) / np.asarray(n.target_mean_square, float) < DRAWS_NMSE))
        out.append(Claim(text1, drawn1 == 0, f"{drawn1} of {total} draw ({int(trained1.sum())} trainings finished)"))
    text_rest = (f"scheme 1's closed loops transition into a stationary state (CMP motion mean square < {STATIONARY_MS}"
                 " × target mean square in every system whose scheme-1 training finished)")
    if not trained1.any():
        out.append(Claim.not_testable(text_rest, f"every scheme-1 training diverged ({total} of {total})"))
    elif n.scheme1_motion is None:
        out.append(Claim.not_testable(text_rest, "the CMP's motion in scheme 1's closed loop was not measured in this "
                                                 "run"))
    else:
        with np.errstate(invalid="ignore"):
            rest = np.asarray(n.scheme1_motion, float) / np.asarray(n.target_mean_square, float) < STATIONARY_MS
        k = int(np.sum(rest & trained1))
        worst = np.asarray(n.scheme1_motion, float)[trained1] / np.asarray(n.target_mean_square, float)[trained1]
        out.append(Claim(text_rest, k == int(trained1.sum()),
                         f"{k} of {int(trained1.sum())} at rest; largest motion / target mean square "
                         f"{float(np.max(worst)) if np.isfinite(worst).all() else float('nan'):.3g}"))
    valid = int(np.sum(np.isfinite(before)))
    for name, after in (("scheme 2", n.scheme2), ("scheme 3", n.scheme3)):
        text = f"{name} improves only some systems (more than none, at most half; paper: 7 and 6 of 15)"
        if valid < 2:
            out.append(Claim.not_testable(text, f"{valid} system(s) with a preliminary agent to improve, need ≥ 2"
                                                f"{n.note}"))
            continue
        with np.errstate(invalid="ignore"):
            improved = int(np.sum(np.asarray(after, float) / before < 1))
        out.append(Claim(text, 0 < improved <= valid / 2, f"{improved} of {valid} improved{n.note}"))
    return out


def closed_loop_error(trained: TrainedAgent, state, curve: Curve, periods: int) -> float:
    """Closed-loop error [m²] from ``state``: settle ``periods`` periods, then the windowed shift-min error over
    ``periods`` periods. NaN if the loop blew up."""
    return closed_loop_run(trained, state, curve, periods)[0]


def closed_loop_run(trained: TrainedAgent, state, curve: Curve, periods: int) -> tuple[float, float]:
    """(closed-loop error [m²] as :func:`closed_loop_error`, the CMP's motion: its mean square about its mean over
    the same ``periods`` periods [m²], per coordinate as the target mean square); NaN, NaN if the loop blew up."""
    agent, period = trained.agent, trained.period
    steps = 2 * periods * period
    pop = run_population(agent.body, steps, state, feedback=agent.feedback)
    if bool(pop.diverged.any()):
        return float("nan"), float("nan")
    cmp = pop.tracked[-(periods * period + 1):, :, 0].double().numpy()
    k_first = state.step + steps - periods * period
    t = (k_first + np.arange(cmp.shape[0] + period)) * agent.dt
    error = float(windowed_shift_error_batch(cmp, curve.target(t, trained.amplitude, trained.omega), period)[0])
    return error, float(np.mean((cmp - cmp.mean(0)) ** 2))


def scheme_job(run_dir: str, curve: tuple[float, float, float], seed: int, pre_time: float, add_time: float,
               eval_periods: int, scheme1_time: float) -> dict:
    """One (curve, seed): preliminary training, E_before, schemes 2 and 3 (then closed), scheme 1 from scratch.

    A preliminary training that diverges (the paper's learning rates can blow a body up) is a result, not a failure
    of the experiment: its errors are NaN, ``preliminary_diverged`` says where, and scheme 1 still runs."""
    import torch

    from bptsb_ros.agent import build_agent
    from bptsb_ros.experiments.common import packaged_config
    from bptsb_ros.tasks.feedback_schemes import train_scheme1, train_scheme2, train_scheme3
    from bptsb_ros.workflows.train import TrainingDiverged

    c = Curve(*curve)
    cfg = packaged_config("lissajous_single", {"lissajous.alpha": c.alpha, "lissajous.beta": c.beta,
                                               "lissajous.delta": c.delta}, seed=seed)
    fresh = build_agent(cfg)
    shape = TrainedAgent(fresh, fresh.body.initial_state(1), {}, Path(run_dir))
    amp, omega, period = shape.amplitude, shape.omega, shape.period

    def target(t: torch.Tensor) -> torch.Tensor:
        return c.target(t, amp, omega)

    ms = float(np.mean((c.target(np.arange(100) / 100, amp, omega)) ** 2))
    updates = max(1, int(round(add_time / (period * fresh.dt))))
    out = {"curve": str(c), "seed": seed, "target_mean_square": ms, "updates": updates, "preliminary_diverged": None}
    try:
        pre = train_single_curve(Path(run_dir) / "preliminary", sim_time=pre_time, seed=seed, curve=c,
                                 fit_time=100, eval_periods=2)
    except TrainingDiverged as err:
        pre = None
        out["preliminary_diverged"] = str(err).split(";")[0]
        out.update({k: float("nan") for k in ("before", "scheme2", "scheme3")})
    schemes = (("scheme2", train_scheme2), ("scheme3", train_scheme3)) if pre is not None else ()
    if pre is not None:
        out["before"] = closed_loop_error(pre, pre.state, c, eval_periods)
    for name, fn in schemes:
        agent = copy.deepcopy(pre.agent)
        kw = {"seed": seed} if name == "scheme3" else {}
        res = fn(agent, pre.state, target, updates, **kw)
        trained = TrainedAgent(agent, res.state, {}, pre.run_dir)
        out[name] = float("nan") if res.diverged is not None else closed_loop_error(trained, res.state, c,
                                                                                     eval_periods)
        out[f"{name}_loss_first_last"] = [res.losses[0], res.losses[-1]] if res.losses else None
        out[f"{name}_diverged_at_update"] = res.diverged
        out[f"{name}_guard"] = res.guard
    res1 = train_scheme1(fresh, target, max(1, int(round(scheme1_time / (period * fresh.dt)))), seed=seed)
    out["scheme1"], out["scheme1_motion"] = (float("nan"), float("nan")) if res1.diverged is not None else \
        closed_loop_run(TrainedAgent(fresh, res1.state, {}, Path(run_dir)), res1.state, c, eval_periods)
    out["scheme1_loss_first_last"] = [res1.losses[0], res1.losses[-1]] if res1.losses else None
    out["scheme1_diverged_at_update"] = res1.diverged
    out["scheme1_guard"] = res1.guard
    Path(run_dir).mkdir(parents=True, exist_ok=True)
    write_atomic(Path(run_dir, "scheme.json"), json.dumps(out))
    return out


@experiment(
    "closed-loop-schemes",
    parallel=True,
    paper_ref="supplement 'Simultaneous training for a closed loop' and its table",
    summary="3 curves × 5 seeds (jobs): scheme 1 (closed loop from scratch), 2 (BPTSB through SWG + body + FL, "
            "L = L_traj + 0.1·L_FB), 3 (FL re-fitted by regression after every update); E_after / E_before",
)
@single_threaded
def run(ctx: Context) -> None:
    n_curves, seeds = ctx.settings["n_curves"], ctx.settings["n_seeds"]
    pre_time, add_time = ctx.settings["pretrain_time"], ctx.settings["add_time"]
    eval_periods, scheme1_time = ctx.settings["eval_periods"], ctx.settings["scheme1_time"]
    inner = derived_seeds(ctx.seed, seeds)
    grid = [(ci, s) for ci in range(n_curves) for s in inner]
    jobs = [(str(ctx.out_dir / f"curve{ci}_seed{s}"), (CURVES[ci].alpha, CURVES[ci].beta, CURVES[ci].delta), s,
             pre_time, add_time, eval_periods, scheme1_time) for ci, s in grid]
    ctx.log(f"closed-loop-schemes: {len(jobs)} jobs (preliminary {pre_time} s, schemes {add_time} s)")
    results = ctx.run_jobs(scheme_job, jobs,
                           names=[f"curve {CURVES[ci]} seed {s}" for ci, s in grid])
    table = {k: np.full((n_curves, seeds), np.nan) for k in ("before", "scheme1", "scheme2", "scheme3")}
    for (ci, s), res in zip(grid, results, strict=True):
        for k in table:
            table[k][ci, inner.index(s)] = res[k]
    ms = np.array([[r["target_mean_square"] for r in results[i * seeds:(i + 1) * seeds]] for i in range(n_curves)])
    ratio2 = table["scheme2"] / table["before"]
    ratio3 = table["scheme3"] / table["before"]
    for ci in range(n_curves):
        for j in range(seeds):
            # the paper's table has a column per seed; ours are other draws, matched by position
            p2 = PAPER_SCHEME2[ci][j] if j < len(PAPER_SCHEME2[ci]) else None
            p3 = PAPER_SCHEME3[ci][j] if j < len(PAPER_SCHEME3[ci]) else None
            ctx.row(f"scheme 2, {CURVES[ci]}, training {j + 1}", "E_after / E_before", "1", ratio2[ci, j], p2)
            ctx.row(f"scheme 3, {CURVES[ci]}, training {j + 1}", "E_after / E_before", "1", ratio3[ci, j], p3)
    n = n_curves * seeds
    failed = [f"{r['curve']} seed {r['seed']}: {r['preliminary_diverged']}" for r in results
              if r["preliminary_diverged"]]
    note = f" ({len(failed)} preliminary training(s) diverged: {'; '.join(failed)})" if failed else ""
    improved2 = int(np.sum(ratio2 < 1))
    improved3 = int(np.sum(ratio3 < 1))
    draws1 = int(np.sum(table["scheme1"] / ms < DRAWS_NMSE))
    draws_before = int(np.sum(table["before"] / ms < DRAWS_NMSE))
    ctx.row("scheme 1", "systems drawing the curve", f"of {n}", draws1, "0 of 15")
    ctx.row("scheme 2", "systems improved (ratio < 1)", f"of {n}", improved2, "7 of 15")
    ctx.row("scheme 3", "systems improved (ratio < 1)", f"of {n}", improved3, "6 of 15")
    ctx.row("regression only (before)", "systems drawing the curve", f"of {n}", draws_before)
    ctx.row("preliminary training", "diverged (no system to improve)", f"of {n}", len(failed), 0)
    trained1 = np.array([[r["scheme1_diverged_at_update"] is None for r in results[i * seeds:(i + 1) * seeds]]
                         for i in range(n_curves)])
    motion1 = np.full((n_curves, seeds), np.nan)
    for (ci, s), res in zip(grid, results, strict=True):
        motion1[ci, inner.index(s)] = res["scheme1_motion"]
    ctx.row("scheme 1", "closed loops at rest (CMP motion < 0.01 × target mean square)", f"of {n}",
            int(np.sum(motion1 / ms < STATIONARY_MS)), "15 of 15")
    ctx.judge(claims, SchemeNumbers(table["before"], table["scheme1"], table["scheme2"],
                                    table["scheme3"], ms, trained1, note, motion1))
    ctx.phase("plotting the scheme ratios")
    from bptsb_ros.analysis.autonomy_plots import plot_scheme_ratios

    ctx.figure(plot_scheme_ratios(ctx.out_dir / "schemes.png", [str(c) for c in CURVES[:n_curves]],
                                  inner, ratio2, ratio3,
                                  np.array(PAPER_SCHEME2)[:n_curves], np.array(PAPER_SCHEME3)[:n_curves]))
    ctx.result.details = {"seeds": inner,
                          "curves": [str(c) for c in CURVES[:n_curves]],
                          "preliminary_sim_time_s": pre_time, "scheme_sim_time_s": add_time,
                          "scheme1_sim_time_s": scheme1_time, "eval_periods": eval_periods,
                          "errors": table, "scheme1_motion": motion1, "target_mean_square": ms,
                          "ratio_scheme2": ratio2, "ratio_scheme3": ratio3,
                          "jobs": results, "preliminary_diverged": failed,
                          "fl_learning_rate": "1.0 (schemes 1, 2; not in the paper)",
                          "scheme1_fl_init": "W ~ N(0, 0.1²)", "scheme3_fit": "ridge (AIC) on the last 10 windows, "
                          "input noise σ 0.08, after every update",
                          "notes": f"{n} systems ({n_curves} curves × {seeds} seeds), preliminary training "
                                   f"{pre_time:g} s (paper config 2,000 s), each scheme {add_time:g} s; the paper "
                                   "gives no scheme durations and no FL learning rate."}
