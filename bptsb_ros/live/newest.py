"""Answer the newest message, drop the backlog: how a brain keeps up, ROS-free.

A brain answers ``/clock`` ticks (or body states) with the command for their step. When it falls behind —
a slow compute, a busy CPU, a realtime body at a high ``rate_scale`` — ticks queue up in its subscription, and
answering them in order keeps it behind for good: each answer is for a step the body has already integrated
(lockstep: rejected as ``stale``; realtime: older than the newest). So a brain node hands every arriving message
to a :class:`Newest` latch, handles everything that is ready (:func:`pump`), and then answers only the newest
message of each latch; the ones it replaced are counted as ``dropped``. A brain that keeps up (every lockstep
run: the body announces one tick and waits for its answer) drops nothing and answers every tick, in order.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any


@dataclass
class Newest:
    """The newest unanswered message of one subscription; ``handler`` answers it.

    Attributes:
        received: messages offered.
        answered: messages handed to ``handler``.
        dropped: messages replaced by a newer one before they were answered.
    """

    handler: Callable[[Any], None]
    pending: Any = None
    has_pending: bool = False
    received: int = 0
    answered: int = 0
    dropped: int = 0

    def offer(self, msg: Any) -> None:
        """A message arrived: it replaces (drops) the one still unanswered."""
        self.received += 1
        if self.has_pending:
            self.dropped += 1
        self.pending, self.has_pending = msg, True

    def answer(self) -> bool:
        """Hand the pending message to ``handler``; False if none was pending."""
        if not self.has_pending:
            return False
        msg, self.pending, self.has_pending = self.pending, None, False
        self.answered += 1
        self.handler(msg)
        return True


#: zero-timeout spins in a row that bring the latches nothing before a turn answers (other callbacks of the node,
#: such as the sim-time clock subscription of ``use_sim_time``, take turns with the latches' messages)
IDLE_SPINS = 2


def pump(spin_once: Callable[[float], None], latches: Sequence[Newest], timeout: float,
         idle_spins: int = IDLE_SPINS) -> int:
    """One turn of a brain's loop: wait up to ``timeout`` [s] for a message (``spin_once(timeout)`` handles at most
    one), then handle every message that is ready (``spin_once(0.0)`` until ``idle_spins`` in a row bring the
    latches no message: 1 is enough for a node whose every subscription feeds a latch), then answer the newest
    message of each latch. Returns the number of answers."""
    spin_once(timeout)
    before, idle = sum(latch.received for latch in latches), 0
    while idle < idle_spins:
        spin_once(0.0)
        now = sum(latch.received for latch in latches)
        idle, before = (idle + 1 if now == before else 0), now
    return sum(latch.answer() for latch in latches)
