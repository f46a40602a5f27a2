"""``bptsb run``: start one live node in this process (like ``ros2 run bptsb_ros <node>``)."""

from __future__ import annotations

import argparse
import importlib

from bptsb_ros.cli.options import USAGE, fail

NAME = "run"
HELP = ("run one ROS 2 node: body_sim, swg_brain, mlp_brain, feedback_brain, task_input, recorder, image_streamer or "
        "mnist_brain")

NODES: dict[str, str] = {
    "body_sim": "soft-body simulator: publishes /clock and the body state, integrates brain commands",
    "swg_brain": "sine-wave generator: rest-length commands on each /clock tick",
    "mlp_brain": "MLP/LIL brain: task input → forces on the movable masses",
    "feedback_brain": "feedback layer: body state → rest-length commands (closed loop)",
    "task_input": "streams the task's input series (NARMA u) on each /clock tick",
    "recorder": "records topics to a rosbag2 MCAP bag (parameters bag_path, topics)",
    "image_streamer": "MNIST loop: one IDX image per episode on camera/image (parameters images, labels)",
    "mnist_brain": "MNIST loop: camera/image → initial displacements on body/reset (agent: a system file)",
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.epilog = (
        "nodes:\n" + "\n".join(f"  {name:<15} {text}" for name, text in NODES.items())
        + "\n\nexamples:\n"
        "  bptsb run body_sim --ros-args --params-file config/body_sim_params.yaml -p mode:=realtime\n"
        "  bptsb run swg_brain --ros-args -p agent:=runs/lissajous   (brains run on sim time by default)\n"
        "Parameters of a node: its config/<node>_params.yaml lists every one with a description."
    )
    parser.add_argument("node", choices=sorted(NODES), metavar="NODE", help="node to run: " + ", ".join(NODES))
    parser.add_argument("ros_args", nargs=argparse.REMAINDER, metavar="--ros-args ...",
                        help="ROS arguments passed to the node (-p name:=value, --params-file FILE, -r from:=to)")


def run(args: argparse.Namespace) -> int:
    ros_args = list(args.ros_args)
    if ros_args and ros_args[0] != "--ros-args":
        return fail("run", f"arguments after the node name must start with --ros-args, got {ros_args[0]!r}", USAGE)
    from bptsb_ros.ros.runtime import block_interrupt

    block_interrupt()  # Ctrl-C while the node imports and starts: a clean stop, not a traceback
    module = importlib.import_module(f"bptsb_ros.ros.{args.node}")
    return int(module.main(ros_args))
