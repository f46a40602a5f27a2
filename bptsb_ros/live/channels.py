"""Command intake of the body simulator (ROS-free): validation, per-step buffering and selection.

Protocol (see ``TOPICS.md``): the body publishes ``/clock`` = t_k right before it integrates step k;
every command is stamped with the sim time of the step it is *in force at*. Time-driven brains (SWG,
task input → MLP) answer ``/clock`` t_k with the command for step k; the feedback brain answers the
body state of step k−1 with the command for step k.

A :class:`CommandChannel` holds one command kind (rest lengths or forces):

* ``lockstep``: commands are buffered by step; the body takes exactly the command for the step it
  integrates. A command for a step already integrated is *stale*.
* ``realtime``: the body takes the newest command; one older than the newest accepted, or older
  than ``max_age_steps`` when it arrives or is used, is *stale*.

Wrong-length, non-finite and out-of-bounds commands (``bounds``, see ``bptsb_ros.live.safety``) are rejected in
both modes, and so is a command stamped more than ``max_ahead`` steps after the next step (a node cannot
claim future steps before the brain answers them). Rejected commands never reach the
integrator; :meth:`CommandChannel.offer` returns a :class:`Rejection` so the node can log it.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

Mode = Literal["lockstep", "realtime"]
MODES: tuple[str, ...] = ("lockstep", "realtime")
REJECT_REASONS: tuple[str, ...] = ("wrong_length", "wrong_names", "non_finite", "out_of_bounds", "stale", "duplicate",
                                   "too_far_ahead", "untrusted_publisher", "queue_full", "off_schedule")


@dataclass(frozen=True)
class Rejection:
    """Why a command was rejected: ``reason`` (one of REJECT_REASONS) and a one-line ``message``."""

    reason: str
    message: str


@dataclass
class Command:
    """A validated command: the step it is in force at, its values (float64, flat) and arrival time [s, monotonic]."""

    step: int
    values: np.ndarray
    received: float


@dataclass
class CommandChannel:
    """Validated commands of one kind for the body.

    Attributes:
        name: ``rest_length`` or ``force`` (used in log lines).
        size: expected number of values (E springs, or 2·M force components).
        names: expected joint names (an empty name list in a message is accepted too).
        mode: ``lockstep`` or ``realtime``.
        max_ahead: furthest step ahead of the next one a command may be stamped for (both modes).
        max_age_steps: realtime: oldest usable command, in steps behind the step being integrated.
        bounds: physical check of finite values: returns why they are out of bounds, or None.
        surely_within: a quick test of the values (True: all finite and within bounds, so neither check can reject
            them; False: run both checks); None: always run them.
        every: commands are taken only for steps k with k % every == 0 (1: every step; 0: none, the source is
            off); one stamped for another step is rejected (``off_schedule``). The body's resets use it.
    """

    name: str
    size: int
    names: list[str]
    mode: Mode
    max_ahead: int = 1
    max_age_steps: int = 10
    bounds: Callable[[np.ndarray], str | None] | None = None
    surely_within: Callable[[np.ndarray], bool] | None = None
    every: int = 1
    pending: dict[int, Command] = field(default_factory=dict)
    latest: Command | None = None
    accepted: int = 0
    rejected: Counter = field(default_factory=Counter)
    last_received: float | None = None

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {self.mode!r}")
        if self.size <= 0:
            raise ValueError(f"channel {self.name}: size must be positive, got {self.size}")
        if self.every < 0:
            raise ValueError(f"channel {self.name}: every must be >= 0, got {self.every}")

    def offer(self, step: int, values: np.ndarray, next_step: int, now: float,
              names: list[str] | None = None) -> Rejection | None:
        """Validate a command for ``step``; store it or return why it was rejected.

        Args:
            step: step index the command is in force at (from its stamp).
            values: the command values (any float sequence; converted to float64).
            next_step: the step the body integrates next (lockstep: the one it waits for).
            now: arrival time [s] on a monotonic clock.
            names: joint names carried by the message (None or empty: not checked).

        Returns:
            None if accepted, else the :class:`Rejection` (also counted).
        """
        vals = np.asarray(values, dtype=np.float64).reshape(-1)
        reason = self._check(step, vals, next_step, names)
        if reason is not None:
            return reason
        cmd = Command(step, vals.copy(), now)
        self.accepted += 1
        self.last_received = now
        if self.mode == "lockstep":
            self.pending[step] = cmd
        else:
            self.latest = cmd
        return None

    def _check(self, step: int, vals: np.ndarray, next_step: int, names: list[str] | None) -> Rejection | None:
        what = f"{self.name} command for step {step}"
        if vals.size != self.size:
            return self._reject("wrong_length", f"{what}: {vals.size} values, expected {self.size}")
        if names and list(names) != self.names:
            return self._reject("wrong_names", f"{what}: joint names do not match the body's ({self.names[0]}, …)")
        if self.surely_within is None or not self.surely_within(vals):
            bad = np.flatnonzero(~np.isfinite(vals))
            if bad.size:
                return self._reject("non_finite", f"{what}: NaN/inf at index {int(bad[0])} ({bad.size} value(s))")
            problem = self.bounds(vals) if self.bounds is not None else None
            if problem:
                return self._reject("out_of_bounds", f"{what}: {problem}")
        if not self.due(step):
            rule = f"only steps that are multiples of {self.every}" if self.every else "none: the source is off"
            return self._reject("off_schedule", f"{what}: this channel takes {rule}")
        if step > next_step + self.max_ahead:
            return self._reject("too_far_ahead", f"{what}: more than {self.max_ahead} step(s) ahead of {next_step}")
        if self.mode == "lockstep":
            if step < next_step:
                return self._reject("stale", f"{what} arrived after that step was integrated (next step {next_step})")
            if step in self.pending:
                return self._reject("duplicate", f"{what}: a command for that step is already queued")
        else:
            if self.latest is not None and step <= self.latest.step:
                return self._reject("stale", f"{what}: not newer than the latest ({self.latest.step})")
            if next_step - step > self.max_age_steps:
                return self._reject("stale", f"{what}: {next_step - step} steps old (max {self.max_age_steps})")
        return None

    def reject(self, step: int, reason: str, message: str) -> Rejection:
        """Reject (and count) a command for ``step`` for a reason found outside the channel (e.g. its sender)."""
        return self._reject(reason, f"{self.name} command for step {step}: {message}")

    def _reject(self, reason: str, message: str) -> Rejection:
        self.rejected[reason] += 1
        return Rejection(reason, f"rejected {message}")

    def due(self, step: int) -> bool:
        """Whether a command for ``step`` is on this channel's schedule (``every``)."""
        return self.every > 0 and step % self.every == 0

    def has(self, step: int) -> bool:
        """Lockstep: a command for ``step`` is queued. Realtime: a usable newest command exists."""
        if self.mode == "lockstep":
            return step in self.pending
        return self.latest is not None and step - self.latest.step <= self.max_age_steps

    def take(self, step: int) -> Command | None:
        """The command in force at ``step`` (lockstep: removed from the queue, older ones dropped), or None."""
        if self.mode == "lockstep":
            cmd = self.pending.pop(step, None)
            for old in [s for s in self.pending if s < step]:
                del self.pending[old]
            return cmd
        return self.latest if self.has(step) else None

    def counts(self) -> dict[str, int]:
        """Accepted and rejected counts by reason (every reason present)."""
        out = {"accepted": self.accepted}
        out.update({f"rejected_{r}": int(self.rejected[r]) for r in REJECT_REASONS})
        return out


#: Number of most recent samples the percentiles (p50, p99) of a timing series are computed over.
PERCENTILE_WINDOW = 10_000


class RunningStats:
    """A series summarized in bounded memory: count, mean and max over every sample, and the last ``window``
    samples for percentiles (a realtime run can last for hours; the node summarizes it every second). The window is
    a numpy ring buffer, so that a summary costs a partition, not a conversion of 10,000 Python floats (a 1 kHz
    body summarizes between two steps).
    """

    def __init__(self, values: Iterable[float] = (), window: int = PERCENTILE_WINDOW) -> None:
        if window < 1:
            raise ValueError(f"window must be >= 1, got {window}")
        self.count = 0
        self.total = 0.0
        self.max = -math.inf
        self._ring = np.empty(window, dtype=np.float64)
        self._next = 0
        for value in values:
            self.append(value)

    def append(self, value: float) -> None:
        value = float(value)
        self.count += 1
        self.total += value
        if value > self.max:
            self.max = value
        self._ring[self._next] = value
        self._next = (self._next + 1) % self._ring.size

    @property
    def recent(self) -> np.ndarray:
        """The last ``window`` samples, oldest first (a copy)."""
        n = min(self.count, self._ring.size)
        if n < self._ring.size:
            return self._ring[:n].copy()
        return np.concatenate([self._ring[self._next:], self._ring[:self._next]])

    def __len__(self) -> int:
        return self.count

    @property
    def mean(self) -> float:
        return self.total / self.count if self.count else 0.0

    def percentile(self, q: float) -> float:
        """The ``q``-th percentile of the last ``window`` samples (0.0 when empty)."""
        return self.percentiles((q,))[0]

    def percentiles(self, qs: Sequence[float]) -> list[float]:
        """The ``qs``-th percentiles of the last ``window`` samples, in one partition (0.0 each when empty)."""
        n = min(self.count, self._ring.size)
        if not n:
            return [0.0] * len(qs)
        return [float(v) for v in np.percentile(self._ring[:n], list(qs))]


@dataclass
class TimingStats:
    """Loop timing of the body: jitter, deadline misses, command age and latency.

    jitter: actual start of a step minus its scheduled wall time [s] (realtime only).
    deadline miss: a step finished after the next step's scheduled start (realtime only).
    compute: wall time to integrate and publish one step [s].
    command age: steps between the step integrated and the stamp of the command used.
    command latency: wall time from publishing ``/clock`` t_k to receiving the command for step k [s],
    always measured from ``/clock``, also for the feedback brain (triggered by the state of step k−1, published
    before ``/clock`` t_k): its commands that arrive before ``/clock`` t_k was published are not counted.

    Each series is a :class:`RunningStats` (a list given to the constructor is converted): mean and max cover
    the whole run, p50 and p99 the last :data:`PERCENTILE_WINDOW` samples.
    """

    jitter: RunningStats = field(default_factory=RunningStats)
    compute: RunningStats = field(default_factory=RunningStats)
    age: RunningStats = field(default_factory=RunningStats)
    latency: RunningStats = field(default_factory=RunningStats)
    deadline_misses: int = 0
    safe_steps: int = 0
    steps: int = 0

    def __post_init__(self) -> None:
        for name in ("jitter", "compute", "age", "latency"):
            value = getattr(self, name)
            if not isinstance(value, RunningStats):
                setattr(self, name, RunningStats(value))

    def summary(self) -> dict[str, float | int]:
        """Counts and mean/p50/p99/max of each series (milliseconds for times, steps for ages); the
        percentiles are over the last :data:`PERCENTILE_WINDOW` samples of a series."""
        out: dict[str, float | int] = {
            "steps": self.steps, "deadline_misses": self.deadline_misses, "safe_command_steps": self.safe_steps,
        }
        for key, series, scale in (("jitter_ms", self.jitter, 1e3), ("compute_ms", self.compute, 1e3),
                                   ("command_latency_ms", self.latency, 1e3), ("command_age_steps", self.age, 1.0)):
            if not series.count:
                continue
            p50, p99 = series.percentiles((50, 99))
            out[f"{key}_mean"] = series.mean * scale
            out[f"{key}_p50"] = p50 * scale
            out[f"{key}_p99"] = p99 * scale
            out[f"{key}_max"] = series.max * scale
        return out
