"""Process lifecycle shared by every live node: rclpy init, clean stop on SIGINT/SIGTERM, exit codes.

rclpy's own signal handlers shut the context down at once, after which a node can no longer publish
its last diagnostics or wait for its messages to be acknowledged. The nodes therefore install their
own handlers: the first SIGINT/SIGTERM sets a stop flag that the node's loop polls (at least every
0.1 s), a second one raises KeyboardInterrupt.

A Ctrl-C while the process is still starting (importing torch and rclpy, loading the agent) is a clean
stop too: ``bptsb launch`` and ``bptsb run`` start a node with SIGINT *blocked* (:func:`block_interrupt`),
so a SIGINT that arrives during the imports stays pending instead of raising KeyboardInterrupt in the
middle of them; :func:`install_stop_handlers` unblocks it once the handlers are in place, the pending
signal sets the stop flag, and the node stops before its first step. SIGTERM is never blocked: it still
ends a node that hangs before its handlers exist (the launcher's escalation, ``PR_SET_PDEATHSIG``).

Exit codes: 0 clean (finished or stopped by a signal), 1 runtime failure, 2 bad parameters.
"""

from __future__ import annotations

import signal
import sys
import time
from collections.abc import Callable
from typing import Protocol

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_BAD_PARAMETERS = 2


class StopFlag:
    """Set by SIGINT/SIGTERM; ``reason`` names the signal."""

    def __init__(self) -> None:
        self.reason: str | None = None

    def __bool__(self) -> bool:
        return self.reason is not None

    def set(self, reason: str) -> None:
        self.reason = reason


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
    """SIGINT/SIGTERM set ``stop``; a second signal raises KeyboardInterrupt. A SIGINT held pending during
    startup is delivered now."""

    def handler(signum: int, frame: object) -> None:
        del frame
        if stop:
            raise KeyboardInterrupt
        stop.set(signal.Signals(signum).name)

    for sig in STOP_SIGNALS:
        signal.signal(sig, handler)
    unblock_interrupt()


def run_node(name: str, factory: Callable[[StopFlag], LiveNode], args: list[str] | None = None) -> int:
    """Init rclpy with ``args`` (``--ros-args ...``; default ``sys.argv``), build the node, run it, clean up.

    ``factory`` raises :class:`~bptsb_ros.ros.params.ParameterError` for bad parameters (exit 2).
    """
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    from bptsb_ros.ros.params import ParameterError

    stop = StopFlag()
    install_stop_handlers(stop)
    rclpy.init(args=sys.argv if args is None else ["bptsb", *args],
               signal_handler_options=SignalHandlerOptions.NO)
    node: LiveNode | None = None
    try:
        try:
            node = factory(stop)
        except ParameterError as err:
            rclpy.logging.get_logger(name).error(str(err))
            return EXIT_BAD_PARAMETERS
        return node.run()
    except KeyboardInterrupt:
        rclpy.logging.get_logger(name).warning("interrupted twice: exiting without a clean stop")
        return EXIT_FAILURE
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()


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
