"""How much a trained NARMA system's training loss varies with the input sequence alone, and what the update guard
makes of that: the question behind a guard that keeps rejecting updates after it has divided the learning rates
so often that no update changes the parameters any more.

For the trained agent in RUN_DIR (a ``bptsb train`` output, or a time-series job's ``agent`` folder) it draws
``--sequences`` fresh training sequences (as the trainer does: u ~ U(0, 1), ``narma.n_inputs`` inputs, the body from
rest) and computes each one's training loss (output MSE after the washout, up to ``train_end``) with the
parameters fixed. It then feeds these losses, in order, to the trainers' own update guard (reject a loss above
10 × the mean of the last 5 accepted ones) and reports its rejections and rate divisions. With the parameters
fixed, every rejection is caused by the input sequence. Where the training's metrics.json is beside the
checkpoint, the guard's rejection rate over its last updates (when the rates were already tiny) is printed too.

    python scripts/narma_loss_spread.py RUN_DIR [--sequences 400] [--seed 12345]

Prints one JSON object: the loss quantiles, the ratio of the largest to the median, the guard's verdicts at fixed
parameters, and the guard's own rate and final learning rates from metrics.json.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from bptsb_ros.config import validate
from bptsb_ros.tasks.narma import NarmaTask
from bptsb_ros.training.checkpoint import load_agent, read_checkpoint
from bptsb_ros.training.guard import UpdateGuard


def fixed_parameter_losses(run_dir: Path, sequences: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(sequences,) training losses [m²] of the agent in ``run_dir`` on fresh input sequences, parameters fixed,
    and (sequences,) the mean error [m] (output − target) of each: a loss that is mostly bias² means the body sat
    at another mean position, not that it followed the target worse."""
    cfg = validate(read_checkpoint(run_dir)["config"], str(run_dir))
    task = NarmaTask(load_agent(run_dir), cfg)
    rng = np.random.default_rng(seed)
    n = cfg.narma
    window = slice(n.washout, n.train_end)
    losses, biases = [], []
    for _ in range(sequences):
        u = rng.uniform(0.0, 1.0, n.n_inputs)
        y = task.target(u)
        out = task.episode(u, grad=False).double().numpy()
        losses.append(float(np.mean((out[window] - y[window]) ** 2)))
        biases.append(float(np.mean(out[window] - y[window])))
    return np.asarray(losses), np.asarray(biases)


def guard_verdicts(losses: np.ndarray) -> dict[str, float | int]:
    """What the trainers' :class:`UpdateGuard` (its default rules) makes of ``losses`` arriving in this order at
    fixed parameters: the share of them it rejects and how often it divides the learning rates."""
    param = torch.nn.Parameter(torch.zeros(1))
    guard = UpdateGuard(torch.optim.SGD([param], lr=1.0))
    rejected = sum(not guard.review(i, float(v)).accepted for i, v in enumerate(losses))
    return {"rejection_rate": rejected / len(losses), "divisions": guard.summary()["divisions"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--sequences", type=int, default=400)
    parser.add_argument("--seed", type=int, default=12345)
    parser.add_argument("--last", type=int, default=10_000, help="the guard's updates counted from metrics.json")
    args = parser.parse_args()
    torch.set_num_threads(1)
    losses, biases = fixed_parameter_losses(args.run_dir, args.sequences, args.seed)
    q = np.quantile(losses, [0.0, 0.5, 0.9, 0.99, 1.0])
    spiked = losses > 10 * q[1]
    report: dict = {"sequences": args.sequences, "loss_quantiles_0_50_90_99_100": q.tolist(),
                    "max_over_median": float(q[-1] / q[1]),
                    "share_above_10x_median": float(np.mean(spiked)),
                    "bias_share_of_loss_spiked": float(np.median(biases[spiked] ** 2 / losses[spiked]))
                    if spiked.any() else None,
                    "bias_share_of_loss_others": float(np.median(biases[~spiked] ** 2 / losses[~spiked])),
                    "bias_spiked_m": np.quantile(biases[spiked], [0, 0.5, 1]).tolist() if spiked.any() else None,
                    "bias_others_m": np.quantile(biases[~spiked], [0, 0.5, 1]).tolist(),
                    "guard_at_fixed_parameters": guard_verdicts(losses)}
    metrics = args.run_dir / "metrics.json"
    if metrics.is_file():
        guard = json.loads(metrics.read_text())["guard"]
        updates = len(json.loads(metrics.read_text())["loss"])
        late = [e for e in guard["events"] if e["update"] >= updates - args.last]
        report["training"] = {"updates": updates, "rejections": guard["rejections"], "divisions": guard["divisions"],
                              f"rejection_rate_last_{args.last}_updates": len(late) / min(args.last, updates),
                              "final_rates": guard["rates"]}
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
