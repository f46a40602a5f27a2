"""docs/ros/index.md's workspace recipe, run as written: from an empty colcon workspace to a `ros2 launch` that
records a bag.

The bash block of the page that sources ROS is run line by line in a fresh HOME, with three substitutions a test
machine needs: the ROS 2 command-line tools built from source (BPTSB_ROS_TOOLS, default /opt/ros-tools-jazzy)
stand in for /opt/ros/jazzy; the workspace's copy of the package is this checkout's working tree instead of a
`git clone`; torch's CPU build is taken by its version (`torch==2.13.0`, the CPU wheel the package index of the
test machine holds) instead of from PyTorch's CPU index. Everything else, the venv, the one pip command for the
Python dependencies (requirements-ros.txt), `colcon build` and `ros2 launch`, is the page's.

It installs torch into a new venv (minutes), so it runs where asked (BPTSB_WORKSPACE_TEST=1: CI does, after the
suite) and where the ROS tools are; a run that demands the tools (BPTSB_REQUIRE_ROS_TOOLS=1) fails without them.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest
from conftest import REPO_ROOT as REPO

ROS_TOOLS = Path(os.environ.get("BPTSB_ROS_TOOLS", "/opt/ros-tools-jazzy"))
PAGE = REPO / "docs" / "ros" / "index.md"
CPU_TORCH = "torch==2.13.0"
#: top-level entries of the checkout that a clone would not hold (build outputs, caches)
NOT_CLONED = {".venv", ".git", "build", "install", "log", "runs", "site", "dist", ".pytest_cache", ".ruff_cache"}


def recipe() -> list[str]:
    """The command lines of the page's workspace block (the bash block that sources ROS 2)."""
    blocks = re.findall(r"```bash\n(.*?)```", PAGE.read_text(encoding="utf-8"), re.DOTALL)
    block = next(b for b in blocks if "source /opt/ros/jazzy/setup.bash" in b)
    return [line for line in block.splitlines() if line.strip()]


def test_the_recipe_is_the_one_this_test_follows():
    lines = recipe()
    assert lines[0] == "source /opt/ros/jazzy/setup.bash"
    assert any("git clone" in line and "src/bptsb_ros" in line for line in lines)
    pip = [line for line in lines if line.startswith("pip install")]
    assert pip == ["pip install torch --index-url https://download.pytorch.org/whl/cpu && "
                   "pip install -r src/bptsb_ros/requirements-ros.txt"]
    assert any(line.startswith("python -m colcon build") for line in lines)
    assert lines[-1].startswith("ros2 launch bptsb_ros ")


def _script(lines: list[str]) -> str:
    out = ["set -eo pipefail"]  # not -u: ROS setup scripts read unset variables
    for line in lines:
        line = line.split("   #")[0].rstrip()
        if line == "source /opt/ros/jazzy/setup.bash":
            line = f"source {ROS_TOOLS}/setup.bash"
        elif "git clone" in line:
            line = "test -f ~/bptsb_ws/src/bptsb_ros/package.xml"  # copied from the working tree beforehand
        line = line.replace("pip install torch --index-url https://download.pytorch.org/whl/cpu",
                            f"pip install {CPU_TORCH}")
        out.append(line)
    return "\n".join(out) + "\n"


def test_the_workspace_recipe_ends_in_a_recorded_launch(tmp_path, ros_env):
    if os.environ.get("BPTSB_WORKSPACE_TEST") != "1":
        pytest.skip("installs torch into a new venv (minutes): BPTSB_WORKSPACE_TEST=1 runs it (CI does)")
    if not (ROS_TOOLS / "setup.bash").is_file():
        reason = f"the ROS 2 tools are not at {ROS_TOOLS} (bash ../shared/ros-tools/setup.sh builds them)"
        if os.environ.get("BPTSB_REQUIRE_ROS_TOOLS") == "1":
            pytest.fail(f"BPTSB_REQUIRE_ROS_TOOLS=1 but {reason}")
        pytest.skip(reason)
    home = tmp_path / "home"
    src = home / "bptsb_ws" / "src" / "bptsb_ros"
    shutil.copytree(REPO, src, ignore=lambda d, names: ({n for n in names if n in NOT_CLONED}
                                                        if Path(d) == REPO else {"__pycache__"} & set(names)))
    env = {k: v for k, v in ros_env.items() if not k.startswith(("VIRTUAL_ENV", "PYTHON", "AMENT", "COLCON"))}
    env.update(HOME=str(home), PATH="/usr/local/bin:/usr/bin:/bin", PYTHONUNBUFFERED="1")
    script = tmp_path / "recipe.sh"
    script.write_text(_script(recipe()))
    run = subprocess.run(["bash", str(script)], cwd=home, env=env, capture_output=True, text=True, timeout=1500,
                         stdin=subprocess.DEVNULL)
    assert run.returncode == 0, f"{run.stdout[-4000:]}\n{run.stderr[-4000:]}"
    bag = home / "bags" / "first_run"
    assert (bag / "metadata.yaml").is_file() and list(bag.glob("*.mcap")), run.stdout[-2000:]
    # the nodes ran the colcon install's package from the workspace venv (not this checkout)
    installed = home / "bptsb_ws" / "install" / "bptsb_ros"
    assert (installed / "lib" / "bptsb_ros" / "body_sim").is_file()
    assert str(REPO) not in (installed / "lib" / "bptsb_ros" / "body_sim").read_text()
