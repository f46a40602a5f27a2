"""Helpers shared by experiment modules: the packaged experiment configs."""

from __future__ import annotations

import re
from pathlib import Path

from bptsb_ros.config import ConfigError, ExperimentConfig, Overrides, config_dir, echo, load_config

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


def looks_like_path(text: str) -> bool:
    """Whether a config argument is a file's path (a path separator, or a ``.yaml``/``.yml`` suffix) rather than
    a packaged config's name."""
    return "/" in text or "\\" in text or text.lower().endswith((".yaml", ".yml"))


def config_source(text: str) -> Path:
    """The file a config argument names: a path as given, or a packaged config's name (``lissajous_single``) as
    that config's file. A missing path whose name is a packaged config's gets a ConfigError that says so (``bptsb
    train config/lissajous_single.yaml`` outside the checkout); an unknown name one naming the packaged ones."""
    if not looks_like_path(text):
        return packaged_config_path(text)
    path = Path(text)
    if not path.is_file() and path.suffix.lower() in (".yaml", ".yml") and CONFIG_NAME.fullmatch(path.stem) \
            and path.stem in packaged_configs():
        raise ConfigError(f"config file not found: {echo(text)} (the packaged config of that name is "
                          f"{path.stem}: give the name alone, without a folder or .yaml)")
    return path


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
