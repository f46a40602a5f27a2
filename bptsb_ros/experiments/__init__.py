"""The paper's experiments, each runnable by name (``bptsb reproduce NAME --scale smoke|short|paper``).

``registry.py`` holds the registry and the runner, ``result.py`` the result.json schema,
``settings_models.py`` each experiment's settings as a pydantic model, ``experiment_settings.py`` the reader of
``settings/<experiment>.yaml`` (each scale's values of that model) and of ``--set``, and each other module one
experiment (or a family of experiments sharing their training).
"""

from bptsb_ros.experiments.experiment_settings import Settings, SettingsError, resolve_settings
from bptsb_ros.experiments.registry import (
    Context,
    Experiment,
    ExperimentError,
    experiment,
    experiments,
    get_experiment,
    run_experiment,
)
from bptsb_ros.experiments.result import SCALES, ExperimentResult, ResultError, read_result, validate_result

__all__ = [
    "SCALES",
    "Context",
    "Experiment",
    "ExperimentError",
    "ExperimentResult",
    "ResultError",
    "Settings",
    "SettingsError",
    "experiment",
    "experiments",
    "get_experiment",
    "read_result",
    "resolve_settings",
    "run_experiment",
    "validate_result",
]
