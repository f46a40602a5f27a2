"""``composed``: ``body_sim`` and the brain nodes of a loop in one process, on the body's executor.

The same nodes as a split launch (one process each), built in one rclpy context: the body first, then the brains in
the loop's order (a brain makes its outputs once it hears its inputs, :meth:`BrainNode.await_inputs`, so each one
needs the node it listens to already built). Every brain leaves its own executor for the body's; after each of the
body's spins, the brains answer the newest message of each of their subscriptions, as their own loop would
(:meth:`BrainNode.answer_newest`). The messages still go through the middleware (rclpy has no intra-process
transport); what composition saves is the processes' scheduling and wake-ups between them.

``recorder`` last in ``--nodes`` hosts the recorder too (``bptsb launch --recorder-in-body``), as a composable
recorder shares its publishers' process: it takes everything waiting each time the body is about to wait for a
message, and after the body's spins and steps once ``batch_wait`` has passed since its last take, when it also spins
its own executor without waiting (parameters, timers, loss reports; :meth:`RecorderNode.serve`), all in the body's
thread, so the body need not wait for it (its ``wait_for_recorder`` must be false). After the run it drains and
closes the bag; a process stopped outright closes the bag marked incomplete.

``python -m bptsb_ros.ros.composed --nodes body_sim,swg_brain --ros-args --params-file FILE [-r ...]``: FILE holds
one section per node (``/**/body_sim: ros__parameters: ...``, :func:`params_file_text`); ``bptsb launch LOOP
--composed`` writes it and starts this. The exit code is the body's, else the recorder's (a bad parameter: 2).
"""

from __future__ import annotations

import argparse
import importlib
import sys
import time
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
RECORDER = "recorder"
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

    from bptsb_ros.bags.errors import BagError
    from bptsb_ros.interface.params import ParameterError

    stop = StopFlag()
    install_stop_handlers(stop)
    rclpy.init(args=["bptsb", *ros_args], signal_handler_options=SignalHandlerOptions.NO)
    nodes: list[Any] = []
    recorder: Any = None
    code = EXIT_FAILURE
    try:
        try:
            for executable in executables:
                if executable == RECORDER:
                    if nodes[0].core.recorder is not None:  # refused before the bag is made
                        raise ParameterError("wait_for_recorder: the recorder runs in this process and takes in the "
                                             "body's loop, which has nothing to wait for: set wait_for_recorder:=false")
                    recorder = node_class(executable)(hosted=True)
                    recorder.host()
                    nodes.append(recorder)
                else:
                    nodes.append(node_class(executable)(stop))
        except (ParameterError, BagError) as err:
            rclpy.logging.get_logger(executables[len(nodes)]).error(str(err))
            code = EXIT_BAD_PARAMETERS
        else:
            body = nodes[0]
            brains = [node for node in nodes[1:] if node is not recorder]
            for brain in brains:
                brain.executor_.remove_node(brain)
                body.executor_.add_node(brain)
                if brain.cpus and brain.cpus != body.cpus:  # one process: its threads run where the body's cpus say
                    brain.get_logger().warning("cpus: in a composed process the body's cpus apply to every node; "
                                               "this node's are not used")

            def after_spin() -> None:
                for brain in brains:
                    brain.answer_newest()
                if recorder is not None:
                    recorder.serve(time.monotonic())

            body.after_spin = after_spin
            if recorder is not None:
                body.before_wait = lambda: recorder.serve(time.monotonic(), idle=True)
                body.after_step = lambda: recorder.serve(time.monotonic())
            code = body.run()
            if not stop:
                stop.set("the body's end")
            for brain in brains:
                brain.finish()
            if recorder is not None:
                recorder.drain_hosted()
                recorded = recorder.close()
                code = code or recorded
    except KeyboardInterrupt:
        rclpy.logging.get_logger(NAME).warning("interrupted twice: exiting without a clean stop")
        code = EXIT_FAILURE
    finally:
        ignore_stop_signals()
        if recorder is not None and not recorder.writer.closed:  # stopped outright: the bag says it is incomplete
            recorder.loss.cut_short = True
            recorded = recorder.close()
            code = code or recorded
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
    parser.add_argument("--nodes", required=True, help="comma-separated: body_sim first, then the loop's brains, then "
                        "optionally recorder (hosted in the body's loop)")
    opts = parser.parse_args(argv[:split])
    executables = [n for n in opts.nodes.split(",") if n]
    unknown = [n for n in executables if n not in MODULES]
    misplaced = RECORDER in executables[:-1]
    if not executables or executables[0] != "body_sim" or unknown or misplaced:
        parser.error(f"--nodes {opts.nodes}: body_sim first, then brain nodes of {', '.join(MODULES)}, then "
                     f"optionally {RECORDER}")
    code = run_composed(executables, argv[split:])
    if args is None:
        exit_process(code)
    return code


if __name__ == "__main__":
    sys.exit(main())
