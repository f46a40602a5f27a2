"""The Python API: what ``import bptsb_ros as bp`` offers a researcher (``bp.load_config``, ``bp.train``, ...).

Each function is the code path the ``bptsb`` command runs, with a Python signature: configs by packaged name or
path with overrides as a mapping, training in memory (no files unless ``out`` is given), simulation of an agent
object, the feedback-layer fit, IPC of arrays, and the paper's experiments by their ``bptsb reproduce`` name
(writing only into ``out``). Nothing here imports torch until a function that needs it is called.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

if TYPE_CHECKING:
    import numpy.typing as npt
    import torch

    from bptsb_ros.agent import Agent
    from bptsb_ros.analysis.ipc import IPCResult
    from bptsb_ros.body.msdn import BodyState
    from bptsb_ros.config import ExperimentConfig, FeedbackConfig, Overrides
    from bptsb_ros.experiments.result import ExperimentResult
    from bptsb_ros.sim.trajectory import Trajectory
    from bptsb_ros.workflows.train import TrainResult, UpdateCallback

def packaged_configs() -> list[str]:
    """Names of the packaged experiment configs, for :func:`load_config`.

    Returns:
        The names, sorted (e.g. ``["lissajous_single", "locomotion_forward", ..., "narma"]``).
    """
    from bptsb_ros.experiments.common import packaged_configs as names

    return names()


def load_config(source: str | os.PathLike[str], overrides: Overrides | None = None, *,
                seed: int | None = None) -> ExperimentConfig:
    """Load and validate an experiment config.

    Args:
        source: a packaged config's name (``"lissajous_single"``, ``"narma"``: a text without a path separator
            or ``.yaml`` suffix; :func:`packaged_configs` lists them) or the path of a YAML file.
        overrides: a mapping ``{"sim_time": 20, "training.lr.k": 100.0}`` (values as they are) or ``--set``
            texts ``["sim_time=20"]`` (values parsed as YAML); a ``profile`` override applies first.
        seed: the random seed, replacing the config's.

    Returns:
        The validated config.

    Raises:
        ConfigError: unknown name, unreadable file, or an invalid key or value (the message names it).
    """
    from bptsb_ros.config import load_config as load
    from bptsb_ros.experiments.common import packaged_config_path

    if isinstance(source, str) and not _looks_like_path(source):
        return load(packaged_config_path(source), overrides, seed)
    return load(Path(source), overrides, seed)


def _looks_like_path(text: str) -> bool:
    separators = [sep for sep in (os.sep, os.altsep, "/") if sep]
    return any(sep in text for sep in separators) or text.lower().endswith((".yaml", ".yml"))


def _config(config: ExperimentConfig | str | os.PathLike[str]) -> ExperimentConfig:
    from bptsb_ros.config import ExperimentConfig

    return config if isinstance(config, ExperimentConfig) else load_config(config)


def build_agent(config: ExperimentConfig | str | os.PathLike[str]) -> Agent:
    """A fresh agent: body with k, d drawn from the config's seed, rest lengths from the layout, a fresh brain.

    Args:
        config: a config from :func:`load_config`, or a packaged config's name or a path (loaded as is).

    Returns:
        The agent (``agent.body``, ``agent.brain``, ``agent.feedback`` for SWG agents).
    """
    from bptsb_ros.agent import build_agent as build

    return build(_config(config))


def load_agent(run_dir: str | os.PathLike[str], *, dtype: Literal["float32", "float64"] | None = None) -> Agent:
    """The agent saved in a run directory (``bptsb train --out`` or :func:`train` with ``out``).

    Args:
        run_dir: the run directory (its ``checkpoint.pt`` is read as data only).
        dtype: convert the agent to this floating-point type; None keeps the trained one.

    Returns:
        The agent, parameters frozen; ``agent.feedback_fitted`` as saved.

    Raises:
        CheckpointError: no readable checkpoint.
    """
    from bptsb_ros.agent import dtype_of
    from bptsb_ros.training.checkpoint import load_agent as load

    return load(run_dir, dtype=None if dtype is None else dtype_of(dtype))


def train(config: ExperimentConfig | str | os.PathLike[str], *, out: str | os.PathLike[str] | None = None,
          callback: UpdateCallback | None = None, progress: bool = False, resume: bool = False,
          overwrite: bool = False, init_from: str | os.PathLike[str] | None = None) -> TrainResult:
    """Train the config's agent with BPTSB (what ``bptsb train`` runs), fit its feedback layer (SWG agents) and
    evaluate it.

    Args:
        config: a config from :func:`load_config`, or a packaged config's name or a path (loaded as is).
        out: a run directory for checkpoint.pt, config.yaml, metrics.json and plots (as ``bptsb train --out``);
            None trains in memory and writes no file.
        callback: ``callback(update, loss)`` after every update: its index and its loss [task units, e.g. m²]
            (a rejected update repeats the previous loss).
        progress: a progress bar on stderr.
        resume: continue the run saved in ``out`` (needs ``out``).
        overwrite: replace a run already in ``out``.
        init_from: a run directory whose trained parameters this training starts from.

    Returns:
        ``result.agent`` (trained), ``result.state`` (the body state where training ended, SWG tasks),
        ``result.losses`` (one per update), ``result.metrics`` (``evaluation``: the paper's metric),
        ``result.files`` (empty in memory).

    Raises:
        ConfigError: ``out`` holds another run (neither ``resume`` nor ``overwrite``), or ``resume`` without one.
        TrainingDiverged: the simulation or the loss diverged and the update guard had nothing to undo.
    """
    from bptsb_ros.workflows.train import train as run

    return run(_config(config), out, resume=resume, overwrite=overwrite, progress=progress, init_from=init_from,
               callback=callback)


def simulate(agent: Agent, steps: int, *, loop: Literal["open", "closed"] = "open", state: BodyState | None = None,
             seed: int = 0, perturb: float = 0.0, wind: Sequence[float] | torch.Tensor | None = None,
             progress: Callable[[int], None] | None = None) -> Trajectory:
    """Simulate an agent headless (what ``bptsb simulate --agent`` runs), without writing anything.

    Args:
        agent: from :func:`build_agent`, :func:`train` (``result.agent``) or :func:`load_agent`.
        steps: number of integration steps T ≥ 1 (of the agent's ``dt``).
        loop: "open" (the brain) or "closed" (the fitted feedback layer of an SWG agent).
        state: start state, e.g. ``result.state`` (where training ended); default: at rest at t = 0.
        seed: seeds ``perturb`` and, for LIL/MLP agents, the NARMA input series (as ``bptsb simulate --seed``).
        perturb: σ [m] of a Gaussian displacement of the movable masses at t = 0 (not with ``state``).
        wind: (2,) constant force on every movable mass [N].
        progress: called with the number of steps done every 100 steps.

    Returns:
        The trajectory: ``positions`` (T+1, N, 2) [m], ``velocities``, ``rest_length`` (T+1, E), ...;
        ``traj.reference_point()`` is the CMP's path (T+1, 2); ``traj.save_npz(path)`` writes it.

    Raises:
        ValueError: bad arguments, or ``loop="closed"`` without a fitted feedback layer.
        SimulationDiverged: the simulation blew up (the message names the step).
    """
    from bptsb_ros.sim.agent_run import simulate_agent

    return simulate_agent(agent, steps, loop=loop, seed=seed, perturb=perturb, wind=wind, state=state,
                          progress=progress)


def fit_feedback(agent: Agent, *, state: BodyState | None = None, config: FeedbackConfig | None = None,
                 seed: int | None = None) -> dict[str, Any]:
    """Fit an SWG agent's feedback layer by ridge regression, in place (what training does after its updates).

    The open loop runs ``config.fit_time`` seconds from ``state``; the SWG signal in force at step k+1 is
    regressed on the body state at step k (``config.state``, plus N(0, ``config.noise``²) input noise) over the
    middle 60 % of the run, the ridge parameter chosen per spring by ``config.criterion``.

    Args:
        agent: an SWG agent with a feedback layer; ``agent.feedback`` is overwritten and
            ``agent.feedback_fitted`` set.
        state: where the open loop starts, e.g. ``result.state`` of :func:`train`; default: at rest at t = 0.
        config: the fit's settings; default: the agent's config ``feedback`` section.
        seed: seeds the input noise; default: the agent's config ``seed``.

    Returns:
        Fit information: ``fit_steps``, ``ridge_lambda_median``, ``fit_rmse_clean_inputs``, ``signal_rms``, ...

    Raises:
        ValueError: the agent is not an SWG agent with a feedback layer.
    """
    from bptsb_ros.config import FeedbackConfig
    from bptsb_ros.training.feedback_fit import fit_feedback as fit

    settings = FeedbackConfig.model_validate(agent.config["feedback"]) if config is None else config
    return fit(agent, settings, state, int(agent.config["seed"]) if seed is None else seed)


def ipc(u: npt.ArrayLike, states: npt.ArrayLike, *, max_degree: int = 3, max_delay: int = 20, min_delay: int = 0,
        washout: int = 100, surrogates: int = 1000, threshold: Literal["tuple-max", "none"] = "tuple-max",
        threshold_scale: float = 1.0, rank_cap: bool = True, orthogonalise_linear: bool = False, seed: int = 0,
        label: str = "states", progress: bool = False) -> IPCResult:
    """Information processing capacity (Dambre et al. 2012) of states driven by an i.i.d. input (``bptsb ipc``),
    as the reference implementation (ipc-module) defines it (:mod:`bptsb_ros.analysis.ipc`).

    Args:
        u: (T,) i.i.d. input uniform in [−1, 1] (map a task's u in [0, 1] by 2u − 1).
        states: (T,) or (T, N); row t is the state after input u(t).
        max_degree: the basis' highest total degree of Legendre products.
        max_delay: the basis' longest input delay [samples].
        min_delay: the basis' shortest input delay [samples].
        washout: samples discarded at the start (at least ``max_delay`` are).
        surrogates: shuffled-input surrogates per degree tuple for the threshold.
        threshold: "tuple-max" (a capacity counts above ``threshold_scale`` × the largest surrogate capacity of
            its degree tuple) or "none" (raw capacities).
        threshold_scale: the factor on the surrogate maximum.
        rank_cap: drop the smallest capacities while their total exceeds the states' rank.
        orthogonalise_linear: the linearity-test variant (degree ≥ 2 orthogonal in-sample to degree 1).
        seed: seeds the surrogate permutations.
        label: the state set's name in the result.
        progress: a progress bar over the surrogates on stderr.

    Returns:
        ``result.total`` (1,) total capacity, ``result.by_degree()`` (1, max_degree), ``result.capacity``
        (1, F) per basis function (``result.terms``, ``result.name(f)``), ``result.rank``.

    Raises:
        IPCError: unsuitable input or states (the message names the problem).
    """
    from bptsb_ros.analysis.ipc import ipc_groups

    return ipc_groups(u, [states], [label], max_degree=max_degree, max_delay=max_delay, min_delay=min_delay,
                      washout=washout, surrogates=surrogates, threshold=threshold, threshold_scale=threshold_scale,
                      rank_cap=rank_cap, orthogonalise_linear=orthogonalise_linear, seed=seed, progress=progress)


def experiment_names() -> list[str]:
    """The paper's experiments that :func:`run_experiment` runs (``bptsb reproduce --list`` describes them).

    Returns:
        Their names, in the order of the paper (e.g. ``"lissajous-closed-loop"``).
    """
    from bptsb_ros.experiments.registry import experiments

    return list(experiments())


def run_experiment(name: str, *, scale: Literal["smoke", "short", "paper"] = "smoke", seed: int = 0,
                   out: str | os.PathLike[str] | None = None, force: bool = False, resume: bool = False,
                   progress: bool = False, workers: int | None = None, scheduler: str | None = None,
                   data: str | os.PathLike[str] | None = None, split: str = "auto",
                   log: Callable[[str], None] | None = None,
                   settings: Mapping[str, Any] | None = None,
                   seeds: Iterable[int] | None = None) -> ExperimentResult | dict[str, Any]:
    """Run one of the paper's experiments (what ``bptsb reproduce NAME`` runs) and return its result.

    Args:
        name: the experiment (:func:`experiment_names`), e.g. ``"lissajous-closed-loop"``.
        scale: "smoke" (seconds), "short" (minutes) or "paper" (the paper's settings).
        seed: the random seed.
        out: the run directory for result.json, figures and trainings (as ``bptsb reproduce --out``); None runs
            in a temporary directory that is removed afterwards (``result.figures`` is then empty).
        force: replace an earlier ``bptsb reproduce`` run in ``out``.
        resume: continue an unfinished run in ``out`` (needs ``out``).
        progress: progress bars on stderr.
        workers: local worker processes for the experiment's independent trainings (None: the CPUs, at smoke
            scale this process; 0: this process); ``result.provenance["jobs"]`` records where they ran.
        scheduler: a Dask scheduler address to run those trainings on instead.
        data: the data directory of experiments that read a data set (MNIST).
        split: the MNIST train/test split ("auto", "paper", "test-8k-2k").
        log: receives the experiment's log lines (default: stderr).
        settings: overrides of the experiment's settings at ``scale`` (as ``bptsb reproduce --set``), e.g.
            ``{"epochs": 3}``; each checked against the setting's type (``bptsb reproduce NAME --show-config``
            lists them).
        seeds: run the experiment once per seed instead (as ``bptsb reproduce --seeds``), each seed in
            ``out/seed-N/``, and return the aggregate over them (``seed`` is then unused).

    Returns:
        The result: ``rows`` (our numbers beside the paper's), ``claims`` (each ``holds`` True, False or None:
        not testable), ``details``, ``wall_s``. With ``seeds``: the aggregate result.json content (each row's
        mean, sd and range over the seeds; each claim's ``verdict`` over the seeds and ``holds_in: [k, n]``).

    Raises:
        ExperimentError: unknown name or scale, ``out`` holds something else, or ``resume`` without ``out``.
        SettingsError: an override names no setting of the experiment or has the wrong type.
    """
    from bptsb_ros.experiments.registry import ExperimentError, execute_experiment

    if seeds is not None:
        from bptsb_ros.experiments.seeds import run_seeds

        multi = {"scale": scale, "force": force, "resume": resume, "progress": progress, "log": log,
                 "workers": workers, "scheduler": scheduler, "data_dir": data, "split": split, "settings": settings}
        if out is not None:
            return run_seeds(name, list(seeds), out_dir=out, **multi)[1]
        if resume:
            raise ExperimentError("resume continues an unfinished run in a directory; give out=")
        with tempfile.TemporaryDirectory(prefix="bptsb-experiment-") as tmp:
            data_out = run_seeds(name, list(seeds), out_dir=Path(tmp) / "run", **multi)[1]
        data_out["figures"] = []  # they were in the temporary directory
        return data_out
    options: dict[str, Any] = {"scale": scale, "seed": seed, "force": force, "resume": resume, "progress": progress,
                               "log": log, "workers": workers, "scheduler": scheduler, "data_dir": data,
                               "split": split, "settings": settings}
    if out is not None:
        return execute_experiment(name, out_dir=out, **options)[1]
    if resume:
        raise ExperimentError("resume continues an unfinished run in a directory; give out=")
    with tempfile.TemporaryDirectory(prefix="bptsb-experiment-") as tmp:
        _, result = execute_experiment(name, out_dir=Path(tmp) / "run", **options)
    result.figures = []  # they were in the temporary directory
    return result
