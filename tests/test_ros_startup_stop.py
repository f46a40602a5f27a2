"""Ctrl-C while the nodes of a loop are still starting (issue 6, finding 3): a clean stop, every node
exits 0, no KeyboardInterrupt traceback, the launcher exits 0."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

from ros_live import REPO, env_for


def test_ctrl_c_during_startup_is_a_clean_stop(tmp_path, ros_env):
    proc = subprocess.Popen([sys.executable, "-m", "bptsb_ros.cli", "launch", "lissajous_open", "--duration", "5",
                             "--bag", str(tmp_path / "bag"), "--grace", "20"],
                            env=env_for(ros_env), cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines = []
    try:
        for line in proc.stdout:  # the launcher announces the loop right before it starts the nodes
            lines.append(line)
            if line.startswith("[launch] lissajous_open:"):
                break
        time.sleep(0.3)  # the nodes are now importing torch and rclpy (that takes seconds here)
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=90)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    out = "".join(lines) + out
    assert "startup complete" not in out, "the stop came too late to test a stop during startup"
    assert "Traceback" not in out and "KeyboardInterrupt" not in out, out
    assert proc.returncode == 0, out
    for node in ("body_sim", "swg_brain", "recorder"):
        assert f"[launch]   {node:<15} ok" in out, out
