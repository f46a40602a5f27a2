"""``bptsb bench --live``: steps per second of lockstep live loops while a bag is recorded, as a ratio to a bare
rclpy anchor measured in the same run, where each step's wall time goes, and each node process's CPU per step.

Each run is ``bptsb launch <loop> --bag DIR --duration S`` (lockstep; the recorder acknowledges, ``body_sim`` waits
for it), exactly as a user starts it. ``body_sim`` times every step's phases (:mod:`bptsb_ros.live.phases`:
recorder wait, publish, wait for commands, compute) and writes them into its ``body_summary.json``; start-up is not
in them. A :class:`CpuSampler` reads the CPU time of every node process (all its threads) ten times a second, and
the CPU of each inside the body's stepping window, divided by the steps, is its CPU per step. Between the loop runs
runs the anchor (:mod:`bptsb_ros.ros.anchor`: two processes ping-pong a 50-float message with the loops' QoS,
pre-serialized, on the EventsExecutor, and a recorder process takes both topics every 20 ms): what the middleware
gives where it runs, now. Each loop run's ``ratio_to_anchor`` is its steps/s over the mean round trips/s of the
anchor runs just before and after it (:func:`with_ratios`), so that a change in the machine's load hits both alike;
runs of several loops are interleaved (anchor, loop A, anchor, loop B, anchor, ...). ``lissajous_closed`` needs a
fitted feedback layer: the bench fits one on a fresh Lissajous agent (10 s of sim time) in its work folder first.

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

from bptsb_ros.files.safe_write import open_for_writing
from bptsb_ros.live.phases import PHASES, row_from_summary

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


def launch_argv(loop: str, bag: Path, seconds: float, agent: str = "", params: tuple[str, ...] = (),
                composed: bool = False, recorder_in_body: bool = False) -> list[str]:
    """The ``bptsb launch`` command line of one recorded lockstep run of ``loop`` for ``seconds`` sim seconds
    (``params``: those of :func:`loop_params`; ``composed``: ``--composed``; ``recorder_in_body``:
    ``--recorder-in-body``)."""
    argv = [sys.executable, "-m", "bptsb_ros.cli", "launch", loop, "--duration", f"{seconds:g}", "--bag", str(bag),
            "--timeout", f"{max(600.0, 60 * seconds):g}", *(["--composed"] if composed else []),
            *(["--recorder-in-body"] if recorder_in_body else [])]
    if agent:
        argv += ["--agent", agent, "--open-loop-steps", str(OPEN_LOOP_STEPS)]
    for param in loop_params(loop, params):
        argv += ["--param", param]
    return argv


class CpuSampler:
    """The CPU time (user + system, every thread) of each node process under a launch, sampled every ``period``
    seconds with the monotonic time of the sample, so that each node's CPU inside the body's stepping window can be
    read off afterwards (:meth:`cpu_in`). A node is a descendant process whose command line runs
    ``bptsb_ros.ros.<node>``."""

    def __init__(self, root_pid: int, period: float = 0.1) -> None:
        import threading

        self.root_pid, self.period = root_pid, period
        self.samples: dict[str, list[tuple[float, float]]] = {}
        self._names: dict[int, str] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _node_of(self, proc: Any) -> str:
        name = self._names.get(proc.pid)
        if name is None:
            cmd = proc.cmdline()
            modules = [a for a in cmd if a.startswith("bptsb_ros.ros.")]
            name = modules[0].rsplit(".", 1)[1] if modules else ""
            if name:  # not cached while empty: a child seen between fork and exec still has the launcher's cmdline
                self._names[proc.pid] = name
        return name

    def _run(self) -> None:
        import psutil

        try:
            root = psutil.Process(self.root_pid)
        except psutil.Error:
            return
        while not self._stop.is_set():
            try:
                children = root.children(recursive=True)
            except psutil.Error:
                return
            for proc in children:
                try:
                    name = self._node_of(proc)
                    if name:
                        t = proc.cpu_times()
                        self.samples.setdefault(name, []).append((time.monotonic(), t.user + t.system))
                except psutil.Error:
                    continue
            self._stop.wait(self.period)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)

    def cpu_in(self, began: float, ended: float) -> dict[str, float]:
        """CPU seconds of each node between the monotonic times ``began`` and ``ended`` (linear between samples;
        a node without samples on both sides of the window is left out)."""
        import numpy as np

        out = {}
        for name, samples in self.samples.items():
            t, cpu = (np.array(x) for x in zip(*samples, strict=True))
            if t[0] <= began and t[-1] >= ended:
                out[name] = float(np.interp(ended, t, cpu) - np.interp(began, t, cpu))
        return out


def live_run(loop: str, seconds: float, workdir: Path, tag: str, agent: str = "", params: tuple[str, ...] = (),
             progress=print, composed: bool = False, recorder_in_body: bool = False) -> dict[str, Any]:
    """One recorded lockstep run of ``loop``: its row (:func:`~bptsb_ros.live.phases.row_from_summary`) with the
    launch's exit code, its wall time with start-up, the messages the recorder counted as lost, and the CPU per step
    of each node process inside the stepping window (``cpu_us_per_step``: CPU microseconds per step, every thread of
    the process; sampled every 0.1 s, :class:`CpuSampler`)."""
    from bptsb_ros.bags.metadata import read_metadata
    from bptsb_ros.bags.recording import recorded_loss

    bag = workdir / f"{tag}_bag"
    log = workdir / f"{tag}_launch.log"
    label = shape_label(composed, recorder_in_body)
    progress(f"bench --live: {loop} ({label}) for {seconds:g} s sim time, recorded; log {log}")
    started = time.monotonic()
    argv = launch_argv(loop, bag, seconds, agent, params, composed, recorder_in_body)
    with open_for_writing(log, "w") as out:
        proc = subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
        sampler = CpuSampler(proc.pid)
        try:
            code = proc.wait()
        finally:
            sampler.stop()
    result: dict[str, Any] = {"loop": loop, "composed": composed, "recorder_in_body": recorder_in_body,
                              "sim_seconds": seconds, "launch_exit_code": code,
                              "wall_with_startup_s": round(time.monotonic() - started, 2), "log": str(log)}
    summary_path = Path(str(bag) + ".launch") / "body_summary.json"
    if not summary_path.is_file() or not (bag / "metadata.yaml").is_file():
        result["error"] = "the run left no body summary or no finished bag; see the log"
        return result
    try:
        summary = json.loads(summary_path.read_text())
        result.update(row_from_summary(summary))
    except (KeyError, ValueError) as err:
        result["error"] = str(err)
        return result
    result["dropped_messages"] = recorded_loss(read_metadata(bag).custom_data)[0]
    window = summary.get("loop_began_monotonic"), summary.get("loop_ended_monotonic")
    if None not in window and result["steps"]:
        result["cpu_us_per_step"] = {name: round(1e6 * cpu / result["steps"], 1)
                                     for name, cpu in sampler.cpu_in(*window).items()}
    return result


def shape_label(composed: bool, recorder_in_body: bool) -> str:
    """How a run's processes are laid out: ``split`` (a process per node and the recorder), ``composed`` (body and
    brains in one), each with ``, recorder in body`` when the recorder runs in the body's process."""
    return ("composed" if composed else "split") + (", recorder in body" if recorder_in_body else "")


def anchor_run(shape: str, seconds: float, progress=print) -> dict[str, Any]:
    """One run of the bare rclpy anchor (:mod:`bptsb_ros.ros.anchor`) for ``seconds`` of wall time."""
    from bptsb_ros.ros.anchor import run_anchor

    progress(f"bench --live: the {shape} anchor (bare rclpy ping-pong + recorder) for {seconds:g} s")
    return run_anchor(shape, seconds)


def with_ratios(report: dict[str, Any]) -> dict[str, Any]:
    """Each loop run's ``ratio_to_anchor``: its steps/s over the mean round trips/s of the anchor runs of its shape
    (split or composed) just before and just after it (``report['sequence']``: the runs in the order they ran); and
    ``ratios``: per loop and shape, the ratios of all its runs."""
    seq = report["sequence"]
    ratios: dict[str, list[float]] = {}
    for i, item in enumerate(seq):
        if item.get("kind") != "loop" or "steps_per_s" not in item:
            continue
        shape = "composed" if item.get("composed") else "split"
        near = [a["round_trips_per_s"] for a in (_neighbour(seq, i, -1, shape), _neighbour(seq, i, 1, shape))
                if a is not None and a.get("round_trips_per_s")]
        if near:
            anchor = sum(near) / len(near)
            item["anchor_round_trips_per_s"] = round(anchor, 1)
            item["ratio_to_anchor"] = round(item["steps_per_s"] / anchor, 3)
            label = shape_label(bool(item.get("composed")), bool(item.get("recorder_in_body")))
            ratios.setdefault(f"{item['loop']} ({label})", []).append(item["ratio_to_anchor"])
    report["ratios"] = ratios
    return report


def _neighbour(seq: list[dict[str, Any]], i: int, direction: int, shape: str) -> dict[str, Any] | None:
    """The nearest anchor run of ``shape`` before (direction -1) or after (+1) position ``i`` of ``seq``."""
    j = i + direction
    while 0 <= j < len(seq):
        if seq[j].get("kind") == "anchor" and seq[j].get("shape") == shape:
            return seq[j]
        j += direction
    return None


def run_live(loops: tuple[str, ...] = LIVE_LOOPS, seconds: float = 10.0, repeats: int = 1,
             workdir: str | Path | None = None, params: tuple[str, ...] = (), progress=print,
             anchor_seconds: float = 5.0, composed: bool = False, recorder_in_body: bool = False) -> dict[str, Any]:
    """``repeats`` interleaved rounds of one recorded lockstep run of each of ``loops`` (``seconds`` sim seconds
    each; ``params``: ``NODE:NAME:=VALUE`` passed to every launch of a loop with that node), each loop run between two
    runs of the bare rclpy anchor (:mod:`bptsb_ros.ros.anchor`, split shape, ``anchor_seconds`` each): anchor, loop
    A, anchor, loop B, anchor, ... With ``composed``, each loop also runs composed (``bptsb launch --composed``)
    between two runs of the composed anchor (ping and pong in one process). With ``recorder_in_body``, each loop also
    runs with the recorder in the body's process (``--recorder-in-body``; split: beside the split anchor, whose
    recorder is a process of its own); with both, also with the whole loop in one process (beside the composed
    anchor). Bags and logs go to ``workdir`` (default: a new temporary folder, kept)."""
    work = Path(workdir) if workdir else Path(tempfile.mkdtemp(prefix="bptsb-bench-live-"))
    work.mkdir(parents=True, exist_ok=True)
    report: dict[str, Any] = {"cpu_count": os.cpu_count(), "load_average_at_start": list(os.getloadavg()),
                              "ros_domain_id": os.environ.get("ROS_DOMAIN_ID", "0"), "workdir": str(work),
                              "params": list(params), "sequence": []}
    agent = ""
    if any(loop.endswith("_closed") for loop in loops):
        progress("bench --live: fitting a feedback layer for the closed loop ...")
        agent = str(fitted_agent(work / "agent"))
    seq = report["sequence"]
    seq.append({"kind": "anchor", **anchor_run("split", anchor_seconds, progress)})
    layouts = ([(False, False)] + ([(False, True)] if recorder_in_body else []) + ([(True, False)] if composed else [])
               + ([(True, True)] if composed and recorder_in_body else []))
    for round_ in range(repeats):
        for loop in loops:
            for together, in_body in layouts:
                shape = "composed" if together else "split"
                if together:
                    seq.append({"kind": "anchor", **anchor_run(shape, anchor_seconds, progress)})
                tag = f"{loop}_{shape}{'_in_body' if in_body else ''}_{round_}"
                seq.append({"kind": "loop", **live_run(loop, seconds, work, tag,
                                                       agent if loop.endswith("_closed") else "", params, progress,
                                                       composed=together, recorder_in_body=in_body)})
                seq.append({"kind": "anchor", **anchor_run(shape, anchor_seconds, progress)})
    report["runs"] = [item for item in seq if item["kind"] == "loop"]
    report["anchors"] = [item for item in seq if item["kind"] == "anchor"]
    report["load_average_at_end"] = list(os.getloadavg())
    return with_ratios(report)


def live_table(report: dict[str, Any]) -> str:
    """A Markdown table of :func:`run_live`'s report: one row per run, steps/s, its ratio to the anchor, per-step
    milliseconds of each phase and the CPU per step of each node process [µs]; then the anchor runs."""
    head = ["loop", "steps", "steps/s", "× anchor", *(f"{p} ms" for p in (*PHASES, "other")), "CPU µs/step", "lost",
            "exit"]
    rows = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in report["runs"]:
        name = r["loop"] + (f" ({shape_label(r['composed'], r['recorder_in_body'])})"
                            if r.get("composed") or r.get("recorder_in_body") else "")
        if "error" in r:
            rows.append(f"| {name} | {r['error']} |" + " |" * (len(head) - 2))
            continue
        cpu = ", ".join(f"{k} {v:.0f}" for k, v in r.get("cpu_us_per_step", {}).items()) or "-"
        ratio = f"{r['ratio_to_anchor']:.2f}" if "ratio_to_anchor" in r else "-"
        cells = [name, str(r["steps"]), f"{r['steps_per_s']:.0f}", ratio,
                 *(f"{r[f'{p}_ms']:.3f}" for p in (*PHASES, "other")), cpu, str(r.get("dropped_messages")),
                 str(r["launch_exit_code"])]
        rows.append("| " + " | ".join(cells) + " |")
    rows.append("")
    for a in report.get("anchors", []):
        what = (f"{a['round_trips_per_s']:.0f} round trips/s, p50 {a['rtt_p50_ms']:.3f} ms" if "round_trips_per_s" in a
                else a.get("error", "no result"))
        rows.append(f"anchor ({a.get('shape')}): {what}")
    return "\n".join(rows)
