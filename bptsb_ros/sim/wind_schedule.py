"""Wind schedules: the wind force on every movable mass at each step (ROS-free).

One schedule feeds the offline simulation (``simulate_open_loop(..., wind=schedule.forces(T, dt))``) and the
live ``wind_source`` node, which publishes ``schedule.force_at(k)`` on ``env/wind`` stamped t_k, in lockstep with
the body; so a live run under a schedule equals the offline one. Kinds:

* ``constant``: ``force`` at every step.
* ``periodic``: calm for the first half of every ``period`` [s], ``force`` for the second half (the locomotion
  headwind, :func:`bptsb_ros.sim.inputs.wind_blowing`); ``period`` 0: always blowing.
* ``switching``: the paper's behavioural-switching wind (supplement "Behavioral switching", "Switching timing"):
  calm and blowing segments in turn; a segment ends h SWG periods (``period`` [s]; h uniform in ``hold_periods``)
  after the start of the period it began in, plus n/100 of a period, n random (``timing`` "random"), 0 ("fixed")
  or a given n — so every switch is at phase n/100 of the SWG period (t_wind = t0 + (2π/ω)·n/100); seeded by
  ``seed`` (:func:`bptsb_ros.sim.inputs.wind_schedule`, which the switching training uses).
* ``file``: a piecewise-constant table from a CSV file with the header ``t,fx,fy`` (t [s] ascending, forces
  [N]): the row with the largest t ≤ k·dt is in force at step k (up to 10⁻⁶ of a step of rounding); calm before
  the first row.

:func:`for_agent` gives the schedule an agent was trained with (a switching agent: its switching wind; a
locomotion agent: its headwind); the ``wind_source`` node uses it unless its parameters say otherwise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

KINDS = ("constant", "periodic", "switching", "file")
#: the published code's wind while the second curve is active: (15·F_wind, +1) N (published-code-facts.md)
PUBLISHED_SWITCHING_FORCE = (15.0, 1.0)
#: largest wind table read from a file (rows)
MAX_TABLE_ROWS = 1_000_000
#: largest wind file read [bytes]: 64 MiB (a million rows of three numbers)
MAX_TABLE_BYTES = 64 * 2**20


class WindScheduleError(ValueError):
    """A wind schedule is malformed; the message names the setting or the file line."""


@dataclass(frozen=True)
class WindSchedule:
    """Wind force (x, y) [N] on every movable mass as a function of the step.

    Attributes:
        kind: one of :data:`KINDS`.
        force: (F_x, F_y) [N] while the wind blows (``constant``, ``periodic``, ``switching``).
        calm: (F_x, F_y) [N] while it does not (``periodic``, ``switching``): (0, 0), or the published code's
            constant +1 N upward force, (0, 1), that its switching agents were trained with.
        period: ``periodic``: the cycle [s]; ``switching``: the SWG period [s] the segments are counted in.
        seed: ``switching``: seed of the segment lengths and switch phases.
        hold_periods: ``switching``: (lo, hi) whole periods per segment, inclusive.
        timing: ``switching``: "random", "fixed" (n = 0) or an integer n in [0, 99] as text.
        start_on: ``switching``: the first segment blows.
        table: ``file``: rows (t [s], F_x, F_y), t ascending.
        source: where the table came from (for messages).
    """

    kind: str
    force: tuple[float, float] = (0.0, 0.0)
    calm: tuple[float, float] = (0.0, 0.0)
    period: float = 0.0
    seed: int = 0
    hold_periods: tuple[int, int] = (3, 8)
    timing: str = "random"
    start_on: bool = False
    table: tuple[tuple[float, float, float], ...] = ()
    source: str = ""
    _cache: dict[str, Any] = field(default_factory=dict, init=False, compare=False, repr=False)

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise WindScheduleError(f"wind schedule kind {self.kind!r}: choose one of {', '.join(KINDS)}")
        for name in ("force", "calm"):
            value = getattr(self, name)
            if len(value) != 2 or not all(math.isfinite(f) for f in value):
                raise WindScheduleError(f"wind {name} must be two finite numbers (x, y) [N], got {value}")
        if not (math.isfinite(self.period) and self.period >= 0):
            raise WindScheduleError(f"wind period must be finite and >= 0 [s], got {self.period}")
        if self.kind == "switching":
            if self.period <= 0:
                raise WindScheduleError("a switching wind needs the SWG period > 0 [s]")
            lo, hi = self.hold_periods
            if not 1 <= lo <= hi:
                raise WindScheduleError(f"hold_periods must satisfy 1 <= lo <= hi, got {self.hold_periods}")
            if self.timing not in ("random", "fixed") and not (self.timing.isascii() and self.timing.isdigit()
                                                                and int(self.timing) < 100):
                raise WindScheduleError(f"timing must be random, fixed or an integer n in [0, 99], got "
                                        f"{self.timing!r}")
        if self.kind == "file" and not self.table:
            raise WindScheduleError("a file wind schedule needs at least one row")

    def describe(self) -> str:
        """One line for logs and the bag's ``custom_data``."""
        fx, fy = self.force
        if self.kind == "constant":
            return f"constant ({fx:g}, {fy:g}) N"
        if self.kind == "periodic":
            return f"periodic ({fx:g}, {fy:g}) N, period {self.period:g} s (calm half, blowing half)"
        if self.kind == "switching":
            return (f"switching ({fx:g}, {fy:g}) N, segments of {self.hold_periods[0]}-{self.hold_periods[1]} periods "
                    f"of {self.period:g} s, timing {self.timing}, seed {self.seed}"
                    + (", starting on" if self.start_on else ""))
        return f"file {self.source or '(table)'} ({len(self.table)} rows)"

    def blowing(self, steps: int, dt: float) -> np.ndarray:
        """(steps + 1,) float: 1 where the wind blows at steps 0..steps, else 0 (``file``: not defined)."""
        k = np.arange(steps + 1)
        if self.kind == "constant":
            return np.ones(steps + 1)
        if self.kind == "periodic":
            from bptsb_ros.sim.inputs import wind_blowing

            return wind_blowing(k, dt, self.period).astype(np.float64)
        if self.kind == "switching":
            return self._switching(steps, dt)[:steps + 1].copy()
        raise WindScheduleError("a file wind schedule has no on/off pattern; use forces()")

    def forces(self, steps: int, dt: float) -> np.ndarray:
        """(steps + 1, 2) float64 wind force [N] in force at steps 0..steps."""
        if steps < 0:
            raise ValueError(f"steps must be >= 0, got {steps}")
        if self.kind == "file":
            rows = self._rows()
            idx = np.searchsorted(rows[:, 0], _row_times(np.arange(steps + 1), dt), side="right") - 1
            return np.where(idx[:, None] >= 0, rows[np.maximum(idx, 0), 1:], 0.0)
        on = self.blowing(steps, dt)[:, None]
        return on * np.asarray(self.force, dtype=np.float64) + (1 - on) * np.asarray(self.calm, dtype=np.float64)

    def force_at(self, step: int, dt: float) -> tuple[float, float]:
        """(F_x, F_y) [N] in force at ``step`` (what ``wind_source`` publishes for it)."""
        if self.kind == "file":
            rows = self._rows()
            i = int(np.searchsorted(rows[:, 0], _row_times(np.array(step), dt), side="right")) - 1
            return (0.0, 0.0) if i < 0 else (float(rows[i, 1]), float(rows[i, 2]))
        on = self.blowing_at(step, dt)
        return tuple(float(on * f + (1 - on) * c) for f, c in zip(self.force, self.calm, strict=True))  # type: ignore[return-value]

    def _rows(self) -> np.ndarray:
        """The file table as a (R, 3) float64 array (converted once)."""
        rows = self._cache.get("rows")
        if rows is None:
            rows = self._cache["rows"] = np.asarray(self.table, dtype=np.float64)
        return rows

    def blowing_at(self, step: int, dt: float) -> float:
        """1.0 when the wind blows at ``step`` (constant, periodic, switching), else 0.0."""
        if self.kind == "constant":
            return 1.0
        if self.kind == "periodic":
            from bptsb_ros.sim.inputs import wind_blowing

            return float(wind_blowing(np.array([step]), dt, self.period)[0])
        if self.kind == "switching":
            return float(self._switching(step, dt)[step])
        raise WindScheduleError("a file wind schedule has no on/off pattern; use force_at()")

    def _switching(self, steps: int, dt: float) -> np.ndarray:
        """The switching pattern (at least steps + 1 long, not to be modified) for steps 0, 1, ...; drawn for a
        doubling horizon and cached (the draw is sequential, so a longer horizon has the same prefix)."""
        from bptsb_ros.sim.inputs import wind_schedule

        cached = self._cache.get("switching")
        if cached is None or cached[0] != dt or len(cached[1]) <= steps:
            horizon = max(steps, 2 * (len(cached[1]) if cached is not None and cached[0] == dt else 1024))
            period = int(round(self.period / dt))
            if period < 1:
                raise WindScheduleError(f"the switching period {self.period:g} s is at most half a time step "
                                        f"({dt:g} s): it rounds to no whole step")
            timing: Any = self.timing if self.timing in ("random", "fixed") else int(self.timing)
            pattern = wind_schedule(horizon, period, np.random.default_rng(self.seed), hold_periods=self.hold_periods,
                                    timing=timing, start_on=self.start_on)
            cached = (dt, pattern)
            self._cache["switching"] = cached
        return cached[1]


def _row_times(steps: np.ndarray, dt: float) -> np.ndarray:
    """Times k·dt [s] at which table rows are looked up; a row stamped exactly at k·dt (up to rounding, 10⁻⁶ of a
    step) is in force at step k."""
    return (np.asarray(steps, dtype=np.float64) + 1e-6) * dt


def read_table(path: str | Path, max_force: float | None = None) -> tuple[tuple[float, float, float], ...]:
    """Rows (t [s], F_x, F_y) of a CSV wind table with the header ``t,fx,fy``; raises WindScheduleError naming
    the file and the problem (missing, not a regular file, over :data:`MAX_TABLE_BYTES`, unreadable, wrong header,
    bad number, t not ascending, too many rows, or a force component beyond ±``max_force`` [N] when given: the
    body's ``max_wind``, which would reject every wind of the run)."""
    from bptsb_ros.files.safe_write import UnsafeFileError, read_regular

    path = Path(path)
    try:
        text = read_regular(path, MAX_TABLE_BYTES).decode("utf-8")
    except FileNotFoundError:
        raise WindScheduleError(f"wind file {path}: no such file") from None
    except UnsafeFileError as err:
        raise WindScheduleError(f"wind file {err}") from None
    except (OSError, UnicodeDecodeError) as err:
        raise WindScheduleError(f"wind file {path}: cannot read it ({err})") from None
    lines = [ln.strip() for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines or [c.strip() for c in lines[0].split(",")] != ["t", "fx", "fy"]:
        raise WindScheduleError(f"wind file {path}: the first line must be the header t,fx,fy")
    if len(lines) - 1 > MAX_TABLE_ROWS:
        raise WindScheduleError(f"wind file {path}: more than {MAX_TABLE_ROWS} rows")
    rows = []
    for n, line in enumerate(lines[1:], start=2):
        cells = line.split(",")
        try:
            values = tuple(float(c) for c in cells)
        except ValueError:
            values = ()
        if len(values) != 3 or not all(math.isfinite(v) for v in values):
            raise WindScheduleError(f"wind file {path}, row {n}: need three finite numbers t,fx,fy, got {line[:80]!r}")
        if rows and values[0] <= rows[-1][0]:
            raise WindScheduleError(f"wind file {path}, row {n}: t = {values[0]:g} s is not after the previous row")
        if values[0] < 0:
            raise WindScheduleError(f"wind file {path}, row {n}: t must be >= 0, got {values[0]:g}")
        if max_force is not None and max(abs(values[1]), abs(values[2])) > max_force:
            raise WindScheduleError(f"wind file {path}, row {n}: force ({values[1]:g}, {values[2]:g}) N is beyond "
                                    f"the body's max_wind of {max_force:g} N per component (every wind would be "
                                    "rejected)")
        rows.append(values)
    if not rows:
        raise WindScheduleError(f"wind file {path}: no rows after the header")
    return tuple(rows)


def for_agent(config: dict[str, Any], extra: dict[str, Any] | None = None) -> WindSchedule:
    """The wind an agent was trained with.

    * a switching agent (checkpoint ``extra`` has ``curve_on``): its switching wind, F_wind ∈ {0, 1} as (F, 0) N
      or the published (15·F, 1) N (``extra['published_wind']``: blowing (15, 1), calm (0, 1)), segments of
      ``extra['hold_periods']`` SWG periods, its training's switch ``timing`` (random, fixed or n);
    * any other Lissajous agent: the same switching wind (the paper's switching setting);
    * a locomotion agent: its periodic headwind (``locomotion.wind_force`` along x, ``wind_period``).

    Raises WindScheduleError for a task without a wind of its own (give the schedule explicitly).
    """
    extra = extra or {}
    task = config.get("task")
    if "curve_on" in extra or task == "lissajous":
        omega = float(config.get("brain", {}).get("omega", 2 * math.pi))
        published = bool(extra.get("published_wind"))
        force = PUBLISHED_SWITCHING_FORCE if published else (1.0, 0.0)
        calm = (0.0, PUBLISHED_SWITCHING_FORCE[1]) if published else (0.0, 0.0)
        hold = tuple(int(h) for h in extra.get("hold_periods", (3, 8)))
        return WindSchedule("switching", force=force, calm=calm, period=2 * math.pi / omega,
                            hold_periods=hold, timing=str(extra.get("timing", "random")))  # type: ignore[arg-type]
    if task == "locomotion":
        loc = config.get("locomotion", {})
        return WindSchedule("periodic", force=(float(loc.get("wind_force", 0.0)), 0.0),
                            period=float(loc.get("wind_period", 0.0)))
    raise WindScheduleError(f"a {task} agent has no wind of its own: give the schedule (constant, periodic, "
                            "switching or file) explicitly")
