"""Nonlinearity of a linear MSDN through geometry (supplement, "Nonlinearity in linear mass-spring-damper
networks"), shown with IPC.

The supplement proves that a body of linear springs driven by a linear input layer (LIL) is nonlinear in the input
because spring forces act along directions that change with the positions (cos θ_ij terms), and that a chain of
masses moving along one line stays linear. Here both bodies, untrained (k ~ U(1, 100), d ~ U(0, 10), LIL weights
~ N(0, 1)), are driven by i.i.d. u ~ U(0, 1) held τ = 20 steps, at several input scales (force = LIL(scale · u);
the paper's scale is 20), all scales of one body in one batched simulation. The IPC (degree ≤ 3) of every movable
mass's x and y, and of all of them together, is computed from the block-end positions (u mapped to [−1, 1]).

Claims: :func:`claims`, each the sentence of the supplement it tests (quoted there) with its premise (the body
responds to the input at all).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import torch

from bptsb_ros.experiments.measured import judge
from bptsb_ros.experiments.registry import Context, experiment
from bptsb_ros.experiments.result import Claim
from bptsb_ros.experiments.timeseries_claims import fmt

#: degree ≥ 2 capacity (all coordinates) above which a body counts as nonlinear; shuffled-input noise is < 0.02
NONLINEAR_MIN = 0.05
#: degree ≥ 2 capacity below which a body counts as linear
LINEAR_MAX = 0.01
SCALES = (1.0, 5.0, 20.0)
#: the paper's input scale (forces from 20·u)
PAPER_SCALE = 20.0
TAU = 20


@dataclass(frozen=True)
class BodyCapacity:
    """The IPC of all of a body's movable coordinates together at one input scale: degree-1 and degree ≥ 2
    capacity (1)."""

    degree_1: float
    degree_2plus: float

    @property
    def total(self) -> float:
        return self.degree_1 + self.degree_2plus


@dataclass(frozen=True)
class NonlinearityNumbers:
    """What the claims of msdn-nonlinearity rest on: input scale → :class:`BodyCapacity`, for the double circle
    (N_mov 17) and for the 1-D chain, both untrained under LIL forces."""

    double_circle: Mapping[float, BodyCapacity]
    chain: Mapping[float, BodyCapacity]


def _responds(c: BodyCapacity) -> bool:
    """The body's states carry the input at all (a finite total capacity > 0)."""
    return bool(math.isfinite(c.total) and c.total > 0)


@judge("msdn-nonlinearity")
def claims(n: NonlinearityNumbers) -> list[Claim]:
    """The supplement ("Nonlinearity in linear mass-spring-damper networks"):

    1. "This indicates that a system with a linear MSDN and a linear input layer (LIL) can generate nonlinear
       information processing capacity (IPC) profiles in a time-series emulation task": the double circle at the
       paper's input scale has degree ≥ 2 capacity > :data:`NONLINEAR_MIN` (above what shuffled inputs give).
       Premise: the body responds to the input (total capacity > 0).
    2. "Therefore, if mass points are located in one dimension and move one-dimensionally, for example, if they
       connect in series and move only in such direction, the system remains linear": the chain's degree ≥ 2
       capacity < :data:`LINEAR_MAX` at every input scale. Premise: the chain responds to the input at every scale
       (total capacity > 0; a chain at rest would be "linear" trivially).
    """
    out: list[Claim] = []
    dc = n.double_circle[PAPER_SCALE]
    by_scale = ", ".join(f"scale {s:g}: {fmt(c.degree_2plus)}" for s, c in n.double_circle.items())
    text = (f"a linear double-circle MSDN under LIL forces has nonlinear (degree ≥ 2) capacity (> {NONLINEAR_MIN} at "
            f"the paper's input scale {PAPER_SCALE:g})")
    if not _responds(dc):
        out.append(Claim.not_testable(text, f"the double circle does not respond to the input at scale "
                                            f"{PAPER_SCALE:g} (total capacity {fmt(dc.total)})"))
    else:
        out.append(Claim(text, bool(dc.degree_2plus > NONLINEAR_MIN),
                         f"degree ≥ 2 capacity = {fmt(dc.degree_2plus)} ({by_scale})"))
    text = (f"a chain moving along one line stays linear (degree ≥ 2 capacity < {LINEAR_MAX} at every input scale)")
    still = [f"scale {s:g}: total capacity {fmt(c.total)}" for s, c in n.chain.items() if not _responds(c)]
    if still:
        out.append(Claim.not_testable(text, "the chain does not respond to the input (" + "; ".join(still) + ")"))
    else:
        worst = max(c.degree_2plus for c in n.chain.values())
        out.append(Claim(text, bool(worst < LINEAR_MAX),
                         f"largest degree ≥ 2 capacity {fmt(worst)}; degree 1: " + ", ".join(
                             f"scale {s:g}: {fmt(c.degree_1)}" for s, c in n.chain.items())))
    return out


def _bodies(seed: int):
    from bptsb_ros.body.msdn import MSDN
    from bptsb_ros.body.shapes import build_shape
    from bptsb_ros.brains import LinearInputLayer
    from bptsb_ros.experiments.timeseries import chain_topology

    gen = torch.Generator().manual_seed(seed)
    out = {}
    for name, topo, axes in (("double-circle (N_mov 17)", build_shape("double_circle", 33, 4.0, 3), (0, 1)),
                             ("1-D chain (8 movable)", chain_topology(8), (0,))):
        body = MSDN(topo, generator=gen, dtype=torch.float64)
        receivers = [m for m in range(body.n_movable) if m != body.cmp_local]  # the CMP gets no force (paper)
        lil = LinearInputLayer(1, 2 * len(receivers), generator=gen, dtype=torch.float64)
        axis_mask = torch.zeros(2, dtype=torch.float64)
        axis_mask[list(axes)] = 1.0

        def forces(u: torch.Tensor, body=body, lil=lil, receivers=receivers, axis_mask=axis_mask) -> torch.Tensor:
            f = u.new_zeros((*u.shape[:-1], body.n_movable, 2))
            f[..., receivers, :] = lil(u).view(*u.shape[:-1], len(receivers), 2) * axis_mask
            return f

        out[name] = (body, forces)
    return out


@experiment(
    "msdn-nonlinearity",
    paper_ref="Supplement 'Nonlinearity in linear mass-spring-damper networks'",
    summary="IPC of an untrained double-circle body under LIL forces (degree >= 2 present) vs a 1-D chain "
            "(degree 1 only)",
)
def run(ctx: Context) -> None:
    from bptsb_ros.analysis.ipc import ipc_groups, mass_groups, to_unit_interval
    from bptsb_ros.analysis.timeseries_plots import IpcPanel, plot_ipc_panels
    from bptsb_ros.experiments.timeseries import one_torch_thread
    from bptsb_ros.sim.blocks import block_positions

    one_torch_thread()
    blocks, max_delay = ctx.settings["blocks"], ctx.settings["max_delay"]
    surrogates = 1000  # per degree tuple, the reference's (ipc-module's) default: cheap at every scale
    washout = 100
    rng = np.random.default_rng(ctx.seed)
    u = rng.uniform(0.0, 1.0, blocks)
    v = to_unit_interval(u)
    scaled = np.stack([s * u for s in SCALES])  # (S, K): one batch member per input scale
    summary: dict[str, dict[str, dict]] = {}
    panels = []
    for name, (body, forces) in _bodies(ctx.seed).items():
        ctx.log(f"msdn-nonlinearity: {name}, {blocks} inputs × τ {TAU} at scales {SCALES}")
        pos = block_positions(body, forces, scaled, TAU)  # (S, K, M, 2)
        movable = body.topology.movable
        groups, labels = [], []
        for s, scale in enumerate(SCALES):
            g, lab = mass_groups(pos[s], movable, body.topology.cmp_index)
            keep = [i for i, lb in enumerate(lab) if "output" not in lb and not np.allclose(np.ptp(g[i], 0), 0)]
            groups += [g[i] for i in keep]
            labels += [f"{lab[i]} @{scale:g}" for i in keep]
        # a linearity test: degree >= 2 functions orthogonalised in-sample against the degree-1 ones, else a
        # linear body's in-sample linear overlaps survive the shuffled-input thresholds (analysis.ipc)
        res = ipc_groups(v, groups, labels, max_degree=3, max_delay=max_delay, washout=washout,
                         surrogates=surrogates, orthogonalise_linear=True, seed=ctx.seed, progress=ctx.progress)
        summary[name] = {}
        for scale in SCALES:
            g = res.group(f"all movable x, y @{scale:g}")
            bd = res.by_degree()[g]
            summary[name][f"{scale:g}"] = {"total": float(res.total[g]), "rank": int(res.rank[g]),
                                           "degree_1": float(bd[0]), "degree_2plus": float(bd[1:].sum()),
                                           "by_degree": bd.tolist()}
            ctx.row(f"{name}, LIL scale {scale:g}", "IPC degree 1 (all movable x, y)", "1", float(bd[0]))
            ctx.row(f"{name}, LIL scale {scale:g}", "IPC degree ≥ 2 (all movable x, y)", "1", float(bd[1:].sum()),
                    "> 0 (double circle) / 0 (chain)")
            ctx.row(f"{name}, LIL scale {scale:g}", "rank of the states", "1", float(res.rank[g]))
        shown = [lab for lab in res.labels if lab.endswith(f"@{SCALES[-1]:g}") and not lab.startswith("all")]
        panels.append([IpcPanel.of(res, shown, f"{name}, untrained, LIL forces (scale {SCALES[-1]:g}): IPC of each "
                                   "movable coordinate", names=[lab.rsplit(" @", 1)[0] for lab in shown])])
    ctx.phase("plotting the IPC panels")
    path = plot_ipc_panels(ctx.out_dir / "msdn_nonlinearity_ipc.png", panels)
    ctx.figure(path)
    numbers = NonlinearityNumbers(*({float(sc): BodyCapacity(v["degree_1"], v["degree_2plus"])
                                     for sc, v in summary[name].items()}
                                    for name in ("double-circle (N_mov 17)", "1-D chain (8 movable)")))
    ctx.judge(claims, numbers)
    ctx.result.details = {"blocks": blocks, "tau": TAU, "washout": washout, "max_delay": max_delay, "max_degree": 3,
                          "surrogates": surrogates, "threshold": res.settings["threshold"],
                          "definition": res.settings["definition"], "input_scales": list(SCALES),
                          "ipc": summary}
