"""``bptsb launch``: start a whole brain–body loop as separate processes, record it, stop it cleanly."""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

from bptsb_ros.cli.options import FAILURE, USAGE, fail, finite_float
from bptsb_ros.files.safe_write import open_for_writing, write_atomic
from bptsb_ros.live.loops import LOOPS, bag_target_problem, format_parameter, loops_help

NAME = "launch"
HELP = "start a live loop (body_sim + brains [+ recorder]) as separate ROS 2 processes"

PACKAGE_PARENT = Path(__file__).resolve().parents[2]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.epilog = loops_help() + (
        "\n\nEach node is a process `python -m bptsb_ros.ros.<node> --ros-args ...`; with --bag the recorder runs "
        "too and is stopped last (--recorder-in-body: it runs in body_sim's process and stops with it).\nIn "
        "lockstep the run lasts --duration seconds of sim time (body_sim exits after the last step); in realtime\n"
        "--duration wall seconds. Ctrl-C stops every node (SIGINT, then SIGTERM/SIGKILL "
        "after --grace). Exit status 0 only if\nevery node exited cleanly and the recording lost nothing (--allow-loss "
        "accepts a lossy one; the bag counts the losses either way).\nA lockstep body waits for the recorder (or, in "
        "its process, records between its steps), so a lockstep recording cannot lose a message. Children get "
        "ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST unless it\n"
        "is set, and inherit ROS_DOMAIN_ID."
    )
    parser.add_argument("loop", choices=sorted(LOOPS), metavar="LOOP", help="loop to run: " + ", ".join(LOOPS))
    parser.add_argument("--agent", default="", metavar="RUN_DIR",
                        help="trained agent (run directory); default: a fresh untrained agent of the loop's task")
    parser.add_argument("--duration", type=finite_float, default=0.0, metavar="SECONDS",
                        help="run length: sim seconds (lockstep) or wall seconds (realtime); 0 = until Ctrl-C")
    parser.add_argument("--bag", default="", metavar="DIR", help="record every loop topic to this rosbag2 MCAP bag")
    parser.add_argument("--allow-loss", action="store_true",
                        help="with --bag: a recording that lost messages (realtime under load) does not fail the run; "
                             "the losses are counted in the bag and reported either way")
    parser.add_argument("--mode", choices=("lockstep", "realtime"), default="lockstep", help="timing mode")
    parser.add_argument("--composed", action="store_true",
                        help="body_sim and the brains in one process on the body's executor (node composition; the "
                             "recorder stays a process of its own unless --recorder-in-body): the same messages, "
                             "fewer process hand-offs")
    parser.add_argument("--recorder-in-body", action="store_true",
                        help="with --bag: the recorder runs in body_sim's process and takes the messages in the "
                             "body's loop (as a composable recorder beside its publishers; with --composed in the one "
                             "process): one process and one reader hand-off fewer; the body does not wait for it")
    parser.add_argument("--namespace", default="", metavar="NS",
                        help="ROS namespace of the loop (one robot of several in a domain): every node runs in it, "
                             "every topic resolves in it, /clock and /diagnostics included (remapped to NS/clock and "
                             "NS/diagnostics); default: the root namespace")
    parser.add_argument("--rate-scale", type=finite_float, default=1.0, help="realtime: sim seconds per wall second")
    parser.add_argument("--seed", type=int, default=0, help="seed of the fresh agent when --agent is not given")
    parser.add_argument("--open-loop-steps", type=int, default=0, metavar="W",
                        help="closed loops: SWG drives steps 0..W before the feedback layer takes over")
    parser.add_argument("--perturb-at", type=finite_float, default=None, metavar="T",
                        help="displace the movable masses at sim time T [s] (>= 0 and within --duration; the state "
                             "of that step; lockstep-deterministic), by N(0, S²) per coordinate; default: no "
                             "perturbation")
    parser.add_argument("--perturb-sigma", type=finite_float, default=0.0, metavar="S",
                        help="standard deviation of the perturbation [m]")
    parser.add_argument("--perturb-seed", type=int, default=0, metavar="N",
                        help="seed of the perturbation's standard-normal pattern (bptsb_ros.sim.perturbation)")
    stream = parser.add_argument_group("mnist_drawing (see a digit, draw it; --agent is an MNIST system file)")
    stream.add_argument("--images", default="", metavar="IDX", help="IDX file of the streamed images (gz or not)")
    stream.add_argument("--labels", default="", metavar="IDX", help="IDX file of their labels")
    stream.add_argument("--first", type=int, default=0, metavar="N", help="index of the first image streamed")
    stream.add_argument("--count", type=int, default=0, metavar="N",
                        help="images streamed, one per episode (0: all from --first on)")
    stream.add_argument("--episode-steps", type=int, default=0, metavar="E",
                        help="steps per episode, image i at step i*E (0: the longest digit target's steps + 1)")
    parser.add_argument("--param", action="append", default=[], metavar="NODE:NAME:=VALUE",
                        help="extra ROS parameter for one node, e.g. body_sim:command_timeout:=5 (repeatable)")
    parser.add_argument("--log-dir", default="", metavar="DIR",
                        help="node logs and body_summary.json (default: BAG.launch/ or a temporary directory)")
    parser.add_argument("--grace", type=finite_float, default=10.0, metavar="SECONDS",
                        help="how long a node may take to stop after SIGINT before SIGTERM, then SIGKILL")
    parser.add_argument("--timeout", type=finite_float, default=0.0, metavar="SECONDS",
                        help="wall-clock limit of the whole run, 0 = none; exceeding it is a failure")


@dataclass
class Child:
    """One node process and its log."""

    name: str
    argv: list[str]
    log_path: Path
    proc: subprocess.Popen | None = None
    threads: list[threading.Thread] = field(default_factory=list)
    stop_requested: bool = False
    killed: str = ""

    @property
    def code(self) -> int | None:
        return None if self.proc is None else self.proc.poll()


def _pump(stream: IO[bytes], name: str, log: IO[str], lock: threading.Lock) -> None:
    """Copy a child's output to its log file and, prefixed, to stderr; close both when the child closes it."""
    try:
        for raw in iter(stream.readline, b""):
            line = raw.decode("utf-8", "replace").rstrip("\n")
            with lock:
                log.write(line + "\n")
                log.flush()
                print(f"[{name}] {line}", file=sys.stderr, flush=True)
    finally:
        stream.close()
        log.close()


PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


def die_with_parent_hook(sig: int = signal.SIGTERM) -> Callable[[], None] | None:
    """A ``preexec_fn`` that makes a child receive ``sig`` when this process dies (Linux ``PR_SET_PDEATHSIG``).

    The children run in their own sessions (a Ctrl-C in the terminal reaches only the launcher, which stops
    them in order), so without this a launcher killed outright (SIGKILL, e.g. a test timeout) would leave
    every node running. SIGTERM makes a node stop cleanly (the recorder closes its bag). The kernel sends the
    signal when the *thread* that started the child exits: :meth:`Launcher.start` runs in the main thread.
    The hook also starts the child with SIGINT blocked (``ros.runtime.block_interrupt``): a Ctrl-C
    requested while the node is still importing and loading stays pending until its handlers are in place,
    so it stops cleanly instead of dying in a KeyboardInterrupt traceback. Where ``prctl`` is unavailable
    (not Linux) the hook only blocks SIGINT.
    """
    from bptsb_ros.ros.runtime import block_interrupt  # ROS-free

    if not sys.platform.startswith("linux"):
        return block_interrupt
    try:
        import ctypes

        prctl = ctypes.CDLL(None, use_errno=True).prctl  # looked up here: the hook runs between fork and exec
    except (OSError, AttributeError):
        return block_interrupt
    parent = os.getpid()

    def hook() -> None:
        block_interrupt()  # held pending until the node's handlers are in place (ros/runtime.py)
        prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0)
        if os.getppid() != parent:  # the launcher died before prctl took effect
            os._exit(1)

    return hook


def child_env() -> dict[str, str]:
    """Environment of the nodes: this one, localhost discovery by default, the package importable."""
    env = dict(os.environ)
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    env.setdefault("RCUTILS_COLORIZED_OUTPUT", "0")
    env["PYTHONUNBUFFERED"] = "1"
    paths = [str(PACKAGE_PARENT)] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p]
    env["PYTHONPATH"] = os.pathsep.join(dict.fromkeys(paths))
    return env


def node_argv(executable: str, params: dict, extra: list[str], namespace: str = "") -> list[str]:
    """Command line of one node: its parameters, ``extra`` (``NAME:=VALUE``) and, in ``namespace`` (normalized),
    ``__ns`` and the remappings of :func:`~bptsb_ros.live.loops.namespace_remaps`."""
    from bptsb_ros.live.loops import namespace_remaps

    argv = [sys.executable, "-m", f"bptsb_ros.ros.{executable}", "--ros-args"]
    if namespace:
        argv += ["-r", f"__ns:={namespace}"]
    for source, target in namespace_remaps(namespace):
        argv += ["-r", f"{source}:={target}"]
    for name, value in params.items():
        argv += ["-p", format_parameter(name, value)]
    for item in extra:
        argv += ["-p", item]
    return argv


def composed_child(planned: dict[str, dict], extra: dict[str, list[str]], namespace: str, log_dir: Path,
                   members: list[str]) -> Child:
    """The one process of ``--composed`` and ``--recorder-in-body``: the nodes ``members`` of ``planned``, body_sim
    first and the recorder last (:func:`~bptsb_ros.live.loops.body_process_nodes`; :mod:`bptsb_ros.ros.composed`),
    their parameters in ``log_dir/composed_params.yaml``, a section per node."""
    from bptsb_ros.live.loops import namespace_remaps
    from bptsb_ros.ros.composed import params_file_text

    nodes = {name: planned[name] for name in members}
    params_file = log_dir / "composed_params.yaml"
    write_atomic(params_file, params_file_text(nodes, extra))
    argv = [sys.executable, "-m", "bptsb_ros.ros.composed", "--nodes", ",".join(nodes), "--ros-args",
            "--params-file", str(params_file)]
    if namespace:
        argv += ["-r", f"__ns:={namespace}"]
    for source, target in namespace_remaps(namespace):
        argv += ["-r", f"{source}:={target}"]
    return Child("composed", argv, log_dir / "composed.log")


def parse_extra(items: list[str], nodes: list[str]) -> dict[str, list[str]]:
    """``NODE:NAME:=VALUE`` items → {node: ['NAME:=VALUE', ...]}; raises ValueError naming a bad item."""
    out: dict[str, list[str]] = {n: [] for n in nodes}
    for item in items:
        node, sep, rest = item.partition(":")
        if not sep or ":=" not in rest or not rest.split(":=", 1)[0]:
            raise ValueError(f"--param {item!r} must look like NODE:NAME:=VALUE")
        if node not in out:
            raise ValueError(f"--param {item!r}: node {node!r} is not part of this loop ({', '.join(nodes)})")
        out[node].append(rest)
    return out


class Launcher:
    """Starts the children, watches them, stops them in order: body, brains, recorder last (a recorder in the
    body's process stops with the body, after it has recorded the run)."""

    def __init__(self, children: list[Child], body: Child, recorder: Child | None, grace: float) -> None:
        self.children = children
        self.body = body
        self.recorder = recorder
        self.grace = grace
        self.lock = threading.Lock()
        self.failures: list[str] = []
        self.stop_reason: str | None = None

    def start(self, env: dict[str, str]) -> None:
        order = ([self.recorder] if self.recorder else []) + [c for c in self.children
                                                              if c not in (self.body, self.recorder)] + [self.body]
        hook = die_with_parent_hook()
        for child in order:
            log = open_for_writing(child.log_path, "w")  # closed by _pump
            try:
                child.proc = subprocess.Popen(child.argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                              stdin=subprocess.DEVNULL, start_new_session=True, preexec_fn=hook)
            except BaseException:
                log.close()
                raise
            t = threading.Thread(target=_pump, args=(child.proc.stdout, child.name, log, self.lock), daemon=True)
            t.start()
            child.threads.append(t)

    def stop(self, child: Child) -> None:
        """SIGINT, then SIGTERM and SIGKILL after ``grace`` seconds each.

        ``child.killed`` names the signal that finally stopped it when SIGINT was not enough.
        """
        if child.proc is None or child.proc.poll() is not None:
            return
        child.stop_requested = True
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
            name = signal.Signals(sig).name
            try:
                child.proc.send_signal(sig)
            except ProcessLookupError:
                return
            if sig != signal.SIGINT:
                child.killed = name
            try:
                child.proc.wait(timeout=self.grace)
                return
            except subprocess.TimeoutExpired:
                self._say(f"{child.name} did not stop within {self.grace:g} s of {name}")

    def stop_all(self) -> None:
        self.stop(self.body)
        for child in self.children:
            if child not in (self.body, self.recorder):
                self.stop(child)
        if self.recorder is not None:
            self.stop(self.recorder)

    def watch(self, *, timeout: float, stop_flag: list[str]) -> None:
        """Poll until the body exits (it ends the run after --duration), another node exits (the loop is broken:
        every node is stopped and the launch fails, as the launch files do), ``timeout`` passes or a signal
        arrives."""
        started = time.monotonic()
        while True:
            if stop_flag:
                self.stop_reason = stop_flag[0]
                return
            now = time.monotonic() - started
            for child in self.children:
                code = child.code
                if code is not None and child is not self.body:
                    self.stop_reason = f"{child.name} exited early with code {code}; the loop is broken"
                    return
            if self.body.code is not None:
                self._say(f"body_sim exited with code {self.body.code}; stopping the other nodes")
                return
            if timeout and now >= timeout:
                self.failures.append(f"timed out after {timeout:g} s")
                self.stop_reason = "timeout"
                return
            time.sleep(0.1)

    def _say(self, text: str) -> None:
        with self.lock:
            print(f"[launch] {text}", file=sys.stderr, flush=True)

    def results(self) -> list[tuple[str, str]]:
        """(node, verdict) per child; updates ``failures``."""
        rows = []
        for child in self.children:
            for t in child.threads:
                t.join(timeout=2.0)
            code = child.code
            if child.killed:
                verdict = f"failed (needed {child.killed})"
            elif code is not None and child is not self.body and not child.stop_requested:
                verdict = f"failed (exited on its own before the end, code {code})"
            elif code == 0:
                verdict = "ok"
            elif code is None:
                verdict = "still running"
            else:
                verdict = f"failed (exit {code})"
            if verdict != "ok":
                self.failures.append(f"{child.name}: {verdict}")
            rows.append((child.name, verdict))
        return rows


def _extra_value(items: list[str], name: str) -> str | None:
    """The value of the last ``name:=VALUE`` of one node's ``--param`` items (a YAML scalar, quotes removed)."""
    from bptsb_ros.files.untrusted_yaml import UntrustedYamlError, load_untrusted_yaml

    values = [item.split(":=", 1)[1] for item in items if item.split(":=", 1)[0] == name]
    if not values:
        return None
    try:
        value = load_untrusted_yaml(values[-1], f"--param {name}", max_bytes=4096, max_nodes=1)
    except UntrustedYamlError:
        return values[-1]
    return values[-1] if isinstance(value, (dict, list)) or value is None else str(value)


def _wind_limit(extra: dict[str, list[str]]) -> float:
    """body_sim's max_wind [N] (its default, or ``--param body_sim:max_wind:=X``), passed on to wind_source; a
    wind_source file table is checked against it here, before any node starts (the body would reject every wind
    beyond it: a run without wind). Raises ValueError naming the argument, or WindScheduleError (a ValueError) naming
    the file's row and the limit."""
    from bptsb_ros.live.safety import DEFAULT_MAX_WIND
    from bptsb_ros.sim.wind_schedule import read_table

    text = _extra_value(extra.get("body_sim", []), "max_wind")
    try:
        limit = DEFAULT_MAX_WIND if text is None else float(text)
    except ValueError:
        raise ValueError(f"--param body_sim:max_wind:={text}: not a number") from None
    if not (limit > 0 and limit < float("inf")):
        raise ValueError(f"--param body_sim:max_wind:={text}: must be finite and > 0")
    wind = extra.get("wind_source")
    if wind is not None and _extra_value(wind, "schedule") == "file":
        path = _extra_value(wind, "file")
        if not path:
            raise ValueError("--param wind_source:schedule:=file needs --param wind_source:file:=CSV")
        read_table(path, max_force=limit)
    return limit


def _perturbation_problem(args: argparse.Namespace) -> str:
    """Why --perturb-at/--perturb-sigma cannot be run ('' when they can), before any node starts."""
    from bptsb_ros.live.loops import perturbation_problem

    if args.perturb_at is not None and args.perturb_at < 0:
        return f"--perturb-at {args.perturb_at:g}: must be >= 0 (sim seconds)"
    problem = perturbation_problem(-1.0 if args.perturb_at is None else args.perturb_at, args.perturb_sigma,
                                   duration=args.duration, rate_scale=args.rate_scale, mode=args.mode)
    return problem.replace("perturb_at:=", "--perturb-at ").replace("perturb_sigma:=", "--perturb-sigma ")


def _check_recording(launcher: Launcher, rows: list[tuple[str, str]], bag: Path, summary_path: Path,
                     allow_loss: bool, row: str = "recorder") -> list[tuple[str, str]]:
    """Count what the recording lost (:func:`bptsb_ros.bags.loss.recording_loss`: the recorder's count and the body's
    published messages against the bag), add it to the body summary as ``recording``, and make the row of the
    recorder's process (``row``: ``recorder``, or ``composed`` when it runs in the body's) say so: ``ok`` only when
    nothing was lost; a loss fails the run unless ``allow_loss``."""
    import json

    from bptsb_ros.bags.errors import BagError
    from bptsb_ros.bags.loss import recording_loss

    summary = None
    try:
        summary = json.loads(summary_path.read_text()) if summary_path.is_file() else None
    except (OSError, ValueError):
        summary = None
    published = summary.get("published_messages") if isinstance(summary, dict) else None
    try:
        loss = recording_loss(bag, published if isinstance(published, dict) else None)
    except BagError as err:
        launcher.failures.append(f"{row}: the bag cannot be checked for losses: {err}")
        return rows
    if isinstance(summary, dict):
        summary["recording"] = {**loss.to_dict(), "allowed": allow_loss}
        write_atomic(summary_path, json.dumps(summary, indent=2) + "\n")
    if not loss.any:
        return rows
    launcher.failures[:] = [f for f in launcher.failures if not f.startswith(f"{row}: failed (exit 1)")]
    if allow_loss:
        verdict = f"{loss.describe()} (allowed by --allow-loss)"
    else:
        verdict = f"failed: {loss.describe()}"
        launcher.failures.append(f"{row}: {loss.describe()} (--allow-loss accepts a lossy recording)")
    return [(name, verdict if name == row else v) for name, v in rows]


def _brain_problem(summary_path: Path) -> str:
    """:func:`~bptsb_ros.live.summary.brain_problem` of the body summary ('' without a readable one)."""
    import json

    from bptsb_ros.live.summary import brain_problem

    try:
        summary = json.loads(summary_path.read_text()) if summary_path.is_file() else None
    except (OSError, ValueError):
        return ""
    return brain_problem(summary) if isinstance(summary, dict) else ""


def node_plan(loop, args: argparse.Namespace, namespace: str, summary_path: Path, plan=None,
              max_wind: float | None = None) -> dict[str, dict]:
    """The parameters of every node of a ``bptsb launch`` of ``loop`` (``args`` as parsed; ``plan``: the checked
    MNIST stream; ``max_wind``: body_sim's, passed on to a wind_source), in start order: body_sim, the brains, and
    the recorder with ``--bag``. The launch files start the same nodes with the same parameters
    (:func:`bptsb_ros.live.loops.loop_node_parameters`)."""
    from bptsb_ros.live.loops import node_parameters, recorder_parameters

    common = dict(agent=args.agent, seed=args.seed, mode=args.mode, duration=args.duration,
                  rate_scale=args.rate_scale, recording=bool(args.bag), open_loop_steps=args.open_loop_steps,
                  namespace=namespace)
    brain_common = dict(common)
    common.update(perturb_at=-1.0 if args.perturb_at is None else args.perturb_at, perturb_sigma=args.perturb_sigma,
                  perturb_seed=args.perturb_seed, recorder_in_body=args.recorder_in_body)

    def with_stream(executable: str, params: dict) -> dict:
        if plan is None:
            return params
        from bptsb_ros.live.mnist_loop import stream_parameters

        return stream_parameters(plan, executable, params, recording=bool(args.bag), duration=args.duration)

    out = {"body_sim": with_stream("body_sim", node_parameters(loop, "body_sim", summary_path=str(summary_path),
                                                               **common))}
    for brain in loop.brains:
        params = with_stream(brain.executable, node_parameters(loop, brain.executable, **brain_common))
        if brain.executable == "wind_source" and max_wind is not None:
            params["max_wind"] = max_wind
        out[brain.executable] = params
    if args.bag:
        out["recorder"] = with_stream("recorder", recorder_parameters(
            loop, args.bag, mode=args.mode, agent=args.agent, open_loop_steps=args.open_loop_steps,
            allow_loss=args.allow_loss, namespace=namespace, recorder_in_body=args.recorder_in_body))
    return out


def run(args: argparse.Namespace) -> int:
    from bptsb_ros.live.loops import agent_loop, body_process_nodes, log_dir_of_bag

    loop = LOOPS[args.loop]
    plan = None
    if loop.name == "mnist_drawing":  # --agent is a system file: checked with the stream, before any node starts
        from bptsb_ros.live.mnist_loop import StreamError, plan_stream

        if args.mode != "lockstep":
            return fail("launch", "mnist_drawing resets the body at stated steps, which needs --mode lockstep", USAGE)
        try:
            plan = plan_stream(args.agent, args.images, args.labels, args.first, args.count, args.episode_steps)
        except StreamError as err:  # the agent, images or labels files
            return fail("launch", err, FAILURE)
    elif loop.needs_agent and not args.agent:
        return fail("launch", f"loop {loop.name} needs --agent RUN_DIR (a trained agent with a fitted feedback layer)",
                    USAGE)
    from bptsb_ros.live.loops import NamespaceError, normalize_namespace

    try:
        namespace = normalize_namespace(args.namespace)
    except NamespaceError as err:
        return fail("launch", f"--namespace: {err}", USAGE)
    if args.recorder_in_body and not args.bag:
        return fail("launch", "--recorder-in-body needs --bag DIR (there is no recorder without a bag)", USAGE)
    if args.duration < 0 or args.rate_scale <= 0 or args.grace <= 0:
        return fail("launch", "--duration must be >= 0, --rate-scale and --grace > 0", USAGE)
    problem = _perturbation_problem(args)
    if problem:
        return fail("launch", problem, USAGE)
    if args.agent and plan is None:
        if not Path(args.agent).exists():
            return fail("launch", f"--agent {args.agent}: no such run directory", FAILURE)
        from bptsb_ros.training.checkpoint import CheckpointError, read_checkpoint

        try:
            read_checkpoint(args.agent)  # data only (weights_only): refused here before any node loads it
            loop = agent_loop(loop, args.agent)
        except CheckpointError as err:
            return fail("launch", f"--agent: {err}", FAILURE)
    if args.bag:
        problem = bag_target_problem(Path(args.bag))
        if problem:
            return fail("launch", f"--bag {args.bag}: {problem}", FAILURE)
    nodes = ["body_sim"] + [b.executable for b in loop.brains] + (["recorder"] if args.bag else [])
    from bptsb_ros.sim.wind_schedule import WindScheduleError

    try:
        extra = parse_extra(args.param, nodes)
        max_wind = _wind_limit(extra)
    except WindScheduleError as err:  # the wind file's content
        return fail("launch", err, FAILURE)
    except ValueError as err:
        return fail("launch", err, USAGE)
    if args.log_dir:
        log_dir = Path(args.log_dir)
    elif args.bag:
        log_dir = log_dir_of_bag(args.bag)
    else:
        log_dir = Path(tempfile.mkdtemp(prefix=f"bptsb-{loop.name}-"))
    try:
        log_dir.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        return fail("launch", f"cannot create the log directory {log_dir}: {err.strerror or err}", FAILURE)
    summary_path = log_dir / "body_summary.json"
    from bptsb_ros.live.viewers import write_viewer_configs

    viewers = write_viewer_configs(log_dir, namespace)

    children: list[Child] = []
    planned = node_plan(loop, args, namespace, summary_path, plan, max_wind)
    members = body_process_nodes(loop, composed=args.composed, recorder_in_body=args.recorder_in_body)
    hosted = members if len(members) > 1 else []  # body_sim alone is a node process like the others
    if hosted:
        children.append(composed_child(planned, extra, namespace, log_dir, hosted))
    for executable, params in planned.items():
        if executable not in hosted:
            children.append(Child(executable, node_argv(executable, params, extra[executable], namespace),
                                  log_dir / f"{executable}.log"))
    body = children[0]
    recorder = children[-1] if args.bag and not args.recorder_in_body else None

    stop_flag: list[str] = []

    def on_signal(signum: int, frame: object) -> None:
        del frame
        if stop_flag:  # second Ctrl-C: give up on a clean stop (the finally below kills the nodes)
            raise KeyboardInterrupt
        stop_flag.append(signal.Signals(signum).name)

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    launcher = Launcher(children, body, recorder, args.grace)
    domain = os.environ.get("ROS_DOMAIN_ID", "0 (default)")
    print(f"[launch] {loop.name}: {', '.join(c.name for c in children)}"
          f"{f' in namespace {namespace}' if namespace else ''}; mode {args.mode}, "
          f"duration {args.duration:g} s {'sim' if args.mode == 'lockstep' else 'wall'} time, ROS_DOMAIN_ID "
          f"{domain}; logs in {log_dir}", file=sys.stderr, flush=True)
    try:
        launcher.start(child_env())
        launcher.watch(timeout=args.timeout, stop_flag=stop_flag)
        if launcher.stop_reason:
            launcher._say(f"stopping ({launcher.stop_reason})")
        launcher.stop_all()
    finally:
        for child in children:
            if child.proc is not None and child.proc.poll() is None:
                child.proc.kill()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    rows = launcher.results()
    if args.bag:
        rows = _check_recording(launcher, rows, Path(args.bag), summary_path, args.allow_loss,
                                "composed" if args.recorder_in_body else "recorder")
    problem = _brain_problem(summary_path)
    if problem:
        launcher.failures.append(problem)
    print("[launch] node exit status:", file=sys.stderr)
    for name, verdict in rows:
        print(f"[launch]   {name:<15} {verdict}", file=sys.stderr)
    if summary_path.is_file():
        print(f"[launch] body summary: {summary_path}", file=sys.stderr)
    if viewers:
        print(f"[launch] RViz and Foxglove configs of this robot: {', '.join(str(v) for v in viewers)}",
              file=sys.stderr)
    if args.bag:
        print(f"[launch] bag: {args.bag}", file=sys.stderr)
    if launcher.failures:
        print("[launch] FAILED: " + "; ".join(launcher.failures), file=sys.stderr)
        return 1
    return 0
