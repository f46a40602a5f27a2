"""What the MNIST experiments share: the data (``--data DIR`` / ``$BPTSB_MNIST_DIR``, ``--split``; at paper
scale ``auto`` is the paper's 60,000 / 10,000 split), the bodies by the paper's N_mov, training several systems
as independent jobs (``--workers`` / ``--scheduler``), and the trained drawing systems on disk.

Trained drawing systems are written to ``RUN_DIR/systems/<brain>-<shape>-<nodes>.pt`` (spec + state dicts,
read back with ``torch.load(weights_only=True)``) with the scale, seed and data split they were trained
with. ``mnist-pca`` and ``mnist-labelmap`` reuse the MLP + multiple-circle N_mov 17 system of an
``mnist-drawing`` run in ``<its --out>/../mnist-drawing`` (the default layout ``runs/reproduce/NAME``) when
that system was trained at the same scale, seed and split; otherwise they train their own. Every result
records where its system came from.
"""

from __future__ import annotations

import re
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bptsb_ros.data.mnist import Split, load_split
from bptsb_ros.experiments.registry import Context


@dataclass(frozen=True)
class Data:
    """The images an experiment trains and tests on (float32 (n, 784) in [0, 1], int64 labels)."""

    train_x: np.ndarray
    train_y: np.ndarray
    test_x: np.ndarray
    test_y: np.ndarray
    description: str

    @property
    def key(self) -> str:
        """What identifies this data for checkpoint reuse."""
        return f"{self.description}; n_train {len(self.train_y)}; n_test {len(self.test_y)}"


def body_label(shape: str, n_movable: int) -> str:
    """A body as the result rows name it, by the paper's count of movable masses: ``multiple-circle (N_mov 17)``."""
    return f"{shape.replace('_', '-')} (N_mov {n_movable})"


def body_nodes(shape: str, n_movable: int) -> int:
    """Masses (``nodes``, fixed ones included) of the ``shape`` body with the paper's ``n_movable`` = N_mov."""
    from bptsb_ros.body.shapes import nodes_for_movable

    return nodes_for_movable(shape, n_movable)


def split_for(ctx: Context) -> str:
    """The split a run uses: ``--split`` as given, except that ``auto`` at paper scale is the paper's split (the
    60,000 training / 10,000 test images; without the training files that is an error naming them, not a quiet
    fall-back to ``test-8k-2k``)."""
    return "paper" if ctx.scale == "paper" and ctx.split == "auto" else ctx.split


def load_data(ctx: Context, n_train: int | None, n_test: int | None) -> Data:
    """The split :func:`split_for` names from ``ctx.data_dir`` (or ``$BPTSB_MNIST_DIR``), cut to the first
    ``n_train`` training and ``n_test`` test images (None: all)."""
    ctx.phase("reading the MNIST data")
    split: Split = load_split(ctx.data_dir, split_for(ctx))
    tx, ty = split.train_x[:n_train], split.train_y[:n_train]
    sx, sy = split.test_x[:n_test], split.test_y[:n_test]
    desc = split.description
    if n_train is not None and n_train < len(split.train_y) or n_test is not None and n_test < len(split.test_y):
        desc += f"; of these the first {len(ty)} training and {len(sy)} test images"
    ctx.result.provenance["data"] = desc
    ctx.log(f"MNIST: {desc}")
    return Data(tx, ty, sx, sy, desc)


def specific_images(x: np.ndarray, y: np.ndarray, per_digit: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``per_digit`` images of every digit chosen at random (supplement "with specific inputs": 10 × 10)."""
    rng = np.random.default_rng(seed)
    picks = []
    for d in range(10):
        idx = np.flatnonzero(y == d)
        if len(idx) < per_digit:
            raise ValueError(f"only {len(idx)} training images of digit {d}; need {per_digit}")
        picks.append(rng.choice(idx, per_digit, replace=False))
    order = np.concatenate(picks)
    return x[order], y[order]


def _call_with_kwargs(fn: Callable[..., Any], kwargs: dict[str, Any]) -> Any:
    return fn(**kwargs)


def run_jobs(ctx: Context, fn: Callable[..., Any], jobs: list[dict[str, Any]],
             costs: Sequence[float] | None = None) -> list[Any]:
    """Run independent trainings ``fn(**job, progress=ctx.progress)`` where the run's ``--workers`` /
    ``--scheduler`` say (:meth:`Context.run_jobs`: one torch and BLAS thread per job, a failure names its job);
    results in job order. ``costs`` (one per job, e.g. its body's masses): the jobs are handed out costliest
    first, so a pool of fewer workers than jobs does not end with one long training alone."""
    order = sorted(range(len(jobs)), key=lambda i: -costs[i]) if costs is not None else list(range(len(jobs)))
    out = ctx.run_jobs(_call_with_kwargs, [(fn, {**jobs[i], "progress": ctx.progress}) for i in order],
                       names=[f"training {i}" for i in order], what=getattr(fn, "__name__", "trainings"))
    results: list[Any] = [None] * len(jobs)
    for i, res in zip(order, out):
        results[i] = res
    return results


_EPOCH = re.compile(r"epoch (\d+)/(\d+)")


class EpochLines:
    """The ``log`` of a training inside a job (its process may be a pool worker or a Dask worker): each line to
    that process's stderr at once, except epoch lines (``... epoch e/E ...``), of which one per ``every_s``
    seconds and the last epoch's, so a 1,000-epoch training does not print 1,000 lines. A line that starts
    with ``rename[0]`` (the system's file id, e.g. ``mlp-multiple_circle-37``) starts with ``rename[1]`` (its
    row label, e.g. ``MLP + multiple-circle (N_mov 17)``) instead."""

    def __init__(self, every_s: float = 30.0, rename: tuple[str, str] | None = None) -> None:
        self.every_s = every_s
        self.rename = rename
        self._last: float | None = None

    def __call__(self, line: str) -> None:
        if self.rename and line.startswith(self.rename[0]):
            line = self.rename[1] + line[len(self.rename[0]):]
        m = _EPOCH.search(line)
        if m:
            now = time.monotonic()
            last_epoch = int(m[1]) >= int(m[2])
            if not last_epoch and self._last is not None and now - self._last < self.every_s:
                return
            self._last = now
        print(line, file=sys.stderr, flush=True)


def job_log(progress: bool, rename: tuple[str, str] | None = None) -> Callable[[str], None] | None:
    """The ``log`` a job passes to its training: :class:`EpochLines` when the run shows progress, else None."""
    return EpochLines(rename=rename) if progress else None


def train_drawing_job(spec_json: dict[str, Any], seed: int, train_x: np.ndarray, train_y: np.ndarray,
                      test_x: np.ndarray, test_y: np.ndarray, epochs: int, batch: int, checkpoint: str,
                      meta: dict[str, Any], progress: bool = False) -> dict[str, Any]:
    """Train one drawing system, save it, evaluate it on the test images; returns logs and test outputs.
    ``progress``: epoch lines (and the guard's) to stderr, see :class:`EpochLines`."""
    from bptsb_ros.tasks.drawing import (
        ImageToBody,
        SystemSpec,
        evaluate_drawing,
        save_system,
        train_drawing,
    )

    spec = SystemSpec.from_json(spec_json)
    system = ImageToBody(spec, seed)
    log = train_drawing(system, train_x, train_y, epochs=epochs, batch=batch, seed=seed,
                        log=job_log(progress, (spec.name, f"{spec.brain.upper()} + "
                                                      f"{body_label(spec.shape, system.body.n_movable)}")))
    Path(checkpoint).parent.mkdir(parents=True, exist_ok=True)
    save_system(system, checkpoint, {**meta, "epochs": epochs, "batch": batch, "seed": seed})
    ev = evaluate_drawing(system, test_x, test_y)
    return {"name": spec.name, "losses": log.losses, "epoch_losses": log.epoch_losses, "train_s": log.wall_s,
            "updates": len(log.losses), "checkpoint": checkpoint, "guard": log.guard, **ev}


def reusable_checkpoint(path: Path, meta: dict[str, Any]) -> bool:
    """True when ``path`` holds a system trained with exactly ``meta`` (scale, seed, data, epochs...)."""
    if not path.is_file():
        return False
    from bptsb_ros.tasks.drawing import load_system

    try:
        _, extra = load_system(path)
    except Exception:  # noqa: BLE001 - an unreadable file is simply not reused
        return False
    return all(extra.get(k) == v for k, v in meta.items())


#: where runs beside this one keep trained drawing systems (experiment → folder inside its run), in order of preference
_SYSTEM_FOLDERS = (("mnist-drawing", "systems"), ("mnist-pca", "systems"), ("mnist-labelmap", "systems"),
                   ("mnist-specific100", "systems/all-data"))


def sibling_systems(ctx: Context, name: str) -> list[Path]:
    """Where a drawing system ``name`` trained with all the data may lie in the runs beside this one (for the same
    seed: :meth:`Context.sibling_run`): mnist-drawing's, or the one mnist-pca, mnist-labelmap or mnist-specific100
    trained when they found none to reuse."""
    return [ctx.sibling_run(exp) / folder / f"{name}.pt" for exp, folder in _SYSTEM_FOLDERS
            if exp != ctx.result.experiment]


def first_reusable(candidates: Sequence[Path], meta: dict[str, Any]) -> Path | None:
    """The first of ``candidates`` that holds a system trained with exactly ``meta``, or None."""
    return next((c for c in candidates if reusable_checkpoint(c, meta)), None)


def obtain_drawing_system(ctx: Context, spec, data: Data, *, epochs: int, batch: int, meta: dict[str, Any],
                          reuse: Path | Sequence[Path] | None = None):
    """A trained drawing system and its test evaluation: loaded from ``reuse`` (a checkpoint, or the first of
    several) when that checkpoint was trained with ``meta``, else trained here (written to ``out_dir/systems``).
    Returns (system, evaluation, source description)."""
    from bptsb_ros.tasks.drawing import evaluate_drawing, load_system

    found = first_reusable([reuse] if isinstance(reuse, Path) else list(reuse or ()), meta)
    if found is not None:
        reuse = found
        system, _ = load_system(reuse)
        ctx.log(f"reusing the trained system {reuse}")
        return system, evaluate_drawing(system, data.test_x, data.test_y), f"reused {reuse}"
    path = ctx.out_dir / "systems" / f"{spec.name}.pt"
    ctx.log(f"training {spec.name} for {epochs} epochs on {len(data.train_y)} images")
    res = run_jobs(ctx, train_drawing_job, [dict(spec_json=spec.to_json(), seed=ctx.seed, train_x=data.train_x,
                                                 train_y=data.train_y, test_x=data.test_x, test_y=data.test_y,
                                                 epochs=epochs, batch=batch, checkpoint=str(path), meta=meta)])[0]
    system, _ = load_system(path)
    evaluation = {k: res[k] for k in ("errors", "drawings", "brain", "displacement")}
    g = res["guard"]
    return system, evaluation, (f"trained here ({res['updates']} updates, {res['train_s']:.0f} s, {g['rejections']} "
                                f"update(s) undone by the guard, final rates {g['rates']})")
