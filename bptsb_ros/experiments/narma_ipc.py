"""IPC of trained expanded-NARMA systems (paper: "Distribution of computational properties", Fig. 3(c)).

Two systems, LIL and MLP brains with the double-circle body (N_mov 17), are trained (independent jobs); at several
epoch counts (0 = untrained) each runs on one long held-out input sequence, and the IPC (degree ≤ 3) is computed
of: the system output (the CMP's y) at every epoch count (the left panel), the target series the output is
trained on (y(t+1) for input u(t); the rightmost bar), and every movable mass's x and y at the last epoch count
(the middle panels). All of them share the input, so one IPC call computes every bar.

Claims: :func:`claims`, each the sentence of the paper it tests (quoted there) with its premise (the trained
systems learned, NMSE < 1).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from bptsb_ros.experiments.experiment_settings import SettingsError
from bptsb_ros.experiments.measured import judge
from bptsb_ros.experiments.registry import Context, experiment
from bptsb_ros.experiments.result import Claim
from bptsb_ros.experiments.timeseries_claims import RANK_TOL, all_of, fmt, not_learned, rank_reached

__all__ = ["BRAINS", "NONLINEAR_MEMORY_MIN", "RANK_TOL", "NarmaIpcNumbers", "SystemIpc", "claims", "run"]

BRAINS = ("lil", "mlp")
#: the nonlinear memory (degree ≥ 2 capacity on past inputs) summed over the movable masses' coordinates above which
#: the body is said to hold nonlinear memories: a tenth of what one coordinate can hold at most (its rank, 1) —
#: clearly more than nothing, since every capacity counted has already passed its surrogate threshold
NONLINEAR_MEMORY_MIN = 0.1


@dataclass(frozen=True)
class SystemIpc:
    """One trained system of Fig. 3(c) (LIL or MLP brain, double-circle body).

    nmse: (S,) held-out NMSE of the output at each stage (epoch count); output: (S, 3) the output's capacity by
    degree (column n − 1: degree n); output_terms: (S, F) the output's capacity for every basis function (the
    order of :attr:`NarmaIpcNumbers.target_terms`); masses: movable mass id → (2, 3), its x's and y's capacity by
    degree at the last stage."""

    nmse: Sequence[float]
    output: Sequence[Sequence[float]]
    output_terms: Sequence[Sequence[float]]
    masses: Mapping[int, Sequence[Sequence[float]]]
    #: movable mass id → (2,) its x's and y's *nonlinear memory* at the last stage: the capacity of the basis
    #: functions of degree ≥ 2 that involve a past input (longest delay ≥ 1)
    nonlinear_memory: Mapping[int, Sequence[float]] = field(default_factory=dict)


@dataclass(frozen=True)
class NarmaIpcNumbers:
    """What the claims of narma-ipc rest on: the stages (epoch counts, the first 0 = untrained), the two systems
    (``"lil"``, ``"mlp"``), the target's capacity by degree (3,) and per basis function (F,), and the total capacity
    of every bar of the figure (label → total; every bar is a 1-D state set)."""

    stages: Sequence[int]
    systems: Mapping[str, SystemIpc]
    target: Sequence[float]
    target_terms: Sequence[float]
    totals: Mapping[str, float]


def _premise(n: NarmaIpcNumbers, brains: Sequence[str]) -> str | None:
    """Did every system of ``brains`` learn by the last stage? The failed premise in words, or None."""
    last = n.stages[-1]
    return not_learned({f"{b.upper()} + double circle at epoch {last}": float(n.systems[b].nmse[-1]) for b in brains})


def _nonlinear(by_degree: Sequence[float]) -> float:
    """Degree ≥ 2 capacity (the paper: "A polynomial with n ≥ 2 is equivalent to a nonlinear profile")."""
    return float(np.sum(np.asarray(by_degree, float)[1:]))


@judge("narma-ipc")
def claims(n: NarmaIpcNumbers) -> list[Claim]:
    """The paper (main text, "Distribution of computational properties", on Fig. 3(c)):

    1. "The system output became asymptotic to the target model as training progressed": for each system the
       output's IPC profile is closer to the target's at the last stage than untrained (L1 distance over every
       basis function, strictly smaller).
    2. "Not only the first-order profile (linear) but also the second- and third-order profiles increased,
       suggesting that the optimization proceeded to enhance higher-order nonlinearity": for each system the
       output's degree-2 and its degree-3 capacity are each larger (strictly) at the last stage than untrained.
       (The first-order part is not tested: the figure's own caption says the total "reached the rank of one in
       all cases", so degree 1 cannot grow together with degrees 2 and 3.)
    3. "However, because the nonlinearity in the system with the LIL depended only on the geometric conditions of
       the body, the third-order profile was too small for reconstruction": the LIL system's output has less
       degree-3 capacity than the target (strictly).
    4. "On the other hand, the MLP could apply nonlinear transformation as well as the body, so the system with the
       MLP comparatively succeeded in reproducing the target nonlinearity": the MLP output's degree-2 and degree-3
       capacities are closer to the target's than the LIL output's (Σₙ₌₂,₃ |Cₙ(output) − Cₙ(target)|, strictly).
    5. "In comparison with the LIL, the MLP system demonstrated higher-order nonlinearity at each mass point as
       well": at every movable mass point the MLP system's degree ≥ 2 capacity (its x and y summed) exceeds the
       LIL system's.
    6. Caption of Fig. 3(c): "The total capacity reached the rank of one in all cases": every bar (outputs at every
       stage, every mass coordinate, the target) within :data:`RANK_TOL` of 1 (inclusive). No premise: it holds of
       any state, trained or not.
    7. "The memory (the delayed time step of the input) was generated by the body since the brain was an FNN.
       Hence, it must be true that the nonlinear information that the brain delivered to the body was transformed
       into nonlinear memories through the dynamics of the body": in the MLP system (the brain that delivers
       nonlinear information) the movable masses hold nonlinear memory — capacity of basis functions of degree ≥ 2
       with a past input (longest delay ≥ 1), summed over every mass coordinate — above
       :data:`NONLINEAR_MEMORY_MIN`. The brain is feedforward, so any capacity on a past input is the body's.

    Premise of 1-5: the systems they name learned by the last stage (held-out NMSE < 1); the untrained stage is
    the baseline and needs none.
    """
    if not n.stages or n.stages[0] != 0:
        raise ValueError(f"the first stage must be the untrained system (epoch 0), got stages {list(n.stages)}")
    last = n.stages[-1]
    target = np.asarray(n.target, float)
    target_terms = np.asarray(n.target_terms, float)
    out: list[Claim] = []

    def per_system(text: str, test) -> Claim:
        verdicts, parts = [], []
        for b in BRAINS:
            premise = _premise(n, (b,))
            verdict, evidence = test(n.systems[b])
            verdicts.append(None if premise else verdict)
            parts.append(f"{b.upper()}: {evidence}" + (f" (not testable: {premise})" if premise else ""))
        return Claim(text, all_of(verdicts), "; ".join(parts))

    def closer(s: SystemIpc) -> tuple[bool, str]:
        first, final = (float(np.abs(np.asarray(s.output_terms[i], float) - target_terms).sum()) for i in (0, -1))
        return bool(final < first), f"distance to the target profile {fmt(first)} → {fmt(final)}"

    out.append(per_system(f"the output's IPC profile approaches the target's with training (L1 distance over the "
                          f"basis functions, epoch 0 → {last}; both systems)", closer))

    def increased(s: SystemIpc) -> tuple[bool, str]:
        first, final = np.asarray(s.output[0], float), np.asarray(s.output[-1], float)
        return (bool(final[1] > first[1] and final[2] > first[2]),
                f"degree 2 {fmt(first[1])} → {fmt(final[1])}, degree 3 {fmt(first[2])} → {fmt(final[2])}")

    out.append(per_system(f"the output's 2nd- and 3rd-order capacities each grow with training (epoch 0 → {last}; "
                          "both systems)", increased))

    lil, mlp = (np.asarray(n.systems[b].output[-1], float) for b in BRAINS)
    text = ("the LIL system's output has too little 3rd-order capacity to reconstruct the target (less than the "
            "target's)")
    premise = _premise(n, ("lil",))
    if premise:
        out.append(Claim.not_testable(text, premise))
    else:
        out.append(Claim(text, bool(lil[2] < target[2]), f"degree 3: LIL output {fmt(lil[2])}, target "
                                                          f"{fmt(target[2])}"))

    text = ("the MLP system's output reproduces the target's nonlinearity better than the LIL's (Σ over degrees 2, 3 "
            "of |output − target| capacity smaller)")
    premise = _premise(n, BRAINS)
    dist = {b: float(np.abs(o[1:3] - target[1:3]).sum()) for b, o in zip(BRAINS, (lil, mlp), strict=True)}
    if premise:
        out.append(Claim.not_testable(text, premise))
    else:
        out.append(Claim(text, bool(dist["mlp"] < dist["lil"]),
                         f"distance: MLP {fmt(dist['mlp'])}, LIL {fmt(dist['lil'])} (degrees 2, 3: MLP "
                         f"{fmt(mlp[1])}, {fmt(mlp[2])}; LIL {fmt(lil[1])}, {fmt(lil[2])}; target {fmt(target[1])}, "
                         f"{fmt(target[2])})"))

    text = ("the MLP system has more higher-order (degree ≥ 2) capacity than the LIL system at each mass point "
            "(x and y summed, every movable mass)")
    premise = _premise(n, BRAINS)
    ms = {b: n.systems[b].masses for b in BRAINS}
    if set(ms["mlp"]) != set(ms["lil"]) or not ms["mlp"]:
        raise ValueError("the two systems' mass points differ (one body, the same movable masses expected)")
    ids = sorted(ms["mlp"])
    per_mass = {b: {i: sum(_nonlinear(axis) for axis in ms[b][i]) for i in ids} for b in BRAINS}
    per_coord = {b: [_nonlinear(axis) for i in ids for axis in ms[b][i]] for b in BRAINS}
    if premise:
        out.append(Claim.not_testable(text, premise))
    else:
        lose = [i for i in ids if not per_mass["mlp"][i] > per_mass["lil"][i]]
        coords = sum(m > c for m, c in zip(per_coord["mlp"], per_coord["lil"], strict=True))
        out.append(Claim(text, not lose,
                         f"MLP larger at {len(ids) - len(lose)} of {len(ids)} mass points ({coords} of "
                         f"{len(per_coord['mlp'])} coordinates); summed over all: MLP {fmt(sum(per_coord['mlp']))}, "
                         f"LIL {fmt(sum(per_coord['lil']))}" + (f"; not at mass {lose}" if lose else "")))

    holds, evidence = rank_reached(n.totals)
    out.append(Claim(f"the total capacity reaches the rank of one in all cases (every bar: outputs, masses, target; "
                     f"|total − 1| ≤ {RANK_TOL:g})", holds, evidence))

    text = ("the body turns the nonlinear forces the MLP delivers into nonlinear memories (degree ≥ 2 capacity on "
            f"past inputs, Δt ≥ 1, summed over the movable masses' x and y, > {NONLINEAR_MEMORY_MIN:g})")
    premise = _premise(n, ("mlp",))
    memory = {b: float(sum(sum(v) for v in n.systems[b].nonlinear_memory.values())) for b in BRAINS}
    if not n.systems["mlp"].nonlinear_memory:
        out.append(Claim.not_testable(text, "the run did not measure the masses' nonlinear memory"))
    elif premise:
        out.append(Claim.not_testable(text, premise))
    else:
        holding = sum(any(v > 0 for v in xy) for xy in n.systems["mlp"].nonlinear_memory.values())
        out.append(Claim(text, memory["mlp"] > NONLINEAR_MEMORY_MIN,
                         f"MLP system: {fmt(memory['mlp'])} over the masses ({holding} of "
                         f"{len(n.systems['mlp'].nonlinear_memory)} masses hold some); LIL system: "
                         f"{fmt(memory['lil'])}"))
    return out


@experiment(
    "narma-ipc",
    parallel=True,
    paper_ref="Fig. 3(c)",
    summary="IPC of the output at several epochs, of the target and of every mass's x, y (LIL, MLP; double circle)",
)
def run(ctx: Context) -> None:
    from bptsb_ros.analysis.ipc import ipc_groups, mass_groups, to_unit_interval
    from bptsb_ros.analysis.timeseries_plots import IpcPanel, plot_ipc_panels
    from bptsb_ros.config import override_mapping
    from bptsb_ros.experiments.timeseries import NarmaJob, ablation_variants, load_states, narma_overrides, run_jobs
    from bptsb_ros.jobs.sweep import Job

    stages, eval_inputs = ctx.settings["stages"], ctx.settings["eval_inputs"]
    if not stages or stages[0] != 0 or list(stages) != sorted(set(stages)):
        raise SettingsError(f"narma-ipc: stages must start at 0 (the untrained system) and grow, got {list(stages)}")
    last = stages[-1]
    max_delay = ctx.settings["max_delay"]
    surrogates = 1000  # per degree tuple, the reference's (ipc-module's) default: cheap at every scale
    washout = ctx.settings["washout"]
    config, extra = ctx.settings["config"], ctx.settings["config_overrides"]
    variants = ablation_variants(ctx)
    main = next(iter(variants))
    trained = [(name, brain) for name, v in variants.items() for brain in BRAINS if brain in v["brains"]]

    def prefix(name: str) -> str:  # of a variant's job names and IPC labels (none for the first variant)
        return "" if name == main else f"{name}-"

    jobs = [Job(f"{prefix(name)}{brain}",
                NarmaJob(config, {**narma_overrides(ctx.scale, last, "double-circle", brain, extra),
                                  **override_mapping(variants[name]["variant_overrides"])}, ctx.seed, tuple(stages),
                         eval_inputs, washout=washout)) for name, brain in trained]
    ctx.log(f"narma-ipc: {len(jobs)} trainings ({config}, states at epochs {stages}; variants {', '.join(variants)}) "
            "as parallel jobs")
    results = run_jobs(ctx, jobs, ctx.out_dir / "sweep")

    groups, labels = [], []
    u = target = None
    for name, brain in trained:
        run_dir = ctx.out_dir / "sweep" / "jobs" / f"{prefix(name)}{brain}"
        sys_label = f"{prefix(name)}{brain.upper()}"
        for e in stages:
            st = load_states(run_dir, e)
            u, target = st["u"], st["target"]
            g, lab = mass_groups(st["positions"], st["movable"], int(st["cmp_index"]))
            groups.append(g[0])
            labels.append(f"{sys_label} output, epoch {e}")
            if e == stages[-1]:
                masses = [(x, lb) for x, lb in zip(g[1:], lab[1:]) if not lb.startswith("all")]
                groups += [x for x, _ in masses]
                labels += [f"{sys_label} {lb}" for _, lb in masses]
    groups.append(target)
    labels.append("target")
    ctx.log(f"narma-ipc: IPC of {len(groups)} state sets, degree ≤ 3, delay ≤ {max_delay}")
    res = ipc_groups(to_unit_interval(u), groups, labels, max_degree=3, max_delay=max_delay, washout=washout,
                     surrogates=surrogates, seed=ctx.seed, progress=ctx.progress)
    bd = res.by_degree()
    memory = res.nonlinear_memory()

    def deg(label: str) -> np.ndarray:
        return bd[res.group(label)]

    summary: dict[str, dict] = {}
    for lab in res.labels:
        g = res.group(lab)
        summary[lab] = {"total": float(res.total[g]), "rank": int(res.rank[g]), "by_degree": bd[g].tolist(),
                        "nonlinear_memory": float(memory[g])}
    for name, brain in trained:
        sys_label = f"{prefix(name)}{brain.upper()}"
        tag = "" if name == main else f"[{name}] "
        for e in stages:
            lab = f"{sys_label} output, epoch {e}"
            for n in range(3):
                ctx.row(f"{tag}{brain.upper()} output, epoch {e}", f"IPC degree {n + 1}", "1", float(deg(lab)[n]))
            ctx.row(f"{tag}{brain.upper()} output, epoch {e}", "NMSE (held-out)", "1",
                    float(results[f"{prefix(name)}{brain}"][f"nmse_{e}"]))
    for n in range(3):
        ctx.row("target (expanded NARMA2)", f"IPC degree {n + 1}", "1", float(deg("target")[n]))

    systems: dict[tuple[str, str], SystemIpc] = {}
    for name, brain in trained:
        sys_label = f"{prefix(name)}{brain.upper()}"
        outs = [res.group(f"{sys_label} output, epoch {e}") for e in stages]
        mass_ids = sorted({int(lab.split()[2]) for lab in res.labels if lab.startswith(f"{sys_label} mass")})
        coords = {i: [res.group(f"{sys_label} mass {i} {a}") for a in "xy"] for i in mass_ids}
        systems[(name, brain)] = SystemIpc(
            nmse=[float(results[f"{prefix(name)}{brain}"][f"nmse_{e}"]) for e in stages], output=bd[outs].tolist(),
            output_terms=res.capacity[outs].tolist(), masses={i: bd[c].tolist() for i, c in coords.items()},
            nonlinear_memory={i: memory[c].tolist() for i, c in coords.items()})
        ctx.row(f"{'' if name == main else f'[{name}] '}{brain.upper()} + double circle, epoch {last}",
                "nonlinear memory of the masses (degree ≥ 2, Δt ≥ 1, summed)", "1",
                float(sum(sum(v) for v in systems[(name, brain)].nonlinear_memory.values())))
    for name, v in variants.items():
        chosen = {b: systems[(name, b)] if b in v["brains"] else systems[(main, b)] for b in BRAINS}
        bars = [lab for lab in res.labels if lab == "target" or any(
            lab.startswith(f"{prefix(name if b in v['brains'] else main)}{b.upper()} ") for b in BRAINS)]
        numbers = NarmaIpcNumbers(stages=tuple(stages), systems=chosen, target=bd[res.group("target")].tolist(),
                                  target_terms=res.capacity[res.group("target")].tolist(),
                                  totals={lab: float(res.total[res.group(lab)]) for lab in bars})
        verdicts = ctx.judge(claims, numbers, label="" if name == main else f"[{name}: {v['help']}] ")
        if name == main:
            main_verdicts = verdicts

    notes = ["target bar: the series the output is trained on, y(t+1) for input u(t)"]
    lil_nonlinear = float(np.sum(deg(f"LIL output, epoch {stages[-1]}")[1:]))
    if any(c.holds is False for c in main_verdicts[1:4]) and lil_nonlinear < 1e-3:
        notes.append("the LIL system's output stays linear: at these amplitudes the body's geometric nonlinearity "
                     f"is tiny in a 1-D output (its degree ≥ 2 capacity after thresholding: {lil_nonlinear:.2g}); "
                     "the MLP (zero-bias ReLU, symmetric input) "
                     "adds mainly even, 2nd-order terms; 3rd order would need trained biases (kinks away from "
                     f"u = 0) — {stages[-1]} Adam epochs are far from the paper's 40,000 SGD epochs")
    if main_verdicts[5].holds is False:
        notes.append("totals deviate from the rank by the in-sample overlap of the basis functions (≈ 1/√T) and by "
                     "capacity beyond delay 20 / degree 3")
    panels = []
    for brain in BRAINS:  # the figure: the first variant's systems (Fig. 3(c))
        left = [f"{brain.upper()} output, epoch {e}" for e in stages] + ["target"]
        right = [lab for lab in res.labels if lab.startswith(f"{brain.upper()} mass")]
        panels.append([IpcPanel.of(res, left, f"{brain.upper()}: output (CMP y)\nby training epoch",
                                   names=[lab.replace(f"{brain.upper()} output, ", "") for lab in left], legend=False),
                       IpcPanel.of(res, right, f"{brain.upper()} + double circle, epoch {stages[-1]}: each movable "
                                   "mass (index, axis)", names=[lab.replace(f"{brain.upper()} mass ", "")
                                                                for lab in right])])
    ctx.phase("plotting the IPC panels")
    ctx.figure(plot_ipc_panels(ctx.out_dir / "narma_ipc.png", panels, width_ratios=[len(stages) + 3, 34]))
    ctx.result.details = {"config": config, "stages": list(stages), "eval_inputs": eval_inputs, "washout": washout,
                          "max_delay": max_delay, "max_degree": 3, "surrogates": surrogates,
                          "threshold": res.settings["threshold"], "variants": variants,
                          "definition": res.settings["definition"], "jobs": results, "ipc": summary, "notes": notes}
