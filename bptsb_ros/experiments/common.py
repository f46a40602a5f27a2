"""Helpers shared by experiment modules: the packaged experiment configs."""

from __future__ import annotations

import re
from pathlib import Path

from bptsb_ros.config import ConfigError, ExperimentConfig, Overrides, echo, load_config

PACKAGE = "bptsb_ros"


def config_dir() -> Path:
    """The directory of the packaged experiment configs: ``config/`` of a source checkout, else the ament
    share directory of an installed package."""
    source = Path(__file__).resolve().parents[2] / "config"
    if source.is_dir():
        return source
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
    except ImportError:
        raise ConfigError(f"the packaged configs are not at {source} and ament_index_python is missing") from None
    try:
        return Path(get_package_share_directory(PACKAGE)) / "config"
    except PackageNotFoundError:
        raise ConfigError(f"the packaged configs are not at {source} and {PACKAGE} is not in the ament "
                          "index (set AMENT_PREFIX_PATH)") from None


#: what a packaged config's name looks like (a name, never a path)
CONFIG_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]*")
#: suffix of the ROS node parameter files that share ``config/`` with the experiment configs
NODE_PARAMS_SUFFIX = "_params"


def packaged_configs() -> list[str]:
    """Names of the packaged experiment configs (``config/<name>.yaml``, node parameter files left out), sorted."""
    return sorted(p.stem for p in config_dir().glob("*.yaml")
                  if CONFIG_NAME.fullmatch(p.stem) and not p.stem.endswith(NODE_PARAMS_SUFFIX))


def packaged_config_path(name: str) -> Path:
    """The file of the packaged experiment config ``name``; ConfigError naming the known ones if there is none."""
    if not isinstance(name, str) or not CONFIG_NAME.fullmatch(name) or name.endswith(NODE_PARAMS_SUFFIX) \
            or not (config_dir() / f"{name}.yaml").is_file():
        raise ConfigError(f"no packaged config named {echo(name)} (packaged: {', '.join(packaged_configs())}); "
                          "give a path to load a file")
    return config_dir() / f"{name}.yaml"


def packaged_config(name: str, overrides: Overrides | None = None, seed: int | None = None) -> ExperimentConfig:
    """Load ``config/<name>.yaml`` with ``--set``-style overrides (or a mapping of them)."""
    return load_config(packaged_config_path(name), overrides, seed)


#: how far apart the seeds of two runs' trainings lie: a run of seed s that trains several systems (agents, seeds
#: of a table) gives them seeds SEED_STRIDE · s, SEED_STRIDE · s + 1, …, so runs of different seeds never share a
#: training (``--seeds 0-9`` are ten independent draws) and seed 0's are 0, 1, … as before
SEED_STRIDE = 1000


def derived_seeds(seed: int, n: int) -> list[int]:
    """The seeds of the ``n`` trainings of a run of seed ``seed`` (:data:`SEED_STRIDE`); ValueError for more than
    :data:`SEED_STRIDE` trainings, which would overlap the next seed's."""
    if not 0 <= n <= SEED_STRIDE:
        raise ValueError(f"a run trains at most {SEED_STRIDE} systems of its own seeds, asked for {n}")
    return [SEED_STRIDE * seed + i for i in range(n)]
