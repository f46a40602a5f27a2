"""The live body without DDS, shared by the tests of its rules and of what is built on them (``test_live_core.py``,
``test_sim_control.py``, ``test_live_speed.py``, ``test_realtime_bench.py``): the fresh float64 Lissajous agent a
node builds from default parameters, a :class:`BodyCore` of given parameters, a fake port with a fake clock that
drives :class:`BodyLoop`, and the offline steps of the same body."""

from __future__ import annotations

import heapq
import itertools

import numpy as np
import torch

from bptsb_ros.interface.params import validate_values
from bptsb_ros.interface.source import SOURCE_PARAMS
from bptsb_ros.live.agent_source import load_source
from bptsb_ros.live.body_core import BodyCore
from bptsb_ros.live.body_params import PARAMS

_AGENT = {}


def agent():
    """The fresh float64 lissajous agent a node builds from default parameters (48 springs, 13 movable masses)."""
    if "a" not in _AGENT:
        values = {p.name: p.default for p in SOURCE_PARAMS}
        values.update(task="lissajous", seed=0)
        _AGENT["a"] = load_source(values)[0]
    return _AGENT["a"]


def core(**params) -> BodyCore:
    p = validate_values(PARAMS, {"task": "lissajous", **params})
    return BodyCore(agent(), p, clock=lambda: 0.0)


BASE = agent().body.l.numpy().copy()
E = BASE.size


class FakePort:
    """A fake clock and message queue: ``brain(port, step)`` answers ``/clock`` t_k by :meth:`send`; a message is
    handled when the loop spins past its arrival time. ``cost``: wall seconds each published step takes."""

    def __init__(self, core: BodyCore, brain=None, cost: float = 0.0, stop_at: float = np.inf) -> None:
        self.core, self.brain, self.cost, self.stop_at = core, brain, cost, stop_at
        self.t, self.inbox, self.seq = 0.0, [], itertools.count()
        self.outputs, self.clocks, self.logs, self.gone = [], [], [], set()
        self.viewed = []  # the steps whose viewers' topics went out

    def send(self, delay: float, fn) -> None:
        heapq.heappush(self.inbox, (self.t + delay, next(self.seq), fn))

    def _deliver(self, until: float) -> bool:
        if self.inbox and self.inbox[0][0] <= until:
            at, _, fn = heapq.heappop(self.inbox)
            self.t = max(self.t, at)
            fn()
            return True
        return False

    def stopped(self) -> bool:
        return self.t >= self.stop_at

    def now(self) -> float:
        return self.t

    def spin_once(self, timeout: float) -> None:
        if not self._deliver(self.t + timeout):
            self.t += timeout

    def drain(self) -> None:
        while self._deliver(self.t):
            pass

    def publisher_gone(self, source: str) -> bool:
        return source in self.gone

    def topic(self, source: str) -> str:
        return f"/{source}"

    def announce(self, step: int) -> None:
        self.clocks.append(step)
        if self.brain:
            self.brain(self, step)

    def publish(self, out, views: bool = True) -> None:
        self.outputs.append(out)
        self.t += self.cost
        self.viewed += [out.state.step] if views else []

    def publish_views(self, out) -> None:
        self.viewed.append(out.state.step)

    def diagnostics(self, slack: float = float("inf")) -> None:
        pass

    def log(self, level: str, text: str) -> None:
        self.logs.append((level, text))


def offline(rests: list[np.ndarray]) -> list[np.ndarray]:
    """Positions (M, 2) of the body stepped with these rest lengths, written out with MSDN directly."""
    body, out, state = agent().body, [], None
    with torch.no_grad():
        for rest in rests:
            r = torch.from_numpy(rest)
            state = body.initial_state(1, rest_length=r) if state is None else body.step(state, rest_length=r)
            out.append(state.r[0].numpy().copy())
    return out


RESTS = [BASE * (1 + 0.02 * np.sin(0.3 * k + np.arange(E))) for k in range(21)]
