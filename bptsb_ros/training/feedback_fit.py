"""Fit the feedback layer (FL) of an SWG agent by ridge regression (paper, closed-loop framework):
run the trained open loop, regress the SWG's next control signal on the current body state (plus
Gaussian input noise), on the middle 60 % of the run."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from bptsb_ros.agent import Agent
from bptsb_ros.body.msdn import BodyState
from bptsb_ros.brains import SineWaveGenerator, fit_ridge
from bptsb_ros.brains.feedback import state_features
from bptsb_ros.config import FeedbackConfig
from bptsb_ros.sim.rollout import simulate_open_loop


def fit_feedback(agent: Agent, cfg: FeedbackConfig, state: BodyState | None, seed: int) -> dict[str, Any]:
    """Fit ``agent.feedback`` in place from an open-loop run starting at ``state``; returns fit info."""
    if agent.feedback is None or not isinstance(agent.brain, SineWaveGenerator):
        raise ValueError("fit_feedback needs an SWG agent with a feedback layer")
    body = agent.body
    steps = int(round(cfg.fit_time / body.dt))
    roll = simulate_open_loop(agent, steps, state=state)
    # every recorded step as one batch row: features of the state at step k ...
    states = BodyState(roll.r[:-1, 0], roll.v[:-1, 0], roll.a[:-1, 0], roll.length[:-1, 0])
    x = state_features(states, cfg.state).double().numpy()
    first = 0 if state is None else state.step
    with torch.no_grad():  # ... and the SWG signal in force at step k+1
        y = agent.brain.signal_at_steps(torch.arange(first + 1, first + steps + 1), body.dt).double().numpy()
    lo, hi = int(0.2 * steps), int(0.8 * steps)
    rng = np.random.default_rng(seed)
    x_fit = x[lo:hi] + cfg.noise * rng.standard_normal(x[lo:hi].shape)
    weights, lambdas = fit_ridge(x_fit, y[lo:hi], criterion=cfg.criterion)
    agent.feedback.load_fit(weights)
    agent.feedback_fitted = True
    pred = np.concatenate([x[lo:hi], np.ones((hi - lo, 1))], 1) @ weights.T
    rmse = float(np.sqrt(np.mean((pred - y[lo:hi]) ** 2)))
    return {
        "fit_steps": hi - lo,
        "noise": cfg.noise,
        "state": cfg.state,
        "ridge_lambda_median": float(np.median(lambdas)),
        "fit_rmse_clean_inputs": rmse,
        "signal_rms": float(np.sqrt(np.mean(y[lo:hi] ** 2))),
    }

