"""IPC of trained expanded-NARMA systems (paper: "Distribution of computational properties", Fig. 3(c)).

Two systems, LIL and MLP brains with the double-circle body (N_mov 17), are trained (independent jobs); at several
epoch counts (0 = untrained) each runs on one long held-out input sequence, and the IPC (degree ≤ 3) is computed
of: the system output (the CMP's y) at every epoch count (the left panel), the target series the output is
trained on (y(t+1) for input u(t); the rightmost bar), and every movable mass's x and y at the last epoch count
(the middle panels). All of them share the input, so one IPC call computes every bar.

Claims (computed):

* the output's 2nd- and 3rd-order capacity grows with training (last epoch count > untrained, both systems);
* the MLP system has more ≥ 3rd-order capacity than the LIL system: in the output, and summed over the movable
  masses' coordinates;
* the output's total capacity reaches its rank, 1 (|total − 1| < :data:`RANK_TOL` for every output bar).
"""

from __future__ import annotations

from bptsb_ros.experiments.registry import Context, experiment

RANK_TOL = 0.1
BRAINS = ("lil", "mlp")


@experiment(
    "narma-ipc",
    paper_ref="Fig. 3(c)",
    summary="IPC of the output at several epochs, of the target and of every mass's x, y (LIL, MLP; double circle)",
    durations={"smoke": "≈ 40 s", "short": "≈ 4 min on an idle 2-core machine (Adam, 300 epochs, 2 workers)",
               "paper": "880 s measured 2026-11-27 (2 systems × 40,000 SGD epochs on 2 workers, then the IPC of "
                        "4 stages with 200 surrogates; numba backend, 2 lightly loaded cores)"},
)
def run(ctx: Context) -> None:
    import numpy as np

    from bptsb_ros.analysis.ipc import ipc_groups, mass_groups, to_unit_interval
    from bptsb_ros.analysis.plots import _save, draw_ipc_bars, plt
    from bptsb_ros.experiments.timeseries import NarmaJob, config_name, load_states, narma_overrides, run_jobs
    from bptsb_ros.sweep import Job

    last = ctx.pick(smoke=1, short=300, paper=40000)
    stages = ctx.pick(smoke=(0, 1), short=(0, 30, 100, 300), paper=(0, 400, 4000, 40000))
    eval_inputs = ctx.pick(smoke=250, short=2000, paper=4000)
    max_delay = ctx.pick(smoke=10, short=20, paper=20)
    surrogates = 1000  # per degree tuple, the reference's (ipc-module's) default: cheap at every scale
    washout = ctx.pick(smoke=30, short=100, paper=100)
    config = config_name(ctx.scale)
    extra = ("narma.n_inputs=40", "narma.washout=10", "narma.train_end=30") if ctx.scale == "smoke" else ()
    jobs = [Job(brain, NarmaJob(config, tuple(narma_overrides(ctx.scale, last, "double-circle", brain, extra)),
                                ctx.seed, tuple(stages), eval_inputs, washout=washout)) for brain in BRAINS]
    ctx.log(f"narma-ipc: {len(jobs)} trainings ({config}, states at epochs {stages}) as parallel jobs")
    results = run_jobs(jobs, ctx.out_dir / "sweep", ctx.log,
                       workers=ctx.pick(smoke=0, short=None, paper=None))

    groups, labels = [], []
    u = target = None
    for brain in BRAINS:
        run_dir = ctx.out_dir / "sweep" / "jobs" / brain
        for e in stages:
            st = load_states(run_dir, e)
            u, target = st["u"], st["target"]
            g, lab = mass_groups(st["positions"], st["movable"], int(st["cmp_index"]))
            groups.append(g[0])
            labels.append(f"{brain.upper()} output, epoch {e}")
            if e == stages[-1]:
                masses = [(x, lb) for x, lb in zip(g[1:], lab[1:]) if not lb.startswith("all")]
                groups += [x for x, _ in masses]
                labels += [f"{brain.upper()} {lb}" for _, lb in masses]
    groups.append(target)
    labels.append("target")
    ctx.log(f"narma-ipc: IPC of {len(groups)} state sets, degree ≤ 3, delay ≤ {max_delay}")
    res = ipc_groups(to_unit_interval(u), groups, labels, max_degree=3, max_delay=max_delay, washout=washout,
                     surrogates=surrogates, seed=ctx.seed, progress=ctx.progress)
    bd = res.by_degree()

    def deg(label: str) -> np.ndarray:
        return bd[res.group(label)]

    summary: dict[str, dict] = {}
    for lab in res.labels:
        g = res.group(lab)
        summary[lab] = {"total": float(res.total[g]), "rank": int(res.rank[g]), "by_degree": bd[g].tolist()}
    for brain in BRAINS:
        for e in stages:
            lab = f"{brain.upper()} output, epoch {e}"
            for n in range(3):
                ctx.row(lab, f"IPC degree {n + 1}", "1", float(deg(lab)[n]))
            ctx.row(lab, "NMSE (held-out)", "1", float(results[brain][f"nmse_{e}"]))
    for n in range(3):
        ctx.row("target (expanded NARMA2)", f"IPC degree {n + 1}", "1", float(deg("target")[n]))

    def nonlinear(b: str, e: int) -> float:
        return float(deg(f"{b.upper()} output, epoch {e}")[1:].sum())

    grows = {b: (nonlinear(b, stages[-1]), nonlinear(b, 0)) for b in BRAINS}
    ctx.claim("the output's 2nd/3rd-order capacity grows with training (both systems)",
              all(a > b for a, b in grows.values()),
              "; ".join(f"{b.upper()}: epoch 0 {v[1]:.3g} → epoch {stages[-1]} {v[0]:.3g}" for b, v in grows.items()))
    out3 = {b: float(deg(f"{b.upper()} output, epoch {stages[-1]}")[2]) for b in BRAINS}
    mass3 = {b: float(sum(deg(lab)[2] for lab in res.labels if lab.startswith(f"{b.upper()} mass"))) for b in BRAINS}
    n_coords = sum(1 for lab in res.labels if lab.startswith("MLP mass"))
    ctx.claim("the MLP system's output has more 3rd-order capacity than the LIL system's", out3["mlp"] > out3["lil"],
              f"degree 3: MLP {out3['mlp']:.3g}, LIL {out3['lil']:.3g}")
    ctx.claim("the MLP system has more 3rd-order capacity at the mass points than the LIL system (sum over x, y)",
              mass3["mlp"] > mass3["lil"], f"degree 3 summed over {n_coords} coordinates: MLP {mass3['mlp']:.3g}, "
                                           f"LIL {mass3['lil']:.3g}")
    outs = [lab for lab in res.labels if " output, epoch " in lab]
    worst = max(abs(res.total[res.group(lab)] - 1) for lab in outs)
    ctx.claim(f"the output's total capacity reaches its rank, 1 (|total − 1| < {RANK_TOL} for every output bar)",
              bool(worst < RANK_TOL),
              "totals: " + ", ".join(f"{lab}: {res.total[res.group(lab)]:.3f}" for lab in outs))

    notes = ["target bar: the series the output is trained on, y(t+1) for input u(t)"]
    lil_nonlinear = float(np.sum(deg(f"LIL output, epoch {stages[-1]}")[1:]))
    if (not all(a > b for a, b in grows.values()) or not out3["mlp"] > out3["lil"]) and lil_nonlinear < 1e-3:
        notes.append("the LIL system's output stays linear: at these amplitudes the body's geometric nonlinearity "
                     f"is tiny in a 1-D output (its degree ≥ 2 capacity after thresholding: {lil_nonlinear:.2g}); "
                     "the MLP (zero-bias ReLU, symmetric input) "
                     "adds mainly even, 2nd-order terms; 3rd order would need trained biases (kinks away from "
                     f"u = 0) — {stages[-1]} Adam epochs are far from the paper's 40,000 SGD epochs")
    if worst >= RANK_TOL:
        notes.append("totals deviate from the rank by the in-sample overlap of the basis functions (≈ 1/√T) and by "
                     "capacity beyond delay 20 / degree 3")
    fig, axes = plt.subplots(len(BRAINS), 2, figsize=(15, 4.2 * len(BRAINS)),
                             gridspec_kw={"width_ratios": [len(stages) + 1.5, 34]})
    maxd = res.max_delays()
    for row, brain in enumerate(BRAINS):
        left = [f"{brain.upper()} output, epoch {e}" for e in stages] + ["target"]
        rows = [res.group(lab) for lab in left]
        draw_ipc_bars(axes[row, 0], [lab.replace(f"{brain.upper()} output, ", "") for lab in left],
                      res.capacity[rows], res.degrees, maxd, res.rank[rows], legend=False)
        axes[row, 0].set_title(f"{brain.upper()}: output (CMP y) by training epoch", fontsize=9)
        right = [lab for lab in res.labels if lab.startswith(f"{brain.upper()} mass")]
        rows = [res.group(lab) for lab in right]
        draw_ipc_bars(axes[row, 1], [lab.replace(f"{brain.upper()} mass ", "") for lab in right],
                      res.capacity[rows], res.degrees, maxd, res.rank[rows])
        axes[row, 1].set_title(f"{brain.upper()} + double circle, epoch {stages[-1]}: each movable mass "
                               "(index, axis)", fontsize=9)
    ctx.figure(_save(fig, ctx.out_dir / "narma_ipc.png"))
    ctx.result.details = {"config": config, "stages": list(stages), "eval_inputs": eval_inputs, "washout": washout,
                          "max_delay": max_delay, "max_degree": 3, "surrogates": surrogates,
                          "threshold": res.settings["threshold"],
                          "definition": res.settings["definition"], "jobs": results, "ipc": summary, "notes": notes}
