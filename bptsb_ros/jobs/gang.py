"""Independent trainings as one batched simulation: a gang of threads in lockstep.

Each training of the gang runs unchanged in a thread of its own (its trainer, guard, files and random
generators are its own). Its held-force windows (``body/held_window.py``, the NARMA and memory tasks'
episodes) do not run in the thread: it hands them to the gang and waits. Once every thread of the gang is
waiting (or done), the gang runs all the waiting windows of one topology as one call of
``body/held_window_kernel.py``, one lane each, so the per-spring loops run over all the trainings at once;
then every thread goes on. A training's numbers equal those it has alone (tests/jobs/test_gang.py).

Threads start one at a time, each once the previous one waits or ends, so code that seeds torch's global
generator and then draws from it (the trainer builds the agent that way) runs for one training at a time.
Code between the windows holds the GIL: a gang pays off where the windows dominate (measured in
docs/speed.md); other trainings in a gang run correctly, only without the speed-up.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np

from bptsb_ros.body.held_window import LaneGroup, WindowLane, as_lanes, run_lanes_backward, run_lanes_forward

T = TypeVar("T")


@dataclass
class _Request:
    """A thread's window (``lane``) or gradient (``handle``, ``g_y``), and what the gang answers."""

    lane: WindowLane | None = None
    handle: tuple[LaneGroup, int] | None = None
    g_y: np.ndarray | None = None
    answer: Any = None
    error: BaseException | None = None
    done: threading.Event = field(default_factory=threading.Event)


@dataclass
class Gang:
    """The lockstep scheduler of :func:`run_gang` (the :class:`~bptsb_ros.body.held_window.LaneRunner` its
    threads use). ``rounds`` counts the kernel rounds run, ``lanes`` the windows run in them."""

    # the coordinating thread waits on _cv; each waiting thread on its request's event alone (a notify_all would
    # wake every thread of the gang at every arrival, all of them contending for the GIL)
    _cv: threading.Condition = field(default_factory=threading.Condition)
    _pending: list[_Request] = field(default_factory=list)
    _live: int = 0
    _finished: int = 0
    _running: bool = False
    rounds: int = 0
    lanes: int = 0
    #: print a line to stderr every this many seconds while the gang runs (None: never)
    report_every_s: float | None = None

    # --- the threads' side (LaneRunner) ---
    def forward(self, lane: WindowLane) -> tuple[np.ndarray, tuple[np.ndarray, ...], Any]:
        y, end, handle = self._submit(_Request(lane=lane))
        return y, end, handle

    def backward(self, handle: Any, g_y: np.ndarray) -> tuple[np.ndarray, ...]:
        return self._submit(_Request(handle=handle, g_y=np.asarray(g_y)))

    def _submit(self, req: _Request) -> Any:
        with self._cv:
            if not self._running:
                raise RuntimeError("this gang has ended: its windows (and their backward) run inside Gang.run")
            self._pending.append(req)
            self._cv.notify()
        req.done.wait()
        if req.error is not None:
            # a fresh exception per thread: one object raised in many threads would collect all their tracebacks
            raise RuntimeError(f"the gang's kernel call failed: {type(req.error).__name__}: {req.error}") \
                from req.error
        return req.answer

    # --- the coordinating thread's side ---
    def _parked(self) -> int:
        return len(self._pending) + self._finished

    def _run_round(self, batch: list[_Request]) -> None:
        """Every waiting window, grouped by key, one kernel call per group; every waiting gradient, one adjoint
        per group it belongs to."""
        windows: dict[tuple, list[_Request]] = {}
        grads: dict[int, list[_Request]] = {}
        for req in batch:
            if req.lane is not None:
                windows.setdefault(req.lane.key, []).append(req)
            else:
                assert req.handle is not None
                grads.setdefault(id(req.handle[0]), []).append(req)
        for reqs in windows.values():
            self._answer(reqs, self._forward_group)
        for reqs in grads.values():
            self._answer(reqs, self._backward_group)
        self.rounds += 1

    @staticmethod
    def _answer(reqs: list[_Request], fn: Callable[[list[_Request]], list[Any]]) -> None:
        try:
            for req, answer in zip(reqs, fn(reqs)):
                req.answer = answer
        except Exception as err:  # noqa: BLE001 - every thread of the group gets the error, as it would alone
            for req in reqs:
                req.error = err

    def _forward_group(self, reqs: list[_Request]) -> list[Any]:
        lanes = [r.lane for r in reqs]
        group, outs = run_lanes_forward(lanes)  # type: ignore[arg-type]
        self.lanes += len(lanes)
        return [(y, end, (group, p)) for p, (y, end) in enumerate(outs)]

    @staticmethod
    def _backward_group(reqs: list[_Request]) -> list[Any]:
        group = reqs[0].handle[0]  # type: ignore[index]
        out = run_lanes_backward(group, {r.handle[1]: r.g_y for r in reqs})  # type: ignore[index]
        return [out[r.handle[1]] for r in reqs]  # type: ignore[index]

    def run(self, fns: Sequence[Callable[[], T]]) -> list[T | BaseException]:
        """See :func:`run_gang`."""
        if self._running:
            raise RuntimeError("this gang is running already")
        self._pending, self._live, self._finished, self._running = [], 0, 0, True
        results: list[Any] = [None] * len(fns)

        def body(i: int) -> None:
            try:
                with as_lanes(self):
                    results[i] = fns[i]()
            except BaseException as err:  # noqa: BLE001 - returned to the caller, the other trainings go on
                results[i] = err
            finally:
                with self._cv:
                    self._live -= 1
                    self._finished += 1
                    self._cv.notify()

        threads = []
        for i in range(len(fns)):
            with self._cv:
                self._live += 1
            t = threading.Thread(target=body, args=(i,), name=f"gang-{i}", daemon=True)
            threads.append(t)
            t.start()
            with self._cv:  # the next thread starts once this one waits for the gang or has ended
                while self._parked() < i + 1:
                    self._cv.wait()
        t0 = last = time.monotonic()
        batch: list[_Request] = []
        try:
            while True:
                with self._cv:
                    while self._live and len(self._pending) < self._live:
                        self._cv.wait()
                    if not self._live:
                        break
                    batch, self._pending = self._pending, []
                self._run_round(batch)
                for req in batch:
                    req.done.set()
                batch = []
                if self.report_every_s is not None and time.monotonic() - last >= self.report_every_s:
                    last = time.monotonic()
                    print(f"gang of {len(fns)} trainings (pid {os.getpid()}): {self._live} running, "
                          f"{self.lanes:,} windows in {self.rounds:,} rounds, "
                          f"{(last - t0) / self.rounds:.3g} s per round", file=sys.stderr, flush=True)
        except BaseException as err:  # Ctrl-C or a failure here: no thread may wait for a round that never comes
            with self._cv:
                self._running = False
                for req in [*batch, *self._pending]:
                    if req.error is None:
                        req.error = err
                    req.done.set()
            raise
        finally:
            with self._cv:
                self._running = False
        for t in threads:
            t.join()
        return results


def run_gang(fns: Sequence[Callable[[], T]], report_every_s: float | None = None) -> list[T | BaseException]:
    """Call every ``fn()`` in a thread of one gang (see the module docstring); the results in order, an exception
    a call raised in its place. The calling thread coordinates the gang and runs its windows; with
    ``report_every_s`` it prints how far the gang is that often (to stderr)."""
    return Gang(report_every_s=report_every_s).run(fns)
