"""Per-step timing records of a realtime body run, and the statistics computed from them (ROS-free).

The realtime loop (:mod:`bptsb_ros.live.body_loop`) appends one record per step to a :class:`StepTimes` when the
body has a ``timing_path``; ``body_sim`` writes them there at exit (:meth:`StepTimes.save`, an ``.npz``), and
``bptsb bench --realtime`` reads them back (:func:`load_step_times`) and summarises them
(:func:`timing_statistics`). Every time is wall time on the body's monotonic clock [s]:

* ``due``: when the step was scheduled to start (start + k·period);
* ``began``: when the loop started it (after waiting and handling messages);
* ``integrated``: when ``BodyCore.integrate`` returned (the physics and the safety rules done);
* ``done``: when the step's messages and the next ``/clock`` were published.

From these: compute = done − began (what the step costs; integrate = integrated − began, publish = done −
integrated), lateness = began − due (the body's ``jitter`` series), period jitter = |began_k − began_(k−1) −
period| (how far each actual period is off the nominal one), and a deadline miss is a step with done > due +
period (it finished after the next step was due; the same rule as the body's ``deadline_misses`` counter).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

#: the columns of a record, in order
FIELDS: tuple[str, ...] = ("step", "due", "began", "integrated", "done")
#: rows a new :class:`StepTimes` holds before it grows (10 min at 100 Hz)
INITIAL_ROWS = 60_000
#: most records a timing file may hold when read back (about 11.6 days at 100 Hz; 400 MB)
MAX_RECORDS = 10**8


class StepTimes:
    """Per-step records (one row of :data:`FIELDS` per step) in a float64 array that doubles when full: 40 bytes
    a step, no allocation in the step except when it grows."""

    def __init__(self, rows: int = INITIAL_ROWS) -> None:
        self._data = np.empty((max(1, rows), len(FIELDS)), dtype=np.float64)
        self.count = 0

    def append(self, step: int, due: float, began: float, integrated: float, done: float) -> None:
        if self.count == len(self._data):
            self._data = np.concatenate([self._data, np.empty_like(self._data)])
        self._data[self.count] = (step, due, began, integrated, done)
        self.count += 1

    def __len__(self) -> int:
        return self.count

    def columns(self) -> dict[str, np.ndarray]:
        """The records as one (n,) array per field (views)."""
        data = self._data[:self.count]
        return {name: data[:, i] for i, name in enumerate(FIELDS)}

    def save(self, path: str | Path, period: float, meta: Mapping[str, str] | None = None) -> None:
        """Write the records, the nominal ``period`` [s] and ``meta`` (strings, e.g. the executor) to ``path`` as an
        ``.npz`` (parents created; written to a temporary file and renamed, so a reader never sees half a file)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        arrays: dict[str, np.ndarray] = {name: np.ascontiguousarray(col) for name, col in self.columns().items()}
        arrays["period"] = np.array(period, dtype=np.float64)
        for key, value in (meta or {}).items():
            arrays[f"meta_{key}"] = np.array(str(value))
        from bptsb_ros.files.safe_write import atomic_writer

        with atomic_writer(path) as out:
            np.savez(out, **arrays)


def load_step_times(path: str | Path, meta: tuple[str, ...] = ("executor",)) -> dict[str, Any]:
    """The records of a timing file (:meth:`StepTimes.save`): one float64 array per field of :data:`FIELDS`,
    ``period`` (float) and the ``meta`` strings present. Read with :func:`bptsb_ros.files.npz.load_npz` (bounded,
    no pickles); raises ``NpzError`` or ValueError (columns of unequal length, a non-positive period) naming the
    file."""
    from bptsb_ros.files.npz import load_npz

    limit = MAX_RECORDS * 8 * (len(FIELDS) + 1)
    arrays = load_npz(path, (*FIELDS, "period"), max_bytes=limit)
    lengths = {arrays[name].shape for name in FIELDS}
    if len(lengths) != 1 or len(next(iter(lengths))) != 1:
        raise ValueError(f"{path}: the timing columns {', '.join(FIELDS)} must be 1-D and of equal length, got "
                         f"shapes {sorted(lengths)}")
    out: dict[str, Any] = {name: np.asarray(arrays[name], dtype=np.float64) for name in FIELDS}
    period = float(arrays["period"])
    if not (np.isfinite(period) and period > 0):
        raise ValueError(f"{path}: period must be a positive number of seconds, got {period}")
    out["period"] = period
    for key in meta:
        try:
            # the file's size is checked against the bound too: the records' bound, not the string's
            out[key] = str(load_npz(path, (f"meta_{key}",), max_bytes=limit + 4096)[f"meta_{key}"])
        except ValueError:  # NpzError is a ValueError: an absent key (older or foreign files)
            continue
    return out


def _spread(values: np.ndarray, prefix: str) -> dict[str, float]:
    """p50, p99 and max of ``values`` [s] as ``<prefix>_p50_ms`` ... [ms] (numpy's linear percentiles)."""
    if not len(values):
        return {}
    p50, p99 = np.percentile(values, (50, 99))
    return {f"{prefix}_p50_ms": float(p50) * 1e3, f"{prefix}_p99_ms": float(p99) * 1e3,
            f"{prefix}_max_ms": float(values.max()) * 1e3}


def timing_statistics(due: np.ndarray, began: np.ndarray, integrated: np.ndarray, done: np.ndarray,
                      period: float) -> dict[str, float | int]:
    """Statistics of one realtime run from its per-step records (arrays (n,) [s], in step order) and nominal
    ``period`` [s]: ``steps``, ``deadline_misses`` (done > due + period) and ``deadline_miss_pct``; p50/p99/max in
    ms of ``compute`` (done − began), ``integrate`` (integrated − began), ``publish`` (done − integrated),
    ``lateness`` (began − due) and ``period_jitter`` (|began_k − began_(k−1) − period|, n − 1 values)."""
    due, began, integrated, done = (np.asarray(a, dtype=np.float64) for a in (due, began, integrated, done))
    n = len(began)
    misses = int(np.count_nonzero(done > due + period))
    out: dict[str, float | int] = {"steps": n, "deadline_misses": misses,
                                   "deadline_miss_pct": 100.0 * misses / n if n else 0.0}
    out.update(_spread(done - began, "compute"))
    out.update(_spread(integrated - began, "integrate"))
    out.update(_spread(done - integrated, "publish"))
    out.update(_spread(began - due, "lateness"))
    out.update(_spread(np.abs(np.diff(began) - period), "period_jitter"))
    return out
