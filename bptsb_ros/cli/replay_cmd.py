"""`bptsb replay`: analyse a recorded live run."""

from __future__ import annotations

import argparse
import json
import sys

NAME = "replay"
HELP = ("Replay a rosbag2 MCAP bag of a live loop: rebuild the trajectories, compute the task's metrics, compare "
        "with the offline simulation of the agent, and write metrics.json, plots and an animation.")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", help="bag directory (metadata.yaml + .mcap) or a .mcap file")
    parser.add_argument("--out", required=True, help="output directory")
    parser.add_argument("--agent", default=None,
                        help="run directory of the agent (mnist_drawing: the MNIST system file); without it no agent "
                        "is loaded (a path stored in the bag is only printed, never loaded: bags are untrusted data)")
    parser.add_argument("--task", choices=("lissajous", "locomotion", "narma"), default=None,
                        help="task whose metric to compute (default: the agent's)")
    from bptsb_ros.live.loops import LOOPS  # ROS-free: keeps --help fast

    parser.add_argument("--loop", default=None, choices=sorted(LOOPS),
                        help="loop that was run (default: from the bag's custom_data)")
    parser.add_argument("--body-node", default="body_sim", metavar="NAME",
                        help="node name of the body simulator, in the run's namespace (or a full /NS/NAME): only its "
                        "messages on the body topics are used; those of other publishers are ignored and reported "
                        "(default: body_sim)")
    parser.add_argument("--no-gif", action="store_true", help="skip the animation")
    parser.add_argument("--skip-damaged", action="store_true",
                        help="skip bag chunks that fail their CRC check (with a warning) instead of stopping")


def run(args: argparse.Namespace) -> int:
    from bptsb_ros.analysis.replay import replay
    from bptsb_ros.bags.errors import BagError
    from bptsb_ros.cli.options import fail

    errors: tuple[type[Exception], ...] = (BagError, ValueError)
    if args.agent:  # only the offline comparison with an agent needs torch (the light install has none)
        from bptsb_ros.training.checkpoint import CheckpointError

        errors += (CheckpointError,)
    try:
        metrics = replay(args.bag, args.out, args.agent, args.task, args.loop, gif=not args.no_gif,
                         skip_damaged=args.skip_damaged, body_node=args.body_node)
    except errors as err:  # the bag's or the agent's contents
        return fail(NAME, err)
    except OSError as err:
        return fail(NAME, f"cannot write --out {args.out}: {err.strerror or err}")
    shown = {k: v for k, v in metrics.items() if k != "files"}
    print(json.dumps(shown, indent=2, default=float))
    print("files: " + ", ".join(metrics["files"]))
    if metrics.get("bag_agent"):
        print(f"the bag names the agent {metrics['bag_agent']!r}; it was not loaded (a bag is untrusted data). "
              f"To compare with the offline simulation, pass it yourself: --agent {metrics['bag_agent']}",
              file=sys.stderr)
    return 0
