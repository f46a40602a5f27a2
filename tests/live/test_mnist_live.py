"""The live "see a digit, draw it" loop: the image stream's schedule, the reset channel's rules (the
body's use of them is tested without DDS in ``test_live_core.py``), a whole ``bptsb launch mnist_drawing`` run equal
to the offline drawing of the same system and images, and its replay's per-digit errors. Planted data
(``mnist_planted.py``): a tiny IDX set and a small seeded, untrained float64 system."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from mnist_planted import write_stream, write_system
from ros_live import bag_positions, bptsb, stamp_ns

from bptsb_ros.data.mnist import MnistError, encode_idx
from bptsb_ros.live.channels import CommandChannel
from bptsb_ros.live.safety import CommandLimits
from bptsb_ros.tasks.digits import load_targets
from bptsb_ros.tasks.mnist_live import pixels, read_stream, shown_image

DT_NS = 10_000_000


def brain_input(x: np.ndarray) -> torch.Tensor:
    """What training feeds the brain, written out here: uint8 pixels / 255 in float32, rows of 784."""
    return torch.from_numpy(x.reshape(len(x), 784).astype(np.float32) / np.float32(255.0))


# -- ROS-free ------------------------------------------------------------------------------------------------
def test_stream_schedule_shows_image_i_at_step_i_times_e():
    shown = {k: shown_image(k, 5, 3) for k in range(-1, 21)}
    assert {k: i for k, i in shown.items() if i is not None} == {0: 0, 5: 1, 10: 2}  # count 3: nothing at 15
    with pytest.raises(ValueError, match="episode_steps"):
        shown_image(0, 0, 3)


def test_read_stream_slices_and_checks(tmp_path):
    images, labels, x = write_stream(tmp_path)
    got_x, got_y = read_stream(images, labels, first=1, count=2)
    np.testing.assert_array_equal(got_x, x[1:3])
    assert got_y.tolist() == [1, 7]
    assert read_stream(images, labels, first=2)[1].tolist() == [7, 0]  # count 0: the rest
    with pytest.raises(MnistError, match="holds 4 images; first 3 and count 2"):
        read_stream(images, labels, first=3, count=2)
    bad = tmp_path / "bad-labels"
    bad.write_bytes(encode_idx(np.array([1, 2, 12, 3], dtype=np.uint8)))
    with pytest.raises(MnistError, match="digits 0-9, found 12"):
        read_stream(images, str(bad))
    np.testing.assert_array_equal(pixels(x).numpy(), brain_input(x).numpy())


def test_reset_channel_takes_only_scheduled_bounded_displacements():
    names = ["mass_1/x", "mass_1/y", "mass_2/x", "mass_2/y"]
    ch = CommandChannel("reset", 4, names, "lockstep", every=10)
    assert [k for k in range(25) if ch.due(k)] == [0, 10, 20]
    assert ch.offer(1, [0.0] * 4, 0, 0.0).reason == "off_schedule"
    assert ch.offer(10, [0.0] * 4, 0, 0.0).reason == "too_far_ahead"
    assert ch.offer(0, [0.1] * 3, 0, 0.0).reason == "wrong_length"
    assert ch.offer(0, [0.1, np.nan, 0, 0], 0, 0.0).reason == "non_finite"
    assert ch.offer(0, [0.1] * 4, 0, 0.0) is None
    off = CommandChannel("reset", 4, names, "lockstep", every=0)
    assert off.offer(0, [0.0] * 4, 0, 0.0).reason == "off_schedule"
    # |d| per mass at most the body's extent: a 3 x 4 box has a 5 m diagonal
    limits = CommandLimits.for_body(np.array([[0.0, 0.0], [3.0, 4.0]]))
    assert limits.check("reset", [3.0, 4.0, -3.0, -4.0]) is None
    assert "movable mass 1" in limits.check("reset", [0.0, 0.0, 3.0, 4.01])


def test_plan_stream_checks_the_launch_arguments(tmp_path):
    from bptsb_ros.live.mnist_loop import StreamError, plan_stream, stream_parameters

    images, labels, _ = write_stream(tmp_path)
    write_system(tmp_path / "sys.pt")
    steps = [len(t) - 1 for t in load_targets()]
    plan = plan_stream(str(tmp_path / "sys.pt"), images, labels, first=1, count=3)
    assert (plan.count, plan.episode_steps) == (3, max(steps) + 1)
    body = stream_parameters(plan, "body_sim", {"mode": "lockstep"}, recording=True, duration=0.0)
    assert body["reset_every"] == max(steps) + 1 and body["max_steps"] == 3 * (max(steps) + 1) - 1
    assert body["command_timeout"] == 10.0  # a reset goes through two nodes: longer than a direct command's 2 s
    longer = stream_parameters(plan, "body_sim", {"command_timeout": 30.0}, recording=True, duration=0.0)
    assert longer["command_timeout"] == 30.0  # a longer wait asked for is kept
    need = max(steps[1], steps[7], steps[0]) + 1
    with pytest.raises(StreamError, match=f"need at least {need} steps"):
        plan_stream(str(tmp_path / "sys.pt"), images, labels, first=1, count=3, episode_steps=need - 1)
    with pytest.raises(StreamError, match="unreadable"):  # an IDX file is no torch file
        plan_stream(images, images, labels)
    run = tmp_path / "run"
    (run / "systems").mkdir(parents=True)
    write_system(run / "systems" / "a.pt")  # a run directory holding one system file stands for it
    assert plan_stream(str(run), images, labels).count == 4
    write_system(run / "systems" / "b.pt")
    with pytest.raises(StreamError, match="holds 2 system files"):
        plan_stream(str(run), images, labels)
    torch.save({"format": 1}, tmp_path / "checkpoint.pt")
    with pytest.raises(StreamError, match="not an MNIST system file"):
        plan_stream(str(tmp_path / "checkpoint.pt"), images, labels)
    with pytest.raises(StreamError, match="images and labels"):
        plan_stream(str(tmp_path / "sys.pt"), "", labels)


# -- live ----------------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_mnist_drawing_live_equals_offline_and_replays(tmp_path, ros_env):
    """Images 1..3 (labels 1, 7, 0), episodes of E = 130 steps: the bag holds every step, resets at 0, 130, 260, and
    equals the offline release of the same displacements; replay's per-digit errors equal a hand computation."""
    from bptsb_ros.analysis.replay import replay
    from bptsb_ros.bags.reader import read_messages

    images, labels, x = write_stream(tmp_path)
    system = write_system(tmp_path / "sys.pt")
    bag, e = tmp_path / "bag", 130
    out = bptsb(["launch", "mnist_drawing", "--agent", str(tmp_path / "sys.pt"), "--images", images, "--labels",
                 labels, "--first", "1", "--count", "3", "--episode-steps", str(e), "--bag", str(bag),
                 "--param", "body_sim:command_timeout:=30.0"], ros_env)  # a slow start of the two nodes is no fault
    assert out.returncode == 0, out.stdout[-4000:]
    stamps, pos = bag_positions(bag)
    assert stamps.tolist() == [k * DT_NS for k in range(3 * e)], "steps missing, repeated or out of order"
    # offline: the same images through the brain, each released for E - 1 steps
    body = system.body
    with torch.no_grad():
        disp = system.displacement(brain_input(x[1:4]))
        r = system.release(disp, e - 1, states=True)  # (3, E, M, 2)
        ref = body.full_positions(r.reshape(-1, *r.shape[2:])).numpy()
    assert np.abs(ref - ref[0]).max() > 0.05  # the body really draws
    assert np.abs(pos - ref).max() <= 1e-9
    resets = {stamp_ns(m.header.stamp) // DT_NS: np.asarray(m.position)
              for *_, m in read_messages(bag, ["/body/reset"])}
    assert sorted(resets) == [0, e, 2 * e]
    np.testing.assert_allclose(np.stack([resets[k] for k in sorted(resets)]), disp.reshape(3, -1).numpy(), atol=1e-12)
    shown = [(stamp_ns(m.header.stamp) // DT_NS, m) for *_, m in read_messages(bag, ["/camera/image"])]
    assert [k for k, _ in shown] == [0, e, 2 * e]
    for i, (_, m) in enumerate(shown):
        assert (m.encoding, m.height, m.width, m.step) == ("mono8", 28, 28, 28)
        np.testing.assert_array_equal(np.frombuffer(bytes(m.data), dtype=np.uint8).reshape(28, 28), x[1 + i])
    assert [m.position[0] for *_, m in read_messages(bag, ["/camera/label"])] == [1.0, 7.0, 0.0]
    summary = json.loads((tmp_path / "bag.launch" / "body_summary.json").read_text())
    assert summary["reset_accepted"] == 3 and summary["rejected_total"] == 0 and summary["safe_command_steps"] == 0
    assert "brain silent" not in out.stdout  # resets are awaited at reset steps only, never in between

    metrics = replay(bag, tmp_path / "replay", tmp_path / "sys.pt", gif=False)
    cmp = body.topology.cmp_index
    targets = load_targets()
    hand = {}
    for i, d in enumerate((1, 7, 0)):  # MSE over the target's own steps 0..T_d, both coordinates
        tgt = targets[d]
        drawing = ref[i * e: i * e + len(tgt), cmp] - body.positions0[cmp].numpy()
        hand[str(d)] = float(np.mean((drawing - tgt) ** 2))
    assert metrics["episode_steps"] == e and metrics["reset_steps"] == [0, e, 2 * e] and metrics["episodes"] == 3
    for key in ("live", "offline"):
        assert metrics[key]["per_digit"].keys() == hand.keys()
        for d, value in hand.items():
            assert metrics[key]["per_digit"][d] == pytest.approx(value, rel=1e-9, abs=1e-15)
    assert metrics["offline_comparison"]["max_abs_drawing_difference_m"] <= 1e-9
    assert metrics["offline_comparison"]["max_abs_reset_difference_m"] <= 1e-12
    assert (tmp_path / "replay" / "drawings.png").is_file()
    alone = replay(bag, tmp_path / "replay_alone", None, gif=False)  # no system: the CMP from the markers
    assert "offline" not in alone and alone["live"]["per_digit"] == pytest.approx(hand, rel=1e-9)


class _Payload:
    """Unpickling this runs ``exec(code)``: what an attacker hides in a system file."""

    def __init__(self, marker) -> None:
        self.code = f"open({str(marker)!r}, 'w').write('payload ran')"

    def __reduce__(self):
        return (exec, (self.code,))


def test_a_system_file_with_code_is_refused(tmp_path, capsys):
    """launch and replay read a system file as data only: one carrying an ``exec`` payload is refused, unrun."""
    from bptsb_ros.cli import main

    images, labels, _ = write_stream(tmp_path)
    write_system(tmp_path / "sys.pt")
    payload = torch.load(tmp_path / "sys.pt", weights_only=True)
    marker = tmp_path / "PAYLOAD_RAN"
    payload["state"]["evil"] = _Payload(marker)
    torch.save(payload, tmp_path / "evil.pt")
    code = main(["launch", "mnist_drawing", "--agent", str(tmp_path / "evil.pt"), "--images", images, "--labels",
                 labels, "--log-dir", str(tmp_path / "logs")])
    err = capsys.readouterr().err
    assert code == 1 and err.startswith("bptsb launch: ") and "refused" in err and "GLOBAL exec" in err, err
    assert not marker.exists(), "the system file's payload ran"
