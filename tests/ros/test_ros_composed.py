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


@pytest.mark.parametrize("nodes", ["swg_brain,body_sim", "body_sim,recorder,swg_brain", "recorder,body_sim",
                                   "body_sim,no_such_brain", ""])
def test_the_command_line_takes_body_sim_first_then_brains_then_the_recorder(nodes, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--nodes", nodes, "--ros-args"])
    assert exc.value.code == 2
    assert "body_sim first, then brain nodes" in capsys.readouterr().err


SHAPES = {"split": [], "composed": ["--composed"], "recorder_in_body": ["--recorder-in-body"],
          "all_in_one": ["--composed", "--recorder-in-body"]}


def _bag_counts(bag) -> dict[str, int]:
    from bptsb_ros.bags.reader import bag_info

    return {t.name: t.message_count for t in bag_info(bag).topics if t.name != "/diagnostics"}


@pytest.mark.parametrize("loop", ["lissajous_open", "narma"])
def test_a_composed_run_records_what_the_split_run_records(loop, tmp_path, ros_env):
    """Body and brains in one process, the recorder in the body's process, or both: the same positions and the same
    number of messages on every topic as the split run (a process per node)."""
    bags, counts = {}, {}
    for shape, flags in SHAPES.items():
        bag = tmp_path / shape / "bag"
        out = bptsb(["launch", loop, "--duration", "2", "--bag", str(bag), *flags], ros_env)
        assert out.returncode == 0, out.stdout[-4000:]
        assert ("composed        ok" in out.stdout) == (shape != "split")
        assert ("recorder        ok" in out.stdout) == ("--recorder-in-body" not in flags)
        assert ("[launch]   body_sim " in out.stdout) == (shape == "split")
        bags[shape], counts[shape] = bag_positions(bag), _bag_counts(bag)
    split_stamps, split_pos = bags["split"]
    assert split_stamps.tolist() == [k * 10_000_000 for k in range(201)]
    for shape, (stamps, pos) in bags.items():
        assert stamps.tolist() == split_stamps.tolist(), shape
        assert np.abs(pos - split_pos).max() <= 1e-9, shape
        assert counts[shape] == counts["split"], shape
    assert np.abs(split_pos - split_pos[0]).max() > 1e-3  # the brains drove the body
    assert counts["split"]["/body/positions"] == 201
    log = (tmp_path / "composed" / "bag.launch" / "composed.log").read_text()
    assert "stopped by the body's end" in log and "[body_sim]" in log
    hosted = (tmp_path / "recorder_in_body" / "bag.launch" / "composed.log").read_text()
    assert "[recorder]: Bag " in hosted and "[recorder]: Recording to " in hosted


def test_a_hosted_recorder_refuses_a_body_that_waits_for_it(tmp_path, ros_env):
    """The recorder in the body's process takes in the body's loop: a body that waits for its acknowledgements
    would wait for a take that only comes after the wait, so that combination is refused with one line."""
    bag = tmp_path / "bag"
    out = bptsb(["launch", "lissajous_open", "--duration", "1", "--bag", str(bag), "--recorder-in-body",
                 "--param", "body_sim:wait_for_recorder:=true"], ros_env)
    assert out.returncode != 0
    assert "wait_for_recorder: the recorder runs in this process" in out.stdout, out.stdout[-3000:]
    assert not bag.exists()  # refused before the recorder made the bag


class _FakeRecorder:
    """The state :meth:`RecorderNode.serve` and :meth:`RecorderNode.drain_hosted` use, with counters: its executor's
    every spin brings the next of ``arrivals`` (then none, after a wait of up to 10 ms)."""

    def __init__(self, arrivals=(), **config) -> None:
        from types import SimpleNamespace

        self.config = SimpleNamespace(**{"batch_wait": 0.02, "drain_quiet": 0.05, "stop_timeout": 5.0, **config})
        self._next_take = self._next_service = 0.0
        self.takes, self.spins, self.received, self.stopped = 0, 0, 0, None
        self.arrivals = iter(arrivals)
        self.executor_ = SimpleNamespace(spin_once=self._spin)
        self.loss = SimpleNamespace(cut_short=False)

    def _spin(self, timeout_sec: float) -> None:
        import time

        self.spins += 1
        got = next(self.arrivals, 0)
        self.received += got
        if not got:
            time.sleep(min(timeout_sec, 0.01))

    def take_ready(self) -> None:
        self.takes += 1

    def begin_stop(self, stop_ns: int) -> None:
        self.stopped = stop_ns

    def get_logger(self):
        from types import SimpleNamespace

        return SimpleNamespace(error=lambda text: None)


def test_a_hosted_recorder_takes_before_every_wait_and_spins_its_executor_every_batch_wait():
    from bptsb_ros.ros.recorder import HOSTED_SPINS, RecorderNode

    fake = _FakeRecorder()
    turns = [(0.0, False), (0.005, False), (0.006, True), (0.02, False), (0.027, False), (0.05, True), (0.1, False)]
    seen = []
    for now, idle in turns:
        RecorderNode.serve(fake, now, idle=idle)
        seen.append((fake.takes, fake.spins // HOSTED_SPINS))
    # takes at 0 (due), 0.006 (idle), 0.027 (0.006 + 0.02 passed), 0.05 (idle), 0.1 (0.05 + 0.02 passed); its
    # executor (parameters, timers, loss reports) at 0, 0.02, 0.05 and 0.1, whether the host waits or not
    assert seen == [(1, 1), (1, 1), (2, 1), (2, 2), (3, 2), (4, 3), (5, 4)]
    assert fake.spins % HOSTED_SPINS == 0


def test_a_hosted_recorder_drains_until_quiet_and_counts_a_drain_cut_short():
    import itertools

    from bptsb_ros.ros.recorder import RecorderNode

    quiet = _FakeRecorder(arrivals=[3, 2, 0, 1])  # a late message after an empty spin resets the quiet time
    RecorderNode.drain_hosted(quiet)
    assert quiet.received == 6 and quiet.stopped is not None and quiet.spins >= 5 and not quiet.loss.cut_short
    busy = _FakeRecorder(arrivals=itertools.repeat(1), stop_timeout=0.05)  # never quiet: cut short at stop_timeout
    RecorderNode.drain_hosted(busy)
    assert busy.loss.cut_short and busy.received == busy.spins


def test_ctrl_c_stops_a_run_with_the_recorder_in_the_body_process_and_closes_a_complete_bag(tmp_path, ros_env):
    """A run without an end (``--duration 0``) stopped by SIGINT to ``bptsb launch`` a second after it started
    stepping: the body's process drains and closes the bag (complete, nothing lost: every tick the body sent, and
    every command the brain answered)."""
    from ros_live import interrupted_launch

    from bptsb_ros.bags.reader import bag_info

    bag = tmp_path / "bag"
    code, out = interrupted_launch(["lissajous_open", "--bag", str(bag), "--recorder-in-body", "--param",
                                    "body_sim:command_timeout:=30.0"], ros_env,
                                   lambda line: "startup complete" in line, 1.0)
    assert code == 0, out[-4000:]
    info = bag_info(bag)
    counts = {t.name: t.message_count for t in info.topics}
    assert info.dropped_messages == 0 and info.recording_complete
    # the answer to the last tick may come after the drain on a very busy machine: at most that one is missing
    assert counts["/clock"] > 50 and counts["/clock"] - 1 <= counts["/brain/rest_length"] <= counts["/clock"]
    assert "composed        ok" in out
