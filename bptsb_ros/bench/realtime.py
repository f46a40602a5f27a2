"""Realtime that holds: ``bptsb bench --realtime`` (a closed loop at 100 Hz, idle and with one core kept busy).

Each condition is one ``bptsb launch <loop> --mode realtime --duration S`` (default the closed Lissajous loop of the
package's example agent, ``bags/lissajous_agent``: dt 0.01 s, so 100 steps a wall second), the live loop exactly as
``bptsb launch`` runs it, with the body's ``timing_path`` set so that it writes every step's wall times
(:mod:`bptsb_ros.live.step_times`), with the ``executor`` parameter of the body and the brains, and with the body's
``rt_priority``, and the body's and brains' ``cpus``. Two conditions, in this order:

* ``idle``: no extra load (the machine as it is: say in the report what else ran on it);
* ``busy``: ``busy`` child processes that spin (:func:`bptsb_ros.bench.soak.start_busy`; default 1, one core kept busy),
  started before the launch and stopped after it.

Per condition (from the body's own records, :func:`~bptsb_ros.live.step_times.timing_statistics`): steps, deadline
misses (count and %), step compute time, its integrate and publish parts, start lateness and period jitter
(p50/p99/max, ms); from the body's run summary: its own deadline-miss counter (the same rule, a cross-check), late
commands (commands the body rejected as stale, every source) and safe-command steps; the executor; the launch's
exit code (a launch that failed after the body wrote its records, e.g. a brain silent on a loaded machine, is
reported with its reason, ``launch_problem``, and its numbers) and wall time; and whether the targets hold
(:data:`TARGETS`).

Beside each condition's loop, under the same busy processes, right after it: the ``paced`` anchor
(:func:`bptsb_ros.ros.anchor.run_paced_anchor`: two bare rclpy processes, one publishing a ping at each due time on
the body's schedule and priority, the other answering; no physics, no brain, no recorder) for ``anchor_seconds``,
judged by the same rule: its misses are what the machine's scheduler and middleware give any loop at that rate
(``anchor`` in the condition; ``anchor_deadline_misses`` and ``anchor_compute_p99_ms``, its publish time, in the
table). The report also says the kernel's preemption model (:func:`kernel_facts`). The report is handed to
``update`` after each condition (``bptsb bench`` rewrites its ``--out``
file then, marked incomplete: a long bench leaves the finished condition on disk).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from bptsb_ros.files.safe_write import open_for_writing

#: the realtime targets: (key of the statistics, bound, what it means); a statistic meets its target when <= bound
#: (deadline misses: == 0)
TARGETS: tuple[tuple[str, float, str], ...] = (
    ("deadline_misses", 0.0, "no deadline miss"),
    ("compute_p99_ms", 0.3, "step compute p99 <= 0.3 ms"),
    ("period_jitter_p99_ms", 2.0, "period jitter p99 < 2 ms"),
)
#: the conditions of a bench: (name, whether the spinning processes run); with a realtime factor a third one,
#: ``factor``: the same loop at that many times real time (rate_scale; 10: 1 kHz wall at dt 0.01 s), idle
CONDITIONS: tuple[tuple[str, bool], ...] = (("idle", False), ("busy", True))
FACTOR_CONDITION = "factor"
#: the columns of :func:`realtime_table`: (key, heading, format)
COLUMNS: tuple[tuple[str, str, str], ...] = (
    ("steps", "steps", "d"), ("deadline_misses", "misses", "d"), ("deadline_miss_pct", "miss %", ".2f"),
    ("compute_p50_ms", "compute p50", ".3f"), ("compute_p99_ms", "p99", ".3f"), ("compute_max_ms", "max", ".2f"),
    ("period_jitter_p99_ms", "jitter p99", ".3f"), ("period_jitter_max_ms", "max", ".2f"),
    ("late_commands", "late cmds", "d"), ("executor", "executor", "s"), ("rt_priority", "FIFO", "d"),
    ("cpus", "CPUs", "s"), ("anchor_deadline_misses", "anchor misses", "d"),
    ("anchor_compute_p99_ms", "anchor p99", ".3f"),
)
#: the anchor's statistics kept in a condition's ``anchor``
ANCHOR_KEYS = ("ticks", "pongs", "seconds", "period_ms", "rt_priority", "deadline_misses", "deadline_miss_pct",
               "compute_p50_ms", "compute_p99_ms", "lateness_p50_ms", "lateness_p99_ms", "lateness_max_ms",
               "scheduling_problem", "pong_problem", "error")
#: stale rejections of these sources are the late commands
SOURCES = ("rest_length", "force", "wind", "reset")


def example_agent() -> Path:
    """The package's example agent (``bags/lissajous_agent``: closed Lissajous loop, dt 0.01 s)."""
    from bptsb_ros.files.package_data import example_agent as packaged

    return packaged()


def late_commands(summary: dict[str, Any]) -> int:
    """Commands the body rejected as stale (arrived after the step they were for), summed over :data:`SOURCES`."""
    return sum(int(summary.get(f"{s}_rejected_stale", 0)) for s in SOURCES)


def targets_met(stats: dict[str, Any]) -> dict[str, bool]:
    """Whether each of :data:`TARGETS` holds for ``stats`` (a statistic that is missing does not)."""
    return {key: key in stats and stats[key] <= bound for key, bound, _ in TARGETS}


def condition_result(summary: dict[str, Any], timing: dict[str, Any]) -> dict[str, Any]:
    """The numbers of one condition from the body's run summary and its timing records (as
    :func:`~bptsb_ros.live.step_times.load_step_times` returns them)."""
    from bptsb_ros.live.step_times import timing_statistics

    stats: dict[str, Any] = timing_statistics(timing["due"], timing["began"], timing["integrated"], timing["done"],
                                              timing["period"])
    stats.update({
        "period_ms": timing["period"] * 1e3,
        "executor": timing.get("executor", "unknown"),
        "deadline_misses_counted_by_body": summary.get("deadline_misses"),
        "late_commands": late_commands(summary),
        "safe_command_steps": summary.get("safe_command_steps"),
        "command_latency_p99_ms": summary.get("command_latency_ms_p99"),
        "rt_priority": summary.get("rt_priority", 0),
        "cpus": summary.get("cpus", "any"),
    })
    stats["targets_met"] = targets_met(stats)
    return stats


def kernel_facts(realtime_file: Path = Path("/sys/kernel/realtime"),
                 preempt_file: Path = Path("/sys/kernel/debug/sched/preempt"),
                 config_files: tuple[Path, ...] | None = None,
                 cmdline_file: Path = Path("/proc/cmdline")) -> dict[str, str]:
    """The kernel's release and version (``uname``) and its preemption model, from the first of these that says:
    ``/sys/kernel/realtime`` (1 on a PREEMPT_RT kernel); ``/sys/kernel/debug/sched/preempt`` (the bracketed mode of a
    dynamic-preemption kernel; root only); the build configuration (``/proc/config.gz``, else
    ``/boot/config-<release>``: ``CONFIG_PREEMPT_RT``, ``CONFIG_PREEMPT``, ``CONFIG_PREEMPT_VOLUNTARY``,
    ``CONFIG_PREEMPT_NONE``), with a ``preempt=`` boot option over it where the kernel honours one
    (``CONFIG_PREEMPT_DYNAMIC``). 'unknown' where none says. The paths are the files read (planted ones in the
    tests)."""
    import gzip
    import re

    uname = os.uname()
    facts = {"kernel": f"{uname.release} {uname.version}", "preemption": "unknown"}
    try:
        if realtime_file.read_text().strip() == "1":
            facts["preemption"] = f"full (realtime) ({realtime_file})"
            return facts
    except OSError:
        pass
    try:
        mode = re.search(r"\((\w+)\)", preempt_file.read_text())
        if mode:
            facts["preemption"] = f"{mode.group(1)} ({preempt_file})"
            return facts
    except OSError:
        pass
    config = ""
    for path in config_files or (Path("/proc/config.gz"), Path(f"/boot/config-{uname.release}")):
        try:
            data = path.read_bytes()
            config = (gzip.decompress(data) if path.suffix == ".gz" else data).decode(errors="replace")
            break
        except (OSError, EOFError, gzip.BadGzipFile):
            continue
    try:
        cmdline = cmdline_file.read_text()
    except OSError:
        cmdline = ""

    def built(option: str) -> bool:
        return re.search(rf"^{option}=y$", config, re.MULTILINE) is not None

    boot = re.search(r"(?:^|\s)preempt=(\w+)", cmdline)
    for option, model in (("CONFIG_PREEMPT_RT", "full (realtime)"), ("CONFIG_PREEMPT", "full"),
                          ("CONFIG_PREEMPT_VOLUNTARY", "voluntary"), ("CONFIG_PREEMPT_NONE", "none")):
        if built(option):
            dynamic = boot and option != "CONFIG_PREEMPT_RT" and built("CONFIG_PREEMPT_DYNAMIC")
            facts["preemption"] = (f"{boot.group(1)} (preempt= boot option; built {model})" if dynamic
                                   else f"{model} ({option}=y)")
            break
    return facts


def anchor_result(anchor: dict[str, Any], seconds: float) -> dict[str, Any]:
    """What a condition keeps of a paced anchor's result (:data:`ANCHOR_KEYS`), with its ``seconds``."""
    return {k: v for k, v in {**anchor, "seconds": seconds}.items() if k in ANCHOR_KEYS}


def realtime_run(name: str, seconds: float, busy: int, workdir: Path, *, loop: str, agent: str, executor: str,
                 rt_priority: int = 0, progress: Callable[[str], None] = print,
                 env: Mapping[str, str] | None = None, rate_scale: float = 1.0, cpus: str = "",
                 anchor_seconds: float = 0.0) -> dict[str, Any]:
    """One condition: ``bptsb launch loop --mode realtime --duration seconds --rate-scale rate_scale`` with ``busy``
    spinning processes, ``executor`` for the body and every brain (and ``cpus``, when given: their CPUs, taskset -c
    form), logs in ``workdir/name``; then, with ``anchor_seconds`` > 0 and the same busy processes, the paced anchor
    at the loop's period, priority and CPUs. Returns :func:`condition_result` plus the run's facts and ``anchor``
    (or ``error``). ``env``: the launch's and the anchor's environment (default this process's)."""
    from bptsb_ros.bench.soak import start_busy, stop_busy
    from bptsb_ros.live.loops import LOOPS
    from bptsb_ros.live.step_times import load_step_times

    logs = workdir / name
    timing_path = logs / "step_times.npz"
    log = workdir / f"{name}_launch.log"
    argv = [sys.executable, "-m", "bptsb_ros.cli", "launch", loop, "--mode", "realtime", "--duration", f"{seconds:g}",
            "--log-dir", str(logs), "--timeout", f"{seconds + 300:g}", "--rate-scale", f"{rate_scale:g}",
            "--param", f"body_sim:timing_path:={timing_path}", "--param", f"body_sim:rt_priority:={rt_priority}"]
    for node in ("body_sim", *(b.executable for b in LOOPS[loop].brains)):
        argv += ["--param", f"{node}:executor:={executor}"]
        if cpus:
            argv += ["--param", f"{node}:cpus:={cpus}"]
        if rt_priority and node != "body_sim":  # the brains one below the body, which preempts them
            argv += ["--param", f"{node}:rt_priority:={max(1, rt_priority - 1)}"]
    if agent:
        argv += ["--agent", agent]
    progress(f"realtime bench: {name}: {loop} for {seconds:g} s at {rate_scale:g}x real time with {busy} busy "
             f"process(es), executor {executor}; log {log}")
    procs = start_busy(busy)
    started = time.monotonic()
    summary_path = logs / "body_summary.json"
    anchor: dict[str, Any] | None = None
    wall: float | None = None  # the launch's wall time, without the anchor's
    load_after: list[float] = []
    try:
        with open_for_writing(log, "w") as out:
            code = subprocess.run(argv, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                  env=None if env is None else dict(env)).returncode
        wall, load_after = time.monotonic() - started, list(os.getloadavg())
        if anchor_seconds > 0 and summary_path.is_file() and timing_path.is_file():
            anchor = _paced_anchor(anchor_seconds, timing_path, rt_priority, cpus, env, progress)
    finally:
        wall = time.monotonic() - started if wall is None else wall
        stop_busy(procs)
    result: dict[str, Any] = {"condition": name, "loop": loop, "agent": agent or "fresh", "seconds": seconds,
                              "rate_scale": rate_scale, "busy_processes": busy, "cpus_asked": cpus or "any",
                              "launch_exit_code": code,
                              "wall_s": round(wall, 1),
                              "log": str(log), "load_average_after": load_after or list(os.getloadavg())}
    if not summary_path.is_file() or not timing_path.is_file():
        result["error"] = "the run left no body summary or no timing records; see the log"
        return result
    if code != 0:  # e.g. the brain fell silent on a loaded machine: the body's records still hold
        result["launch_problem"] = _last_line(log)
    result.update(condition_result(json.loads(summary_path.read_text()), load_step_times(timing_path)))
    if anchor is not None:
        result["anchor"] = anchor
        if "error" not in anchor:
            result["anchor_deadline_misses"] = anchor["deadline_misses"]
            result["anchor_compute_p99_ms"] = anchor["compute_p99_ms"]
    return result


def _paced_anchor(seconds: float, timing_path: Path, rt_priority: int, cpus: str, env: Mapping[str, str] | None,
                  progress: Callable[[str], None]) -> dict[str, Any]:
    """The paced anchor at the period of the loop's records (``timing_path``), its priority and CPUs, polling as
    long before each tick as the body's default ``busy_wait``; a failure to run it is its ``error``, not the
    condition's."""
    from bptsb_ros.live.body_params import PARAMS
    from bptsb_ros.live.step_times import load_step_times
    from bptsb_ros.ros.anchor import run_paced_anchor

    busy_wait = next(p.default for p in PARAMS if p.name == "busy_wait")
    try:
        period = load_step_times(timing_path)["period"]
        progress(f"realtime bench: the paced anchor (bare rclpy tick and pong) for {seconds:g} s at {1 / period:g} Hz")
        found = run_paced_anchor(seconds, period, priority=rt_priority, busy=busy_wait, cpus=cpus,
                                 env=None if env is None else dict(env))
    except (OSError, ValueError, subprocess.SubprocessError) as err:  # ValueError: a bad record or JSON line
        found = {"error": f"the paced anchor could not run: {err}"}
    return anchor_result(found, seconds)


def _last_line(log: Path) -> str:
    """The launch's last ``FAILED`` line (why it exited non-zero), or its last line."""
    lines = [line.strip() for line in log.read_text(errors="replace").splitlines() if line.strip()]
    failed = [line for line in lines if "FAILED" in line]
    return (failed or lines or ["(empty log)"])[-1][:300]


def run_realtime_bench(seconds: float = 600.0, busy: int = 1, *, executor: str = "events", rt_priority: int = 0,
                       cpus: str = "", loop: str = "lissajous_closed",
                       agent: str | None = None, workdir: str | Path | None = None,
                       update: Callable[[dict[str, Any]], None] | None = None,
                       progress: Callable[[str], None] = print, factor: float = 0.0,
                       anchor_seconds: float | None = None) -> dict[str, Any]:
    """Both conditions (:data:`CONDITIONS`) for ``seconds`` each, and with ``factor`` > 0 the ``factor`` condition
    (the loop at ``factor`` × real time, idle); logs and records in ``workdir`` (default: a new temporary
    directory, kept); ``update(report)``, when given, gets the report after each condition. ``agent``: None for the
    example agent, '' for a fresh one (open loops only). ``cpus``: the CPUs of the body and its brains (taskset -c
    form; empty: wherever they start). ``anchor_seconds``: the paced anchor's run after each condition (None: as
    long as the condition; 0: none)."""
    work = Path(workdir) if workdir else Path(tempfile.mkdtemp(prefix="bptsb-realtime-"))
    work.mkdir(parents=True, exist_ok=True)
    agent_dir = str(example_agent()) if agent is None else agent
    report: dict[str, Any] = {"cpu_count": os.cpu_count(), "load_average_at_start": list(os.getloadavg()),
                              **kernel_facts(),
                              "ros_domain_id": os.environ.get("ROS_DOMAIN_ID", "0"), "workdir": str(work),
                              "targets": {key: text for key, _, text in TARGETS}, "conditions": {}}
    runs = [(name, busy if loaded else 0, 1.0) for name, loaded in CONDITIONS]
    if factor > 0:
        runs.append((FACTOR_CONDITION, 0, factor))
    for name, n_busy, rate in runs:
        report["conditions"][name] = realtime_run(name, seconds, n_busy, work, loop=loop, agent=agent_dir,
                                                  executor=executor, rt_priority=rt_priority, progress=progress,
                                                  rate_scale=rate, cpus=cpus,
                                                  anchor_seconds=seconds if anchor_seconds is None else anchor_seconds)
        if update is not None:
            update(report)
    return report


def realtime_table(report: dict[str, Any]) -> str:
    """The conditions of a report as a text table (times in ms), one row per condition, then the targets."""
    heads = ["condition"] + [h for _, h, _ in COLUMNS]
    rows, notes = [], []
    for name, r in report["conditions"].items():
        rate = r.get("rate_scale", 1.0)
        label = f"{name} ({r.get('busy_processes', 0)} busy{f', {rate:g}x' if rate != 1.0 else ''})"
        if "error" in r:
            notes.append(f"{name}: error: {r['error']}")
            continue
        rows.append([label] + [format(r[k], f) if k in r and r[k] is not None else "-" for k, _, f in COLUMNS])
        if r.get("launch_problem"):
            notes.append(f"{name}: the launch exited {r.get('launch_exit_code')}: {r['launch_problem']}")
        if "error" in r.get("anchor", {}):
            notes.append(f"{name}: the paced anchor failed: {r['anchor']['error']}")
    widths = [max(len(row[i]) for row in [heads, *rows]) for i in range(len(heads))]
    lines = ["  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True)).rstrip() for row in [heads, *rows]]
    lines += notes
    for name, r in report["conditions"].items():
        if "targets_met" in r:
            lines.append(f"{name}: " + "; ".join(f"{text}: {'met' if r['targets_met'][key] else 'NOT met'}"
                                                 for key, _, text in TARGETS))
    if "preemption" in report:
        lines.append(f"kernel {report.get('kernel', '?')}: preemption {report['preemption']}")
    return "\n".join(lines)
