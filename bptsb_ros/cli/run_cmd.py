"""``bptsb run``: start one live node in this process (like ``ros2 run bptsb_ros <node>``)."""

from __future__ import annotations

import argparse
import importlib

from bptsb_ros.cli.options import USAGE, fail
from bptsb_ros.interface.nodes import NODES as ALL_NODES

NAME = "run"
#: node name -> one line, from the node table (:data:`bptsb_ros.interface.nodes.NODES`)
NODES: dict[str, str] = {node.name: node.help for node in ALL_NODES}
HELP = "run one ROS 2 node: " + ", ".join(NODES)


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
