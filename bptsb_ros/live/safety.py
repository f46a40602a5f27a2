"""Safety rules of the live body (ROS-free): physical bounds on commands, the rule for who may command the
body, and recovery when the live simulation diverges anyway. ``body_sim`` calls these; they hold no ROS.

* :class:`CommandLimits` — rest lengths in (``min_rest_length``, ``max_rest_length``] (the lower bound is 0
  unless the agent's own SWG commands rest lengths <= 0, see :func:`rest_length_floor`), every force
  component and wind component within ±``max_force`` / ±``max_wind`` [N]. A command outside is rejected
  (``out_of_bounds``), never integrated, and counted like the other rejections (wind included).
* :class:`PublisherRule` — commands are accepted only while every publisher on the command topic is a node
  named in ``command_publishers`` (default: this package's brains for that topic). DDS gives a subscriber
  no sender identity per message, so while any other node publishes on the topic, every command on it is
  rejected (``untrusted_publisher``) and the body runs on the safe command: an intruder can stop the brain
  from steering, never steer itself. Node names can be forged by anyone on the domain; SROS2 (DDS security)
  is what authenticates publishers (see docs/ros/security.md).
* :class:`DivergenceRecovery` — when a step diverges (non-finite or runaway state), either restore the last
  good state and integrate the step with the safe command (``restore``; if that diverges too, the body is put
  back to its initial layout at rest; if even that diverges, the run stops) or stop the run cleanly
  (``stop``). The node finishes its bag either way: nothing recorded is lost.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Generic, Literal, TypeVar

import numpy as np

from bptsb_ros.interface.nodes import command_publishers

#: Brains of this package that publish each command source (the default ``command_publishers``), from the node
#: table (:data:`bptsb_ros.interface.nodes.NODES`, each node's ``commands``).
DEFAULT_PUBLISHERS: dict[str, tuple[str, ...]] = command_publishers()
#: Default publishers allowed to perturb the body (``perturb_publishers``): any node. A perturbation is a test the
#: user runs (``ros2 topic pub``, a script), bounded by ``max_displacement``; list node names to restrict it.
DEFAULT_PERTURB_PUBLISHERS: tuple[str, ...] = ("*",)
#: who may call the body's simulator services by default: the node ``ros2 service call`` creates for a
#: ``std_srvs/srv/Trigger`` (``_ros2cli_requester_<package>_<service type>``)
DEFAULT_CONTROL_CALLERS: tuple[str, ...] = ("_ros2cli_requester_std_srvs_Trigger",)
#: ``command_publishers`` entry that accepts commands from any node (not for a shared network).
ANY_PUBLISHER = "*"
#: Default limits [N] of a force-command component and of a wind component.
DEFAULT_MAX_FORCE = 1.0e4
DEFAULT_MAX_WIND = 1.0e3
#: The default ``max_rest_length`` is this many times the layout's size (:func:`body_extent`).
REST_LENGTH_EXTENT_FACTOR = 10.0

DivergencePolicy = Literal["restore", "stop"]
DIVERGENCE_POLICIES: tuple[str, ...] = ("restore", "stop")


def body_extent(positions: np.ndarray) -> float:
    """Size of a layout (N, 2) [m]: the diagonal of its bounding box (at least the largest distance between two
    masses)."""
    span = np.ptp(np.asarray(positions, dtype=np.float64), axis=0)
    return float(np.hypot(*span)) or 1.0


def rest_length_floor(rest: np.ndarray, amplitude: np.ndarray | None) -> float:
    """Default lower bound [m] of rest-length commands for an agent with trained rest lengths ``rest`` (E,) and
    SWG amplitudes ``amplitude`` (E,) (None: no SWG).

    0 (commands must be positive) unless the SWG itself commands rest lengths <= 0: l·(1 + A sin) reaches
    l·(1 − |A|) < 0 when |A| > 1, which the paper's model (and BPTSB training) allows. Then the bound is that
    lowest SWG rest length minus one full swing max(l·|A|), room for the feedback layer that replaces the SWG.
    """
    if amplitude is None:
        return 0.0
    rest, amp = np.asarray(rest, dtype=np.float64), np.abs(np.asarray(amplitude, dtype=np.float64))
    lowest = float((rest * (1.0 - amp)).min())
    return 0.0 if lowest > 0 else lowest - float((rest * amp).max())


@dataclass(frozen=True)
class CommandLimits:
    """Physical bounds of commands: rest lengths in (min_rest_length, max_rest_length] [m], |force component| <=
    max_force [N], |wind component| <= max_wind [N], |displacement component| of a perturbation <=
    max_displacement [m], and the length of each mass's reset displacement (x, y) at most max_displacement
    (``for_body``: the body's extent; a body released from farther away than its own size is no drawing, only a
    numerical risk)."""

    max_rest_length: float
    max_force: float = DEFAULT_MAX_FORCE
    max_wind: float = DEFAULT_MAX_WIND
    min_rest_length: float = 0.0
    max_displacement: float = math.inf

    def __post_init__(self) -> None:
        for name in ("max_rest_length", "max_force", "max_wind"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be finite and > 0, got {value}")
        if not (np.isfinite(self.min_rest_length) and self.min_rest_length < self.max_rest_length):
            raise ValueError(f"min_rest_length must be finite and below max_rest_length, got {self.min_rest_length}")

    @classmethod
    def for_body(cls, positions: np.ndarray, max_rest_length: float = 0.0, max_force: float = DEFAULT_MAX_FORCE,
                 max_wind: float = DEFAULT_MAX_WIND, min_rest_length: float = 0.0) -> CommandLimits:
        """Limits for a body with layout ``positions`` (N, 2); ``max_rest_length`` 0 means
        ``REST_LENGTH_EXTENT_FACTOR`` × its extent."""
        limit = max_rest_length or REST_LENGTH_EXTENT_FACTOR * body_extent(positions)
        return cls(float(limit), float(max_force), float(max_wind), float(min_rest_length),
                   max_displacement=body_extent(positions))

    def surely_within(self, source: str, values: np.ndarray) -> bool:
        """True when float64 ``values`` of command ``source`` are all finite and within bounds, decided by two
        reductions (a NaN makes min and max NaN, and every comparison with NaN is False); False means "look closer"
        (:meth:`check` and the finiteness test say why, if anything is wrong). Resets are always looked at closer."""
        if source == "rest_length":
            lo, lo_open, hi = self.min_rest_length, True, self.max_rest_length
        elif source in ("force", "wind"):
            hi = self.max_force if source == "force" else self.max_wind
            lo, lo_open = -hi, False
        else:
            return False
        low, high = values.min(), values.max()
        return bool((low > lo if lo_open else low >= lo) and high <= hi)

    def check(self, source: str, values: np.ndarray) -> str | None:
        """Why finite ``values`` of command ``source`` (rest_length, force, wind, perturbation or reset) are out of
        bounds, or None."""
        vals = np.asarray(values, dtype=np.float64).reshape(-1)
        if source == "reset":  # (x, y) displacement per movable mass
            norm = np.hypot(vals[0::2], vals[1::2])
            far = np.flatnonzero(norm > self.max_displacement)
            if not far.size:
                return None
            return (f"displacement of {norm[far[0]]:.6g} m of movable mass {int(far[0])} beyond "
                    f"{self.max_displacement:g} m ({far.size} mass(es) out of bounds)")
        if source == "perturbation":
            bad = np.flatnonzero(np.abs(vals) > self.max_displacement)
            bound = f"[-{self.max_displacement:g}, {self.max_displacement:g}] m (the body's extent)"
        elif source == "rest_length":
            bad = np.flatnonzero((vals <= self.min_rest_length) | (vals > self.max_rest_length))
            bound = f"({self.min_rest_length:g}, {self.max_rest_length:g}] m"
        else:
            limit = self.max_force if source == "force" else self.max_wind
            bad = np.flatnonzero(np.abs(vals) > limit)
            bound = f"[-{limit:g}, {limit:g}] N"
        if not bad.size:
            return None
        i = int(bad[0])
        return f"value {vals[i]:.6g} at index {i} outside {bound} ({bad.size} value(s) out of bounds)"


@dataclass
class PublisherRule:
    """Which nodes may publish a command source. ``allowed``: node names (``name``, or ``/namespace/name`` to
    pin the namespace); ``*`` allows any node; empty: :data:`DEFAULT_PUBLISHERS` of the source."""

    source: str
    allowed: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if not self.allowed:
            self.allowed = DEFAULT_PUBLISHERS.get(self.source, ())

    def untrusted(self, publishers: Iterable[tuple[str, str]]) -> list[str]:
        """Fully qualified names of the publishers ``(namespace, name)`` that are not allowed (sorted)."""
        if ANY_PUBLISHER in self.allowed:
            return []
        out = set()
        for namespace, name in publishers:
            full = f"{namespace.rstrip('/')}/{name}"
            if name not in self.allowed and full not in self.allowed:
                out.add(full)
        return sorted(out)


@dataclass
class WindIntake:
    """Validation and counts of wind messages [N] (x, y): non-finite or out-of-bounds ones are rejected."""

    limits: CommandLimits
    accepted: int = 0
    rejected: Counter = field(default_factory=Counter)

    def offer(self, wind: np.ndarray, untrusted: Sequence[str] = (), topic: str = "env/wind") -> str | None:
        """None if ``wind`` is accepted, else the rejection message (counted by reason); ``untrusted``: publishers
        on its topic that the publisher rule does not allow (then every wind on it is rejected)."""
        wind = np.asarray(wind, dtype=np.float64)
        if untrusted:
            self.rejected["untrusted_publisher"] += 1
            return (f"rejected wind {wind.tolist()}: {topic} has publisher(s) not in command_publishers "
                    f"({', '.join(untrusted)})")
        if not np.isfinite(wind).all():
            self.rejected["non_finite"] += 1
            return f"rejected wind {wind.tolist()}: NaN/inf"
        problem = self.limits.check("wind", wind)
        if problem:
            self.rejected["out_of_bounds"] += 1
            return f"rejected wind {wind.tolist()}: {problem}"
        self.accepted += 1
        return None

    def counts(self) -> dict[str, int]:
        return {"accepted": self.accepted, "rejected_non_finite": int(self.rejected["non_finite"]),
                "rejected_out_of_bounds": int(self.rejected["out_of_bounds"]),
                "rejected_untrusted_publisher": int(self.rejected["untrusted_publisher"])}


def runaway(v: np.ndarray, a: np.ndarray, dt: float, limit: float = 1e6) -> str | None:
    """Why a finite state will leave a ``limit`` [m] box within one step (|v|·dt or |a|·dt² beyond it), or None.

    A command that overwhelms the springs shows up in positions only a step later; judging the state that
    received it by its velocity and acceleration keeps the last good state good.
    """
    speed, accel = float(np.abs(v).max(initial=0.0)), float(np.abs(a).max(initial=0.0))
    if speed * dt > limit or accel * dt * dt > limit:
        return f"|v| = {speed:.3g} m/s, |a| = {accel:.3g} m/s² would move a mass beyond {limit:g} m within one step"
    return None


State = TypeVar("State")


@dataclass
class DivergenceRecovery(Generic[State]):
    """What the live body does when a step diverges (see the module docstring). ``events`` counts divergences."""

    policy: str = "restore"
    events: int = 0

    def __post_init__(self) -> None:
        if self.policy not in DIVERGENCE_POLICIES:
            raise ValueError(f"policy must be one of {DIVERGENCE_POLICIES}, got {self.policy!r}")

    def recover(self, step: int, retry: Callable[[], State], reset: Callable[[], State],
                problem: Callable[[State], str | None]) -> tuple[State | None, str]:
        """Handle a divergence at ``step``: returns (state to continue from, or None to stop; what was done).

        Args:
            retry: integrates ``step`` from the last good state with the safe command.
            reset: the initial layout at rest, under the safe command, as the state of ``step``.
            problem: why a state is diverged, or None when it is good.
        """
        self.events += 1
        if self.policy == "stop":
            return None, "stopping the run (on_divergence: stop)"
        state = retry()
        if problem(state) is None:
            return state, f"restored the last good state (step {step - 1}) and integrated step {step} with the " \
                          "safe command"
        state = reset()
        if problem(state) is None:
            return state, f"the safe command diverged too; reset the body to its initial layout at rest at step {step}"
        return None, "even the initial layout with the safe command diverges; stopping the run"
