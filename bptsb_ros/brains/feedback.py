"""Feedback layer (FL): a linear map from body state to the SWG's control signal, fitted by ridge
regression, that replaces the SWG to close the loop (paper, "Autonomous behavior through brain
function transfer").

Open loop:   l(t+Δt) = l·(1 + A·sin(ω(t+Δt) + φ))
Closed loop: l(t+Δt) = l·(1 + W·[s(t), 1])      with s(t) the body state (spring lengths by default).
"""

from __future__ import annotations

from typing import Literal

import numpy as np
import torch
from torch import nn

from bptsb_ros.body.msdn import BodyState

StateType = Literal["spring_length", "position", "velocity", "acceleration"]
STATE_TYPES: tuple[str, ...] = ("spring_length", "position", "velocity", "acceleration")


def state_features(state: BodyState, state_type: StateType) -> torch.Tensor:
    """Body state → feature matrix (B, F): spring lengths (E), or flattened movable r, v or a (2M)."""
    if state_type == "spring_length":
        return state.length
    if state_type == "position":
        return state.r.flatten(1)
    if state_type == "velocity":
        return state.v.flatten(1)
    if state_type == "acceleration":
        return state.a.flatten(1)
    raise ValueError(f"unknown state type {state_type!r}; choose one of {', '.join(STATE_TYPES)}")


def fit_ridge(
    x: np.ndarray,
    y: np.ndarray,
    *,
    lambdas: np.ndarray | None = None,
    criterion: Literal["aic", "gcv"] = "aic",
) -> tuple[np.ndarray, np.ndarray]:
    """Ridge regression y ≈ [x, 1] W per output column, the ridge parameter chosen per column.

    For each candidate λ the effective degrees of freedom are df = Σ s²/(s² + λ) (s: singular values
    of the centred inputs); the column's λ minimises AIC = n·log(RSS/n) + 2·df, or GCV =
    n·RSS/(n − df)². The bias is not penalised.

    Args:
        x: (n, F) inputs. y: (n, K) targets.

    Returns:
        weights: (K, F + 1), last column the bias; chosen: (K,) the λ chosen for each output.
    """
    if x.ndim != 2 or y.ndim != 2 or x.shape[0] != y.shape[0]:
        raise ValueError(f"fit_ridge needs x (n, F) and y (n, K) with equal n, got {x.shape} and {y.shape}")
    if not (np.isfinite(x).all() and np.isfinite(y).all()):
        raise ValueError("fit_ridge: inputs or targets contain NaN/inf")
    n = x.shape[0]
    lambdas = np.logspace(-8, 4, 49) if lambdas is None else np.asarray(lambdas, dtype=np.float64)
    x_mean, y_mean = x.mean(0), y.mean(0)
    xc, yc = x - x_mean, y - y_mean
    u, s, vt = np.linalg.svd(xc, full_matrices=False)
    uty = u.T @ yc  # (r, K)
    best_score = np.full(y.shape[1], np.inf)
    best_w = np.zeros((x.shape[1], y.shape[1]))
    chosen = np.zeros(y.shape[1])
    for lam in lambdas:
        shrink = s / (s * s + lam)  # (r,)
        w = vt.T @ (shrink[:, None] * uty)  # (F, K)
        rss = ((yc - xc @ w) ** 2).sum(0) + 1e-300
        df = float((s * s / (s * s + lam)).sum())
        if criterion == "aic":
            score = n * np.log(rss / n) + 2 * df
        else:
            score = n * rss / max(n - df, 1e-9) ** 2
        better = score < best_score
        best_score = np.where(better, score, best_score)
        best_w[:, better] = w[:, better]
        chosen[better] = lam
    bias = y_mean - x_mean @ best_w
    return np.concatenate([best_w.T, bias[:, None]], axis=1), chosen


class FeedbackLayer(nn.Module):
    """Linear feedback map from body state features (F) to the control signal of E springs.

    ``weight`` is (E, F + 1) with the bias in the last column; rows of springs that are not fed back
    (``driven`` False) are zero, so those springs keep their rest length.
    """

    def __init__(self, n_features: int, n_springs: int, *, state_type: StateType = "spring_length",
                 driven: torch.Tensor | None = None, dtype: torch.dtype = torch.float32) -> None:
        super().__init__()
        if state_type not in STATE_TYPES:
            raise ValueError(f"unknown state type {state_type!r}; choose one of {', '.join(STATE_TYPES)}")
        self.state_type: StateType = state_type
        self.weight = nn.Parameter(torch.zeros(n_springs, n_features + 1, dtype=dtype))
        mask = torch.ones(n_springs, dtype=torch.bool) if driven is None else driven.to(torch.bool)
        self.register_buffer("driven", mask)

    def signal_from_features(self, features: torch.Tensor) -> torch.Tensor:
        """features (B, F) → control signal (B, E)."""
        out = features @ self.weight[:, :-1].T + self.weight[:, -1]
        return out * self.driven

    def signal(self, state: BodyState) -> torch.Tensor:
        """Control signal (B, E) computed from a body state."""
        return self.signal_from_features(state_features(state, self.state_type))

    def rest_length(self, base: torch.Tensor, state: BodyState) -> torch.Tensor:
        """Rest length (B, E) for the next step from the current state: l·(1 + W·[s, 1])."""
        return self.rest_length_from_features(base, state_features(state, self.state_type))

    def rest_length_from_features(self, base: torch.Tensor, features: torch.Tensor) -> torch.Tensor:
        """Rest length (B, E) from state features (B, F) laid out as ``state_features`` does."""
        return base * (1 + self.signal_from_features(features))

    def load_fit(self, weights: np.ndarray) -> None:
        """Copy a (E, F + 1) ridge solution in (undriven rows are zeroed)."""
        w = torch.as_tensor(weights, dtype=self.weight.dtype)
        if w.shape != self.weight.shape:
            raise ValueError(f"feedback weights must be {tuple(self.weight.shape)}, got {tuple(w.shape)}")
        with torch.no_grad():
            self.weight.copy_(w * self.driven.unsqueeze(-1))
