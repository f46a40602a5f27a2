"""Config validation: unknown keys, wrong types and inconsistent settings fail naming the key."""


import pytest
import yaml
from conftest import REPO_ROOT

from bptsb_ros.config import ConfigError, load_config, validate

CONFIGS = sorted((REPO_ROOT / "config").glob("*.yaml"))
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


NARMA = REPO_ROOT / "config" / "narma.yaml"


def test_narma_and_memory_default_to_the_authors_rates_and_offer_the_paper_table():
    """Hand values: the authors' timeseries/expandedNARMA.yaml and memory.yaml (k 1e3, d 1e2, l 1, brain 1e-2)
    and the paper's learning-rate table, row "Time-series emulation" (k 1e4, d 1e3, l 1e1, brain 1e-1)."""
    from bptsb_ros.experiments.common import packaged_config
    from bptsb_ros.experiments.experiment_settings import resolve_settings
    from bptsb_ros.experiments.timeseries import narma_overrides

    lr = load_config(NARMA).training.lr
    assert (lr.k, lr.d, lr.l, lr.brain) == (1e3, 1e2, 1.0, 1e-2)
    paper_config = resolve_settings("memory-task", "paper")["config"]
    memory = packaged_config(paper_config, narma_overrides("paper", 1, "double-circle", "lil",
                                                           ("narma.target=memory", "narma.delay=8")))
    assert memory.narma.target == "memory" and memory.training.lr == lr and memory.training.reject_factor == 10
    cfg = load_config(NARMA, ["profile=paper_table"])
    lr = cfg.training.lr
    assert (lr.k, lr.d, lr.l, lr.brain) == (1e4, 1e3, 10.0, 0.1) and cfg.profile == "paper_table"
    # the other overrides apply over the profile, wherever they stand on the command line
    assert load_config(NARMA, ["training.lr.k=5", "profile=paper_table"]).training.lr.k == 5


def test_profiles_merge_over_the_file_and_bad_ones_name_the_problem(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("task: lissajous\nsim_time: 10\nprofile: long\nprofiles:\n"
                 "  long: {sim_time: 50, training: {lr: {k: 7}}}\n")
    cfg = load_config(p)
    assert cfg.sim_time == 50 and cfg.training.lr.k == 7 and cfg.training.lr.d == 1e3  # merged key by key
    assert validate(cfg.model_dump(mode="json")).profile == "long"  # the resolved config records it
    plain = load_config(p, ["profile="])
    assert plain.sim_time == 10 and plain.training.lr.k == 1e4 and plain.profile == ""
    with pytest.raises(ConfigError, match=r"profile 'short' is not defined in .*c\.yaml \(defined: long\)"):
        load_config(p, ["profile=short"])
    p.write_text("task: lissajous\nprofiles: 3\n")
    with pytest.raises(ConfigError, match="profiles in .* must map each profile name to a mapping"):
        load_config(p)
    p.write_text("task: lissajous\nprofile: x\n")
    with pytest.raises(ConfigError, match=r"profile 'x' is not defined .*\(defined: none\)"):
        load_config(p)


@pytest.mark.parametrize("key, suggestion", [
    ("sim_tme", "sim_time"), ("trainig", "training"), ("training.lr.phaze", "training.lr.phase"),
    ("lissajous.alfa", "lissajous.alpha"), ("body.amplitude", "brain.amplitude"),  # in the wrong section
])
def test_a_near_miss_key_suggests_the_valid_one(tmp_path, key, suggestion):
    *sections, last = key.split(".")
    p = tmp_path / "c.yaml"
    p.write_text("task: lissajous\n" + "".join(f"{'  ' * i}{s}:\n" for i, s in enumerate(sections))
                 + f"{'  ' * len(sections)}{last}: 1\n")
    with pytest.raises(ConfigError, match=rf"{key.replace('.', '[.]')}: unknown key; did you mean "
                                          rf"{suggestion.replace('.', '[.]')}\?"):
        load_config(p)
    # the same key as a --set override: one line, the same suggestion
    with pytest.raises(ConfigError) as err:
        load_config(EXPERIMENTS[0], [f"{key}=1"])
    assert str(err.value) == f"override {key}: unknown key; did you mean {suggestion}?"


@pytest.mark.parametrize("key", ["xyzzy", "training.lr.spring", "narma.quux", "feedback.zz"])
def test_a_far_key_suggests_nothing(tmp_path, key):
    with pytest.raises(ConfigError) as err:
        load_config(EXPERIMENTS[0], [f"{key}=1"])
    assert str(err.value) == f"override {key}: unknown key"
    nested: object = 1
    for part in reversed(key.split(".")):
        nested = {part: nested}
    p = tmp_path / "c.yaml"
    p.write_text(yaml.safe_dump({"task": "lissajous", **nested}))
    with pytest.raises(ConfigError, match=f"{key.replace('.', '[.]')}: unknown key") as err:
        load_config(p)
    assert "did you mean" not in str(err.value)


def test_an_override_past_a_value_is_not_a_section():
    with pytest.raises(ConfigError, match=r"^override body\.dt\.x: body\.dt is a value, not a section$"):
        load_config(EXPERIMENTS[0], ["body.dt.x=1"])


def test_a_yaml_tag_is_refused_naming_it(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("task: !!python/object/apply:os.system [echo hi]\n")
    with pytest.raises(ConfigError, match=r"uses the YAML tag 'tag:yaml\.org,2002:python/object/apply:os\.system', "
                                          r"which is not plain data"):
        load_config(p)


def test_override_mapping_parses_texts_keeps_values_and_lets_the_last_key_win():
    from bptsb_ros.config import ConfigError, override_mapping

    assert override_mapping(["sim_time=20", "training.lr_decay=false", "body.shape=multiple_circle",
                             "sim_time=30"]) == {"sim_time": 30, "training.lr_decay": False,
                                                 "body.shape": "multiple_circle"}
    value = [1.5, 2.5]
    got = override_mapping({"training.lr.k": 1e-05, "wind": value})
    assert got == {"training.lr.k": 1e-05, "wind": [1.5, 2.5]} and got["wind"] is not value  # a copy
    assert override_mapping(None) == {} and override_mapping(()) == {}
    with pytest.raises(ConfigError, match="must look like key=value"):
        override_mapping(["sim_time"])


def test_a_live_nodes_fresh_body_parameters_follow_the_config_schema():
    """The nodes' shape parameters are made from BodyConfig/BrainConfig/ExperimentConfig: the same choices and bounds
    (hand values of the schema), the node's own defaults where it differs (0 masses: the task's default)."""
    from bptsb_ros.interface.params import ParameterError
    from bptsb_ros.interface.source import SOURCE_PARAMS

    p = {s.name: s for s in SOURCE_PARAMS}
    assert p["shape"].choices == ("", "double_circle", "multiple_circle", "caterpillar") and p["shape"].default == ""
    assert p["integrator"].choices == ("verlet", "published") and p["integrator"].default == "verlet"
    assert p["brain_type"].choices == ("", "swg", "mlp", "lil")
    assert p["dtype"].choices == ("float32", "float64") and p["dtype"].default == "float64"
    assert p["task"].choices == ("lissajous", "locomotion", "narma")
    assert (p["size"].default, p["size"].positive, p["size"].maximum) == (4.0, True, 1000.0)
    assert (p["dt"].default, p["dt"].positive, p["dt"].maximum) == (0.01, True, 1.0)
    assert (p["nodes"].default, p["nodes"].minimum, p["nodes"].maximum) == (0, 0, 2001)
    assert "diameter of circular bodies [m]" in p["size"].description
    assert p["size"].validate(1000.0) == 1000.0 and p["dt"].validate(1.0) == 1.0
    for name, bad in (("size", 1000.5), ("size", 0.0), ("dt", 1.5), ("nodes", 2002), ("integrator", "euler")):
        with pytest.raises(ParameterError):
            p[name].validate(bad)
