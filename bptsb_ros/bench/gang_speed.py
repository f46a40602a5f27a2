"""The memory task's trainings alone, as a gang (:mod:`bptsb_ros.jobs.gang`) and as a population
(:mod:`bptsb_ros.workflows.population`): wall milliseconds per training update, and what the memory task costs at
the paper's schedule each way.

The system is the memory task's (``config/narma.yaml`` with the LIL brain, the multiple circle of 37 masses,
target u(t − Δt), fused episodes: a 3,000-step window per update). ``alone``: one training's updates;
``gang``: ``members`` trainings (Δt 1, 2, … and seeds 0, 1, …) in one gang, their wall time per update and per
member, after every member has made its first update (agent building and the first call kept out). The
estimate packs the paper's 17 Δt × 2 bodies × 5 seeds = 170 trainings of 40,000 updates onto ``workers``
processes, each a gang or a population of 85 (``bptsb reproduce memory-task --scale paper`` runs populations), at the
measured rates; it assumes a worker runs as fast beside the others as alone, which on a busy machine it does not
(``load_average``).
"""

from __future__ import annotations

import os
import time
from typing import Any

#: the memory task at the paper's schedule: trainings (17 Δt × 2 bodies × 5 seeds) and updates each
PAPER_TRAININGS, PAPER_UPDATES = 170, 40_000
MEMORY_OVERRIDES: dict[str, Any] = {"brain.type": "lil", "body.shape": "multiple_circle", "body.nodes": 37,
                                    "narma.target": "memory", "narma.brain_input": "symmetric",
                                    "training.backend": "fused"}


def _member(seed: int, delay: int, updates: int, out: dict[int, tuple[float, float]]) -> None:
    """Build one memory-task training, make one update, then ``updates`` more: ``out[seed]`` = (the time after the
    first update, the time at the end) [s, ``time.perf_counter``]."""
    from bptsb_ros.bench.workloads import narma_task_update

    _, update = narma_task_update({**MEMORY_OVERRIDES, "narma.delay": delay}, seed)
    update()
    t0 = time.perf_counter()
    for _ in range(updates):
        update()
    out[seed] = (t0, time.perf_counter())


def measure(members: int, updates: int) -> dict[str, Any]:
    """ms per update of one training alone and of ``members`` trainings in one gang (one torch thread)."""
    import torch

    from bptsb_ros.jobs.gang import Gang

    if members < 1:
        return {"error": f"a gang needs at least one training, got {members}"}
    torch.set_num_threads(1)
    alone: dict[int, tuple[float, float]] = {}
    _member(0, 8, updates, alone)
    alone_ms = 1e3 * (alone[0][1] - alone[0][0]) / updates
    timed: dict[int, tuple[float, float]] = {}
    gang = Gang()
    t0 = time.perf_counter()
    out = gang.run([lambda s=s: _member(s, 1 + s % 17, updates, timed) for s in range(members)])
    errors = [str(e) for e in out if isinstance(e, BaseException)]
    if errors:
        return {"error": errors[0]}
    # the members' first updates end in the same round (lockstep), so from the earliest of those to the last end
    # is ``updates`` rounds of the whole gang
    gang_ms = 1e3 * (max(end for _, end in timed.values()) - min(first for first, _ in timed.values())) / updates
    return {"members": members, "updates_timed": updates, "alone_ms_per_update": round(alone_ms, 2),
            "gang_ms_per_update_of_all": round(gang_ms, 1), "gang_ms_per_member_update": round(gang_ms / members, 2),
            "gang_windows": gang.lanes,
            "gang_wall_s": round(time.perf_counter() - t0, 1),
            "gang_over_alone": round(alone_ms / (gang_ms / members), 2)}


def measure_population(members: int, updates: int) -> dict[str, Any]:
    """ms per member-update of ``members`` trainings (Δt 1, 2, … and seeds 0, 1, … as in :func:`measure`) as one
    population (:mod:`bptsb_ros.workflows.population`), after a 1-update population warmed the kernels' dispatch."""
    from bptsb_ros.experiments.common import packaged_config
    from bptsb_ros.workflows.population import train_population

    def cfgs(epochs: int) -> list[Any]:
        return [packaged_config("narma", {**MEMORY_OVERRIDES, "narma.delay": 1 + s % 17, "epochs": epochs},
                                seed=s) for s in range(members)]

    train_population(cfgs(1), [None] * members, progress=False)
    results, failures = train_population(cfgs(updates), [None] * members, progress=False)
    if failures:
        return {"error": str(failures[0].error)}
    seconds = results[0].metrics["train_seconds"]
    return {"population_members": members, "population_updates_timed": updates,
            "population_ms_per_update_of_all": round(1e3 * seconds / updates, 1),
            "population_ms_per_member_update": round(1e3 * seconds / updates / members, 3)}


def paper_estimate(entry: dict[str, Any], workers: int = 2) -> dict[str, float]:
    """Hours of the memory task at the paper's schedule on ``workers`` processes: trainings alone, in gangs and as
    populations (where measured)."""
    per_worker = PAPER_TRAININGS * PAPER_UPDATES / workers / 3.6e6
    out = {"workers": workers, "alone_h": round(per_worker * entry["alone_ms_per_update"], 2),
           "gangs_h": round(per_worker * entry["gang_ms_per_member_update"], 2)}
    if "population_ms_per_member_update" in entry:
        out["populations_h"] = round(per_worker * entry["population_ms_per_member_update"], 2)
    return out


def _child(conn, members: int, updates: int) -> None:
    try:
        entry = measure(members, updates)
        if "error" not in entry:
            pop = measure_population(members, updates)
            if "error" in pop:  # the gang's numbers stand; the population's failure is reported beside them
                entry["population_error"] = pop["error"]
            else:
                entry.update(pop)
                entry["population_over_alone"] = round(entry["alone_ms_per_update"] /
                                                       entry["population_ms_per_member_update"], 2)
            entry["paper_memory_task"] = paper_estimate(entry)
        entry["load_average"] = list(os.getloadavg())
        conn.send(entry)
    except Exception as err:  # noqa: BLE001 - reported in the bench file
        conn.send({"error": f"{type(err).__name__}: {err}"})


def run_isolated(quick: bool, timeout_s: float = 1800) -> dict[str, Any]:
    """:func:`measure` in a fresh process (85 members, 30 updates; ``quick``: 8 members, 5 updates)."""
    import multiprocessing as mp

    members, updates = (8, 5) if quick else (85, 30)
    ctx = mp.get_context("spawn")
    parent, child = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_child, args=(child, members, updates))
    proc.start()
    child.close()
    result = parent.recv() if parent.poll(timeout_s) else {"error": "timed out"}
    proc.join(30)
    if proc.is_alive():  # timed out: it must not go on using the cores, nor hold up this process's exit
        proc.kill()
        proc.join()
    return result
