"""Experiment configs: the YAML files' schema (:mod:`~bptsb_ros.config.experiment`) and the translation of the
authors' published configs into ours (:mod:`~bptsb_ros.config.authors`).

``bptsb_ros.config`` keeps the names it has always exported (``load_config``, ``ExperimentConfig``, ``ConfigError``
…): they are defined in :mod:`~bptsb_ros.config.experiment`.
"""

from bptsb_ros.config.experiment import (
    ECHO_CHARS,
    MAX_CONFIG_BYTES,
    MAX_YAML_NODES,
    TASKS,
    BodyConfig,
    BrainConfig,
    ConfigError,
    ExperimentConfig,
    FeedbackConfig,
    LearningRates,
    LissajousConfig,
    LocomotionConfig,
    NarmaConfig,
    Overrides,
    TrainingConfig,
    apply_overrides,
    apply_profile,
    check_override_key,
    config_dir,
    config_keys,
    did_you_mean,
    echo,
    load_config,
    override_items,
    override_mapping,
    parse_override,
    safe_yaml,
    validate,
)

__all__ = ["ECHO_CHARS", "MAX_CONFIG_BYTES", "MAX_YAML_NODES", "TASKS", "BodyConfig", "BrainConfig", "ConfigError",
           "ExperimentConfig", "FeedbackConfig", "LearningRates", "LissajousConfig", "LocomotionConfig", "NarmaConfig",
           "Overrides", "TrainingConfig", "apply_overrides", "apply_profile", "check_override_key", "config_dir",
           "config_keys", "did_you_mean", "echo", "load_config", "override_items", "override_mapping", "parse_override",
           "safe_yaml", "validate"]
