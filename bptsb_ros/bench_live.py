"""``bptsb bench --live``: steps per second of lockstep live loops while a bag is recorded, and where each step's
wall time goes.

Each run is ``bptsb launch <loop> --bag DIR --duration S`` (lockstep; the recorder acknowledges, ``body_sim`` waits
for it), exactly as a user starts it. ``body_sim`` times every step's phases (:mod:`bptsb_ros.live.phases`:
recorder wait, publish, wait for commands, compute) and writes them into its ``body_summary.json``; start-up is not
in them. Runs of several loops are interleaved (loop A, loop B, loop A, ...) so that a change in the machine's load
hits every loop alike. ``lissajous_closed`` needs a fitted feedback layer: the bench fits one on a fresh Lissajous
agent (10 s of sim time) in its work folder first.

The runs use the caller's ROS_DOMAIN_ID (use a private one).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from bptsb_ros.live.phases import PHASES, row_from_summary
from bptsb_ros.safe_files import open_for_writing

#: the loops ``bptsb bench --live`` runs by default
LIVE_LOOPS: tuple[str, ...] = ("lissajous_closed", "narma")
#: open-loop steps the closed loop runs on the SWG before the feedback layer takes over
OPEN_LOOP_STEPS = 30


def fitted_agent(run_dir: Path, seed: int = 3) -> Path:
    """A fresh float64 Lissajous agent with a feedback layer fitted on 10 s of sim time, saved as a checkpoint in
    ``run_dir`` (the agent ``lissajous_closed`` needs)."""
    from bptsb_ros.agent import build_agent
    from bptsb_ros.config import validate
    from bptsb_ros.training.checkpoint import save_checkpoint
    from bptsb_ros.training.feedback_fit import fit_feedback

    cfg = validate({"task": "lissajous", "seed": seed, "dtype": "float64", "feedback": {"fit_time": 10.0}})
    agent = build_agent(cfg)
    fit_feedback(agent, cfg.feedback, None, seed)
    save_checkpoint(run_dir, agent, {"feedback_fitted": True})
    return run_dir


def loop_params(loop: str, params: tuple[str, ...]) -> tuple[str, ...]:
    """The ``NODE:NAME:=VALUE`` parameters of ``params`` whose node is part of ``loop`` (the others are left out,
    so that one list can serve several loops)."""
    from bptsb_ros.live.loops import LOOPS

    nodes = {"body_sim", "recorder", *(b.executable for b in LOOPS[loop].brains)}
    return tuple(p for p in params if p.split(":", 1)[0] in nodes)


def launch_argv(loop: str, bag: Path, seconds: float, agent: str = "", params: tuple[str, ...] = ()) -> list[str]:
    """The ``bptsb launch`` command line of one recorded lockstep run of ``loop`` for ``seconds`` sim seconds
    (``params``: those of :func:`loop_params`)."""
    argv = [sys.executable, "-m", "bptsb_ros.cli", "launch", loop, "--duration", f"{seconds:g}", "--bag", str(bag),
            "--timeout", f"{max(600.0, 60 * seconds):g}"]
    if agent:
        argv += ["--agent", agent, "--open-loop-steps", str(OPEN_LOOP_STEPS)]
    for param in loop_params(loop, params):
        argv += ["--param", param]
    return argv


def live_run(loop: str, seconds: float, workdir: Path, tag: str, agent: str = "", params: tuple[str, ...] = (),
             progress=print) -> dict[str, Any]:
    """One recorded lockstep run of ``loop``: its row (:func:`~bptsb_ros.live.phases.row_from_summary`) with the
    launch's exit code, its wall time with start-up, and the messages the recorder counted as lost."""
    from bptsb_ros.bags.metadata import read_metadata
    from bptsb_ros.bags.recording import recorded_loss

    bag = workdir / f"{tag}_bag"
    log = workdir / f"{tag}_launch.log"
    progress(f"bench --live: {loop} for {seconds:g} s sim time, recorded; log {log}")
    started = time.monotonic()
    with open_for_writing(log, "w") as out:
        code = subprocess.run(launch_argv(loop, bag, seconds, agent, params), stdout=out, stderr=subprocess.STDOUT,
                              stdin=subprocess.DEVNULL).returncode
    result: dict[str, Any] = {"loop": loop, "sim_seconds": seconds, "launch_exit_code": code,
                              "wall_with_startup_s": round(time.monotonic() - started, 2), "log": str(log)}
    summary_path = Path(str(bag) + ".launch") / "body_summary.json"
    if not summary_path.is_file() or not (bag / "metadata.yaml").is_file():
        result["error"] = "the run left no body summary or no finished bag; see the log"
        return result
    try:
        result.update(row_from_summary(json.loads(summary_path.read_text())))
    except (KeyError, ValueError) as err:
        result["error"] = str(err)
        return result
    result["dropped_messages"] = recorded_loss(read_metadata(bag).custom_data)[0]
    return result


def run_live(loops: tuple[str, ...] = LIVE_LOOPS, seconds: float = 10.0, repeats: int = 1,
             workdir: str | Path | None = None, params: tuple[str, ...] = (), progress=print) -> dict[str, Any]:
    """``repeats`` interleaved rounds of one recorded lockstep run of each of ``loops`` (``seconds`` sim seconds
    each; ``params``: ``NODE:NAME:=VALUE`` passed to every launch of a loop with that node). Bags and logs go to
    ``workdir`` (default: a new temporary folder, kept)."""
    work = Path(workdir) if workdir else Path(tempfile.mkdtemp(prefix="bptsb-bench-live-"))
    work.mkdir(parents=True, exist_ok=True)
    report: dict[str, Any] = {"cpu_count": os.cpu_count(), "load_average_at_start": list(os.getloadavg()),
                              "ros_domain_id": os.environ.get("ROS_DOMAIN_ID", "0"), "workdir": str(work),
                              "params": list(params), "runs": []}
    agent = ""
    if any(loop.endswith("_closed") for loop in loops):
        progress("bench --live: fitting a feedback layer for the closed loop ...")
        agent = str(fitted_agent(work / "agent"))
    for round_ in range(repeats):
        for loop in loops:
            report["runs"].append(live_run(loop, seconds, work, f"{loop}_{round_}",
                                           agent if loop.endswith("_closed") else "", params, progress))
    report["load_average_at_end"] = list(os.getloadavg())
    return report


def live_table(report: dict[str, Any]) -> str:
    """A Markdown table of :func:`run_live`'s report: one row per run, steps/s and per-step milliseconds."""
    head = ["loop", "steps", "steps/s", *(f"{p} ms" for p in (*PHASES, "other")), "lost", "exit"]
    rows = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in report["runs"]:
        if "error" in r:
            rows.append(f"| {r['loop']} | {r['error']} |" + " |" * (len(head) - 2))
            continue
        cells = [r["loop"], str(r["steps"]), f"{r['steps_per_s']:.0f}",
                 *(f"{r[f'{p}_ms']:.3f}" for p in (*PHASES, "other")), str(r.get("dropped_messages")),
                 str(r["launch_exit_code"])]
        rows.append("| " + " | ".join(cells) + " |")
    return "\n".join(rows)
