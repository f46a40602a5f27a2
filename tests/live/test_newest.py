"""A brain that fell behind answers the newest tick only (:mod:`bptsb_ros.live.newest`), without DDS: a fake
executor holds a backlog of ``/clock`` ticks and hands over one message per ``spin_once``, as rclpy's does."""

from __future__ import annotations

from collections import deque

from bptsb_ros.live.newest import Newest, pump


class FakeExecutor:
    """Queued messages per latch; ``spin_once`` hands the oldest one to its latch (at most one per call). A latch
    None stands for another callback of the node (the sim-time clock of ``use_sim_time``: every tick twice)."""

    def __init__(self) -> None:
        self.queue: deque = deque()
        self.spins = 0

    def spin_once(self, timeout: float) -> None:
        self.spins += 1
        if self.queue:
            latch, msg = self.queue.popleft()
            if latch is not None:
                latch.offer(msg)


def test_a_backlog_of_ticks_is_answered_once_with_the_newest():
    answers: list[int] = []
    clock = Newest(answers.append)
    ex = FakeExecutor()
    for k in range(100, 277):  # 177 ticks queued: the brain is 176 steps behind; the node's time source gets them too
        ex.queue.extend([(None, k), (clock, k)])
    assert pump(ex.spin_once, [clock], 0.1) == 1
    assert answers == [276] and clock.dropped == 176 and clock.received == 177 and clock.answered == 1
    assert not ex.queue
    assert pump(ex.spin_once, [clock], 0.1) == 0 and answers == [276]  # nothing new: no answer


def test_a_brain_that_keeps_up_answers_every_tick_in_order_and_two_subscriptions_each_their_newest():
    answers: list[int] = []
    clock = Newest(answers.append)
    ex = FakeExecutor()
    for k in range(5):  # lockstep: one tick, its answer, the next tick
        ex.queue.append((clock, k))
        assert pump(ex.spin_once, [clock], 0.1) == 1
    assert answers == [0, 1, 2, 3, 4] and clock.dropped == 0
    states: list[str] = []
    state = Newest(states.append)
    ex.queue.extend([(clock, 5), (state, "s4"), (clock, 6), (state, "s5")])
    assert pump(ex.spin_once, [clock, state], 0.1) == 2
    assert answers[-1] == 6 and states == ["s5"] and clock.dropped == 1 and state.dropped == 1
