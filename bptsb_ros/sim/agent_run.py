"""Headless simulation of an agent as a :class:`~bptsb_ros.sim.trajectory.Trajectory`: the one path behind
``bptsb simulate --agent`` and :func:`bptsb_ros.simulate`.

SWG agents modulate their rest lengths (open loop) or run their fitted feedback layer (closed loop); LIL/MLP
agents get the task input series ``narma_inputs(seed, n)``, held for the config's ``narma.tau`` steps by
``held_inputs`` and scaled by ``narma.input_scale`` (kept as the extra ``input``, the per-step brain input in
force at each step): what the NARMA evaluation and the live ``task_input`` node feed for that seed.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Literal

import numpy as np
import torch

from bptsb_ros.agent import Agent
from bptsb_ros.body.msdn import BodyState
from bptsb_ros.brains import SineWaveGenerator
from bptsb_ros.sim.inputs import brain_input, narma_inputs
from bptsb_ros.sim.rollout import held_inputs, simulate_closed_loop, simulate_open_loop
from bptsb_ros.sim.trajectory import Trajectory, trajectory_from_rollout

Loop = Literal["open", "closed"]


def simulate_agent(
    agent: Agent,
    steps: int,
    *,
    loop: Loop = "open",
    seed: int = 0,
    perturb: float = 0.0,
    wind: Sequence[float] | torch.Tensor | None = None,
    state: BodyState | None = None,
    progress: Callable[[int], None] | None = None,
) -> Trajectory:
    """Simulate ``agent`` for ``steps`` steps without gradients.

    Args:
        agent: a built, trained or loaded agent (its body's ``dt``, integrator and backend are used).
        steps: number of integration steps T (≥ 1); the trajectory holds T + 1 rows.
        loop: "open" (the trained brain) or "closed" (the fitted feedback layer of an SWG agent).
        seed: seeds the perturbation and, for LIL/MLP agents, the NARMA input series u ~ U(0, 1).
        perturb: σ [m] of the N(0, σ²) displacement of every movable mass coordinate at t = 0 (≥ 0).
        wind: (2,) constant force on every movable mass [N], or None.
        state: start state (B = 1; its ``step`` sets the SWG clock), e.g. where training ended; default: at
            rest in the layout at t = 0. Excludes ``perturb``.
        progress: called with the number of steps done every 100 steps and at the end.

    Returns:
        The trajectory (positions (T+1, N, 2) [m], ...; see :mod:`bptsb_ros.sim.trajectory`).

    Raises:
        ValueError: bad ``steps``, ``perturb`` or ``loop``; ``loop="closed"`` without a fitted feedback layer.
        SimulationDiverged: the simulation blew up (the message names the step).
    """
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 1:
        raise ValueError(f"steps must be an integer >= 1, got {steps!r}")
    if not np.isfinite(perturb) or perturb < 0:
        raise ValueError(f"perturb must be a finite number >= 0 [m], got {perturb!r}")
    if loop not in ("open", "closed"):
        raise ValueError(f"loop must be 'open' or 'closed', got {loop!r}")
    if state is not None and perturb > 0:
        raise ValueError("perturb displaces the start at rest; it cannot apply to a given state")
    feedback = agent.feedback
    if loop == "closed" and feedback is None:
        raise ValueError("the agent has no feedback layer (an SWG agent with feedback.enabled has one); "
                         "run the open loop")
    if loop == "closed" and not agent.feedback_fitted:
        raise ValueError("the agent's feedback layer was never fitted (fit_feedback fits it; training fits it "
                         "for SWG agents); run the open loop")
    steps = int(steps)
    body = agent.body
    real = body.l.dtype
    gen = torch.Generator().manual_seed(seed)
    displacement = None
    if perturb > 0:
        displacement = (perturb * torch.randn(1, body.n_movable, 2, generator=gen, dtype=torch.float64)).to(real)
    force = None if wind is None else torch.as_tensor(wind, dtype=real)
    extras: dict[str, np.ndarray] = {}
    if loop == "closed" and feedback is not None:
        roll = simulate_closed_loop(body, feedback, steps, state=state, wind=force, displacement=displacement,
                                    progress=progress)
    else:
        inputs = None
        if not isinstance(agent.brain, SineWaveGenerator):
            narma = agent.config["narma"]
            tau = int(narma["tau"])
            u = narma_inputs(seed, (steps - 1) // tau + 1)
            inputs = brain_input(torch.from_numpy(held_inputs(u, tau, steps)).to(real), narma)
            extras["input"] = inputs.numpy().copy()
        roll = simulate_open_loop(agent, steps, state=state, inputs=inputs, wind=force, displacement=displacement,
                                  progress=progress)
    return trajectory_from_rollout(body, roll, extras=extras)
