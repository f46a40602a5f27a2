"""Config validation: unknown keys, wrong types and inconsistent settings fail naming the key."""

from pathlib import Path

import pytest

from bptsb_ros.config import ConfigError, load_config, validate

CONFIGS = sorted((Path(__file__).resolve().parents[1] / "config").glob("*.yaml"))
EXPERIMENTS = [p for p in CONFIGS if not p.name.endswith("_params.yaml")]


@pytest.mark.parametrize("path", EXPERIMENTS, ids=lambda p: p.name)
def test_shipped_configs_validate(path):
    cfg = load_config(path)
    assert cfg.task in ("lissajous", "locomotion", "narma")


def test_unknown_key_is_named(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("task: lissajous\ntraining:\n  lr:\n    spring: 3\n")
    with pytest.raises(ConfigError, match=r"training\.lr\.spring: unknown key"):
        load_config(p)


def test_wrong_type_is_named(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("task: lissajous\nsim_time: fast\n")
    with pytest.raises(ConfigError, match=r"sim_time: .*number"):
        load_config(p)


def test_override_and_bad_override(tmp_path):
    cfg = load_config(EXPERIMENTS[0], ["sim_time=20", "training.lr.k=5"], seed=3)
    assert cfg.sim_time == 20 and cfg.training.lr.k == 5 and cfg.seed == 3
    with pytest.raises(ConfigError, match="key=value"):
        load_config(EXPERIMENTS[0], ["sim_time"])
    with pytest.raises(ConfigError, match=r"body\.nodes"):
        load_config(EXPERIMENTS[0], ["body.nodes=many"])


def test_inconsistent_task_and_brain():
    with pytest.raises(ConfigError, match="needs brain.type 'swg'"):
        validate({"task": "lissajous", "brain": {"type": "mlp"}})
    with pytest.raises(ConfigError, match="caterpillar"):
        validate({"task": "locomotion", "body": {"shape": "double_circle"}})


def test_missing_and_malformed_files(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "nope.yaml")
    p = tmp_path / "bad.yaml"
    p.write_text("task: [unclosed\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(p)


def test_bad_body_window_and_learning_rates_name_the_key():
    with pytest.raises(ConfigError, match=r"body: double_circle needs an odd number"):
        validate({"task": "lissajous", "body": {"nodes": 24}})
    with pytest.raises(ConfigError, match=r"locomotion\.speed_block"):
        validate({"task": "locomotion", "body": {"shape": "caterpillar", "nodes": 10},
                  "training": {"update_steps": 150}})
    with pytest.raises(ConfigError, match="every learning rate is zero"):
        validate({"task": "lissajous", "training": {"lr": {"k": 0, "d": 0, "l": 0, "amplitude": 0, "phase": 0}}})
