"""Bad input to configs and command-line arguments: one clear error naming the
problem, bounded in size, a non-zero exit, and nothing lost or left behind."""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest
from conftest import REPO_ROOT as REPO

from bptsb_ros.cli import main
from bptsb_ros.config import ECHO_CHARS, ConfigError, load_config

CONFIG = REPO / "config" / "lissajous_single.yaml"
TINY = ["--set", "sim_time=1", "--set", "feedback.fit_time=1", "--set", "lissajous.eval_periods=1", "--no-progress"]


def _bomb(levels: int) -> str:
    """A YAML alias bomb: ``levels`` anchors, each a list of nine aliases of the previous one (9**levels leaves)."""
    lines = ["task: lissajous", "a0: &a0 [x, x, x, x, x, x, x, x, x]"]
    for i in range(1, levels):
        lines.append(f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]")
    return "\n".join(lines) + "\n"


def test_alias_bomb_is_refused_with_a_short_message(tmp_path):
    path = tmp_path / "bomb.yaml"
    path.write_text(_bomb(6))  # 531,441 leaves from 0.4 kB; the old code echoed all of them in the error
    assert path.stat().st_size < 600
    with pytest.raises(ConfigError) as err:
        load_config(path)
    assert "alias" in str(err.value) and len(str(err.value)) < 400


def test_echoed_values_are_truncated(tmp_path):
    path = tmp_path / "long.yaml"
    path.write_text("task: lissajous\nbody:\n  shape: " + "x" * 100_000 + "\n")
    with pytest.raises(ConfigError, match=r"body\.shape") as err:
        load_config(path)
    assert len(str(err.value)) < 300 + ECHO_CHARS
    with pytest.raises(ConfigError) as err:
        load_config(CONFIG, ["narma.extra=[" + ", ".join(["123456789"] * 5_000) + "]"])
    assert "narma.extra: unknown key" in str(err.value) and len(str(err.value)) < 300 + ECHO_CHARS


@pytest.mark.parametrize("override, key", [
    ("brain.amplitude=.nan", "brain.amplitude"), ("body.size=.inf", "body.size"),
    ("training.lr.k=-.inf", "training.lr.k"), ("lissajous.delta=.nan", "lissajous.delta"),
    ("body.k_init=[1, .inf]", "body.k_init"), ("body.dt=5", "body.dt"),
])
def test_every_float_must_be_finite_and_in_range(override, key):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        load_config(CONFIG, [override])


def test_body_size_is_bounded(capsys, tmp_path):
    with pytest.raises(ConfigError, match=r"body\.nodes: Input should be less than or equal to 2001"):
        load_config(CONFIG, ["body.nodes=1000001"])
    code = main(["simulate", "--shape", "double_circle", "--nodes", "40001", "--steps", "1",
                 "--out", str(tmp_path / "x.npz")])
    err = capsys.readouterr().err
    assert code == 2 and "40001 masses is more than the maximum of 2001" in err and "Traceback" not in err


@pytest.mark.parametrize("args", [["--perturb", "nan"], ["--wind", "inf", "0"], ["--dt", "nan"], ["--size=-inf"]])
def test_cli_floats_must_be_finite(args, capsys, tmp_path):
    with pytest.raises(SystemExit) as exc:
        main(["simulate", "--shape", "double_circle", "--steps", "1", "--out", str(tmp_path / "x.npz"), *args])
    assert exc.value.code == 2
    assert "must be a finite number" in capsys.readouterr().err
    assert not (tmp_path / "x.npz").exists()


def test_train_never_replaces_a_run_without_force(tmp_path, capsys):
    run = tmp_path / "run"
    assert main(["train", str(CONFIG), "--out", str(run), *TINY]) == 0
    checkpoint = (run / "checkpoint.pt").read_bytes()
    capsys.readouterr()
    assert main(["train", str(CONFIG), "--out", str(run), "--seed", "5", *TINY]) == 1  # --out's contents: runtime
    err = capsys.readouterr().err
    assert f"--out {run} already holds a run" in err and "--force" in err
    assert (run / "checkpoint.pt").read_bytes() == checkpoint  # nothing lost
    assert main(["train", str(CONFIG), "--out", str(run), "--seed", "5", "--force", *TINY]) == 0
    assert (run / "checkpoint.pt").read_bytes() != checkpoint


def test_resume_of_a_missing_run_leaves_nothing(tmp_path, capsys):
    run = tmp_path / "missing" / "run"
    assert main(["train", str(CONFIG), "--out", str(run), "--resume", *TINY]) == 1
    assert "no checkpoint at" in capsys.readouterr().err
    assert not run.exists() and not run.parent.exists()


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    return err


@pytest.mark.ros
@pytest.mark.skipif(not os.path.isdir("/sys/kernel"), reason="needs a read-only /sys")
def test_unwritable_outputs_give_one_line(tmp_path, capsys):
    a_file = tmp_path / "file"
    a_file.write_text("keep me")
    for bag in ("/sys/kernel/bptsb_bag", str(a_file / "bag")):
        assert main(["launch", "lissajous_open", "--duration", "0.1", "--bag", bag]) == 1  # a runtime failure
        assert _one_line_error(capsys).startswith("bptsb launch: --bag")
    bag = tmp_path / "bag"
    _tiny_bag(bag)
    for out in ("/sys/kernel/bptsb_replay", str(a_file), str(a_file / "sub")):
        assert main(["replay", str(bag), "--out", out, "--no-gif"]) == 1
        assert f"cannot write --out {out}" in _one_line_error(capsys)
    assert a_file.read_text() == "keep me"


def _tiny_bag(bag: Path) -> None:
    import numpy as np

    from bptsb_ros.bags.writer import BagWriter
    from bptsb_ros.ros import messages as m

    with BagWriter(bag) as w:
        for k in range(3):
            pos = np.array([[0.0, 0.0], [1.0, 0.0], [0.5, 0.1 * k]])
            w.write_message("/body/positions", m.pose_array(k, 10_000_000, pos, "msdn"), k * 10_000_000)


def test_bag_qos_alias_bomb_gives_a_short_error():
    """offered_qos_profiles is untrusted bag data: nested aliases (9^6 = 531,441 strings from ~0.3 kB) must be
    refused by the bounded loader with a short message, not expanded and echoed (several MB)."""
    from bptsb_ros.bags.errors import BagError
    from bptsb_ros.bags.qos import qos_profiles_from_value

    levels = ["a0: &a0 [lol, lol, lol, lol, lol, lol, lol, lol, lol]"]
    levels += [f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 9)}]" for i in range(1, 6)]
    text = "- {" + ", ".join(level.replace(": ", ": ", 1) for level in levels) + ", history: *a5}"
    assert len(text) < 400
    with pytest.raises(BagError) as err:
        qos_profiles_from_value(text)
    assert len(str(err.value)) < 500


@pytest.mark.ros
def test_bag_schema_names_never_import_arbitrary_modules():
    """A schema name read from a bag picks the module to import: only installed ROS messages are imported."""
    import sys

    from bptsb_ros.bags.msgdefs import MessageDefinitionError, get_message_class

    assert get_message_class("geometry_msgs/msg/PoseArray").__name__ == "PoseArray"
    sys.modules.pop("json.tool", None)
    for name in ("json/tool/PoseArray", "json/msg/PoseArray", "idlelib/idle/PoseArray"):
        with pytest.raises(MessageDefinitionError, match="not an installed ROS 2 message"):
            get_message_class(name)
    assert "json.tool" not in sys.modules and "idlelib.idle" not in sys.modules


def test_perturb_step_is_bounded_before_the_integer_conversion():
    from bptsb_ros.interface.params import ParameterError
    from bptsb_ros.live.body_params import MAX_PERTURB_AHEAD, perturb_step

    assert perturb_step(1.0, 0.01, 100) == 100  # the last step of a 100-step run
    assert perturb_step(1.0049, 0.01, 100) == 100
    with pytest.raises(ParameterError, match=r"1.0051 s is after the run.s last step \(1 s\)"):
        perturb_step(1.0051, 0.01, 100)  # rounds to step 101
    for at in (1e307, 1.7e308):  # 1e307 / 0.01 = inf: int(round(inf)) was an OverflowError
        with pytest.raises(ParameterError, match="is after the run's last step"):
            perturb_step(at, 0.01, 100)
    assert perturb_step(MAX_PERTURB_AHEAD * 0.01, 0.01, 0) == MAX_PERTURB_AHEAD  # no end: at most this far ahead
    with pytest.raises(ParameterError, match=re.escape(f"more than {MAX_PERTURB_AHEAD:g} steps")):
        perturb_step(1e307, 0.01, 0)


LATE = "after the run's last step"


@pytest.mark.parametrize("args, why", [  # why: the refusal's wording, None when accepted
    (["--duration", "5", "--perturb-at", "5"], None), (["--duration", "5", "--perturb-at", "5.001"], LATE),
    (["--duration", "5", "--perturb-at", "1e307"], LATE), (["--duration", "0", "--perturb-at", "1e307"], None),
    (["--duration", "2", "--mode", "realtime", "--rate-scale", "3", "--perturb-at", "6"], None),
    (["--duration", "2", "--mode", "realtime", "--rate-scale", "3", "--perturb-at", "6.01"], LATE),
    (["--duration", "5", "--perturb-at", "-0.5"], "--perturb-at -0.5: must be >= 0"),
    (["--duration", "5", "--perturb-at", "0"], None),
])
def test_launch_checks_perturb_at_against_the_run_before_starting(args, why, capsys):
    import argparse

    from bptsb_ros.cli import launch_cmd

    parser = argparse.ArgumentParser()
    launch_cmd.add_arguments(parser)
    problem = launch_cmd._perturbation_problem(parser.parse_args(["lissajous_open", *args, "--perturb-sigma", "0.1"]))
    assert (problem == "") == (why is None), problem
    if why is not None:  # refused by the command itself, before any node starts: one line, exit 2
        assert why in problem
        assert main(["launch", "lissajous_open", *args, "--perturb-sigma", "0.1"]) == 2
        err = _one_line_error(capsys)
        assert "--perturb-at" in err and why in err


@pytest.mark.slow
def test_body_sim_refuses_a_perturbation_beyond_any_step_in_one_line(tmp_path, ros_env):
    """--duration 0 (no end): the launcher cannot know the step, body_sim refuses it at start-up (it crashed
    with an OverflowError traceback)."""
    from ros_live import bptsb

    out = bptsb(["launch", "lissajous_open", "--duration", "0", "--perturb-at", "1e307", "--perturb-sigma", "0.1",
                 "--timeout", "120", "--log-dir", str(tmp_path / "logs")], ros_env)
    assert out.returncode == 1 and "Traceback" not in out.stdout, out.stdout[-3000:]
    assert "parameter 'perturb_at': 1e+307 s is more than 1e+09 steps" in out.stdout


RECURSIVE = ["&a [*a]", "&m {x: *m}", "&a [1, [2, *a]]"]


@pytest.mark.parametrize("text", RECURSIVE)
def test_a_recursive_yaml_alias_is_refused_at_once(text):
    """A 7-byte self-referencing alias expands without end; the one safe loader refuses it (every YAML input of the
    package goes through it), and a shared alias that is no cycle still loads."""
    from bptsb_ros.files.untrusted_yaml import UntrustedYamlError, load_untrusted_yaml

    with pytest.raises(UntrustedYamlError, match="recursive alias"):
        load_untrusted_yaml(text, "t")
    assert load_untrusted_yaml("a: &a [1]\nb: [*a, [*a]]", "t") == {"a": [1], "b": [[1], [[1]]]}


def test_recursive_aliases_in_every_yaml_input_give_one_line(tmp_path, capsys):
    import shutil

    cfg = tmp_path / "loop.yaml"
    cfg.write_text("task: lissajous\nbody: &b {shape: *b}\n")
    bag = tmp_path / "bag"
    shutil.copytree(REPO / "bags" / "lissajous_closed_example", bag)
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: &a {version: 9, files: [*a]}\n")
    runs = [["train", str(cfg), "--out", str(tmp_path / "t")],
            ["sweep", str(cfg), "--seeds", "0", "--out", str(tmp_path / "s"), "--workers", "0"],
            ["reproduce", "memory-task", "--set", "delays=&a [*a]", "--out", str(tmp_path / "r")],
            ["bag", "info", str(bag)], ["replay", str(bag), "--out", str(tmp_path / "p"), "--no-gif"]]
    for argv in runs:
        code = main(argv)
        err = capsys.readouterr().err
        assert code in (1, 2) and "recursive alias" in err and err.count("\n") == 1, (argv, err)
    assert not (tmp_path / "t").exists() and not (tmp_path / "r").exists()
    # recover treats the unreadable metadata.yaml as damage: rebuilt from the data, the old one kept beside it
    assert main(["bag", "recover", str(bag)]) == 0
    assert "recursive alias" in capsys.readouterr().out
    assert (bag / "metadata.yaml.damaged").read_text().startswith("rosbag2_bagfile_information: &a")
