#!/usr/bin/env python3
"""Mutation check: does the test suite notice when the code is wrong?

Each mutant is a one-line change written as an exact text replacement in one file of the package. For each,
the script copies the working tree (tracked and untracked, non-ignored files) to a temporary directory, applies
the replacement there (the working tree itself is never modified, so Ctrl-C is always safe), runs the fast
tests named for that mutant with ``pytest -x``, and reports the mutant **killed** (a test failed) or
**survived** (every test passed: the tests cannot see that bug).

Usage (``make mutation`` runs the first form)::

    python scripts/mutation_check.py                 # every mutant; exit 0 only if every one is killed
    python scripts/mutation_check.py --list          # the mutants and their tests, run nothing
    python scripts/mutation_check.py -k swg -k qos   # only mutants whose id contains one of the words
    python scripts/mutation_check.py -k qos --tests tests/test_bags_recorder.py   # which test kills them?

Exit status: 0 all killed, 1 some survived, 2 the check itself could not run (a mutant's target text is not
found exactly once — update it when the line moves —, the unmutated tests fail, or the copy imports the
package from elsewhere).
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


@dataclass(frozen=True)
class Mutant:
    """Replace ``old`` (must occur exactly once in ``path``) by ``new``; ``tests`` are pytest node ids/paths."""

    id: str
    path: str
    old: str
    new: str
    what: str
    tests: tuple[str, ...]


BRAINS = "tests/test_brains.py"
TASKS = "tests/test_tasks.py"
# The numba kernel is the default backend, so the physics tests run through it; test_kernel.py pins the torch
# path to the kernel (float64, 1e-12), which is how a mutant of the torch path is caught.
BODY = ("tests/test_physics.py", "tests/test_simulate.py", "tests/test_kernel.py")
MNIST_LIVE = "tests/test_mnist_live.py"
LIVE_CORE = "tests/test_live_core.py"
CLAIMS_SWG = "tests/test_claims_swg.py"
CLAIMS_MNIST = "tests/test_claims_mnist.py"
CLAIMS_TS = "tests/test_claims_timeseries.py"
TS = "bptsb_ros/experiments/"
RECORDED_QOS = ("tests/test_bags_writer.py", "tests/test_bags_recorder.py::test_stop_signal_keeps_every_message")

MUTANTS: tuple[Mutant, ...] = (
    # -- issue 13: everything above the body ------------------------------------------------------------
    Mutant("feedback-sign", "bptsb_ros/brains/feedback.py",
           "return base * (1 + self.signal_from_features(features))",
           "return base * (1 - self.signal_from_features(features))",
           "closed-loop rest length l(1 + W·s) → l(1 − W·s)", (BRAINS,)),
    Mutant("ridge-noise-x0", "bptsb_ros/training/feedback_fit.py",
           "x_fit = x[lo:hi] + cfg.noise * rng",
           "x_fit = x[lo:hi] + 0 * cfg.noise * rng",
           "ridge input noise ×0", (BRAINS,)),
    Mutant("ridge-noise-x10", "bptsb_ros/training/feedback_fit.py",
           "x_fit = x[lo:hi] + cfg.noise * rng",
           "x_fit = x[lo:hi] + 10 * cfg.noise * rng",
           "ridge input noise ×10", (BRAINS,)),
    Mutant("ridge-bias-mean", "bptsb_ros/brains/feedback.py",
           "bias = y_mean - x_mean @ best_w",
           "bias = y_mean",
           "ridge bias replaced by the target mean", (BRAINS,)),
    Mutant("swg-amplitude-0.9", "bptsb_ros/brains/swg.py",
           "s = self.amplitude * torch.sin(",
           "s = 0.9 * self.amplitude * torch.sin(",
           "SWG amplitude ×0.9", (BRAINS,)),
    Mutant("swg-cos", "bptsb_ros/brains/swg.py",
           "self.amplitude * torch.sin(self.omega",
           "self.amplitude * torch.cos(self.omega",
           "SWG sin → cos", (BRAINS,)),
    Mutant("swg-minus-phase", "bptsb_ros/brains/swg.py",
           "t.unsqueeze(-1) + self.phase)",
           "t.unsqueeze(-1) - self.phase)",
           "SWG phase −φ", (BRAINS,)),
    Mutant("swg-half-omega", "bptsb_ros/brains/swg.py",
           "torch.sin(self.omega * t.unsqueeze(-1)",
           "torch.sin(self.omega / 2 * t.unsqueeze(-1)",
           "SWG ω/2", (BRAINS,)),
    Mutant("locomotion-no-step", "bptsb_ros/training/trainer.py",
           "            optimizer.step()\n",
           "            optimizer.step() if cfg.task != \"locomotion\" else None\n",
           "optimizer.step() skipped for locomotion",
           ("tests/test_training.py::test_locomotion_training_lowers_loss",)),
    Mutant("resume-fp16-velocity", "bptsb_ros/tasks/base.py",
           'return {"r": s.r, "v": s.v,',
           'return {"r": s.r, "v": s.v.half().to(s.v.dtype),',
           "resume checkpoint rounds velocities to fp16",
           ("tests/test_training.py::test_resume_continues_where_it_stopped",)),
    Mutant("qos-depth-10", "bptsb_ros/bags/qos.py",
           "depth=int(profile.depth),",
           "depth=10,",
           "recorded QoS depth 10", RECORDED_QOS),
    Mutant("qos-history-keep-last", "bptsb_ros/bags/qos.py",
           "history=profile.history.name.lower(),",
           'history="keep_last",',
           "recorded QoS history forced to keep_last", RECORDED_QOS),
    Mutant("qos-durability-upper", "bptsb_ros/bags/qos.py",
           '"durability": self.durability,',
           '"durability": self.durability.upper(),',
           "QoS durability written upper-case", RECORDED_QOS),
    Mutant("qos-durability-upper-recorded", "bptsb_ros/bags/qos.py",
           "durability=profile.durability.name.lower(),",
           "durability=profile.durability.name,",
           "recorded QoS durability upper-case (rclpy enum name)", RECORDED_QOS),
    Mutant("replay-shift-min-x2", "bptsb_ros/analysis/replay.py",
           'out["trajectory_mse_shift_min"] = windowed_shift_error(',
           'out["trajectory_mse_shift_min"] = 2 * windowed_shift_error(',
           "replay's trajectory_mse_shift_min ×2",
           ("tests/test_replay.py::test_replay_lissajous_metric_of_a_planted_run",)),
    # -- issue 8 §5: the live MNIST loop ----------------------------------------------------------------
    Mutant("mnist-live-no-reset", "bptsb_ros/live/body_core.py",
           "return None if cmd is None else torch.from_numpy(cmd.values)",
           "return None",
           "body_sim ignores every accepted reset", (LIVE_CORE, MNIST_LIVE)),
    Mutant("mnist-live-await-every-step", "bptsb_ros/live/body_core.py",
           "if not self.silent[s] and self.channels[s].due(step)",
           "if not self.silent[s]",
           "body_sim awaits a reset at every step, not only at reset steps", (LIVE_CORE, MNIST_LIVE)),
    Mutant("mnist-live-pixels-256", "bptsb_ros/tasks/mnist_live.py",
           "astype(np.float32) / 255.0)",
           "astype(np.float32) / 256.0)",
           "live pixels / 256 instead of / 255", (MNIST_LIVE,)),
    Mutant("mnist-live-reset-bound-x10", "bptsb_ros/live/safety.py",
           "far = np.flatnonzero(norm > self.max_displacement)",
           "far = np.flatnonzero(norm > 10 * self.max_displacement)",
           "reset displacement bound ×10", (MNIST_LIVE,)),
    Mutant("narma-0.4", "bptsb_ros/tasks/narma.py",
           "y[t + 1] = 0.3 * y[t] + np.sum",
           "y[t + 1] = 0.4 * y[t] + np.sum",
           "expanded-NARMA coefficient 0.3 → 0.4", (TASKS,)),
    Mutant("narma2-10-0.4", "bptsb_ros/tasks/narma.py",
           "y[t + 1] = 0.3 * y[t] + 0.05",
           "y[t + 1] = 0.4 * y[t] + 0.05",
           "NARMA2/NARMA10 coefficient 0.3 → 0.4", ("tests/test_timeseries.py",)),
    Mutant("lissajous-no-beta", "bptsb_ros/tasks/lissajous.py",
           "torch.sin(beta * omega * t + delta)",
           "torch.sin(omega * t + delta)",
           "Lissajous target without β", (TASKS,)),
    # -- the body (already caught before issue 13; kept so that it stays so) --------------------------------
    Mutant("body-damping-sign", "bptsb_ros/body/forces.py",
           "torch.addcmul(coef.unsqueeze(-1) * diff, d.unsqueeze(-1), dv)",
           "torch.addcmul(coef.unsqueeze(-1) * diff, -d.unsqueeze(-1), dv)",
           "damping force sign flipped", BODY),
    Mutant("body-verlet-position-half", "bptsb_ros/body/msdn.py",
           "r = r.add_(state.a, alpha=0.5 * dt * dt)",
           "r = r.add_(state.a, alpha=dt * dt)",
           "½ dropped in the Verlet position update", BODY),
    Mutant("body-verlet-velocity-half", "bptsb_ros/body/msdn.py",
           "v = torch.add(v, state.a + a, alpha=0.5 * dt)",
           "v = torch.add(v, state.a + a, alpha=dt)",
           "½ dropped in the Verlet velocity update", BODY),
    Mutant("body-published-velocity-x2", "bptsb_ros/body/msdn.py",
           "v = torch.add(v, a, alpha=0.5 * dt)",
           "v = torch.add(v, a, alpha=dt)",
           "published integrator's velocity update ×2", BODY),
    # -- the numba kernel (the default backend): the same updates in the compiled window ----------------------
    Mutant("kernel-verlet-velocity-half", "bptsb_ros/body/kernel.py",
           "vn[m, c] = vc[m, c] + half_dt * (a[m, c] + an[m, c])",
           "vn[m, c] = vc[m, c] + dt * (a[m, c] + an[m, c])",
           "kernel: ½ dropped in the Verlet velocity update", BODY),
    Mutant("kernel-damping-sign", "bptsb_ros/body/kernel.py",
           "f0 = kq * x0 + d[e] * w0",
           "f0 = kq * x0 - d[e] * w0",
           "kernel: damping force sign flipped (x component)", BODY),
    Mutant("kernel-clamp-threshold", "bptsb_ros/body/kernel.py",
           "if clamp and rn[m, 1] < zero:",
           "if clamp and rn[m, 1] < zero - 0.01:",
           "kernel: ground clamp threshold changed (y < 0 → y < −0.01)", BODY),
    Mutant("kernel-verlet-position-half", "bptsb_ros/body/kernel.py",
           "return np.array([dt, 0.5 * dt * dt, 0.5 * dt,",
           "return np.array([dt, dt * dt, 0.5 * dt,",
           "kernel: ½ dropped in the Verlet position update", BODY),
    Mutant("body-ground-half", "bptsb_ros/body/forces.py",
           "ground_c * torch.exp(-ground_c * y)",
           "0.5 * ground_c * torch.exp(-ground_c * y)",
           "soft ground force ×½", BODY),
    Mutant("body-air-drag-x2", "bptsb_ros/body/forces.py",
           "out = -air_drag * v",
           "out = -2 * air_drag * v",
           "air drag ×2", BODY),
    Mutant("body-clamp-threshold", "bptsb_ros/body/msdn.py",
           "v = v.masked_fill(r[..., 1:] < 0, 0.0)",
           "v = v.masked_fill(r[..., 1:] < -0.01, 0.0)",
           "ground clamp threshold changed (y < 0 → y < −0.01)", BODY),
    # -- issue 10 §2: wind schedules and perturbations, live --------------------------------------------
    Mutant("displaced-velocity", "bptsb_ros/body/msdn.py",
           "v = state.v.expand_as(r).clone()",
           "v = torch.zeros_like(r)",
           "a perturbation also stops the masses", ("tests/test_live_autonomy.py::test_simulate_perturbed_equals_a_"
                                                    "step_by_step_loop",)),
    Mutant("live-perturb-rest", "bptsb_ros/live/body_core.py",
           "kicked = self.body.displaced(new, d, rest, force)",
           "kicked = self.body.displaced(new, d, self.base, force)",
           "the live perturbation recomputes a with the trained instead of the commanded rest lengths",
           (f"{LIVE_CORE}::test_perturbation_displaces_its_step_only_with_the_commanded_rest_lengths",
            "tests/test_live_autonomy.py::test_live_perturbation_equals_offline_and_replay_reports_the_return")),
    Mutant("wind-periodic-half", "bptsb_ros/tasks/locomotion.py",
           "return np.mod(t + 0.5 * dt, period) >= 0.5 * period",
           "return np.mod(t - 0.5 * dt, period) >= 0.5 * period",
           "the periodic wind starts blowing a step late", ("tests/test_live_autonomy.py::test_constant_and_"
                                                            "periodic_schedules_by_hand",)),
    Mutant("wind-file-row", "bptsb_ros/sim/wind_schedule.py",
           'i = int(np.searchsorted(rows[:, 0], _row_times(np.array(step), dt), side="right")) - 1',
           'i = int(np.searchsorted(rows[:, 0], _row_times(np.array(step), dt), side="left"))',
           "a wind table row takes effect a row late", ("tests/test_live_autonomy.py::test_file_schedule_and_its_"
                                                        "errors",)),
    Mutant("return-ratio", "bptsb_ros/analysis/replay_lissajous.py",
           "E_live=errors[\"live\"], E_offline=errors[\"offline\"],",
           "E_live=errors[\"offline\"], E_offline=errors[\"offline\"],",
           "replay reports the offline error as the live one", ("tests/test_live_autonomy.py::test_return_metrics_on_"
                                                                "planted_offsets",)),
    # -- the SWG experiments' claims (tests/test_claims_swg.py: planted numbers) --------------------------
    Mutant('claims-swg-draws-inclusive', "bptsb_ros/experiments/claim_rules.py",
           'return bool(nmse < DRAWS_NMSE)',
           'return bool(nmse <= DRAWS_NMSE)',
           'a curve at error = 0.1 × target mean square counts as drawn', (CLAIMS_SWG,)),
    Mutant('claims-swg-at-most-float', "bptsb_ros/experiments/claim_rules.py",
           'return bool(x <= bound + EPS)',
           'return bool(x <= bound)',
           'inclusive bounds fail on float rounding (0.8 − 0.6 > 0.2)', (CLAIMS_SWG,)),
    Mutant('claims-swg-closed-larger-ge', "bptsb_ros/experiments/lissajous_closed_loop.py",
           'out.append(Claim(larger, ratio > 1,',
           'out.append(Claim(larger, ratio >= 1,',
           "closed-loop error equal to the SWG's counts as larger", (CLAIMS_SWG,)),
    Mutant('claims-swg-closed-larger-premise', "bptsb_ros/experiments/lissajous_closed_loop.py",
           '    if not (draws(open_nmse) and draws(closed_nmse)):',
           '    if not draws(open_nmse):',
           "'larger' tested on a closed loop that draws nothing", (CLAIMS_SWG,)),
    Mutant('claims-swg-lpert-falls-or', "bptsb_ros/experiments/lissajous_perturbation.py",
           'return bool(rate[-1] < rate[0] and r < FALL_R), r',
           'return bool(rate[-1] < rate[0] or r < FALL_R), r',
           'falls: and → or', (CLAIMS_SWG,)),
    Mutant('claims-swg-lpert-same-premise', "bptsb_ros/experiments/lissajous_perturbation.py",
           '    elif min(ro.min(), rc.min()) >= 1:',
           '    elif max(ro.min(), rc.min()) >= 1:',
           "'almost the same' needs both loops (not one) to fail somewhere", (CLAIMS_SWG,)),
    Mutant('claims-swg-lpert-same-mean', "bptsb_ros/experiments/lissajous_perturbation.py",
           'gap, worst = float(np.max(diff)),',
           'gap, worst = float(np.mean(diff)),',
           "'almost the same' at every σ → on average", (CLAIMS_SWG,)),
    Mutant('claims-swg-swap-tol-strict', "bptsb_ros/experiments/lissajous_switching.py",
           'swap = (at_most(abs(b0["f_x"] - w["f_y"]), FREQ_TOL) and',
           'swap = (abs(b0["f_x"] - w["f_y"]) < FREQ_TOL and',
           'frequency agreement within 0.1 Hz made strict', (CLAIMS_SWG,)),
    Mutant('claims-swg-grew-premise', "bptsb_ros/experiments/lissajous_switching.py",
           '    elif not drawn:',
           '    elif False:',
           "'error grew' tested without the switching learned", (CLAIMS_SWG,)),
    Mutant('claims-swg-grew-ge', "bptsb_ros/experiments/lissajous_switching.py",
           'out.append(Claim(grew_text, after > n.pre_nmse,',
           'out.append(Claim(grew_text, after >= n.pre_nmse,',
           'an unchanged error counts as grown', (CLAIMS_SWG,)),
    Mutant('claims-swg-bif-any-period', "bptsb_ros/experiments/lissajous_switching.py",
           'p1 = all(p == 1 for p in per_trained.values())',
           'p1 = all(p >= 1 for p in per_trained.values())',
           'any period (not period 1) at the trained F_wind', (CLAIMS_SWG,)),
    Mutant('claims-swg-bif-learned-any', "bptsb_ros/experiments/lissajous_switching.py",
           'learned = all(draws(v) for v in nmse.values())',
           'learned = any(draws(v) for v in nmse.values())',
           "switching 'learned' when one of the two curves is drawn", (CLAIMS_SWG,)),
    Mutant('claims-swg-bif-diverged-counts', "bptsb_ros/experiments/lissajous_switching.py",
           'n_multi, n_aper = int(np.sum(untrained > 1)), int(np.sum(untrained == 0))',
           'n_multi, n_aper = int(np.sum(untrained > 1)), int(np.sum(untrained <= 0))',
           'a diverged row counts as more diverse dynamics', (CLAIMS_SWG,)),
    Mutant('claims-swg-bif-p1-premise', "bptsb_ros/experiments/lissajous_switching.py",
           '    elif not p1:',
           '    elif False:',
           "'more diverse' tested when the trained values are not period 1", (CLAIMS_SWG,)),
    Mutant('claims-swg-timing-random-any', "bptsb_ros/experiments/lissajous_switching.py",
           'out.append(Claim(rand_text, bool(conv.all()),',
           'out.append(Claim(rand_text, bool(conv.any()),',
           'random timing: every n → some n', (CLAIMS_SWG,)),
    Mutant('claims-swg-timing-random-premise', "bptsb_ros/experiments/lissajous_switching.py",
           '    if not draws(rand[0]):',
           '    if False:',
           'random timing tested though its n = 0 run draws nothing', (CLAIMS_SWG,)),
    Mutant('claims-swg-timing-band-gt', "bptsb_ros/experiments/lissajous_switching.py",
           'out.append(Claim(fixed_text, band[0] >= BAND_MIN,',
           'out.append(Claim(fixed_text, band[0] > BAND_MIN,',
           'a band of exactly 5 n is not a band', (CLAIMS_SWG,)),
    Mutant('claims-swg-timing-fixed-premise', "bptsb_ros/experiments/lissajous_switching.py",
           '    if not draws(fixed[0]):',
           '    if False:',
           'fixed-timing band tested though the system does not switch at n = 0', (CLAIMS_SWG,)),
    Mutant('claims-swg-schemes-s1-premise', "bptsb_ros/experiments/closed_loop_schemes.py",
           '    if not trained1.any():',
           '    if False:',
           "scheme 1 'draws nothing' when every scheme-1 training diverged", (CLAIMS_SWG,)),
    Mutant('claims-swg-schemes-not-all', "bptsb_ros/experiments/closed_loop_schemes.py",
           'out.append(Claim(text, 0 < improved <= valid / 2,',
           'out.append(Claim(text, 0 < improved < valid,',
           "'only 7 of 15' read as 'some but not all'", (CLAIMS_SWG,)),
    Mutant('claims-swg-schemes-half-strict', "bptsb_ros/experiments/closed_loop_schemes.py",
           'out.append(Claim(text, 0 < improved <= valid / 2,',
           'out.append(Claim(text, 0 < improved < valid / 2,',
           "exactly half improved is not 'only some'", (CLAIMS_SWG,)),
    Mutant('claims-swg-schemes-ratio-le', "bptsb_ros/experiments/closed_loop_schemes.py",
           'improved = int(np.sum(np.asarray(after, float) / before < 1))',
           'improved = int(np.sum(np.asarray(after, float) / before <= 1))',
           'E_after = E_before counts as improved', (CLAIMS_SWG,)),
    Mutant('claims-swg-schemes-one-system', "bptsb_ros/experiments/closed_loop_schemes.py",
           '        if valid < 2:',
           '        if valid < 1:',
           "'only some' tested on a single system", (CLAIMS_SWG,)),
    Mutant('claims-swg-loco-forward', "bptsb_ros/experiments/locomotion_closed_loop.py",
           'forward = np.asarray(n.open_speed, float) > 0',
           'forward = np.asarray(n.open_speed, float) >= 0',
           'an agent at rest counts as having learned forward motion', (CLAIMS_SWG,)),
    Mutant('claims-swg-loco-small-n', "bptsb_ros/experiments/locomotion_closed_loop.py",
           '    if lo == 0 and hi == n_fw:',
           '    if False:',
           "8/20 consistency 'holds' for a sample too small to contradict it", (CLAIMS_SWG,)),
    Mutant('claims-swg-hw-near-strict', "bptsb_ros/experiments/locomotion_headwind.py",
           'out.append(Claim(text1, all(at_most(v, NEAR) for v in rel.values()),',
           'out.append(Claim(text1, all(v < NEAR for v in rel.values()),',
           'within 25 % of v_tgt made strict', (CLAIMS_SWG,)),
    Mutant('claims-swg-hw-drop-old', "bptsb_ros/experiments/locomotion_headwind.py",
           'holds = early < calm and early < late and at_most(abs(late - calm) / tgt, NEAR)',
           'holds = early < late',
           "drop-and-recover back to 'first half slower than second half'", (CLAIMS_SWG,)),
    Mutant('claims-swg-hw-far-relative', "bptsb_ros/experiments/locomotion_headwind.py",
           'out.append(Claim(text4, e_strong > INTERP,',
           'out.append(Claim(text4, e_strong > float(np.nanmean(err[(winds >= -1) & (winds <= 1)])),',
           "'far' back to 'larger than inside [−1, 1]'", (CLAIMS_SWG,)),
    Mutant('claims-swg-hw-open-interval', "bptsb_ros/experiments/locomotion_headwind.py",
           'inside = (winds > -1) & (winds < 1) & ~np.isin(winds, TRAINED)',
           'inside = (winds > -1) & (winds <= 1) & ~np.isin(winds, TRAINED)',
           '−1 < F_wind < 1 includes F_wind = 1', (CLAIMS_SWG,)),
    Mutant('claims-swg-hw-learned-premise', "bptsb_ros/experiments/locomotion_headwind.py",
           '    learned = all(at_most(e, NEAR) for e in trained_err.values())',
           '    learned = True',
           'interpolation claims tested with the trained F_wind off target', (CLAIMS_SWG,)),
    Mutant('claims-swg-lp-falls-le', "bptsb_ros/experiments/locomotion_perturbation.py",
           'out.append(Claim(text, hi_rate < lo_rate,',
           'out.append(Claim(text, hi_rate <= lo_rate,',
           'a flat return rate counts as falling', (CLAIMS_SWG,)),
    Mutant('claims-swg-lp-same-premise', "bptsb_ros/experiments/locomotion_perturbation.py",
           '    elif min(rates["open"].min(), rates["closed"].min()) >= 1:',
           '    elif False:',
           "'almost the same' tested when no perturbation made either loop fail", (CLAIMS_SWG,)),
    Mutant('claims-swg-lp-closed-premise', "bptsb_ros/experiments/locomotion_perturbation.py",
           '"closed": None if n.closed_succeeded else',
           '"closed": None if True else',
           'closed-loop claims tested on a closed loop that did not succeed', (CLAIMS_SWG,)),
    # -- the MNIST experiments' claims and separation scores (tests/test_claims_mnist.py: planted numbers) ----------
    Mutant('claims-mnist-learned-z2', "bptsb_ros/experiments/mnist_claims.py",
           'LEARNED_Z = 3.0',
           'LEARNED_Z = 2.0',
           "'learned' margin 3 → 2 binomial standard errors", (CLAIMS_MNIST,)),
    Mutant('claims-mnist-learned-no-margin', "bptsb_ros/experiments/mnist_claims.py",
           'return self.chance + LEARNED_Z * math.sqrt(',
           'return self.chance + 0 * math.sqrt(',
           "'learned' = any accuracy above chance", (CLAIMS_MNIST,)),
    Mutant('claims-mnist-chance-uniform', "bptsb_ros/experiments/mnist_claims.py",
           'float(np.bincount(labels).max() / labels.size)',
           'float(1 / len(np.unique(labels)))',
           'chance = 1 / labels instead of the most common label\'s share', (CLAIMS_MNIST,)),
    Mutant('claims-mnist-and-open-hides-false', "bptsb_ros/experiments/mnist_claims.py",
           '    if any(not c.holds for c in tested):',
           '    if not open_ and any(not c.holds for c in tested):',
           'an untestable comparison hides a refuting one', (CLAIMS_MNIST,)),
    Mutant('claims-mnist-and-open-refutes', "bptsb_ros/experiments/mnist_claims.py",
           '    if any(not c.holds for c in tested):',
           '    if any(not c.holds for c in checks):',
           'an untestable comparison refutes the claim', (CLAIMS_MNIST,)),
    Mutant('claims-mnist-separated-ge', "bptsb_ros/experiments/mnist_claims.py",
           'return Check(text, body.silhouette > brain.silhouette)',
           'return Check(text, body.silhouette >= brain.silhouette)',
           'equal silhouettes count as more separation in the body', (CLAIMS_MNIST,)),
    Mutant('claims-mnist-drawing-no-premise', "bptsb_ros/experiments/mnist_drawing.py",
           'bool(n.mse[a] < n.mse[b]), not_learned(names))',
           'bool(n.mse[a] < n.mse[b]), None)',
           'drawing errors compared between systems that did not learn', (CLAIMS_MNIST,)),
    Mutant('claims-mnist-drawing-le', "bptsb_ros/experiments/mnist_drawing.py",
           'bool(n.mse[a] < n.mse[b]), not_learned(names))',
           'bool(n.mse[a] <= n.mse[b]), not_learned(names))',
           'an equal drawing error counts as smaller', (CLAIMS_MNIST,)),
    Mutant('claims-mnist-pca-no-digit-8', "bptsb_ros/experiments/mnist_pca.py",
           'EMPHASISED = (5, 7, 8)',
           'EMPHASISED = (5, 7)',
           "'especially labels 5, 7 and 8' without 8", (CLAIMS_MNIST,)),
    Mutant('claims-mnist-pca-no-premise', "bptsb_ros/experiments/mnist_pca.py",
           '    premise = not_learned({label: n.drawing}, "the system did not learn to draw")',
           '    premise = None',
           'PCA claims tested on a system that did not learn', (CLAIMS_MNIST,)),
    Mutant('claims-mnist-lm-centre-premise', "bptsb_ros/experiments/mnist_labelmap.py",
           '    if len(centre) != 10 or wrong:',
           '    if len(centre) != 10:',
           'label maps judged around drawings of another digit', (CLAIMS_MNIST,)),
    Mutant('claims-mnist-lm-argmax-ties', "bptsb_ros/experiments/mnist_labelmap.py",
           '    top = np.flatnonzero(size >= size.max() - EPS)',
           '    top = np.array([int(np.argmax(size))])',
           'largest label-map size by argmax (a tie across the kinds ignored)', (CLAIMS_MNIST,)),
    Mutant('claims-mnist-lm-float-means', "bptsb_ros/experiments/mnist_labelmap.py",
           'return Claim(text, not at_most(mo, mj), f"joined:',
           'return Claim(text, bool(mj < mo), f"joined:',
           'joined smaller: equal sizes averaging to different floats count as smaller', (CLAIMS_MNIST,)),
    Mutant('claims-mnist-lm-mostly-mean', "bptsb_ros/experiments/mnist_labelmap.py",
           'return Claim(text, not at_most(float(size[p]), MOSTLY), f"smallest',
           'return Claim(text, not at_most(float(size[~joined].mean()), MOSTLY), f"smallest',
           "'other maps mostly original' on the mean, not every mass", (CLAIMS_MNIST,)),
    Mutant('claims-mnist-sp-high-strict', "bptsb_ros/experiments/mnist_specific100.py",
           'bool(n.skill[k].accuracy >= HIGH_ACCURACY)',
           'bool(n.skill[k].accuracy > HIGH_ACCURACY)',
           "'high accuracy' at 90 % made strict", (CLAIMS_MNIST,)),
    Mutant('claims-mnist-sp-every-label-ge', "bptsb_ros/experiments/mnist_specific100.py",
           'each.append(Check(f"digit {d}: {fmt(v)}", bool(v > 0),',
           'each.append(Check(f"digit {d}: {fmt(v)}", bool(v >= 0),',
           'a digit with silhouette 0 counts as separated', (CLAIMS_MNIST,)),
    Mutant('claims-mnist-ro-95-inclusive', "bptsb_ros/experiments/mnist_readout.py",
           'bool(sk[k].accuracy > BODY_ACCURACY)',
           'bool(sk[k].accuracy >= BODY_ACCURACY)',
           "'higher than 95 %' met at 95 %", (CLAIMS_MNIST,)),
    Mutant('claims-mnist-ro-little-strict', "bptsb_ros/experiments/mnist_readout.py",
           'at_most(gap, LITTLE), (dc, mc)))',
           'gap < LITTLE, (dc, mc)))',
           "'within 1 point' made strict (fails on float rounding)", (CLAIMS_MNIST,)),
    Mutant('claims-mnist-ro-brain-premise', "bptsb_ros/experiments/mnist_readout.py",
           'sk[k].accuracy > sk[brain].accuracy, (k, brain)) for k in bodies]',
           'sk[k].accuracy > sk[brain].accuracy, (k,)) for k in bodies]',
           'body > brain tested though the brain alone did not learn', (CLAIMS_MNIST,)),
    Mutant('sep-probe-train-half', "bptsb_ros/analysis/separation.py",
           'return float(model.score(features[test], labels[test]))',
           'return float(model.score(features[~test], labels[~test]))',
           'linear probe scored on its own training half', (CLAIMS_MNIST,)),
    Mutant('sep-probe-raw', "bptsb_ros/analysis/separation.py",
           'model = make_pipeline(StandardScaler(), LogisticRegression(max_iter=2000))',
           'model = make_pipeline(LogisticRegression(max_iter=2000))',
           'linear probe on unstandardised features', (CLAIMS_MNIST,)),
    Mutant('sep-full-raw', "bptsb_ros/analysis/separation.py",
           'full = StandardScaler().fit_transform(features)',
           'full = features',
           'all-feature silhouette on unstandardised features', (CLAIMS_MNIST,)),
    Mutant('sep-no-stratify', "bptsb_ros/analysis/separation.py",
           'stratify = labels if counts[counts > 0].min() >= 2 else None',
           'stratify = None',
           'probe halves not stratified by label', (CLAIMS_MNIST,)),
    Mutant('sep-chance-all-points', "bptsb_ros/analysis/separation.py",
           '"probe_chance": float(np.bincount(labels[test]).max() / len(test))',
           '"probe_chance": float(np.bincount(labels).max() / len(labels))',
           "probe chance from all points, not the scored half", (CLAIMS_MNIST,)),
    Mutant('sep-per-label-full', "bptsb_ros/analysis/separation.py",
           '"per_label_2d": silhouette_per_label(pts, labels)',
           '"per_label_2d": silhouette_per_label(features, labels)',
           'per-label silhouettes on all features, not the 2-D PCA plane', (CLAIMS_MNIST,)),
    Mutant('labelmap-half-width', "bptsb_ros/experiments/mnist_analysis.py",
           '    return size / DELTA_SCALE',
           '    return size / DELTA_SCALE / 2',
           'label-map shifts within ±size/10', (CLAIMS_MNIST,)),
    Mutant('labelmap-start-first-samples', "bptsb_ros/experiments/mnist_analysis.py",
           'base = torch.as_tensor(evaluation["displacement"][best]',
           'base = torch.as_tensor(evaluation["displacement"][:10]',
           "label maps start at the first 10 samples, not each digit's best", (CLAIMS_MNIST,)),
    Mutant('labelmap-centre-corner', "bptsb_ros/experiments/mnist_analysis.py",
           'centre = maps["labels"][:, 0, grid // 2, grid // 2]',
           'centre = maps["labels"][:, 0, 0, 0]',
           "the 'unshifted' cell read at a corner of the grid", (CLAIMS_MNIST,)),
    # -- the time-series experiments' claims (tests/test_claims_timeseries.py: planted numbers) -----------------
    Mutant("claims-ts-learned-inclusive", TS + "timeseries_claims.py",
           "return bool(nmse < LEARNED_NMSE)",
           "return bool(nmse <= LEARNED_NMSE)",
           "a system at NMSE 1 (no better than the mean) counts as learned", (CLAIMS_TS,)),
    Mutant("claims-ts-all-of-none-wins", TS + "timeseries_claims.py",
           "    if any(v is False for v in verdicts):",
           "    if all(v is False for v in verdicts):",
           "a false comparison beside an untestable one makes the claim untestable, not false", (CLAIMS_TS,)),
    Mutant("claims-ts-rank-strict", TS + "timeseries_claims.py",
           "far = [lab for lab, g in gap.items() if not at_most(g, RANK_TOL)]",
           "far = [lab for lab, g in gap.items() if not g < RANK_TOL]",
           "|total − 1| = 0.1 (1.1 in floats) no longer reaches the rank", (CLAIMS_TS,)),
    Mutant("claims-ts-emu-unlearned-compared", TS + "narma_emulation.py",
           '        return None, f"{text} (not testable: {premise})"',
           "        return bool(n.nmse[better] < n.nmse[worse]), text",
           "emulation errors compared although a system did not learn or diverged (the old 'infinite error')",
           (CLAIMS_TS,)),
    Mutant("claims-ts-emu-body-reversed", TS + "narma_emulation.py",
           'body = [_pair(n, ("multiple-circle", br), ("double-circle", br)) for br in BRAINS]',
           'body = [_pair(n, ("double-circle", br), ("multiple-circle", br)) for br in BRAINS]',
           "the body claim asks whether the double circle is better", (CLAIMS_TS,)),
    Mutant("claims-ts-nipc-masses-degree3", TS + "narma_ipc.py",
           "per_mass = {b: {i: sum(_nonlinear(axis) for axis in ms[b][i]) for i in ids} for b in BRAINS}",
           "per_mass = {b: {i: sum(float(axis[2]) for axis in ms[b][i]) for i in ids} for b in BRAINS}",
           "mass points: degree 3 only instead of degree ≥ 2 (the old claim)", (CLAIMS_TS,)),
    Mutant("claims-ts-nipc-masses-summed", TS + "narma_ipc.py",
           'lose = [i for i in ids if not per_mass["mlp"][i] > per_mass["lil"][i]]',
           'lose = [] if sum(per_coord["mlp"]) > sum(per_coord["lil"]) else ids',
           "'at each mass point' read as 'summed over the masses'", (CLAIMS_TS,)),
    Mutant("claims-ts-nipc-grow-sum", TS + "narma_ipc.py",
           "return (bool(final[1] > first[1] and final[2] > first[2]),",
           "return (bool(final[1:].sum() > first[1:].sum()),",
           "'2nd- and 3rd-order profiles increased' read as their sum (the old claim)", (CLAIMS_TS,)),
    Mutant("claims-ts-nipc-grow-middle-stage", TS + "narma_ipc.py",
           "first, final = np.asarray(s.output[0], float), np.asarray(s.output[-1], float)",
           "first, final = np.asarray(s.output[1], float), np.asarray(s.output[-1], float)",
           "growth measured from the middle stage, not from the untrained system", (CLAIMS_TS,)),
    Mutant("claims-ts-nipc-mlp-more-3rd", TS + "narma_ipc.py",
           'out.append(Claim(text, bool(dist["mlp"] < dist["lil"]),',
           'out.append(Claim(text, bool(mlp[2] > lil[2]),',
           "'reproducing the target nonlinearity' back to 'more 3rd order than the LIL' (the old proxy)",
           (CLAIMS_TS,)),
    Mutant("claims-ts-nipc-lil3-mlp", TS + "narma_ipc.py",
           "bool(lil[2] < target[2])",
           "bool(mlp[2] < target[2])",
           "the LIL's 'too small third order' read from the MLP", (CLAIMS_TS,)),
    Mutant("claims-ts-nipc-rank-outputs-only", TS + "narma_ipc.py",
           "    holds, evidence = rank_reached(n.totals)\n    out.append(Claim(f\"the total capacity reaches the rank "
           "of one in all cases (every bar:",
           "    holds, evidence = rank_reached({k: v for k, v in n.totals.items() if 'output' in k})\n"
           "    out.append(Claim(f\"the total capacity reaches the rank of one in all cases (every bar:",
           "'in all cases' back to the output bars only (the old claim)", (CLAIMS_TS,)),
    Mutant("claims-ts-nipc-premise-untrained", TS + "narma_ipc.py",
           "float(n.systems[b].nmse[-1]) for b in brains",
           "float(n.systems[b].nmse[0]) for b in brains",
           "the learning premise read at the untrained stage", (CLAIMS_TS,)),
    Mutant("claims-ts-tipc-one-step-is-now", TS + "target_ipc.py",
           "ONE_STEP: Term = ((1, 1),)",
           "ONE_STEP: Term = ((0, 1),)",
           "the one-step-delayed term F1(u(t−1)) replaced by F1(u(t))", (CLAIMS_TS,)),
    Mutant("claims-ts-tipc-narma10-single-largest", TS + "target_ipc.py",
           '("NARMA10", (ONE_STEP, TEN_STEP))',
           '("NARMA10", (ONE_STEP,))',
           "NARMA10's F1(u(t−1)) must be the single largest term (the old claim)", (CLAIMS_TS,)),
    Mutant("claims-ts-tipc-ten-step-over-one-step", TS + "target_ipc.py",
           "top, top_cap = p.largest_other(TEN_STEP, ONE_STEP)",
           "top, top_cap = p.largest_other(TEN_STEP)",
           "NARMA10's 10-step term must exceed the 1-step one too", (CLAIMS_TS,)),
    Mutant("claims-ts-tipc-share1-inclusive", TS + "target_ipc.py",
           "holds = holds and share1 > 0.5 and one > top_cap",
           "holds = holds and share1 >= 0.5 and one > top_cap",
           "a degree-1 share of exactly half counts as dominant", (CLAIMS_TS,)),
    Mutant("claims-ts-tipc-shares-summed", TS + "target_ipc.py",
           'holds = all(shares["expanded NARMA"][d] > shares[k][d] for k in names[1:] for d in (0, 1))',
           'holds = all(sum(shares["expanded NARMA"]) > sum(shares[k]) for k in names[1:])',
           "'second- and third-order proportions' read as their sum (the old claim)", (CLAIMS_TS,)),
    Mutant("claims-ts-tipc-memory-delay", TS + "target_ipc.py",
           "focus: Term = ((MEMORY_DELAY, 1),)",
           "focus: Term = ((MEMORY_DELAY - 1, 1),)",
           "the memory target's profile in focus read at Δt = 7", (CLAIMS_TS,)),
    Mutant("claims-ts-msdn-any-scale", TS + "msdn_nonlinearity.py",
           "dc = n.double_circle[PAPER_SCALE]",
           "dc = max(n.double_circle.values(), key=lambda c: c.degree_2plus)",
           "double circle's nonlinearity read at its most nonlinear scale, not the paper's", (CLAIMS_TS,)),
    Mutant("claims-ts-msdn-chain-paper-scale", TS + "msdn_nonlinearity.py",
           "worst = max(c.degree_2plus for c in n.chain.values())",
           "worst = n.chain[PAPER_SCALE].degree_2plus",
           "the chain linear at the paper's scale only, not at every scale", (CLAIMS_TS,)),
    Mutant("claims-ts-msdn-chain-at-rest", TS + "msdn_nonlinearity.py",
           "    if still:",
           "    if False:",
           "a chain that does not respond counts as linear", (CLAIMS_TS,)),
    Mutant("claims-ts-mem-generally-mean", TS + "memory_task.py",
           "out.append(Claim(text, 2 * len(wins) > len(delays),",
           'out.append(Claim(text, bool(mean["multiple-circle"].mean() < mean["double-circle"].mean()),',
           "'generally smaller' back to 'smaller on average over Δt' (the old claim)", (CLAIMS_TS,)),
    Mutant("claims-ts-mem-rho-strict", TS + "memory_task.py",
           "verdicts.append(None if premise else at_most(RHO_MIN, rho))",
           "verdicts.append(None if premise else bool(rho > RHO_MIN))",
           "Spearman ρ = 0.8 no longer a growing error", (CLAIMS_TS,)),
    Mutant("claims-ts-mem-focus-index", TS + "memory_task.py",
           "fi = delays.index(n.focus)",
           "fi = delays.index(n.focus) + 1",
           "the Δt = 8 comparisons read at the next Δt", (CLAIMS_TS,)),
    Mutant("claims-ts-mem-first-seed", TS + "memory_task.py",
           "first = {b: float(err[b][fi, 0]) for b in BODY_NAMES}",
           "first = {b: float(err[b][fi].mean()) for b in BODY_NAMES}",
           "the IPC's premise read from the mean over seeds, not the seed whose IPC it is", (CLAIMS_TS,)),
)


class CheckError(RuntimeError):
    """The mutation check itself cannot run (exit status 2)."""


def check_targets(mutants: list[Mutant], root: Path) -> None:
    """Every mutant's target text must occur exactly once in its file; raise naming every one that does not."""
    problems = []
    for m in mutants:
        path = root / m.path
        if not path.is_file():
            problems.append(f"{m.id}: file {m.path} does not exist")
            continue
        count = path.read_text().count(m.old)
        if count != 1:
            problems.append(f"{m.id}: target text {m.old!r} found {count} times in {m.path} (need exactly 1)")
    if problems:
        raise CheckError("mutant targets out of date (edit MUTANTS in scripts/mutation_check.py):\n  "
                         + "\n  ".join(problems))


def copy_tree(dest: Path) -> None:
    """Copy the working tree's tracked and untracked, non-ignored files (uncommitted edits included)."""
    listing = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], cwd=REPO,
                             check=True, capture_output=True).stdout.decode().split("\0")
    for rel in filter(None, listing):
        src = REPO / rel
        if src.is_file():  # a tracked file deleted in the working tree is skipped
            (dest / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / rel)


def test_env(root: Path) -> dict[str, str]:
    """The environment for pytest in the copy: the copy's package first on sys.path, localhost-only DDS."""
    env = dict(os.environ)
    env["PYTHONPATH"] = str(root) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env.setdefault("AMENT_PREFIX_PATH", str(Path(sys.executable).resolve().parent.parent))
    env["PYTHONDONTWRITEBYTECODE"] = "1"
    return env


def run_pytest(root: Path, tests: tuple[str, ...] | list[str], timeout: float) -> tuple[int | None, str, float]:
    """(exit status or None on timeout, last line of output, seconds) of ``pytest -x -q tests`` in ``root``."""
    cmd = [sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", "--no-header", *tests]
    start = time.monotonic()
    with subprocess.Popen(cmd, cwd=root, env=test_env(root), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                          text=True, start_new_session=True) as proc:
        try:
            out, _ = proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, 9)
            proc.communicate()
            return None, f"timed out after {timeout:.0f} s", time.monotonic() - start
        except BaseException:  # Ctrl-C: take the test run (and the processes it started) down with us
            os.killpg(proc.pid, 9)
            proc.communicate()
            raise
    lines = [ln for ln in out.strip().splitlines() if ln.strip()]
    return proc.returncode, (lines[-1] if lines else ""), time.monotonic() - start


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("-k", dest="select", action="append", default=[],
                        help="run only mutants whose id contains this word (repeatable)")
    parser.add_argument("--list", action="store_true", help="list the mutants and their tests, run nothing")
    parser.add_argument("--tests", nargs="+", metavar="TEST",
                        help="run these pytest targets instead of each mutant's own (which test kills it?)")
    parser.add_argument("--no-baseline", action="store_true", help="skip running the tests on the unmutated copy")
    parser.add_argument("--timeout", type=float, default=600.0, help="seconds per test run (default 600)")
    args = parser.parse_args(argv)

    mutants = [m for m in MUTANTS if not args.select or any(w in m.id for w in args.select)]
    if args.tests:
        mutants = [replace(m, tests=tuple(args.tests)) for m in mutants]
    if not mutants:
        print(f"no mutant id contains any of {args.select}", file=sys.stderr)
        return 2
    if args.list:
        for m in mutants:
            print(f"{m.id:32s} {m.path:36s} {m.what}\n{'':32s} tests: {' '.join(m.tests)}")
        return 0
    try:
        check_targets(mutants, REPO)
        with tempfile.TemporaryDirectory(prefix="bptsb-mutation-") as tmp:
            root = Path(tmp) / "repo"
            copy_tree(root)
            probe = subprocess.run([sys.executable, "-c", "import bptsb_ros; print(bptsb_ros.__file__)"], cwd=root,
                                   env=test_env(root), capture_output=True, text=True)
            if not probe.stdout.strip().startswith(str(root)):
                raise CheckError(f"the copy imports bptsb_ros from {probe.stdout.strip() or probe.stderr.strip()}, "
                                 f"not from {root}")
            if not args.no_baseline:
                tests = sorted({t for m in mutants for t in m.tests})
                print(f"baseline: {len(tests)} test targets on the unmutated copy ...", flush=True)
                code, last, secs = run_pytest(root, tests, args.timeout)
                if code != 0:
                    raise CheckError(f"the unmutated tests do not pass ({last}); fix them before checking mutants")
                print(f"baseline: {last} ({secs:.0f} s)\n", flush=True)
            results = []
            for m in mutants:
                path = root / m.path
                original = path.read_text()
                path.write_text(original.replace(m.old, m.new, 1))
                try:
                    code, last, secs = run_pytest(root, m.tests, args.timeout)
                finally:
                    path.write_text(original)
                verdict = "survived" if code == 0 else "killed"
                results.append((m, verdict))
                why = "timeout" if code is None else last
                print(f"{verdict:8s}  {m.id:32s} {m.what}  [{why}; {secs:.0f} s]", flush=True)
    except CheckError as err:
        print(f"mutation check error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("\ninterrupted; the working tree was never modified", file=sys.stderr)
        return 130
    survived = [m.id for m, v in results if v == "survived"]
    print(f"\n{len(results) - len(survived)} of {len(results)} mutants killed"
          + (f"; SURVIVED: {', '.join(survived)}" if survived else ""))
    return 1 if survived else 0


if __name__ == "__main__":
    sys.exit(main())
