"""bptsb_ros: backpropagation through soft body (BPTSB) — differentiable mass-spring-damper bodies and their
brains, trained offline in torch and run live as ROS 2 nodes recorded to MCAP bags.

The version follows semantic versioning: the minor number grows with each round of new experiments or
interfaces, the patch number with fixes only; every release has its section in CHANGELOG.md. The version is
stated once, in ``package.xml``: ``setup.py`` reads it from there, and ``__version__`` is the installed
distribution's (or, imported from a source checkout, that checkout's ``package.xml``).

The Python API (``import bptsb_ros as bp``; :mod:`bptsb_ros.api`): ``bp.load_config``, ``bp.build_agent``,
``bp.train``, ``bp.simulate``, ``bp.fit_feedback``, ``bp.ipc``, ``bp.run_experiment`` and the types they
return. The names are attributes resolved on first use (PEP 562), so ``import bptsb_ros`` stays cheap
(``bptsb --version`` imports it) and torch is imported only when a function that needs it runs.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

#: public name → the module that defines it (imported on first access)
_LAZY: dict[str, str] = {
    # functions
    "packaged_configs": "bptsb_ros.api",
    "load_config": "bptsb_ros.api",
    "build_agent": "bptsb_ros.api",
    "load_agent": "bptsb_ros.api",
    "train": "bptsb_ros.api",
    "simulate": "bptsb_ros.api",
    "fit_feedback": "bptsb_ros.api",
    "ipc": "bptsb_ros.api",
    "experiment_names": "bptsb_ros.api",
    "run_experiment": "bptsb_ros.api",
    # what they take and return
    "ExperimentConfig": "bptsb_ros.config",
    "FeedbackConfig": "bptsb_ros.config",
    "Agent": "bptsb_ros.agent",
    "BodyState": "bptsb_ros.body.msdn",
    "TrainResult": "bptsb_ros.workflows.train",
    "Trajectory": "bptsb_ros.sim.trajectory",
    "IPCResult": "bptsb_ros.analysis.ipc",
    "ExperimentResult": "bptsb_ros.experiments.result",
    # what they raise
    "ConfigError": "bptsb_ros.config",
    "CheckpointError": "bptsb_ros.training.checkpoint",
    "TrainingDiverged": "bptsb_ros.workflows.train",
    "SimulationDiverged": "bptsb_ros.body.msdn",
    "IPCError": "bptsb_ros.analysis.ipc",
    "ExperimentError": "bptsb_ros.experiments.registry",
}

#: the public names (literal, for type checkers and linters; a test keeps it equal to _LAZY's keys)
__all__ = [
    "__version__",
    "packaged_configs", "load_config", "build_agent", "load_agent", "train", "simulate", "fit_feedback", "ipc",
    "experiment_names", "run_experiment",
    "ExperimentConfig", "FeedbackConfig", "Agent", "BodyState", "TrainResult", "Trajectory", "IPCResult",
    "ExperimentResult",
    "ConfigError", "CheckpointError", "TrainingDiverged", "SimulationDiverged", "IPCError", "ExperimentError",
]

if TYPE_CHECKING:  # what type checkers and IDEs see; at run time __getattr__ imports on first access
    from bptsb_ros.agent import Agent
    from bptsb_ros.analysis.ipc import IPCError, IPCResult
    from bptsb_ros.api import (
        build_agent,
        experiment_names,
        fit_feedback,
        ipc,
        load_agent,
        load_config,
        packaged_configs,
        run_experiment,
        simulate,
        train,
    )
    from bptsb_ros.body.msdn import BodyState, SimulationDiverged
    from bptsb_ros.config import ConfigError, ExperimentConfig, FeedbackConfig
    from bptsb_ros.experiments.registry import ExperimentError
    from bptsb_ros.experiments.result import ExperimentResult
    from bptsb_ros.sim.trajectory import Trajectory
    from bptsb_ros.training.checkpoint import CheckpointError
    from bptsb_ros.workflows.train import TrainingDiverged, TrainResult


def _version() -> str:
    """The package's version: a source checkout's ``package.xml`` where the package is imported from one, else
    the installed distribution's metadata (written from that same ``package.xml`` by ``setup.py``)."""
    from bptsb_ros.files.package_data import checkout_root

    root = checkout_root()
    if root is not None:
        import xml.etree.ElementTree as ET

        found = ET.parse(root / "package.xml").getroot().findtext("version")
        if found:
            return found.strip()
    from importlib.metadata import version

    return version(__name__)


def __getattr__(name: str) -> Any:
    """Import the module defining a public name on first access (PEP 562) and cache the name here."""
    if name == "__version__":
        globals()[name] = value = _version()
        return value
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
