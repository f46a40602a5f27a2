"""Simulator controls of the live body, ROS-free: pause, resume, step N while paused, reset to the layout.

``body_sim`` offers them as ``std_srvs/srv/Trigger`` services (``~/pause``, ``~/resume``, ``~/step``,
``~/reset``) and hands each call to :meth:`SimControl.call`; :class:`~bptsb_ros.live.body_loop.BodyLoop` asks
:meth:`SimControl.holding` at every step boundary. The semantics, the same in both timing modes:

* ``pause``: the body finishes the step it is integrating and takes no further step; it keeps handling messages
  (commands that arrive are queued or kept as the newest, as usual) and publishing ``/diagnostics``. Lockstep:
  no further ``/clock`` goes out, so ``/clock`` and the last published state name the same step. Realtime: the
  ``/clock`` of the next step is already out (brains compute during the period), the body holds before
  integrating it; the schedule is shifted by the paused time (no burst of catch-up steps, no deadline misses).
* ``resume``: stepping goes on from the next step (also ends a ``step`` in progress).
* ``step`` (only while paused): advance ``n`` steps (the node's ``step_count`` parameter), each exactly as an
  unpaused step (lockstep: announced, its commands awaited; realtime: at the realtime pace), then hold again.
  A new ``step`` call while steps are left replaces what is left with ``n``.
* ``reset``: the next step the body takes is the body at rest at its layout (``MSDN.initial_state`` with that
  step's rest lengths and force; the state of that step, not integrated), as a ``body/reset`` with zero
  displacement. Sim time goes on (``/clock`` never goes back: brains, recorders and bags would see time jump
  back). While paused the reset shows at the next ``step`` or ``resume``.

Every call is answered (``success``, ``message``) and reported as a :class:`ControlCall` to ``sink`` — the node
publishes it on ``/diagnostics`` (status ``<node>: control``), so a bag records what was called, at which step and
by whom (``callers``: the nodes that had a client of the service when it was called; the middleware does not say
which of them sent a request, so all are named). The callers are held to the body's command-source rule
(``control_callers``, :class:`~bptsb_ros.live.safety.PublisherRule`): while a node not allowed has a client of a
service, every call of it is refused (``untrusted``), as a command is rejected while a foreign node publishes on
its topic.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

#: the calls :meth:`SimControl.call` takes (the services of ``body_sim``)
CALLS: tuple[str, ...] = ("pause", "resume", "step", "reset")


@dataclass(frozen=True)
class ControlCall:
    """One call: its ``name``, the last integrated ``step`` when it was handled (-1: none yet), the wall time
    ``wall`` [s since the epoch], whether it was accepted (``ok``), the answer text, and the state after it."""

    name: str
    step: int
    wall: float
    ok: bool
    message: str
    paused: bool
    steps_left: int
    callers: tuple[str, ...] = ()
    untrusted: tuple[str, ...] = ()

    def values(self) -> list[tuple[str, str]]:
        """Key/value texts of the call (the control diagnostic's values; ``callers`` and ``untrusted_callers``:
        fully qualified node names, comma-separated)."""
        return [("call", self.name), ("step", str(self.step)), ("wall_time", f"{self.wall:.6f}"),
                ("accepted", str(self.ok)), ("paused", str(self.paused)), ("steps_left", str(self.steps_left)),
                ("callers", ", ".join(self.callers)), ("untrusted_callers", ", ".join(self.untrusted))]


class SimControl:
    """Pause, resume, step and reset requests of one live body (see the module docstring).

    Args:
        paused: start paused (the first step waits for ``resume`` or ``step``).
        sink: receives every :class:`ControlCall` (default: kept in :attr:`calls`).
        clock: wall time [s since the epoch] of a call.
    """

    def __init__(self, paused: bool = False, sink: Callable[[ControlCall], None] | None = None,
                 clock: Callable[[], float] = time.time) -> None:
        self.paused = paused
        self.steps_left = 0
        self.reset_pending = False
        self.last_step = -1  # the last integrated step
        self.count = 0
        self.refused = 0  # calls refused for untrusted callers
        self.calls: list[ControlCall] = []
        self.sink = sink or self.calls.append
        self.clock = clock

    def call(self, name: str, n: int = 1, callers: tuple[str, ...] = (),
             untrusted: tuple[str, ...] = ()) -> tuple[bool, str]:
        """Handle the call ``name`` (one of :data:`CALLS`; ``step``: ``n`` >= 1 steps) made while ``callers`` had
        clients of the service, of which ``untrusted`` are not allowed (then it is refused); returns (accepted,
        answer)."""
        at = f"after step {self.last_step}" if self.last_step >= 0 else "before the first step"
        if name not in CALLS:
            raise ValueError(f"unknown control call {name!r}: expected one of {', '.join(CALLS)}")
        if untrusted:
            ok, text = False, (f"refused: ~/{name} has client(s) not in control_callers ({', '.join(untrusted)}); "
                               f"{'paused' if self.paused else 'running'} {at}")
            self.refused += 1
        elif name == "pause":
            ok, text = True, f"paused {at}" if not self.paused else f"already paused {at}"
            self.paused, self.steps_left = True, 0
        elif name == "resume":
            ok, text = True, f"resumed {at}" if self.paused else f"not paused ({at}); running"
            self.paused, self.steps_left = False, 0
        elif name == "step":
            if not self.paused:
                ok, text = False, f"refused: step needs a paused body (call pause first); running {at}"
            elif n < 1:
                ok, text = False, f"refused: step_count must be >= 1, got {n}"
            else:
                ok, text = True, f"stepping {n} step(s) {at}, then paused again"
                self.steps_left = n
        else:  # reset
            ok, text = True, f"the next step is the body at rest at its layout (requested {at})"
            self.reset_pending = True
        self.count += 1
        self.sink(ControlCall(name, self.last_step, self.clock(), ok, text, self.paused, self.steps_left,
                              tuple(callers), tuple(untrusted)))
        return ok, text

    def holding(self) -> bool:
        """Whether the body must not take its next step now (paused, and no ``step`` left)."""
        return self.paused and self.steps_left == 0

    def stepped(self, step: int) -> None:
        """The body integrated ``step`` (a paused body spent one of its ``step`` steps)."""
        self.last_step = step
        if self.paused and self.steps_left:
            self.steps_left -= 1

    def take_reset(self) -> bool:
        """Whether a ``reset`` call waits for the step being integrated now (then it is used up)."""
        pending, self.reset_pending = self.reset_pending, False
        return pending
