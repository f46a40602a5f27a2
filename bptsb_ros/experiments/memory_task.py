"""The memory task (supplement, "Memory task", Fig. "The memory task").

The CMP's y must reproduce the input Δt task steps ago, y(t) = u(t − Δt), with an LIL brain (no memory of its
own) and a double-circle or multiple-circle body (N_mov 17 each). Every (body, Δt, seed) is an independent
training; each body's trainings run as populations (``workflows/population.py``: stacked parameters, one batched
simulation; each member's numbers its training's alone), as many at once as the run has workers (setting
``population``; without it, one sweep job per training). The error is the NMSE on a long held-out input.

Figures: (a) error vs Δt, mean ± std over seeds, per body; (b) input, target and outputs at Δt = 8; (c) the IPC of
the output and of every movable mass's x and y at Δt = 8, with F₁(u(t−8)) in black (red in the paper, where red
is not also a degree's colour). Masses are named by ID as in the paper: their order among the movable masses
(0-16, the CMP last); ``details["movable_masses"]`` gives each body's mass index of every ID.

Claims: :func:`claims`, each the sentence of the supplement it tests (quoted there) with its premise (the systems
it compares learned, NMSE < 1).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from bptsb_ros.experiments.claim_rules import at_most
from bptsb_ros.experiments.common import derived_seeds
from bptsb_ros.experiments.measured import judge
from bptsb_ros.experiments.registry import Context, experiment
from bptsb_ros.experiments.result import Claim
from bptsb_ros.experiments.timeseries_claims import RANK_TOL, all_of, fmt, not_learned, rank_reached

__all__ = ["EQUAL_TOL", "FOCUS_DELAY", "RHO_MIN", "MemoryNumbers", "claims", "id_list", "paper_id", "run", "spearman"]

#: Spearman rank correlation of the mean error with Δt at or above which (inclusive) "the larger Δt, the larger
#: the error" holds: a monotone trend up to noise (1 is strictly monotone; one swap of neighbours in 5 gives 0.9)
RHO_MIN = 0.8
FOCUS_DELAY = 8
#: the output's F₁(u(t−Δt)) capacity "does not equal" the target's when they differ by more than this
EQUAL_TOL = 0.1
BODY_NAMES = ("double-circle", "multiple-circle")


def spearman(x, y) -> float:
    """Spearman rank correlation (no ties expected)."""
    rx, ry = np.argsort(np.argsort(x)), np.argsort(np.argsort(y))
    return float(np.corrcoef(rx, ry)[0, 1])


@dataclass(frozen=True)
class MemoryNumbers:
    """What the claims of memory-task rest on.

    delays: (D,) the Δt trained; nmse: body (``"double-circle"``, ``"multiple-circle"``) → (D, S) held-out NMSE per
    Δt and seed; focus: the Δt of the IPC figure (8); the IPC is that of each body's first seed at Δt = focus:
    output_f1, body → the output's F₁(u(t−focus)) capacity; target_f1, the target's; per_mass_f1, the multiple
    circle's movable mass ID (the CMP excluded) → its F₁(u(t−focus)) capacity (the larger of its x and y);
    cmp_neighbours, the IDs of the multiple circle's masses joined to the CMP by a spring; totals, every IPC bar's
    total capacity (label → total; every bar is a 1-D state set)."""

    delays: Sequence[int]
    nmse: Mapping[str, Sequence[Sequence[float]]]
    focus: int
    output_f1: Mapping[str, float]
    target_f1: float
    per_mass_f1: Mapping[int, float]
    cmp_neighbours: Sequence[int]
    totals: Mapping[str, float]
    #: the epoch counts (0 = untrained) at which the first seed's Δt = focus outputs were measured, and body → the
    #: output's F₁(u(t−focus)) capacity at each (empty: not measured)
    stages: Sequence[int] = ()
    output_f1_by_stage: Mapping[str, Sequence[float]] = field(default_factory=dict)


@judge("memory-task")
def claims(n: MemoryNumbers) -> list[Claim]:
    """The supplement ("Memory task"), on its figure:

    1. "The larger the delayed time step Δt, the larger the reconstruction error, regardless of the body shape": for
       each body the Spearman correlation of the mean error (over seeds) with Δt ≥ :data:`RHO_MIN`.
    2. "The systems with a multiple-circle structure generally tended to have smaller errors than those with a
       double-circle structure": the multiple circle's mean error is smaller (strictly) at more than half of the Δt.
    3. "The system with multiple circles can emulate the target time-series more accurately" (Δt = 8, panel (b)):
       the multiple circle's mean error at Δt = focus is smaller (strictly).
    4. "In the double-circle structure, the output IPC does not equal the target IPC even after sufficient training
       epochs, while the multiple-circle body can reproduce most of it": the target's IPC is F₁(u(t−8)) alone, so
       the double circle's output F₁(u(t−8)) differs from the target's by more than :data:`EQUAL_TOL`, and the
       multiple circle's is more than half the target's.
    5. "Focusing on the IPC of each mass point in the multiple-circle body, we can see that the profiles of the time
       delay Δt=8 at the mass points with IDs 14, 15, and 16 are relatively large. These mass points are located at
       the innermost part of the circles and connected to the CMP directly": the mean F₁(u(t−8)) capacity of the
       masses joined to the CMP exceeds that of the other movable masses (the CMP excluded).
    6. Caption: "The total capacity reached the rank of one in all cases": every IPC bar within :data:`RANK_TOL`
       of 1 (inclusive). No premise.
    7. Caption of (c), "the IPC values of the system output, which are arranged from left to right according to
       training epochs", with 4's "even after sufficient training epochs": at every measured epoch the double
       circle's output F₁(u(t−focus)) differs from the target's by more than :data:`EQUAL_TOL`, while the
       multiple circle's is larger at the last epoch than untrained and there more than half the target's.
       Premise: 4's.

    Premise of 1-5: the systems each reads learned (NMSE < 1): 1 and 2 every (body, Δt) (mean over seeds), 3 both
    bodies at Δt = focus (mean over seeds), 4 and 5 the first-seed systems whose IPC they read.
    """
    delays = list(n.delays)
    if len(delays) < 2 or n.focus not in delays:
        raise ValueError(f"need at least two Δt including the focus {n.focus}, got {delays}")
    err = {b: np.asarray(n.nmse[b], float) for b in BODY_NAMES}
    mean = {b: err[b].mean(axis=1) for b in BODY_NAMES}
    fi = delays.index(n.focus)

    def system(b: str, dt: int) -> str:
        return f"LIL + {b} at Δt = {dt}"

    every = {b: {system(b, dt): float(mean[b][i]) for i, dt in enumerate(delays)} for b in BODY_NAMES}
    out: list[Claim] = []

    verdicts, parts = [], []
    for b in BODY_NAMES:
        rho = spearman(np.array(delays), mean[b])
        premise = not_learned(every[b])
        verdicts.append(None if premise else at_most(RHO_MIN, rho))
        parts.append(f"{b}: ρ = {rho:.2f}" + (f" (not testable: {premise} (mean over seeds))" if premise else ""))
    out.append(Claim(f"the error grows with Δt in both bodies (Spearman ρ of the mean error with Δt ≥ {RHO_MIN})",
                     all_of(verdicts), "; ".join(parts)))

    text = "the multiple-circle body generally has the smaller error (at more than half of the Δt, mean over seeds)"
    premise = not_learned({**every["double-circle"], **every["multiple-circle"]})
    if premise:
        out.append(Claim.not_testable(text, f"{premise} (mean over seeds)"))
    else:
        wins = [dt for i, dt in enumerate(delays) if mean["multiple-circle"][i] < mean["double-circle"][i]]
        out.append(Claim(text, 2 * len(wins) > len(delays),
                         f"smaller at {len(wins)} of {len(delays)} Δt ({wins}); mean NMSE over Δt: multiple-circle "
                         f"{fmt(float(mean['multiple-circle'].mean()))}, double-circle "
                         f"{fmt(float(mean['double-circle'].mean()))}"))

    text = f"at Δt = {n.focus} the multiple circle emulates the target more accurately (smaller NMSE, mean over seeds)"
    premise = not_learned({system(b, n.focus): float(mean[b][fi]) for b in BODY_NAMES})
    if premise:
        out.append(Claim.not_testable(text, f"{premise} (mean over seeds)"))
    else:
        out.append(Claim(text, bool(mean["multiple-circle"][fi] < mean["double-circle"][fi]),
                         f"NMSE: multiple-circle {fmt(float(mean['multiple-circle'][fi]))}, double-circle "
                         f"{fmt(float(mean['double-circle'][fi]))}"))

    first = {b: float(err[b][fi, 0]) for b in BODY_NAMES}
    focus = f"F₁(u(t−{n.focus}))"
    text = (f"at Δt = {n.focus} the double circle's output IPC does not equal the target's (its {focus} off by > "
            f"{EQUAL_TOL:g}) while the multiple circle's reproduces most of it (> half the target's {focus})")
    premise = not_learned({f"{system(b, n.focus)} (first seed)": first[b] for b in BODY_NAMES})
    if premise:
        out.append(Claim.not_testable(text, premise))
    else:
        dc, mc = n.output_f1["double-circle"], n.output_f1["multiple-circle"]
        holds = abs(dc - n.target_f1) > EQUAL_TOL and mc > 0.5 * n.target_f1
        out.append(Claim(text, bool(holds), f"output {focus}: double-circle {fmt(dc)}, multiple-circle {fmt(mc)}; "
                                            f"target {fmt(n.target_f1)}"))

    text = (f"multiple circle, Δt = {n.focus}: the per-mass {focus} capacity is largest at the masses joined to the "
            "CMP (their mean exceeds the other movable masses' mean)")
    near = [c for i, c in n.per_mass_f1.items() if i in n.cmp_neighbours]
    far = [c for i, c in n.per_mass_f1.items() if i not in n.cmp_neighbours]
    if not near or not far:
        raise ValueError("the multiple circle's movable masses must include masses joined to the CMP and others")
    premise = not_learned({f"{system('multiple-circle', n.focus)} (first seed)": first["multiple-circle"]})
    if premise:
        out.append(Claim.not_testable(text, premise))
    else:
        out.append(Claim(text, bool(np.mean(near) > np.mean(far)),
                         f"joined to the CMP (IDs {sorted(n.cmp_neighbours)}): mean {fmt(float(np.mean(near)))} (max "
                         f"{fmt(max(near))}); others: mean {fmt(float(np.mean(far)))} (max {fmt(max(far))})"))

    holds, evidence = rank_reached(n.totals)
    out.append(Claim(f"the total capacity reaches the rank of one in all cases (every IPC bar at Δt = {n.focus}; "
                     f"|total − 1| ≤ {RANK_TOL:g})", holds, evidence))

    text = (f"by training epoch (Δt = {n.focus}): the double circle's output {focus} stays off the target's at every "
            f"epoch (by > {EQUAL_TOL:g}), while the multiple circle's grows from the untrained one to more than half "
            "the target's")
    by_stage = {b: [float(v) for v in n.output_f1_by_stage.get(b, ())] for b in BODY_NAMES}
    premise = not_learned({f"{system(b, n.focus)} (first seed)": first[b] for b in BODY_NAMES})
    if len(n.stages) < 2 or any(len(by_stage[b]) != len(n.stages) for b in BODY_NAMES):
        out.append(Claim.not_testable(text, "the run did not measure the output's IPC at two or more training epochs"))
    elif premise:
        out.append(Claim.not_testable(text, premise))
    else:
        dc, mc = by_stage["double-circle"], by_stage["multiple-circle"]
        holds = (all(abs(v - n.target_f1) > EQUAL_TOL for v in dc) and mc[-1] > mc[0]
                 and mc[-1] > 0.5 * n.target_f1)
        shown = "; ".join(f"{b}: " + ", ".join(f"{fmt(v)} (epoch {e})" for e, v in zip(n.stages, by_stage[b],
                                                                                     strict=True))
                          for b in BODY_NAMES)
        out.append(Claim(text, bool(holds), f"output {focus}: {shown}; target {fmt(n.target_f1)}"))
    return out


def paper_id(label: str, movable: Sequence[int]) -> str:
    """A state-set label of :func:`~bptsb_ros.analysis.ipc.mass_groups` with the mass named by its ID as the paper
    numbers them, its place among the movable masses: ``"mass 22 x"`` → ``"ID 6 x"`` in the double circle of 33
    masses (movable: 16-32); other labels unchanged."""
    kind, *rest = label.split(" ")
    if kind != "mass" or len(rest) != 2:
        return label
    return f"ID {list(movable).index(int(rest[0]))} {rest[1]}"


def id_list(ids: Sequence[int]) -> str:
    """Sorted IDs with runs of consecutive ones as ranges: ``[0, 1, 2, 5]`` → ``"0–2, 5"``."""
    runs: list[list[int]] = []
    for i in sorted(ids):
        if runs and i == runs[-1][-1] + 1:
            runs[-1].append(i)
        else:
            runs.append([i])
    return ", ".join(f"{r[0]}–{r[-1]}" if len(r) > 2 else ", ".join(map(str, r)) for r in runs)


@experiment(
    "memory-task",
    parallel=True,
    paper_ref="Supplement 'Memory task' (Fig. 'The memory task')",
    summary="LIL + double-/multiple-circle (N_mov 17) reproduce u(t − Δt); error vs Δt, Δt = 8 series and IPC",
)
def run(ctx: Context) -> None:
    from bptsb_ros.analysis.ipc import ipc_groups, mass_groups, to_unit_interval
    from bptsb_ros.analysis.timeseries_plots import IpcPanel, plot_ipc_panels, plot_memory_error
    from bptsb_ros.config import override_mapping
    from bptsb_ros.experiments.timeseries import (
        BODIES,
        N_MOV,
        NarmaJob,
        job_dir,
        load_states,
        narma_overrides,
        population_jobs,
        run_jobs,
    )
    from bptsb_ros.jobs.sweep import Job

    epochs, delays, eval_inputs = ctx.settings["epochs"], ctx.settings["delays"], ctx.settings["eval_inputs"]
    seeds = derived_seeds(ctx.seed, ctx.settings["n_seeds"])
    surrogates = 1000  # per degree tuple, the reference's (ipc-module's) default: cheap at every scale
    max_delay, washout = ctx.settings["max_delay"], ctx.settings["washout"]
    config, extra = ctx.settings["config"], ctx.settings["config_overrides"]
    # the stages below the training's length, then the trained system itself
    stages = tuple(sorted({0, *(e for e in ctx.settings["ipc_stages"] if e < epochs), epochs}))
    focus = FOCUS_DELAY if FOCUS_DELAY in delays else delays[len(delays) // 2]
    jobs, staged = [], []
    for body in BODIES:
        for dt in delays:
            for seed in seeds:
                over = narma_overrides(ctx.scale, epochs, body, "lil",
                                       {"narma.target": "memory", "narma.delay": dt, **override_mapping(extra)})
                # the first seed's Δt = focus system is measured at every stage of ipc_stages (a training of its
                # own; a population member equals its solo training)
                job = Job(f"{body}_dt{dt}_s{seed}", NarmaJob(config, over, seed,
                                                             stages if (dt, seed) == (focus, seeds[0]) else (epochs,),
                                                             eval_inputs, washout=washout))
                (staged if (dt, seed) == (focus, seeds[0]) else jobs).append(job)
    populations: dict[str, str] = {}
    if ctx.settings["population"]:  # each body's trainings as populations, as many at once as the run has slots
        jobs, populations = population_jobs(jobs, -(-ctx.slots(len(jobs)) // len(BODIES)))
        ctx.log(f"memory-task: {len(populations) + len(staged)} trainings ({config}, {epochs} epochs) as "
                f"{len(jobs)} populations and {len(staged)} trainings measured at epochs {list(stages)}")
    else:
        ctx.log(f"memory-task: {len(jobs) + len(staged)} trainings ({config}, {epochs} epochs) as parallel jobs")
    jobs = staged + jobs  # the staged trainings first: they take longest alone
    results = run_jobs(ctx, jobs, ctx.out_dir / "sweep", gangs=ctx.settings["gangs"] and not populations)
    err = {b: np.array([[results[f"{b}_dt{dt}_s{s}"]["nmse"] for s in seeds] for dt in delays]) for b in BODIES}
    for b in BODIES:
        for i, dt in enumerate(delays):
            ctx.row(f"LIL + {b} (N_mov {N_MOV})", f"NMSE at Δt = {dt} (mean of {len(seeds)} seeds)", "1",
                    float(err[b][i].mean()))
    rho = {b: spearman(np.array(delays), err[b].mean(axis=1)) for b in BODIES}
    avg = {b: float(err[b].mean()) for b in BODIES}

    # IPC at Δt = 8 (first seed): the output at every stage and every movable coordinate, both bodies, one call
    groups, labels, states, cmp_neighbours, movable = [], [], {}, {}, {}
    u = None
    for b in BODIES:
        where = job_dir(ctx.out_dir / "sweep", f"{b}_dt{focus}_s{seeds[0]}", populations)
        for e in stages[:-1]:
            early = load_states(where, e)
            groups.append(early["positions"][:, list(early["movable"]).index(int(early["cmp_index"])), 1])
            labels.append(f"{b}: output, epoch {e}")
        st = load_states(where, epochs)
        states[b] = st
        u = st["u"]
        movable[b] = [int(i) for i in st["movable"]]
        g, lab = mass_groups(st["positions"], st["movable"], int(st["cmp_index"]))
        keep = [i for i, lb in enumerate(lab) if not lb.startswith("all")]
        groups += [g[i] for i in keep]
        labels += [f"{b}: {paper_id(lab[i], movable[b])}" for i in keep]
        from bptsb_ros.body.shapes import build_shape

        topo = build_shape(BODIES[b][0], BODIES[b][1], 4.0, 3)
        cmp = topo.cmp_index
        cmp_neighbours[b] = sorted({movable[b].index(int(j)) for i, j in topo.springs if i == cmp} |
                                   {movable[b].index(int(i)) for i, j in topo.springs if j == cmp})
    groups.append(states["double-circle"]["target"])
    labels.append("target")
    res = ipc_groups(to_unit_interval(u), groups, labels, max_degree=3, max_delay=max_delay, washout=washout,
                     surrogates=surrogates, seed=ctx.seed, progress=ctx.progress)
    f = res.index(((focus, 1),))
    per_mass: dict[str, dict[int, float]] = {}
    for b in BODIES:
        cmp_id = movable[b].index(int(states[b]["cmp_index"]))
        per_mass[b] = {k: float(max(res.capacity[res.group(f"{b}: ID {k} {a}"), f] for a in "xy"))
                       for k in range(len(movable[b])) if k != cmp_id}
    out_f = {b: float(res.capacity[res.group(f"{b}: output (CMP y)"), f]) for b in BODIES}
    by_stage = {b: [float(res.capacity[res.group(f"{b}: output, epoch {e}"), f]) for e in stages[:-1]] + [out_f[b]]
                for b in BODIES}
    for b in BODIES:
        for e, v in zip(stages, by_stage[b], strict=True):
            ctx.row(f"LIL + {b} (N_mov {N_MOV}), Δt = {focus}, epoch {e}", f"output F₁(u(t−{focus})) capacity", "1",
                    v)
    for b in BODIES:
        ctx.row(f"LIL + {b} (N_mov {N_MOV}), Δt = {focus}", f"output F₁(u(t−{focus})) capacity", "1", out_f[b],
                "target: 1")
    ctx.judge(claims, MemoryNumbers(
        delays=tuple(delays), nmse={b: err[b].tolist() for b in BODIES}, focus=focus, output_f1=out_f,
        target_f1=float(res.capacity[res.group("target"), f]), per_mass_f1=per_mass["multiple-circle"],
        cmp_neighbours=cmp_neighbours["multiple-circle"],
        totals={lab: float(res.total[res.group(lab)]) for lab in res.labels}, stages=stages,
        output_f1_by_stage=by_stage))

    ctx.phase("plotting the errors and IPC")
    # figures (a) error vs Δt, (b) Δt = focus series, (c) IPC
    t = np.arange(washout, min(washout + 60, len(u)))
    outputs = {}
    for b in BODIES:
        st = states[b]
        outputs[b] = st["positions"][t, list(st["movable"]).index(int(st["cmp_index"])), 1]
    ctx.figure(plot_memory_error(ctx.out_dir / "memory_error.png", delays, err, t, u,
                                 states["double-circle"]["target"], outputs, focus))
    ctx.figure(plot_ipc_panels(ctx.out_dir / "memory_ipc.png", [[IpcPanel.of(
        res, [lab for lab in res.labels if lab.startswith(f"{b}:")] + ["target"],
        f"(c) IPC, LIL + {b}, Δt = {focus} (black: F₁(u(t−{focus})); movable mass IDs, joined to the CMP: "
        f"{id_list(cmp_neighbours[b])})",
        names=[lab.replace(f"{b}: ", "") for lab in res.labels if lab.startswith(f"{b}:")] + ["target"],
        highlight=f)] for b in BODIES]))
    notes = [] if ctx.scale == "paper" else [f"{ctx.scale} scale: Δt in {list(delays)} only, {len(seeds)} seed(s), "
                                             f"{epochs} Adam epochs"]
    if min(rho.values()) < RHO_MIN:
        notes.append(f"error not increasing with Δt: the errors ({', '.join(f'{b} {avg[b]:.3g}' for b in avg)} on "
                     f"average) show the systems barely trained in {epochs} epochs — the output's offset and scale, "
                     "not its memory, dominate the error")
    ctx.result.details = {"config": config, "epochs": epochs, "delays": list(delays), "seeds": seeds,
                          "eval_inputs": eval_inputs, "washout": washout, "surrogates": surrogates,
                          "nmse": {b: err[b].tolist() for b in BODIES}, "spearman": rho,
                          "f1_focus_per_mass": {b: {str(k): v for k, v in d.items()} for b, d in per_mass.items()},
                          "cmp_neighbours": cmp_neighbours, "movable_masses": movable, "output_f1_focus": out_f,
                          "notes": notes}
