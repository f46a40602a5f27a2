"""Where the wall time of a lockstep run goes, step by step (ROS-free): the numbers behind ``bptsb bench --live``.

:class:`~bptsb_ros.live.body_loop.BodyLoop` splits every lockstep step into four phases and adds each one's wall
seconds to a :class:`StepPhases`:

* ``recorder``: waiting until the recorder acknowledged step k − ``recorder_window`` (``wait_for_recorder``);
* ``commands``: from ``/clock`` t_k going out until every awaited command for step k is in (the brains' round
  trip, including the middleware and the body's own message handling);
* ``compute``: ``BodyCore.integrate`` (commands taken, ``MSDN.step``, divergence check, perturbation);
* ``publish``: ``/clock`` and the step's state, markers and diagnostics handed to the middleware.

What is left of the stepping wall time (held while paused, paced while a brain was silent, the loop itself) is
``other``. The stepping wall time runs from the first step's start to the last step's end: start-up (discovery,
the brains' first messages) is not in it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

#: the phases of a lockstep step, in the order they happen
PHASES: tuple[str, ...] = ("recorder", "publish", "commands", "compute")


@dataclass
class StepPhases:
    """Wall seconds per phase (:data:`PHASES`), summed over the steps of a run, and the stepping wall time.

    Attributes:
        seconds: phase name -> wall seconds summed over all steps.
        steps: steps completed.
        began: monotonic time [s] the first step started (None before it).
        ended: monotonic time [s] the last step ended.
    """

    seconds: dict[str, float] = field(default_factory=lambda: dict.fromkeys(PHASES, 0.0))
    steps: int = 0
    began: float | None = None
    ended: float = 0.0

    def add(self, phase: str, seconds: float) -> None:
        """Add ``seconds`` [s] to ``phase`` (one of :data:`PHASES`)."""
        self.seconds[phase] += seconds

    def step_done(self, began: float, ended: float) -> None:
        """A step that started at ``began`` and ended at ``ended`` (monotonic seconds) is complete."""
        if self.began is None:
            self.began = began
        self.ended = ended
        self.steps += 1

    @property
    def wall(self) -> float:
        """Stepping wall time [s]: first step's start to the last step's end (0.0 before any step)."""
        return 0.0 if self.began is None else self.ended - self.began

    def summary(self) -> dict[str, float | int]:
        """``loop_steps``, ``loop_wall_s``, ``loop_steps_per_s``, the stepping window ``loop_began_monotonic`` ..
        ``loop_ended_monotonic`` (CLOCK_MONOTONIC seconds, the same clock in every process of the machine) and
        ``phase_ms_<phase>`` (mean milliseconds per step, also ``phase_ms_other``), or {} before the first step; the
        split is :func:`split` of the totals."""
        if not self.steps:
            return {}
        row = split(self.steps, self.wall, self.seconds)
        out: dict[str, float | int] = {"loop_steps": self.steps, "loop_wall_s": self.wall,
                                       "loop_steps_per_s": row["steps_per_s"], "loop_began_monotonic": self.began,
                                       "loop_ended_monotonic": self.ended}
        out.update({f"phase_ms_{name}": row[f"{name}_ms"] for name in (*PHASES, "other")})
        return out


def split(steps: int, wall: float, seconds: Mapping[str, float]) -> dict[str, float]:
    """Steps per second and the mean milliseconds per step of each phase of ``seconds`` (totals [s] over ``steps``
    steps that took ``wall`` seconds), and ``other_ms``: the wall time per step the phases do not account for.

    Raises ValueError for no steps or a wall time that is not positive.
    """
    if steps <= 0 or not wall > 0:
        raise ValueError(f"a split needs steps > 0 and a positive wall time, got {steps} steps in {wall} s")
    out = {"steps_per_s": steps / wall}
    for name, total in seconds.items():
        out[f"{name}_ms"] = 1e3 * total / steps
    out["other_ms"] = 1e3 * (wall - sum(seconds.values())) / steps
    return out


def row_from_summary(summary: Mapping[str, Any]) -> dict[str, float | int]:
    """The bench row of a body summary (``body_summary.json`` of a lockstep run): steps, wall seconds, steps/s and
    per-step milliseconds of every phase. Raises KeyError naming what a summary without phase timing lacks."""
    missing = [k for k in ("loop_steps", "loop_wall_s", *(f"phase_ms_{p}" for p in (*PHASES, "other")))
               if k not in summary]
    if missing:
        raise KeyError(f"the body summary has no phase timing ({', '.join(missing)}): not a lockstep run of this "
                       "version")
    row: dict[str, float | int] = {"steps": int(summary["loop_steps"]), "wall_s": float(summary["loop_wall_s"]),
                                   "steps_per_s": float(summary["loop_steps_per_s"])}
    row.update({f"{p}_ms": float(summary[f"phase_ms_{p}"]) for p in (*PHASES, "other")})
    return row
