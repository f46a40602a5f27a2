"""Helpers shared by experiment modules: the packaged experiment configs."""

from __future__ import annotations

from pathlib import Path

from bptsb_ros.config import ConfigError, ExperimentConfig, load_config

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


def packaged_config(name: str, overrides: list[str] | None = None, seed: int | None = None) -> ExperimentConfig:
    """Load ``config/<name>.yaml`` with ``--set``-style overrides."""
    return load_config(config_dir() / f"{name}.yaml", overrides or [], seed)
