"""Soak test of live recording under CPU load: ``bptsb bench --soak`` (the numbers behind the recorder's guarantees).

Two runs of ``bptsb launch <loop> --bag ... --allow-loss``, each while this process keeps extra CPU load going with
child processes that spin (started before the launch, stopped after it):

* **realtime** for ``realtime_seconds`` wall seconds with ``realtime_busy`` spinning processes (default 1: one core
  kept busy). Realtime cannot wait for the recorder, so this measures what a loaded machine loses, if anything.
* **lockstep** for ``lockstep_seconds`` sim seconds with ``lockstep_busy`` spinning processes (default 8). The body
  waits for the recorder's acknowledgements, so the expected loss is 0 however slow the run gets.

Each run reports: steps the body published (``steps_published``), messages the body published and the bag holds from
it, every message the bag holds, the drops the recorder counted (``dropped_counted_by_recorder``, from the bag's
``custom_data``), the drops the launcher found (the recorder's count or the body's published counts minus the bag,
whichever is larger: ``dropped_total``), whether the recorder's final drain completed, how long the body waited for
the recorder, the launch's exit code and the wall time. The runs use the caller's ROS_DOMAIN_ID (use a private one).
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

from bptsb_ros.files.safe_write import open_for_writing

SPIN = "while True: pass"


def start_busy(n: int) -> list[subprocess.Popen]:
    """``n`` child processes that spin until stopped (:func:`stop_busy`)."""
    return [subprocess.Popen([sys.executable, "-c", SPIN], stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL) for _ in range(n)]


def stop_busy(procs: list[subprocess.Popen]) -> None:
    for proc in procs:
        if proc.poll() is None:
            proc.kill()
        proc.wait()


def soak_run(mode: str, seconds: float, busy: int, workdir: Path, loop: str = "lissajous_open",
             progress=print) -> dict[str, Any]:
    """One recorded run of ``loop`` in ``mode`` for ``seconds`` (wall in realtime, sim in lockstep) with ``busy``
    spinning processes; returns its numbers (see the module docstring)."""
    from bptsb_ros.bags.metadata import read_metadata
    from bptsb_ros.bags.reader import bag_info
    from bptsb_ros.bags.recording import recorded_loss

    bag = workdir / f"{mode}_bag"
    log = workdir / f"{mode}_launch.log"
    argv = [sys.executable, "-m", "bptsb_ros.cli", "launch", loop, "--mode", mode, "--duration", f"{seconds:g}",
            "--bag", str(bag), "--allow-loss", "--timeout", f"{max(600.0, 20 * seconds):g}"]
    progress(f"soak: {mode} {loop} for {seconds:g} s with {busy} busy process(es); log {log}")
    procs = start_busy(busy)
    started = time.monotonic()
    try:
        with open_for_writing(log, "w") as out:
            code = subprocess.run(argv, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL).returncode
    finally:
        wall = time.monotonic() - started
        stop_busy(procs)
    result: dict[str, Any] = {"mode": mode, "loop": loop, "seconds": seconds, "busy_processes": busy,
                              "launch_exit_code": code, "wall_s": round(wall, 1), "log": str(log), "bag": str(bag)}
    summary_path = Path(str(bag) + ".launch") / "body_summary.json"
    if not summary_path.is_file() or not (bag / "metadata.yaml").is_file():
        result["error"] = "the run left no body summary or no finished bag; see the log"
        return result
    summary = json.loads(summary_path.read_text())
    published = summary.get("published_messages", {})
    from_body = sum(c.count for c in bag_info(bag).publishers if c.publisher is not None
                    and c.publisher.node == "body_sim")
    counted, by_topic, complete = recorded_loss(read_metadata(bag).custom_data)
    recording = summary.get("recording", {})
    result.update({
        "steps_published": int(summary["steps"]) + 1,
        "body_messages_published": sum(published.values()),
        "body_messages_recorded": from_body,
        "messages_recorded": read_metadata(bag).message_count,
        "dropped_counted_by_recorder": counted,
        "dropped_by_topic": by_topic,
        "dropped_total": recording.get("dropped_messages"),
        "recording_complete": complete,
        "recorder_wait_s": round(float(summary.get("recorder_wait_s", 0.0)), 3),
        "deadline_misses": summary.get("deadline_misses"),
    })
    return result


def run_soak(realtime_seconds: float = 60.0, lockstep_seconds: float = 10.0, realtime_busy: int = 1,
             lockstep_busy: int = 8, workdir: str | Path | None = None, progress=print) -> dict[str, Any]:
    """The realtime and the lockstep soak run (a run with 0 seconds is left out); bags and logs go to ``workdir``
    (default: a new temporary directory, kept)."""
    work = Path(workdir) if workdir else Path(tempfile.mkdtemp(prefix="bptsb-soak-"))
    work.mkdir(parents=True, exist_ok=True)
    report: dict[str, Any] = {"cpu_count": os.cpu_count(), "load_average_at_start": list(os.getloadavg()),
                              "ros_domain_id": os.environ.get("ROS_DOMAIN_ID", "0"), "workdir": str(work)}
    if realtime_seconds > 0:
        report["realtime"] = soak_run("realtime", realtime_seconds, realtime_busy, work, progress=progress)
    if lockstep_seconds > 0:
        report["lockstep"] = soak_run("lockstep", lockstep_seconds, lockstep_busy, work, progress=progress)
    return report
