"""Replay analysis of a recorded live run: rebuild the trajectories from a rosbag2 MCAP bag, compute
the task's metrics, and compare with the offline simulation of the same agent.

Works on our bags and on any rosbag2 MCAP bag with the loop's topics (``bptsb_ros/ros/TOPICS.md``):
the body layout comes from the ``body/markers`` topic (spring endpoints, fixed/movable/CMP colours),
time from the header stamps (sim time of step k = k·dt exactly). Only the messages of the node that owns each
topic are used (``body_sim`` for the body's state; :mod:`bptsb_ros.analysis.provenance`): messages of other
publishers are ignored and reported (``publishers`` in the metrics), a step with two different states from the
body fails the replay, and a bag that does not record publishers is read whole with a warning.
"""

from __future__ import annotations

import errno
import sys
from pathlib import Path
from typing import Any

import numpy as np

from bptsb_ros.analysis.bag_run import (
    BODY_NODE,
    LOOPS_CLOSED,
    LOOPS_WIND,
    BagRun,
    animate_run,
    bag_custom_data,
    read_run,
    recording_summary,
)
from bptsb_ros.bags.errors import BagError
from bptsb_ros.files.safe_write import json_text, write_atomic


# -- metrics ---------------------------------------------------------------------------------------
def task_metrics(run: BagRun, task: str, config: dict[str, Any]) -> dict[str, Any]:
    """The task's metric computed from a run's positions (and inputs for NARMA)."""
    t = run.steps * run.dt
    out: dict[str, Any] = {"task": task, "steps": int(len(run.steps)), "first_step": int(run.steps[0]),
                           "duration_s": float(t[-1] - t[0])}
    if task == "lissajous":
        from bptsb_ros.analysis.replay_lissajous import lissajous_target
        from bptsb_ros.tasks.lissajous import windowed_shift_error

        if run.cmp_index < 0:
            raise BagError("the Lissajous metric needs the CMP (from body/markers)")
        target, _, _, omega = lissajous_target(config)
        cmp = run.positions[:, run.cmp_index]
        period = int(round(2 * np.pi / omega / run.dt))
        out["metric"] = "trajectory_mse_shift_min"
        out["trajectory_mse"] = float(np.mean((cmp - target(t)) ** 2))
        out["trajectory_mse_shift_min"] = windowed_shift_error(cmp, target, float(t[0]), run.dt, period)
        half = len(cmp) // 2  # the second half: past the start-up transient of a run that began at rest
        if len(cmp) - half > period:
            out["trajectory_mse_shift_min_second_half"] = windowed_shift_error(
                cmp[half:], target, float(t[half]), run.dt, period)
        out["_plot"] = {"t": t, "cmp": cmp, "target": target(t)}
    elif task == "locomotion":
        from bptsb_ros.tasks.locomotion import mean_speed

        out["metric"] = "mean_forward_speed"
        out["mean_forward_speed"] = mean_speed(run.positions[:, :, 0], float(t[-1] - t[0]))
        x = run.positions[:, :, 0].mean(-1)
        out["_plot"] = {"t": t[1:], "speed": np.diff(x) / np.diff(t)}
    elif task == "narma":
        from bptsb_ros.tasks.narma import expanded_narma, nmse

        n = config.get("narma", {})
        tau, washout = int(n.get("tau", 20)), int(n.get("washout", 30))
        if run.cmp_index < 0 or not run.inputs:
            raise BagError("the NARMA metric needs the CMP (body/markers) and the task/input topic")
        row = {int(s): i for i, s in enumerate(run.steps)}
        blocks = []  # consecutive blocks from the start: NARMA has memory, a gap breaks every later target
        while (len(blocks) + 1) * tau in row and len(blocks) * tau + 1 in run.inputs:
            blocks.append(len(blocks))
        u = np.array([run.inputs[j * tau + 1] for j in blocks])
        if len(u) <= washout + 2:
            raise BagError(f"the run holds {len(u)} NARMA inputs; need more than the washout ({washout})")
        y = expanded_narma(u, int(n.get("order", 2)))
        out_y = np.array([run.positions[row[(j + 1) * tau], run.cmp_index, 1] for j in blocks])
        out["metric"] = "nmse_after_washout"
        out["nmse_after_washout"] = nmse(out_y[washout:], y[washout:])
        out["_plot"] = {"u": u, "y": y, "out": out_y}
    return out


def offline_positions(agent_dir: str | Path, loop: str, steps: int, inputs: dict[int, float],
                      open_loop_steps: int = 0, wind: np.ndarray | None = None,
                      perturbations: dict[int, np.ndarray] | None = None) -> np.ndarray:
    """(steps+1, N, 2) positions of the offline simulation of the same agent and loop, in float64.

    Closed loops with ``open_loop_steps`` = W run the SWG for steps 0..W, then the feedback layer (as
    ``bptsb launch --open-loop-steps W`` does). ``wind``: (steps + 1, 2) wind [N] in force at each step (a wind
    loop without it gets the agent's own schedule, ``wind_schedule.for_agent``); ``perturbations``: {step: (M, 2)
    displacement [m]} applied to the state of that step, as ``body_sim`` does (``sim.perturbation``).
    """
    import torch

    from bptsb_ros.sim.perturbation import simulate_perturbed
    from bptsb_ros.sim.rollout import simulate_open_loop
    from bptsb_ros.sim.trajectory import trajectory_from_rollout
    from bptsb_ros.training.checkpoint import feedback_fitted, load_agent, read_checkpoint

    agent = load_agent(agent_dir, dtype=torch.float64)
    perturbations = perturbations or {}
    wrong = [k for k, d in perturbations.items() if np.shape(d) != (agent.body.n_movable, 2)]
    if wrong:
        raise BagError(f"the perturbation at step {wrong[0]} displaces {np.shape(perturbations[wrong[0]])[0]} masses; "
                       f"the agent's body has {agent.body.n_movable} movable masses")
    if loop == "narma":
        from bptsb_ros.sim.inputs import brain_input

        if perturbations:
            raise BagError("the offline comparison of a perturbed run supports the SWG and feedback loops, not narma")
        scale = float(agent.config["narma"]["input_scale"])
        if not inputs:
            raise BagError("the narma loop's offline comparison needs the task/input topic")
        series, last = [], inputs[min(inputs)]
        for k in range(steps + 1):  # the input in force at each step; a lost message keeps the previous value
            last = inputs.get(k, last)
            series.append(last)
        roll = simulate_open_loop(agent, steps, inputs=brain_input(torch.tensor(series, dtype=torch.float64),
                                                                   {**agent.config["narma"], "input_scale": scale}))
        return trajectory_from_rollout(agent.body, roll).positions
    feedback_from = None
    if loop in LOOPS_CLOSED:
        if agent.feedback is None or not feedback_fitted(agent_dir):
            raise BagError(f"loop {loop} needs an agent with a fitted feedback layer; {agent_dir} has none")
        feedback_from = max(open_loop_steps, 0)  # the SWG drives steps 0..W (all of them when W >= steps)
    if wind is None and loop in LOOPS_WIND:  # the agent's own schedule, as the wind_source node sends it by default
        from bptsb_ros.sim.wind_schedule import for_agent

        wind = for_agent(agent.config, read_checkpoint(agent_dir)["extra"]).forces(steps, agent.dt)
    r = simulate_perturbed(agent, steps, perturbations, wind=wind, feedback_from=feedback_from)
    return agent.body.full_positions(r).numpy()


def replay(bag: str | Path, out_dir: str | Path, agent_dir: str | Path | None = None, task: str | None = None,
           loop: str | None = None, gif: bool = True, skip_damaged: bool = False,
           body_node: str = BODY_NODE) -> dict[str, Any]:
    """Analyse a bag; writes metrics.json, plots and an animation to ``out_dir``; returns the metrics.

    Only the messages of ``body_node`` (and of the other topics' owners) are used; ``publishers`` in the metrics
    reports the foreign and duplicate messages left out (warnings on stderr too).

    The agent is loaded only from ``agent_dir``, never from a path read from the bag: a bag is untrusted
    data. The agent the bag names (its ``custom_data``) is reported as ``bag_agent`` so the user can pass it.
    """
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise NotADirectoryError(errno.ENOTDIR, "it exists and is not a directory", str(out_dir))
    out_dir.mkdir(parents=True, exist_ok=True)
    custom = bag_custom_data(bag)
    if (loop or custom.get("loop")) == "mnist_drawing":  # episodes of drawings: analysis/mnist_replay.py
        from bptsb_ros.analysis.mnist_replay import replay_mnist

        return replay_mnist(bag, out_dir, agent_dir, gif=gif, skip_damaged=skip_damaged, body_node=body_node)
    named = custom.get("agent") if custom.get("agent") not in (None, "", "fresh") else None
    config: dict[str, Any] = {}
    if agent_dir is not None:
        from bptsb_ros.training.checkpoint import read_checkpoint

        config = read_checkpoint(agent_dir)["config"]
    run = read_run(bag, dt=float(config["body"]["dt"]) if config else None, skip_damaged=skip_damaged,
                   body_node=body_node, loop=loop)
    for line in run.provenance.warnings(bag):
        print(line, file=sys.stderr, flush=True)
    from bptsb_ros.analysis import control_calls as cc

    calls = cc.control_calls(bag, run.custom.get("namespace", ""), body_node)
    for line in cc.warnings(calls, bag):
        print(line, file=sys.stderr, flush=True)
    task = task or config.get("task")
    loop = loop or run.custom.get("loop")
    metrics: dict[str, Any] = {"bag": str(bag), "agent": str(agent_dir) if agent_dir else None,
                               **({"bag_agent": named} if named and agent_dir is None else {}), "loop": loop,
                               "mode": run.custom.get("mode"), "dt": run.dt, "recorded_steps": int(len(run.steps)),
                               "missing_steps": len(run.missing_steps), "publishers": run.provenance.to_dict(),
                               "recording": recording_summary(run.custom), "control_calls": cc.summary(calls)}
    segment = run.rows(run.longest_contiguous())
    if metrics["missing_steps"]:
        metrics["metric_steps"] = [int(segment.steps[0]), int(segment.steps[-1])]
    plots: dict[str, Any] = {}
    if task:
        live = task_metrics(segment, task, config)
        plots = live.pop("_plot", {})
        metrics["live"] = live
    if agent_dir is not None and loop:
        try:
            _compare_offline(run, segment, agent_dir, loop, task, config, metrics, plots)
        except BagError as err:  # the live metrics stand; say why there is no offline comparison
            metrics["offline_comparison"] = {"skipped": str(err)}
    files = _write(out_dir, segment, metrics, plots, task, gif)
    metrics["files"] = [str(f) for f in files]
    write_atomic(out_dir / "metrics.json", json_text(metrics, indent=2, default=float))
    return metrics


def _compare_offline(run: BagRun, segment: BagRun, agent_dir: str | Path, loop: str, task: str | None,
                     config: dict[str, Any], metrics: dict[str, Any], plots: dict[str, Any]) -> None:
    """The offline simulation of the same agent, loop, inputs, wind and perturbations: position difference, the
    task metric offline, and for Lissajous runs the return criterion / switching segments (into ``metrics``)."""
    last = int(run.steps[-1])
    warm = int(run.custom.get("open_loop_steps", 0))
    wind = run.wind_series(last) if loop in LOOPS_WIND else None
    off = offline_positions(agent_dir, loop, last, run.inputs, warm, wind=wind, perturbations=run.perturbations)
    diff = np.abs(off[run.steps] - run.positions)
    metrics["offline_comparison"] = {"max_abs_position_difference_m": float(diff.max()),
                                     "steps_compared": int(len(run.steps)),
                                     "perturbed_steps": sorted(run.perturbations)}
    if task == "lissajous" and run.cmp_index >= 0:
        autonomy = _lissajous_autonomy(agent_dir, loop, segment, off, wind, warm, last, config)
        plots["autonomy"] = autonomy.pop("_plot")
        metrics.update(autonomy)
    if task:
        off_run = BagRun(run.dt, segment.steps, off[segment.steps], None, None, run.springs, run.fixed,
                         run.cmp_index, run.inputs, run.custom)
        offline = task_metrics(off_run, task, config)
        plots["offline"] = offline.pop("_plot", {})
        metrics["offline"] = offline


def _lissajous_autonomy(agent_dir: str | Path, loop: str, segment: BagRun, off: np.ndarray, wind: np.ndarray | None,
                        warm: int, last: int, config: dict[str, Any]) -> dict[str, Any]:
    """``perturbation``: the return criterion of a perturbed run, live and offline; ``switching``: the per-segment
    errors of a switching run (``analysis.replay_lissajous``)."""
    from bptsb_ros.analysis.replay_lissajous import blowing, lissajous_target, return_metrics, switching_metrics
    from bptsb_ros.training.checkpoint import read_checkpoint

    out: dict[str, Any] = {"_plot": {}}
    c = segment.cmp_index
    cmp = {"live": segment.positions[:, c], "offline": off[segment.steps, c]}
    kicks = [k for k in segment.perturbations if segment.steps[0] <= k <= segment.steps[-1]]
    if kicks:
        orig = offline_positions(agent_dir, loop, last, segment.inputs, warm, wind=wind)
        runs = {**cmp, "unperturbed": orig[segment.steps, c]}
        out["perturbation"] = return_metrics(runs, int(segment.steps[0]), max(kicks), segment.dt, config)
        target, *_ = lissajous_target(config)
        out["_plot"]["perturbation"] = {"runs": runs, "target": target(segment.steps * segment.dt)}
    if loop == "lissajous_switching" and wind is not None and int(segment.steps[0]) == 0:
        out["switching"] = switching_metrics(cmp, wind[segment.steps], segment.dt, config,
                                             read_checkpoint(agent_dir)["extra"])
        out["_plot"]["switching"] = {"cmp": cmp["live"], "target": out["switching"].pop("_target"),
                                     "wind": blowing(wind[segment.steps]).astype(np.float64)}
    return out


#: loops whose first ``open_loop_steps`` steps the SWG drives before the feedback layer closes the loop
CLOSED_LOOPS = ("lissajous_closed",)


def _write(out_dir: Path, run: BagRun, metrics: dict, plots: dict, task: str | None, gif: bool) -> list[Path]:
    from bptsb_ros.analysis import plots as P

    files: list[Path] = [out_dir / "metrics.json"]
    t = run.steps * run.dt
    if run.spring_lengths is not None:
        files.append(P.plot_spring_lengths(out_dir / "spring_lengths.png", t, run.spring_lengths))
    if task == "lissajous" and "cmp" in plots:
        off = plots.get("offline", {}).get("cmp")
        curves = {f"live ({metrics.get('loop') or 'bag'})": plots["cmp"]}
        if off is not None:
            curves["offline simulation"] = off
        warm = int(run.custom.get("open_loop_steps", 0) or 0)
        closes = (warm - int(run.steps[0])) * run.dt if metrics.get("loop") in CLOSED_LOOPS and warm > 0 else None
        files.append(P.plot_lissajous(out_dir / "lissajous.png", plots["t"], curves, plots["target"],
                                      closes_at=closes if closes is not None and closes >= 0 else None))
    elif task == "locomotion" and "speed" in plots:
        speeds = {"live": plots["speed"]}
        if "speed" in plots.get("offline", {}):
            speeds["offline"] = plots["offline"]["speed"]
        files.append(P.plot_speed(out_dir / "speed.png", plots["t"], speeds, window=max(1, int(round(1.0 / run.dt))),
                                  shade=wind_periods(run), shade_label="wind blowing"))
    elif task == "narma" and "u" in plots:
        files.append(P.plot_series(out_dir / "narma.png", {"input u": plots["u"], "target y": plots["y"],
                                                          "live output": plots["out"]}, "sample [τ steps]",
                                  "u [-]; target y, output (CMP y) [m]"))
    files += _autonomy_figures(out_dir, run, metrics, plots.get("autonomy", {}))
    if gif and len(run.springs):
        files.append(animate_run(out_dir / "replay.gif", run))
    return files


def _autonomy_figures(out_dir: Path, run: BagRun, metrics: dict, plots: dict) -> list[Path]:
    """perturbation.png (the perturbed run against the offline ones) and switching_curves.png (the first measured
    segment without and with wind over their targets)."""
    from bptsb_ros.analysis import autonomy_plots as A

    files = []
    t = run.steps * run.dt
    if "perturbation" in plots and "perturbation" in metrics:
        p = metrics["perturbation"]
        if "E_live" in p:
            verdict = (f"{'returned' if p['returned_live'] else 'did not return'} (E / E_orig = "
                       f"{p['E_live'] / p['E_orig']:.3g}, criterion < 2)")
        else:
            verdict = p.get("problem", "")
        files.append(A.plot_perturbed_run(out_dir / "perturbation.png", t, plots["perturbation"]["runs"],
                                          plots["perturbation"]["target"], p["perturbed_at_step"] * run.dt,
                                          p["eval_steps"][0] * run.dt if "eval_steps" in p else None, verdict))
    if "switching" in plots and metrics.get("switching", {}).get("segments"):
        segs = metrics["switching"]["segments"]
        chosen = {}
        for want in (False, True):
            s = next((s for s in segs if s["wind"] == want), None)
            if s is not None:
                chosen[f"{'wind' if want else 'no wind'} (steps {s['steps'][0]}-{s['steps'][1]})"] = (
                    s["steps"][0], s["steps"][1] + 1)
        sw = plots["switching"]
        files.append(A.plot_switching_curves(out_dir / "switching_curves.png", sw["cmp"], sw["target"], sw["wind"],
                                             chosen, title="live run"))
    return files


def wind_periods(run: BagRun) -> list[tuple[float, float]]:
    """Time intervals [s] in which the wind blew (non-zero x component, from ``env/wind``), as (start, end) pairs;
    a wind stamped at step k holds until the next message."""
    if not run.wind:
        return []
    steps = sorted(run.wind)
    out: list[tuple[float, float]] = []
    end_step = int(run.steps[-1])
    for i, k in enumerate(steps):
        nxt = steps[i + 1] if i + 1 < len(steps) else end_step + 1
        if run.wind[k][0] != 0 and nxt > k:
            a, b = k * run.dt, nxt * run.dt
            if out and abs(out[-1][1] - a) < 1e-9:
                out[-1] = (out[-1][0], b)
            else:
                out.append((a, b))
    return out
