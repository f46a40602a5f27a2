"""Helpers of the multi-process live-loop tests (``test_ros_loop.py``, ``test_ros_faults.py``):
node processes on the test session's private ROS domain (``ros_env`` / ``ros_domain_id`` fixtures of
``conftest.py``), an in-test probe node, bag reading, offline references."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parent.parent


def env_for(ros_env: dict[str, str]) -> dict[str, str]:
    """Environment of the ROS processes of a test: ``ros_env`` (the session's private domain, discovery on this
    host only) with the package importable and unbuffered output."""
    env = dict(ros_env)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env.pop("ROS_STATIC_PEERS", None)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO)] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
    env["PYTHONUNBUFFERED"] = "1"
    return env


def bptsb(args: list[str], ros_env: dict[str, str], timeout: float = 180) -> subprocess.CompletedProcess:
    """Run the ``bptsb`` CLI; output (stdout and stderr together) in ``.stdout``.

    Past ``timeout`` the CLI gets SIGINT (``bptsb launch`` then stops its nodes in order) and, if it is still
    running a minute later, SIGKILL; then ``subprocess.TimeoutExpired`` is raised with the output.

    A lockstep ``launch`` gets ``body_sim:command_timeout:=30`` unless the arguments set one: on busy cores a brain's
    first answers can take longer than the default 2 s, and the body would count it silent (a failed launch) for
    being slow, not broken; a dead brain still fails the run (its steps stand on the safe command).
    """
    if args[:1] == ["launch"] and "realtime" not in args and not any("command_timeout" in a for a in args):
        args = [*args, "--param", "body_sim:command_timeout:=30.0"]
    proc = subprocess.Popen([sys.executable, "-m", "bptsb_ros.cli", *args], env=env_for(ros_env), cwd=REPO,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        out, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGINT)
        try:
            out, _ = proc.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
            out, _ = proc.communicate()
        raise subprocess.TimeoutExpired(proc.args, timeout, output=out) from None
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return subprocess.CompletedProcess(proc.args, proc.returncode, out)


def interrupted_launch(args: list[str], ros_env: dict[str, str], ready: Callable[[str], bool], delay: float,
                       timeout: float = 90) -> tuple[int, str]:
    """Run ``bptsb launch ARGS``, read its output until a line for which ``ready`` holds, wait ``delay`` seconds, send
    it SIGINT (Ctrl-C) and wait for it; returns its exit code and all its output (stdout and stderr together)."""
    proc = subprocess.Popen([sys.executable, "-m", "bptsb_ros.cli", "launch", *args], env=env_for(ros_env), cwd=REPO,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines = []
    try:
        for line in proc.stdout:
            lines.append(line)
            if ready(line):
                break
        time.sleep(delay)
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=timeout)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return proc.returncode, "".join(lines) + out


def start_node(node: str, params: dict[str, Any], ros_env: dict[str, str], log: Path) -> subprocess.Popen:
    """Start ``python -m bptsb_ros.ros.<node> --ros-args -p ...``, output to ``log``."""
    from bptsb_ros.live.loops import format_parameter

    argv = [sys.executable, "-m", f"bptsb_ros.ros.{node}", "--ros-args"]
    for name, value in params.items():
        argv += ["-p", format_parameter(name, value)]
    with log.open("w") as out:  # the child keeps its own copy of the descriptor
        return subprocess.Popen(argv, env=env_for(ros_env), cwd=REPO, stdout=out, stderr=subprocess.STDOUT)


def stamp_ns(stamp: Any) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def bag_positions(bag: Path) -> tuple[np.ndarray, np.ndarray]:
    """(stamps [ns] (K,), positions (K, N, 2)) of ``/body/positions`` in a bag."""
    from bptsb_ros.bags.reader import read_messages
    from bptsb_ros.ros.messages import pose_array_positions

    stamps, rows = [], []
    for _, _, _, msg in read_messages(bag, ["/body/positions"]):
        stamps.append(stamp_ns(msg.header.stamp))
        rows.append(pose_array_positions(msg))
    return np.array(stamps, dtype=np.int64), np.array(rows, dtype=np.float64)


def fresh_agent(task: str, seed: int = 0):
    """The fresh float64 agent the nodes build from default parameters for ``task``."""
    from bptsb_ros.interface.source import SOURCE_PARAMS
    from bptsb_ros.live.agent_source import load_source

    values = {p.name: p.default for p in SOURCE_PARAMS}
    values.update(task=task, seed=seed)
    return load_source(values)[0]


def save_fitted_agent(run_dir: Path, seed: int = 3) -> None:
    """A small Lissajous agent (untrained body and SWG) with a feedback layer fitted on 10 s, as a checkpoint."""
    from bptsb_ros.agent import build_agent
    from bptsb_ros.config import validate
    from bptsb_ros.training.checkpoint import save_checkpoint
    from bptsb_ros.training.feedback_fit import fit_feedback

    cfg = validate({"task": "lissajous", "seed": seed, "dtype": "float64", "feedback": {"fit_time": 10.0}})
    agent = build_agent(cfg)
    fit_feedback(agent, cfg.feedback, None, seed)
    save_checkpoint(run_dir, agent, {"feedback_fitted": True})


class Probe:
    """An rclpy node in the test process on ``domain`` (the ``ros_domain_id`` fixture; own context), collecting
    messages per topic."""

    def __init__(self, domain: int, name: str = "test_probe", namespace: str = "") -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node

        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = Node(name, namespace=namespace or None, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.messages: dict[str, list[Any]] = {}

    def subscribe(self, msg_type: type, topic: str, qos: Any, callback: Callable[[Any], None] | None = None) -> None:
        self.messages[topic] = []

        def on_msg(msg: Any) -> None:
            self.messages[topic].append(msg)
            if callback is not None:
                callback(msg)

        self.node.create_subscription(msg_type, topic, on_msg, qos)

    def spin_until(self, condition: Callable[[], bool], timeout: float) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if condition():
                return True
            self.executor.spin_once(timeout_sec=0.05)
        return condition()

    @staticmethod
    def wait_matched(publishers: list[Any], timeout: float) -> bool:
        """Wait until every publisher has a matched subscriber (matching needs no spinning)."""
        end = time.monotonic() + timeout
        while any(p.get_subscription_count() < 1 for p in publishers):
            if time.monotonic() > end:
                return False
            time.sleep(0.005)
        return True

    def close(self) -> None:
        import rclpy

        self.node.destroy_node()
        rclpy.shutdown(context=self.context)


def stop(proc: subprocess.Popen, timeout: float = 20) -> int:
    """SIGINT a node process and wait for it; kill it if it does not stop."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return proc.returncode
