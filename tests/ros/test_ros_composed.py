"""``bptsb launch LOOP --composed``: body_sim and the brains in one process on the body's executor. Its params file
(a section per node), its node classes and its command line are checked without DDS; launched, a composed lockstep
run records the same positions as the split run of the same loop (one process per node), for a loop of one brain and
for the NARMA loop's chain of two (task input → MLP brain)."""

from __future__ import annotations

import numpy as np
import pytest
from ros_live import bag_positions, bptsb

from bptsb_ros.ros.composed import main, node_class, params_file_text


def test_the_params_file_has_a_section_per_node_and_types_every_value():
    text = params_file_text({"body_sim": {"mode": "lockstep", "duration": 2.0, "max_steps": 5, "paused": False,
                                          "wait_for": ["rest_length"], "wait_for_subscribers": [],
                                          "topics.clock": "/r1/clock"},
                             "swg_brain": {"task": "lissajous", "seed": 3}},
                            {"swg_brain": ["qos_depth:=40"]})
    assert text == (
        "/**/body_sim:\n"
        "  ros__parameters:\n"
        "    mode: 'lockstep'\n"
        "    duration: 2.0\n"
        "    max_steps: 5\n"
        "    paused: false\n"
        "    wait_for: ['rest_length']\n"
        "    topics.clock: '/r1/clock'\n"
        "/**/swg_brain:\n"
        "  ros__parameters:\n"
        "    task: 'lissajous'\n"
        "    seed: 3\n"
        "    qos_depth: 40\n")


def test_each_node_module_gives_its_one_node_class():
    from bptsb_ros.ros.body_sim import BodySim
    from bptsb_ros.ros.mnist_brain import MnistBrain
    from bptsb_ros.ros.swg_brain import SwgBrain

    assert (node_class("body_sim"), node_class("swg_brain"), node_class("mnist_brain")) == (BodySim, SwgBrain,
                                                                                           MnistBrain)


@pytest.mark.parametrize("nodes", ["swg_brain,body_sim", "body_sim,recorder", "body_sim,no_such_brain", ""])
def test_the_command_line_takes_body_sim_first_then_brains(nodes, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--nodes", nodes, "--ros-args"])
    assert exc.value.code == 2
    assert "body_sim first, then brain nodes" in capsys.readouterr().err


@pytest.mark.parametrize("loop", ["lissajous_open", "narma"])
def test_a_composed_run_records_what_the_split_run_records(loop, tmp_path, ros_env):
    bags = {}
    for shape in ("split", "composed"):
        bag = tmp_path / shape / "bag"
        out = bptsb(["launch", loop, "--duration", "2", "--bag", str(bag), *(["--composed"] if shape == "composed"
                                                                             else [])], ros_env)
        assert out.returncode == 0, out.stdout[-4000:]
        assert ("composed        ok" in out.stdout) == (shape == "composed") and "recorder        ok" in out.stdout
        bags[shape] = bag_positions(bag)
    (split_stamps, split_pos), (stamps, pos) = bags["split"], bags["composed"]
    assert stamps.tolist() == [k * 10_000_000 for k in range(201)] == split_stamps.tolist()
    assert np.abs(pos - split_pos).max() <= 1e-9
    assert np.abs(pos - pos[0]).max() > 1e-3  # the brains drove the body
    log = (tmp_path / "composed" / "bag.launch" / "composed.log").read_text()
    assert "stopped by the body's end" in log and "[body_sim]" in log
