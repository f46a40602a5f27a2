"""``composed``: ``body_sim`` and the brain nodes of a loop in one process, on the body's executor.

The same nodes as a split launch (one process each), built in one rclpy context: the body first, then the brains in
the loop's order (a brain makes its outputs once it hears its inputs, :meth:`BrainNode.await_inputs`, so each one
needs the node it listens to already built). Every brain leaves its own executor for the body's; after each of the
body's spins, the brains answer the newest message of each of their subscriptions, as their own loop would
(:meth:`BrainNode.answer_newest`). The messages still go through the middleware (rclpy has no intra-process
transport); what composition saves is the processes' scheduling and wake-ups between them.

``python -m bptsb_ros.ros.composed --nodes body_sim,swg_brain --ros-args --params-file FILE [-r ...]``: FILE holds
one section per node (``/**/body_sim: ros__parameters: ...``, :func:`params_file_text`); ``bptsb launch LOOP
--composed`` writes it and starts this. The exit code is the body's (a brain's bad parameter: 2).
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Mapping, Sequence
from typing import Any

from bptsb_ros.interface.nodes import NODES
from bptsb_ros.interface.params import ParamValue, params_sections_text
from bptsb_ros.ros.runtime import (
    EXIT_BAD_PARAMETERS,
    EXIT_FAILURE,
    StopFlag,
    exit_process,
    ignore_stop_signals,
    install_stop_handlers,
)

NAME = "composed"
MODULES = {node.name: node.module for node in NODES}


def params_file_text(nodes: Mapping[str, Mapping[str, ParamValue]], extra: Mapping[str, Sequence[str]]) -> str:
    """A ROS params file with one section per node (any namespace): ``nodes`` maps a node to its parameters,
    ``extra`` to ``NAME:=VALUE`` texts (the value YAML, as ``-p`` reads it); empty lists are left out
    (:func:`~bptsb_ros.interface.params.params_sections_text`)."""
    return params_sections_text({f"/**/{node}": params for node, params in nodes.items()},
                                {f"/**/{node}": items for node, items in extra.items()})


def node_class(executable: str) -> type:
    """The node class a node's module runs: the one class of that module built on rclpy's ``Node``."""
    from rclpy.node import Node

    module = importlib.import_module(MODULES[executable])
    found = [obj for obj in vars(module).values()
             if isinstance(obj, type) and issubclass(obj, Node) and obj.__module__ == module.__name__]
    if len(found) != 1:
        raise LookupError(f"{module.__name__} defines {len(found)} node classes, not one")
    return found[0]


def run_composed(executables: Sequence[str], ros_args: list[str]) -> int:
    """Build ``executables`` (``body_sim`` first) in one context with ``ros_args``, run the body's loop with the
    brains on its executor, then finish every brain (summary, acknowledgements). Returns the exit code."""
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    from bptsb_ros.interface.params import ParameterError

    stop = StopFlag()
    install_stop_handlers(stop)
    rclpy.init(args=["bptsb", *ros_args], signal_handler_options=SignalHandlerOptions.NO)
    nodes: list[Any] = []
    code = EXIT_FAILURE
    try:
        try:
            for executable in executables:
                nodes.append(node_class(executable)(stop))
        except ParameterError as err:
            rclpy.logging.get_logger(executables[len(nodes)]).error(str(err))
            code = EXIT_BAD_PARAMETERS
        else:
            body, brains = nodes[0], nodes[1:]
            for brain in brains:
                brain.executor_.remove_node(brain)
                body.executor_.add_node(brain)
                if brain.cpus and brain.cpus != body.cpus:  # one process: its threads run where the body's cpus say
                    brain.get_logger().warning("cpus: in a composed process the body's cpus apply to every node; "
                                               "this node's are not used")

            def answer() -> None:
                for brain in brains:
                    brain.answer_newest()

            body.after_spin = answer
            code = body.run()
            if not stop:
                stop.set("the body's end")
            for brain in brains:
                brain.finish()
    except KeyboardInterrupt:
        rclpy.logging.get_logger(NAME).warning("interrupted twice: exiting without a clean stop")
        code = EXIT_FAILURE
    finally:
        ignore_stop_signals()
        for node in reversed(nodes):
            node.destroy_node()
        rclpy.try_shutdown()
        ignore_stop_signals()
    return code


def main(args: list[str] | None = None) -> int:
    """``--nodes body_sim,BRAIN,...`` then ``--ros-args ...``; default sys.argv."""
    argv = sys.argv[1:] if args is None else list(args)
    split = argv.index("--ros-args") if "--ros-args" in argv else len(argv)
    parser = argparse.ArgumentParser(prog=f"python -m bptsb_ros.ros.{NAME}", description=__doc__.split("\n")[0])
    parser.add_argument("--nodes", required=True, help="comma-separated: body_sim first, then the loop's brains")
    opts = parser.parse_args(argv[:split])
    executables = [n for n in opts.nodes.split(",") if n]
    unknown = [n for n in executables if n not in MODULES or n == "recorder"]
    if not executables or executables[0] != "body_sim" or unknown:
        parser.error(f"--nodes {opts.nodes}: body_sim first, then brain nodes of {', '.join(MODULES)} "
                     "(not the recorder)")
    code = run_composed(executables, argv[split:])
    if args is None:
        exit_process(code)
    return code


if __name__ == "__main__":
    sys.exit(main())
