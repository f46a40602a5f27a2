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
EDGES = "tests/test_validation_edges.py"
NUMBERS = "tests/test_reported_numbers.py"
RECORDED_QOS = ("tests/test_bags_writer.py", "tests/test_bags_recorder.py::test_stop_signal_keeps_every_message")
LEARN = "tests/test_trainers_learn.py::"
LEARN_MORE = "tests/test_trainers_learn_more.py::"
L_LISS = LEARN + "test_lissajous_trainer_reports_the_window_loss_and_one_sgd_step_lowers_it"
L_LOCO = LEARN + "test_locomotion_trainer_reports_the_speed_loss_after_the_warm_up_and_one_step_lowers_it"
L_HEADWIND = LEARN + "test_headwind_trainer_pushes_with_the_periodic_wind_against_a_constant_target"
L_CLAMP = LEARN + "test_lissajous_trainer_projects_the_body_parameters_onto_non_negative_values"
L_NARMA = LEARN + "test_narma_trainer_reports_the_loss_after_the_washout_and_one_step_lowers_it"
L_DRAW = (LEARN_MORE + "test_drawing_loss_per_batch_and_the_epoch_loss_weighted_by_batch_size",
          LEARN_MORE + "test_drawing_sgd_step_at_the_paper_rates_and_a_few_steps_lower_the_loss")
L_READOUT = LEARN_MORE + "test_readout_loss_is_the_cross_entropy_of_the_sampled_states_and_adam_steps_lower_it"
L_SWITCH = LEARN_MORE + "test_switching_loss_follows_the_wind_schedule_and_an_sgd_step_lowers_it"
L_S1 = LEARN_MORE + "test_scheme1_loss_of_the_closed_loop_from_rest_and_its_sgd_step"
L_S2 = LEARN_MORE + "test_scheme2_loss_is_trajectory_plus_a_tenth_of_the_fl_loss_and_its_sgd_step"
L_S3 = LEARN_MORE + "test_scheme3_refits_the_fl_on_the_last_windows_with_noise_and_steps_the_swg"
L_FIT = LEARN_MORE + "test_feedback_fit_from_a_running_state_reports_its_clean_input_error"
L_RATES = (LEARN_MORE + "test_shipped_swg_configs_use_the_paper_table",
           LEARN_MORE + "test_narma_config_uses_the_authors_rates_and_its_profile_the_paper_table",
           LEARN_MORE + "test_module_rate_tables_are_the_papers")

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
           "s = self.amplitude * (sin_t",
           "s = 0.9 * self.amplitude * (sin_t",
           "SWG amplitude ×0.9", (BRAINS,)),
    Mutant("swg-cos", "bptsb_ros/brains/swg.py",
           "s = self.amplitude * (sin_t * torch.cos(self.phase) + cos_t * torch.sin(self.phase))",
           "s = self.amplitude * (cos_t * torch.cos(self.phase) - sin_t * torch.sin(self.phase))",
           "SWG sin → cos", (BRAINS,)),
    Mutant("swg-minus-phase", "bptsb_ros/brains/swg.py",
           "(sin_t * torch.cos(self.phase) + cos_t * torch.sin(self.phase))",
           "(sin_t * torch.cos(self.phase) - cos_t * torch.sin(self.phase))",
           "SWG phase −φ", (BRAINS,)),
    Mutant("swg-half-omega", "bptsb_ros/brains/swg.py",
           "return self._signal_from_phase(self.omega * t.to(torch.float64))",
           "return self._signal_from_phase(self.omega / 2 * t.to(torch.float64))",
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
    Mutant("control-realtime-no-shift", "bptsb_ros/live/body_loop.py",
           "start, wall_end, core.resumed_at = start + held, wall_end + held, port.now()",
           "start, wall_end, core.resumed_at = start, wall_end + held, port.now()",
           "a realtime pause leaves the schedule as it was: a burst of catch-up steps after resume",
           ("tests/test_sim_control.py",)),
    Mutant("control-pause-is-silence", "bptsb_ros/live/body_core.py",
           "quiet = last is None or now - max(last, self.resumed_at) > timeout",
           "quiet = last is None or now - last > timeout",
           "a realtime brain counts as silent after a pause longer than command_timeout",
           ("tests/test_sim_control.py",)),
    Mutant("control-lockstep-no-hold", "bptsb_ros/live/body_loop.py",
           "        while self._more(step):\n            self.hold()\n",
           "        while self._more(step):\n",
           "a paused lockstep body keeps stepping", ("tests/test_sim_control.py",)),
    Mutant("control-step-never-ends", "bptsb_ros/live/sim_control.py",
           "            self.steps_left -= 1", "            pass",
           "~/step advances without end", ("tests/test_sim_control.py",)),
    Mutant("control-reset-ignored", "bptsb_ros/live/body_core.py",
           "        if self.control.take_reset():", "        if False:",
           "the ~/reset call never takes effect", ("tests/test_sim_control.py",)),
    Mutant("newest-answers-oldest", "bptsb_ros/live/newest.py",
           "        self.pending, self.has_pending = msg, True",
           "        self.pending, self.has_pending = (self.pending if self.has_pending else msg), True",
           "a brain behind answers the oldest queued tick, not the newest", ("tests/test_newest.py",)),
    Mutant("newest-no-drain", "bptsb_ros/live/newest.py",
           "        idle, before = (idle + 1 if now == before else 0), now",
           "        idle, before = IDLE_SPINS, now",
           "a brain answers after one message instead of the whole ready backlog", ("tests/test_newest.py",)),
    Mutant("newest-one-idle-spin", "bptsb_ros/live/newest.py", "IDLE_SPINS = 2", "IDLE_SPINS = 1",
           "a brain's turn ends at the first spin for another callback (use_sim_time's clock) mid-backlog",
           ("tests/test_newest.py",)),
    Mutant("brain-answers-every-tick", "bptsb_ros/ros/brain_node.py",
           "self.create_subscription(msg_type, topic, latch.offer, qos)",
           "self.create_subscription(msg_type, topic, handler, qos)",
           "a brain answers every queued tick in order again (stays behind)",
           ("tests/test_ros_services.py::test_a_real_brain_behind_by_176_ticks_answers_only_the_newest",)),
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
           'inside = (rel_w > -1) & (rel_w < 1) & ~np.isclose(winds, trained[0])',
           'inside = (rel_w > -1) & (rel_w <= 1) & ~np.isclose(winds, trained[0])',
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
    # -- every training loop trains what it says (tests/test_trainers_learn*.py: independent losses, SGD steps) ---
    Mutant("trainer-mnist-readout-no-step", "bptsb_ros/tasks/mnist_readout.py",
           "                opt.step()\n                if model.system is not None:",
           "                pass\n                if model.system is not None:",
           "the MNIST readout never steps its optimiser", (L_READOUT,)),
    Mutant("trainer-mnist-readout-sgd", "bptsb_ros/tasks/mnist_readout.py",
           'cls = torch.optim.SGD if model.spec.optimizer == "sgd" else torch.optim.Adam',
           "cls = torch.optim.SGD",
           "the MNIST readout trains with SGD instead of the documented Adam", (L_READOUT,)),
    Mutant("trainer-mnist-readout-states-from-t0", "bptsb_ros/tasks/mnist_readout.py",
           "return r[:, self.every:: self.every]",
           "return r[:, : -1: self.every]",
           "readout states sampled at 0, 0.1, ..., 0.9 s instead of 0.1 ... 1.0 s", (L_READOUT,)),
    Mutant("trainer-mnist-drawing-no-step", "bptsb_ros/tasks/mnist_drawing.py",
           "                opt.step()\n                system.body.clamp_parameters_()",
           "                system.body.clamp_parameters_()",
           "the MNIST drawing never steps its optimiser", L_DRAW),
    Mutant("trainer-mnist-drawing-epoch-unweighted", "bptsb_ros/tasks/mnist_drawing.py",
           "epoch_sum += out.losses[-1] * len(idx)\n            count += len(idx)",
           "epoch_sum += out.losses[-1]\n            count += 1",
           "the drawing's epoch loss an unweighted mean over batches (a short last batch counts fully)", L_DRAW),
    Mutant("trainer-mnist-drawing-padded-rows", "bptsb_ros/tasks/mnist_drawing.py",
           "return (sq * mask).sum(1) / (2 * self.mask[labels].sum(1))",
           "return sq.mean(1) / 2",
           "a drawing's MSE also over the padded rows after its target ended", L_DRAW),
    Mutant("trainer-mnist-paper-lr-brain", "bptsb_ros/tasks/mnist_drawing.py",
           'PAPER_LR = {"k": 1e4, "d": 1e3, "l": 1.0, "brain": 1.0}',
           'PAPER_LR = {"k": 1e4, "d": 1e3, "l": 1.0, "brain": 0.1}',
           "MNIST brain rate 1e-1 instead of the paper's 1e0", (*L_RATES, *L_DRAW)),
    Mutant("trainer-narma-over-washout", "bptsb_ros/tasks/narma.py",
           "sl = slice(n.washout, n.train_end)",
           "sl = slice(0, n.train_end)",
           "NARMA trains over the washout too", (L_NARMA,)),
    Mutant("trainer-narma-eval-slice", "bptsb_ros/tasks/narma.py",
           "test = slice(n.train_end, n.n_inputs)",
           "test = slice(n.washout, n.n_inputs)",
           "NARMA's test NMSE over every sample after the washout, not the held-out ones", (L_NARMA,)),
    Mutant("trainer-narma-output-block-start", "bptsb_ros/tasks/narma.py",
           "return win.r[n.tau - 1:: n.tau, 0, body.cmp_local, 1]",
           "return win.r[0:: n.tau, 0, body.cmp_local, 1]",
           "NARMA output read at the first step of each block, not at its end", (L_NARMA,)),
    Mutant("trainer-narma-no-step", "bptsb_ros/training/trainer.py",
           "                optimizer.step()\n",
           "                optimizer.step() if cfg.task != \"narma\" else None\n",
           "optimizer.step() skipped for NARMA", (L_NARMA,)),
    Mutant("trainer-optim-d-rate-of-k", "bptsb_ros/training/optim.py",
           '{"name": "d", "params": [body.d], "lr": lr.d}',
           '{"name": "d", "params": [body.d], "lr": lr.k}',
           "the damping coefficients stepped with the spring constants' rate", (L_LISS, L_LOCO, L_NARMA)),
    Mutant("trainer-no-projection", "bptsb_ros/training/trainer.py",
           "                agent.body.clamp_parameters_(tc.projection)",
           "                pass",
           "train() no longer projects k, d, l onto ≥ 0 after a step", (L_CLAMP,)),
    Mutant("trainer-projection-ignored", "bptsb_ros/training/trainer.py",
           "agent.body.clamp_parameters_(tc.projection)",
           "agent.body.clamp_parameters_()",
           "train() ignores training.projection (always clamps)",
           ("tests/test_fused.py::test_unsupported_configs_fall_back_with_one_line",)),
    Mutant("projection-reset-to-zero", "bptsb_ros/body/msdn.py",
           "p.masked_fill_(p < 0, RESET_VALUE)",
           "p.masked_fill_(p < 0, 0.0)",
           "the reset projection sets negative k, d, l to 0, not 0.1",
           ("tests/test_physics.py::test_reset_projection_sets_negative_k_d_l_to_0_1_and_keeps_the_rest",)),
    Mutant("trainer-lr-decay-ignored", "bptsb_ros/training/trainer.py",
           "                divide_rates_(optimizer, 10.0)",
           "                pass",
           "training.lr_decay divides no rate",
           ("tests/test_fused.py::test_lr_decay_divides_every_rate_by_100_after_90_percent_of_more_than_1000_updates",)),
    Mutant("loco-authors-draw-extent-over-4", "bptsb_ros/experiments/locomotion_common.py",
           "sig * p_extent / 8 * noise",
           "sig * p_extent / 4 * noise",
           "the authors' position noise σ·P/4 instead of σ·P/8",
           ("tests/test_locomotion_experiments.py::"
            "test_authors_draw_scales_positions_by_extent_over_8_and_velocities_by_their_x_range",)),
    Mutant("lpert-restart-last-window-only", "bptsb_ros/experiments/lissajous_perturbation.py",
           "    return per_window.mean(0)",
           "    return per_window[-1]",
           "the restart trial's error from the last window, not the mean of the last 3",
           ("tests/test_autonomy.py::test_authors_window_error_is_the_mean_training_loss_of_the_last_windows",)),
    Mutant("trainer-mnist-drawing-no-projection", "bptsb_ros/tasks/mnist_drawing.py",
           "                opt.step()\n                system.body.clamp_parameters_()",
           "                opt.step()",
           "the MNIST drawing no longer projects k, d, l onto ≥ 0", L_DRAW),
    Mutant("trainer-scheme1-no-projection", "bptsb_ros/training/closed_loop_schemes.py",
           "            body.clamp_parameters_()\n        if failure is None:\n            state = s.detach()",
           "            pass\n        if failure is None:\n            state = s.detach()",
           "scheme 1 no longer projects k, d, l onto ≥ 0", (L_S1,)),
    Mutant("trainer-lissajous-targets-early", "bptsb_ros/tasks/lissajous.py",
           "self.target(self.window_times(k0))",
           "self.target(self.window_times(k0 - 1))",
           "Lissajous window compared with the target one step early", (L_LISS,)),
    Mutant("trainer-lissajous-config-phase-rate", "config/lissajous_single.yaml",
           "lr: {k: 1.0e+4, d: 1.0e+3, l: 1.0e+1, amplitude: 1.0e+1, phase: 1.0e+2}",
           "lr: {k: 1.0e+4, d: 1.0e+3, l: 1.0e+1, amplitude: 1.0e+1, phase: 1.0e+1}",
           "Lissajous φ rate 1e1 instead of the paper's 1e2", (*L_RATES, L_LISS)),
    Mutant("trainer-locomotion-ramp-from-zero", "bptsb_ros/tasks/locomotion.py",
           "target = self.cfg.locomotion.target_slope * (block_end - self.train_start_step) * self.agent.dt",
           "target = self.cfg.locomotion.target_slope * block_end * self.agent.dt",
           "locomotion's target ramp counts the warm-up as training time", (L_LOCO,)),
    Mutant("trainer-headwind-sign", "bptsb_ros/tasks/locomotion.py",
           "force[torch.from_numpy(on), :, 0] = loc.wind_force",
           "force[torch.from_numpy(on), :, 0] = -loc.wind_force",
           "the headwind blows from behind", (L_HEADWIND,)),
    Mutant("trainer-headwind-config-amplitude-rate", "config/locomotion_headwind.yaml",
           "lr: {k: 1.0e+0, d: 1.0e-2, l: 1.0e-3, amplitude: 1.0e-5, phase: 1.0e-4}",
           "lr: {k: 1.0e+0, d: 1.0e-2, l: 1.0e-3, amplitude: 1.0e-4, phase: 1.0e-4}",
           "headwind A rate 1e-4 instead of the paper's 1e-5", (*L_RATES, L_HEADWIND)),
    Mutant("trainer-locomotion-config-k-rate", "config/locomotion_forward.yaml",
           "lr: {k: 1.0e+2, d: 1.0e+0, l: 1.0e-1, amplitude: 1.0e-3, phase: 1.0e-2}",
           "lr: {k: 1.0e+3, d: 1.0e+0, l: 1.0e-1, amplitude: 1.0e-3, phase: 1.0e-2}",
           "locomotion k rate 1e3 instead of the paper's 1e2", (*L_RATES, L_LOCO)),
    Mutant("trainer-narma-config-brain-rate", "config/narma.yaml",
           "lr: {k: 1.0e+3, d: 1.0e+2, l: 1.0e+0, brain: 1.0e-2}",
           "lr: {k: 1.0e+3, d: 1.0e+2, l: 1.0e+0, brain: 1.0e-1}",
           "NARMA brain rate 1e-1 instead of the authors' 1e-2", (*L_RATES, L_NARMA)),
    Mutant("trainer-switching-wind-late", "bptsb_ros/tasks/lissajous_switching.py",
           "wind = torch.as_tensor(schedule[rel:rel + window], dtype=dtype)",
           "wind = torch.as_tensor(schedule[rel - 1:rel + window - 1], dtype=dtype)",
           "switching target follows the wind of the previous step", (L_SWITCH,)),
    Mutant("trainer-switching-lr-k", "bptsb_ros/tasks/lissajous_switching.py",
           "SWITCHING_LR = LearningRates(k=1e3, d=1e2, l=1e0, amplitude=1e0, phase=1e1)",
           "SWITCHING_LR = LearningRates(k=1e4, d=1e2, l=1e0, amplitude=1e0, phase=1e1)",
           "switching k rate 1e4 instead of the paper's 1e3", (*L_RATES, L_SWITCH)),
    Mutant("trainer-scheme1-targets-early", "bptsb_ros/training/closed_loop_schemes.py",
           "t = step_times(state.step + 1, window, body.dt)  # float64",
           "t = step_times(state.step, window, body.dt)  # float64",
           "scheme 1 compares step k with the target of step k − 1", (L_S1,)),
    Mutant("trainer-scheme1-init-std", "bptsb_ros/training/closed_loop_schemes.py",
           "fb.weight.normal_(0.0, init_std, generator",
           "fb.weight.normal_(0.0, 2 * init_std, generator",
           "scheme 1's FL starts from N(0, (2σ)²)", (L_S1,)),
    Mutant("trainer-closed-loop-lr-l", "bptsb_ros/training/closed_loop_schemes.py",
           "CLOSED_LOOP_LR = LearningRates(k=1e4, d=1e3, l=1e0, amplitude=1e0, phase=1e1)",
           "CLOSED_LOOP_LR = LearningRates(k=1e4, d=1e3, l=1e1, amplitude=1e0, phase=1e1)",
           "closed-loop l rate 1e1 instead of the paper's 1e0", (*L_RATES, L_S1)),
    Mutant("trainer-scheme2-alpha-1", "bptsb_ros/training/closed_loop_schemes.py",
           "loss = l_traj + alpha * l_fb",
           "loss = l_traj + l_fb",
           "scheme 2's L_FB weighted 1 instead of α = 0.1", (L_S2,)),
    Mutant("trainer-scheme2-fb-same-step", "bptsb_ros/training/closed_loop_schemes.py",
           "swg.signal_at_steps(torch.arange(first, first + window), body.dt))\n",
           "swg.signal_at_steps(torch.arange(first - 1, first + window - 1), body.dt))\n",
           "scheme 2's L_FB pairs state k with the SWG signal of step k, not k + 1", (L_S2,)),
    Mutant("trainer-scheme3-refit-first-windows", "bptsb_ros/training/closed_loop_schemes.py",
           "xs, ys = xs[-fit_windows:], ys[-fit_windows:]",
           "xs, ys = xs[:fit_windows], ys[:fit_windows]",
           "scheme 3 refits the FL on the first windows, not the last", (L_S3,)),
    Mutant("trainer-scheme3-refit-no-noise", "bptsb_ros/training/closed_loop_schemes.py",
           "fit_ridge(x + noise * rng.standard_normal(x.shape)",
           "fit_ridge(x + 0 * noise * rng.standard_normal(x.shape)",
           "scheme 3 refits the FL without input noise", (L_S3,)),
    Mutant("trainer-scheme3-refit-signal-k", "bptsb_ros/training/closed_loop_schemes.py",
           "ys.append(swg.signal_at_steps(torch.arange(first, first + window), body.dt)",
           "ys.append(swg.signal_at_steps(torch.arange(first - 1, first + window - 1), body.dt)",
           "scheme 3 regresses the SWG signal of step k, not k + 1, on state k", (L_S3,)),
    Mutant("trainer-feedback-fit-clock-from-zero", "bptsb_ros/training/feedback_fit.py",
           "first = 0 if state is None else state.step",
           "first = 0",
           "the FL fit from a running state regresses the SWG signal of the clock from 0", (L_FIT,)),
    # -- tests that can fail §3/§4: both sides of every validation at its edge, reported numbers -----------------
    # (run them alone: -k edge). EDGES pins each check's accepted limit and the value just past it on each side.
    Mutant("edge-ipc-input-lower", "bptsb_ros/analysis/ipc.py",
           "u.min() < -1 - 1e-12 or",
           "u.min() < -2 or",
           "IPC input below −1 accepted (only the upper side checked)", (EDGES,)),
    Mutant("edge-ipc-surrogates-0", "bptsb_ros/analysis/ipc.py",
           'if threshold != "none" and surrogates < 1:',
           'if threshold != "none" and surrogates < 0:',
           "surrogates = 0 accepted with a surrogate threshold", (EDGES,)),
    Mutant("edge-ipc-label-count", "bptsb_ros/analysis/ipc.py",
           "if len(labels) != len(xs):",
           "if len(labels) > len(xs):",
           "too few labels for the state sets accepted", (EDGES,)),
    Mutant("edge-wind-timing-100", "bptsb_ros/sim/wind_schedule.py",
           "and int(self.timing) < 100):",
           "and int(self.timing) <= 100):",
           "switching timing n = 100 accepted (n in [0, 99])", (EDGES,)),
    Mutant("edge-wind-hold-0", "bptsb_ros/sim/wind_schedule.py",
           "            if not 1 <= lo <= hi:",
           "            if not 0 <= lo <= hi:",
           "hold_periods with lo = 0 accepted", (EDGES,)),
    Mutant("edge-wind-table-repeated-t", "bptsb_ros/sim/wind_schedule.py",
           "if rows and values[0] <= rows[-1][0]:",
           "if rows and values[0] < rows[-1][0]:",
           "a wind table with a repeated t accepted", (EDGES,)),
    Mutant("edge-wind-table-negative-t", "bptsb_ros/sim/wind_schedule.py",
           "        if values[0] < 0:",
           "        if values[0] < -1:",
           "a wind table row at t = −0.5 s accepted", (EDGES,)),
    Mutant("edge-wind-table-force-sign", "bptsb_ros/sim/wind_schedule.py",
           "max(abs(values[1]), abs(values[2])) > max_force",
           "max(values[1], values[2]) > max_force",
           "a wind table force beyond −max_wind accepted (only the positive side checked)", (EDGES,)),
    Mutant("edge-limits-min-equals-max", "bptsb_ros/live/safety.py",
           "self.min_rest_length < self.max_rest_length):",
           "self.min_rest_length <= self.max_rest_length):",
           "min_rest_length = max_rest_length accepted (an empty range)", (EDGES,)),
    Mutant("edge-limits-rest-open-below", "bptsb_ros/live/safety.py",
           "(vals <= self.min_rest_length)",
           "(vals < self.min_rest_length)",
           "a rest length exactly at min_rest_length accepted (the range is open below)", (EDGES,)),
    Mutant("edge-limits-negative-displacement", "bptsb_ros/live/safety.py",
           "bad = np.flatnonzero(np.abs(vals) > self.max_displacement)",
           "bad = np.flatnonzero(vals > self.max_displacement)",
           "perturbation components below −max_displacement accepted", (EDGES,)),
    Mutant("edge-runaway-acceleration", "bptsb_ros/live/safety.py",
           "if speed * dt > limit or accel * dt * dt > limit:",
           "if speed * dt > limit:",
           "a runaway by acceleration alone not seen", (EDGES,)),
    Mutant("edge-realtime-max-age-offer", "bptsb_ros/live/channels.py",
           "if next_step - step > self.max_age_steps:",
           "if next_step - step >= self.max_age_steps:",
           "a realtime command exactly max_age_steps old rejected as stale", (EDGES,)),
    Mutant("edge-realtime-max-age-use", "bptsb_ros/live/channels.py",
           "step - self.latest.step <= self.max_age_steps",
           "step - self.latest.step < self.max_age_steps",
           "a realtime command exactly max_age_steps old no longer used", (EDGES,)),
    Mutant("edge-realtime-not-newer", "bptsb_ros/live/channels.py",
           "if self.latest is not None and step <= self.latest.step:",
           "if self.latest is not None and step < self.latest.step:",
           "a realtime command for the latest step accepted again", (EDGES, "tests/test_body_safety.py")),
    Mutant("edge-look-ahead", "bptsb_ros/live/channels.py",
           "if step > next_step + self.max_ahead:",
           "if step >= next_step + self.max_ahead:",
           "a command exactly max_ahead steps ahead rejected", (EDGES,)),
    Mutant("edge-md5sums-star-name", "bptsb_ros/data/mnist.py",
           'sums[parts[1].lstrip("*").removesuffix(".gz")]',
           'sums[parts[1].removesuffix(".gz")]',
           "an md5sum binary-mode line ('MD5 *NAME') names no file", (EDGES,)),
    Mutant("edge-mnist-label-10", "bptsb_ros/data/mnist.py",
           "if y.size and int(y.max()) > 9:",
           "if y.size and int(y.max()) > 10:",
           "label 10 accepted as a digit", (EDGES,)),
    Mutant("edge-result-bool-number", "bptsb_ros/experiments/result.py",
           "    if isinstance(value, bool) or not isinstance(value, (int, float)):",
           "    if not isinstance(value, (int, float)):",
           "a boolean in a result row (ours/paper/wall_s) accepted as a number", (EDGES,)),
    Mutant("edge-result-wall-zero", "bptsb_ros/experiments/result.py",
           'if not _finite(data["wall_s"]) or data["wall_s"] < 0:',
           'if not _finite(data["wall_s"]) or data["wall_s"] <= 0:',
           "wall_s = 0 refused", (EDGES,)),
    Mutant("edge-guard-patience-0", "bptsb_ros/training/guard.py",
           "if patience < 1:",
           "if patience < 0:",
           "update guard patience 0 accepted", (EDGES,)),
    Mutant("edge-config-narma-split", "bptsb_ros/config.py",
           "not (n.washout < n.train_end < n.n_inputs)",
           "not (n.washout <= n.train_end < n.n_inputs)",
           "narma washout = train_end accepted (no training sample)", (EDGES,)),
    Mutant("edge-config-lr-swg-rates", "bptsb_ros/config.py",
           'for k in ("k", "d", "l", *kinds)):',
           'for k in ("k", "d", "l")):',
           "an SWG agent that trains only amplitude/phase refused as 'nothing trained'", (EDGES,)),
    Mutant("edge-msdn-dt-nan", "bptsb_ros/body/msdn.py",
           "if not (math.isfinite(dt) and dt > 0):",
           "if dt <= 0:",
           "MSDN accepts dt = NaN or inf (the old check)", (EDGES,)),
    Mutant("edge-dt-to-ns-inf", "bptsb_ros/ros/topics.py",
           "if not (math.isfinite(dt) and dt > 0 and math.isfinite(dt * NS_PER_S)):",
           "if not dt > 0:",
           "dt_to_ns of an infinite dt an OverflowError again (the old check)", (EDGES,)),
    Mutant("edge-switching-nmse-own-centre", TS + "lissajous_switching.py",
           "ms = float(np.mean((target[a:b] - target[a:b].mean(0)) ** 2))",
           "ms = float(np.mean((target[a:b] - target.mean(0)) ** 2))",
           "a segment's NMSE normalised about the whole run's centre, not its own figure's", (NUMBERS,)),
    Mutant("edge-switching-nmse-whole-run", TS + "lissajous_switching.py",
           'out[label] = {"mse": err, "nmse": err / ms, "steps": b - a}',
           'out[label] = {"mse": err, "nmse": err / float(np.mean((target - target.mean(0)) ** 2)), "steps": b - a}',
           "every segment normalised by the whole run's mean square", (NUMBERS,)),
    Mutant("edge-report-fmt-rounds-to-1e4", "bptsb_ros/analysis/report.py",
           ' or "e" in plain:',
           ":",
           "9999.5 shown as '1e+04' (the old format)", (NUMBERS,)),
    Mutant("edge-report-fmt-small", "bptsb_ros/analysis/report.py",
           "abs(value) < 1e-3 or",
           "abs(value) <= 1e-3 or",
           "0.001 shown in scientific form", (NUMBERS,)),
    Mutant("edge-report-order-scale", "bptsb_ros/analysis/report.py",
           'scales = {"paper": 0, "short": 1, "smoke": 2}',
           'scales = {"paper": 0, "short": 2, "smoke": 1}',
           "smoke results listed before short ones", (NUMBERS,)),
    Mutant("edge-report-order-unregistered", "bptsb_ros/analysis/report.py",
           'order.get(pr[1]["experiment"], len(order))',
           'order.get(pr[1]["experiment"], -1)',
           "experiments of no paper listed first", (NUMBERS,)),
    Mutant("edge-report-duration-minutes", "bptsb_ros/analysis/report.py",
           "    if seconds < 120:",
           "    if seconds <= 120:",
           "120 s shown as '120 s', not '2.0 min'", (NUMBERS,)),
    Mutant("edge-wind-half-step", "bptsb_ros/sim/wind_schedule.py",
           "            if period < 1:",
           "            if period < 0:",
           "a switching period of half a time step (0 whole steps) no longer refused", (EDGES,)),
    Mutant("edge-mnist-count-fewer-labels", "bptsb_ros/data/mnist.py",
           "if y.ndim != 1 or y.shape[0] != x.shape[0]:",
           "if y.ndim != 1 or y.shape[0] > x.shape[0]:",
           "fewer labels than images accepted", (EDGES,)),
    Mutant("edge-ipc-cli-basis-count", "bptsb_ros/cli/ipc_cmd.py",
           "if total > MAX_BASIS_FUNCTIONS:",
           "if total >= MAX_BASIS_FUNCTIONS:",
           "a basis of exactly the maximum size refused", (EDGES,)),
    Mutant("edge-launch-rate-scale-0", "bptsb_ros/cli/launch_cmd.py",
           "args.rate_scale <= 0 or",
           "args.rate_scale < 0 or",
           "launch --rate-scale 0 accepted", (EDGES,)),
    Mutant("edge-param-maximum", "bptsb_ros/ros/params.py",
           "if self.maximum is not None and v > self.maximum:",
           "if self.maximum is not None and v >= self.maximum:",
           "a node parameter exactly at its (inclusive) maximum refused", (EDGES,)),
    Mutant("edge-param-positive-zero", "bptsb_ros/ros/params.py",
           "if self.positive and not v > 0:",
           "if self.positive and v < 0:",
           "a positive node parameter of 0 accepted", (EDGES,)),
    Mutant("edge-recover-torn-header", "bptsb_ros/bags/recover.py",
           'reason = "truncated record header"',
           'reason = "truncated record"',
           "the stop reason of a torn record header no longer says so (the split assert sees it)",
           ("tests/test_bags_recover.py::test_recovers_exactly_the_complete_chunks",)),
    Mutant("recorder-stop-handler-lock", "bptsb_ros/ros/recorder.py",
           "        self.ns: int | None = None\n\n    def __call__(self, *_: object) -> None:\n",
           "        self.ns: int | None = None\n        self.evt = __import__('threading').Event()\n\n"
           "    def __call__(self, *_: object) -> None:\n        self.evt.set()\n",
           "the recorder's stop handler sets a threading.Event (a lock a nested signal deadlocks on)",
           ("tests/test_bags_recorder.py::test_the_stop_handler_survives_signals_inside_itself",)),
    Mutant("recorder-stop-handler-last", "bptsb_ros/ros/recorder.py",
           "        if self.ns is None:\n            self.ns = time.time_ns()",
           "        self.ns = time.time_ns()",
           "the recorder's stop time is the last signal's, not the first's",
           ("tests/test_bags_recorder.py::test_the_stop_handler_survives_signals_inside_itself",)),
    Mutant("guard-mark-live-history", "bptsb_ros/training/guard.py",
           'return {"history": list(self.history[:mark["history"]]),',
           'return {"history": list(self.history),',
           "a saved checkpoint holds the guard's history of the save, not of its snapshot",
           ("tests/test_guard.py::test_a_mark_gives_the_state_of_its_moment_after_later_updates",)),
    Mutant("raw-template-last-occurrence", "bptsb_ros/ros/raw_out.py",
           "        at = data.find(value.tobytes())\n",
           "        at = data.rfind(value.tobytes())\n",
           "a sentinel's last occurrence is taken for its field (a stale copy after the content wins)",
           ("tests/test_live_speed.py::test_a_sentinel_copy_after_the_content_does_not_stop_the_template",)),
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
