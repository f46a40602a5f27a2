"""Process lifecycle shared by every live node: rclpy init, clean stop on SIGINT/SIGTERM, exit codes.

rclpy's own signal handlers shut the context down at once, after which a node can no longer publish
its last diagnostics or wait for its messages to be acknowledged. The nodes therefore install their
own handlers: the first SIGINT/SIGTERM sets a stop flag that the node's loop polls (at least every
0.1 s); a second one raises KeyboardInterrupt ("exit now") only when it comes more than
:data:`DUPLICATE_WINDOW` seconds after the first. A stop signal sent to a whole process group without a
terminal (a script's ``kill -INT -PGID``, systemd, a supervisor) reaches every node directly *and* through
``ros2 launch``, which forwards SIGINT to its children when it is non-interactive: those two copies of one
request arrive within milliseconds and count as one, so the node still stops cleanly with its summary.

A Ctrl-C while the process is still starting (importing torch and rclpy, loading the agent) is a clean
stop too: ``bptsb launch`` and ``bptsb run`` start a node with SIGINT *blocked* (:func:`block_interrupt`),
so a SIGINT that arrives during the imports stays pending instead of raising KeyboardInterrupt in the
middle of them; :func:`install_stop_handlers` unblocks it once the handlers are in place, the pending
signal sets the stop flag, and the node stops before its first step. SIGTERM is never blocked: it still
ends a node that hangs before its handlers exist (the launcher's escalation, ``PR_SET_PDEATHSIG``).

Exit codes: 0 clean (finished or stopped by a signal), 1 runtime failure, 2 bad parameters.
"""

from __future__ import annotations

import os
import signal
import sys
import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:
    from bptsb_ros.interface.params import Param

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_BAD_PARAMETERS = 2


#: a stop signal this soon [s] after the first is the same request delivered twice (group + launcher)
DUPLICATE_WINDOW = 2.0


class StopFlag:
    """Set by SIGINT/SIGTERM; ``reason`` names the signal, ``since`` is when (monotonic seconds)."""

    def __init__(self) -> None:
        self.reason: str | None = None
        self.since = 0.0
        self.duplicates = 0

    def __bool__(self) -> bool:
        return self.reason is not None

    def set(self, reason: str) -> None:
        self.reason = reason
        self.since = time.monotonic()

    def signal(self, reason: str, now: float | None = None) -> bool:
        """A stop signal arrived: True when it means "exit now" (a repeat more than ``DUPLICATE_WINDOW`` seconds
        after the first), False when it is the first or a duplicate of it (counted in ``duplicates``)."""
        now = time.monotonic() if now is None else now
        if not self:
            self.set(reason)
            self.since = now
            return False
        if now - self.since <= DUPLICATE_WINDOW:
            self.duplicates += 1
            return False
        return True


class LiveNode(Protocol):
    def run(self) -> int: ...

    def destroy_node(self) -> None: ...


STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def block_interrupt() -> None:
    """Hold SIGINT pending (the mask is inherited across exec) until :func:`unblock_interrupt`."""
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})


def unblock_interrupt() -> None:
    """Deliver a SIGINT held pending by :func:`block_interrupt` (call once the handlers are set)."""
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


def install_stop_handlers(stop: StopFlag) -> None:
    """SIGINT/SIGTERM set ``stop``; a repeat more than ``DUPLICATE_WINDOW`` s later raises KeyboardInterrupt.
    A SIGINT held pending during startup is delivered now."""

    def handler(signum: int, frame: object) -> None:
        del frame
        if stop.signal(signal.Signals(signum).name):
            raise KeyboardInterrupt

    for sig in STOP_SIGNALS:
        signal.signal(sig, handler)
    unblock_interrupt()


def node_help(name: str, params: Sequence[Param], summary: str = "") -> str:
    """``<node> --help``: usage, what the node does and every parameter with its default, whether it can be
    changed live (``ros2 param set``) and its constraints."""
    from bptsb_ros.interface.params import describe, yaml_value

    lines = [f"usage: ros2 run bptsb_ros {name} [--help] [--ros-args -p NAME:=VALUE ... "
             f"[--params-file config/{name}_params.yaml]]", ""]
    if summary:
        lines += [summary.strip().splitlines()[0], ""]
    lines.append("parameters (name: default  description):")
    for p in params:
        lines.append(f"  {p.name}: {yaml_value(p.default)}")
        lines.append(f"      {describe(p)}")
    lines += ["", "Only ROS arguments (after --ros-args) are accepted; any other argument is an error.",
              "Exit status: 0 finished or stopped by SIGINT/SIGTERM, 1 runtime failure, 2 bad parameters or "
              "arguments."]
    return "\n".join(lines)


def check_cli(name: str, argv: list[str], params: Sequence[Param], summary: str = "") -> int | None:
    """Handle the non-ROS arguments of a node's command line (``argv`` without the program name).

    ``-h``/``--help`` prints :func:`node_help` and returns 0; any other non-ROS argument is an error (message on
    stderr, returns 2); None: go on and start the node.
    """
    from rclpy._rclpy_pybind11 import RCLInvalidROSArgsError, UnknownROSArgsError
    from rclpy.utilities import remove_ros_args

    try:
        rest = remove_ros_args(args=["prog", *argv])[1:]
    except UnknownROSArgsError as err:  # e.g. --ros-args -p a:=1 --zzz: rcl's message is the list of them
        unknown = str(err).strip("[]").replace("'", "")  # rcl gives the list's repr: ['--zzz', '--y']
        print(f"{name}: unknown ROS argument(s) {unknown} after --ros-args (ROS arguments are -p NAME:=VALUE, "
              f"-r FROM:=TO, --params-file FILE, --log-level LEVEL; {name} --help lists the parameters)",
              file=sys.stderr)
        return EXIT_BAD_PARAMETERS
    except RCLInvalidROSArgsError as err:
        print(f"{name}: invalid ROS arguments: {_rcl_reason(str(err))}", file=sys.stderr)
        return EXIT_BAD_PARAMETERS
    if any(a in ("-h", "--help") for a in rest):
        print(node_help(name, params, summary))
        return EXIT_OK
    if rest:
        print(f"{name}: unrecognized argument(s) {' '.join(rest)}: node options are ROS parameters, e.g. "
              f"--ros-args -p agent:=RUN_DIR ({name} --help lists them)", file=sys.stderr)
        return EXIT_BAD_PARAMETERS
    return None


def _rcl_reason(message: str) -> str:
    """rcl's argument error without its prefix and C source locations (``…, at /src/rcl/lexer.c:239``)."""
    import re

    first = (message.strip().splitlines() or ["(no reason given)"])[0]
    first = first.removeprefix("Failed to parse ROS arguments: ")
    return re.sub(r", at [^,]*\.c:\d+", "", first) or "(no reason given)"


def run_node(name: str, factory: Callable[[StopFlag], LiveNode], args: list[str] | None = None, *,
             params: Sequence[Param] = (), summary: str = "") -> int:
    """Init rclpy with ``args`` (``--ros-args ...``; default ``sys.argv``), build the node, run it, clean up.

    ``--help`` prints ``params`` and exits 0; other non-ROS arguments exit 2 (:func:`check_cli`).
    ``factory`` raises :class:`~bptsb_ros.interface.params.ParameterError` for bad parameters (exit 2).
    """
    argv = sys.argv[1:] if args is None else list(args)
    code = check_cli(name, argv, params, summary)
    if code is not None:
        unblock_interrupt()
        return code

    import rclpy
    from rclpy.signals import SignalHandlerOptions

    from bptsb_ros.interface.params import ParameterError

    stop = StopFlag()
    install_stop_handlers(stop)
    rclpy.init(args=["bptsb", *argv], signal_handler_options=SignalHandlerOptions.NO)
    node: LiveNode | None = None
    code = EXIT_FAILURE
    try:
        try:
            node = factory(stop)
        except ParameterError as err:
            rclpy.logging.get_logger(name).error(str(err))
            code = EXIT_BAD_PARAMETERS
        else:
            code = node.run()
    except KeyboardInterrupt:
        rclpy.logging.get_logger(name).warning("interrupted twice: exiting without a clean stop")
        code = EXIT_FAILURE
    finally:
        ignore_stop_signals()  # the stop is done: a late SIGINT/SIGTERM must not turn a clean exit into a failure
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        ignore_stop_signals()  # rclpy's shutdown restored the default handlers
    if args is None:
        exit_process(code)
    return code


def ignore_stop_signals() -> None:
    """SIGINT/SIGTERM are ignored from now on (the node has stopped and is only cleaning up)."""
    for sig in STOP_SIGNALS:
        signal.signal(sig, signal.SIG_IGN)


def exit_process(code: int) -> None:
    """End a node process that has finished its work (run summary logged, bag closed, messages acknowledged) at
    once, without the interpreter's teardown of torch and the middleware: on a loaded machine that teardown takes
    seconds, beyond ``ros2 launch``'s SIGTERM escalation (5 s), which would then report a clean node as failed.
    Only for a node run as a program (``main()`` without arguments: ``ros2 run``, launch files, ``python -m``)."""
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


class Throttle:
    """Let a message through at most once per ``period`` seconds per key; count the ones held back."""

    def __init__(self, period: float = 1.0) -> None:
        self.period = period
        self._last: dict[str, float] = {}
        self._held: dict[str, int] = {}

    def __call__(self, key: str) -> tuple[bool, int]:
        """(emit now?, number of messages of this key suppressed since the last emitted one)."""
        now = time.monotonic()
        last = self._last.get(key)
        if last is not None and now - last < self.period:
            self._held[key] = self._held.get(key, 0) + 1
            return False, 0
        self._last[key] = now
        return True, self._held.pop(key, 0)


def log_line(logger: Any, level: str, text: str) -> None:
    """One line at ``level`` (error, warning, else info); one call site per severity: rclpy refuses a site whose
    severity changes."""
    if level == "error":
        logger.error(text)
    elif level == "warning":
        logger.warning(text)
    else:
        logger.info(text)


def wait_acked(logger: Any, pubs: Sequence[Any], timeout: float, setting: str = "") -> None:
    """Wait (up to ``timeout`` [s] in all; 0: not at all) until the reliable subscribers of ``pubs`` acknowledged
    every message, polling the publishers in turn, 10 ms each, so one dead subscriber cannot use up the time of the
    others; a publisher whose subscribers have all left (their process ended first) has nobody left to wait for; a
    warning names the publishers still pending (and ``setting``, the parameter that sets ``timeout``)."""
    from rclpy.duration import Duration

    started, poll = time.monotonic(), Duration(nanoseconds=10_000_000)
    pending = [pub for pub in pubs if pub.get_subscription_count() > 0] if timeout > 0 else []
    while pending and time.monotonic() < started + timeout:
        pending = [pub for pub in pending if pub.get_subscription_count() > 0 and not pub.wait_for_all_acked(poll)]
    if pending:
        limit = f"{setting} {timeout:g} s" if setting else f"limit {timeout:g} s"
        logger.warning(f"subscribers of {', '.join(pub.topic_name for pub in pending)} did not acknowledge every "
                       f"message within {time.monotonic() - started:.2f} s ({limit}); the last ones may be lost")


def make_executor(kind: str, context: Any) -> Any:
    """The executor of a live node: ``events`` (``rclpy.experimental.EventsExecutor``; a SingleThreadedExecutor where
    this rclpy has none) or ``single`` (``SingleThreadedExecutor``), on ``context``."""
    from rclpy.executors import SingleThreadedExecutor

    if kind == "events":
        try:
            from rclpy.experimental import EventsExecutor
        except ImportError:
            return SingleThreadedExecutor(context=context)
        return EventsExecutor(context=context)
    return SingleThreadedExecutor(context=context)


def executor_kind(executor: Any) -> str:
    """The ``executor`` value that names ``executor`` as :func:`make_executor` made it: ``events`` or ``single`` (what
    a node actually got, since ``events`` falls back to ``single`` where this rclpy has no EventsExecutor)."""
    return "events" if type(executor).__name__ == "EventsExecutor" else "single"
