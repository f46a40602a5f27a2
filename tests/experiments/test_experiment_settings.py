"""Experiment settings as data (``bptsb_ros/experiments/settings/<name>.yaml``): the values every experiment ran
with before they moved out of the code, the loader's validation, ``--show-config``, ``--set`` and the record in
result.json."""

from __future__ import annotations

import json
import math
import re
from collections.abc import Iterator
from types import UnionType
from typing import Annotated, Any, ClassVar, Union, get_args, get_origin

import pytest
import yaml
from pydantic import BaseModel, Field, ValidationError
from pydantic.fields import FieldInfo

from bptsb_ros.cli import main
from bptsb_ros.experiments import run_experiment
from bptsb_ros.experiments.experiment_settings import (
    SETTINGS_DIR,
    Settings,
    SettingsError,
    load_settings_file,
    parse_settings,
    resolve_settings,
)
from bptsb_ros.experiments.registry import _REGISTRY, Context, experiment, experiments
from bptsb_ros.experiments.report import build_report
from bptsb_ros.experiments.result import ResultError, validate_result
from bptsb_ros.experiments.settings_models import (
    SETTINGS_MODELS,
    ClosedLoopSchemesSettings,
    ExperimentSettings,
    Float,
    Int,
    LocomotionHeadwindVariant,
    MemoryTaskSettings,
    MnistReadoutSettings,
    Number,
    Str,
    SwitchingVariant,
    VariantSettings,
)

_NARMA_SMOKE = ["narma.n_inputs=40", "narma.washout=10", "narma.train_end=30"]
_MNIST = {"n_train": (50, None, None), "n_test": (30, None, None)}
_AGENT = {"sim_time": (4, 200, 1000), "warmup_windows": (1, 100, 100), "fit_time": (4, 100, 100),
          "eval_time": (2, 20, 100), "handover_time": (1, 5, 5), "gait_time": (1, 2.0, 2.0),
          "projection": ("clamp",) * 3, "config_overrides": ([],) * 3}
_SWITCHING = {"pretrain_time": (5, 1000, 2000), "switching_time": (5, 2000, 30000),
              "hold": ((2, 3), (3, 8), (3, 8))}
_NARMA_CONFIG = {"config": ("narma_adam", "narma_adam", "narma"), "config_overrides": (_NARMA_SMOKE, [], [])}

#: (smoke, short, paper) of every setting, copied by hand from the ``ctx.pick(smoke=..., short=..., paper=...)``
#: calls (and the scale-dependent config choice of the time-series experiments) of the experiment code before the
#: settings moved into data files; lists were tuples there
PLANTED: dict[str, dict[str, tuple]] = {
    "mnist-drawing": {**_MNIST, "epochs": (1, 3, 50)},
    "mnist-pca": {**_MNIST, "epochs": (1, 3, 50)},
    # smoke: 100 test images, the fewest from the start of the MNIST test set that hold every digit (30 hold no 8)
    "mnist-labelmap": {**_MNIST, "n_test": (100, None, None), "epochs": (1, 3, 50), "grid": (3, 15, 41)},
    "mnist-specific100": {"per_digit": (2, 10, 10), "epochs": (1, 150, 1000), "grid": (3, 15, 41)},
    "mnist-readout": {**_MNIST, "epochs": (1, 2, 100), "guard_factor": (0, 0, 0), "guard_window": (5, 5, 5)},
    "narma-emulation": {"epochs": (1, 120, 40000), "eval_inputs": (150, 1000, 3000), "washout": (30, 100, 100),
                        **_NARMA_CONFIG, "ablations": (False, False, True)},
    # its `last = ctx.pick(smoke=1, short=300, paper=40000)` was the last stage (the training's length): no setting
    "narma-ipc": {"stages": ((0, 1), (0, 30, 100, 300), (0, 400, 4000, 40000)),
                  "eval_inputs": (250, 2000, 4000), "max_delay": (10, 20, 20), "washout": (30, 100, 100),
                  **_NARMA_CONFIG, "ablations": (False, False, True)},
    "memory-task": {"epochs": (1, 60, 40000), "delays": ((1, 8, 17), (1, 4, 8, 12, 17), tuple(range(1, 18))),
                    "n_seeds": (1, 2, 5), "eval_inputs": (150, 800, 3000), "max_delay": (10, 20, 20),
                    "washout": (30, 100, 100), "gangs": (True, True, True), "population": (True, True, True),
                    "ipc_stages": ((0, 1), (0, 6, 60), (0, 400, 4000, 40000)), **_NARMA_CONFIG},
    "target-ipc": {"samples": (1500, 6000, 10000)},
    "msdn-nonlinearity": {"blocks": (800, 3000, 5000), "max_delay": (10, 20, 20)},
    "lissajous-closed-loop": {"sim_time": (10, 1000, 2000), "fit_time": (10, 100, 100), "eval_periods": (2, 10, 10)},
    "lissajous-perturbation": {"sim_time": (10, 1000, 2000), "fit_time": (10, 100, 100), "n_seeds": (6, 100, 100),
                               "run_periods": (6, 50, 300), "eval_periods": (3, 10, 10), "settle_periods": (2, 10, 10)},
    "lissajous-switching": {**_SWITCHING, "pretrain_eval_periods": (3, 10, 10), "segment_periods": (6, 15, 20),
                            "transient_periods": (2, 5, 5)},
    "lissajous-bifurcation": {**_SWITCHING, "transient_periods": (3, 30, 100), "record_periods": (9, 30, 50)},
    "lissajous-timing": {**_SWITCHING, "settle_periods": (2, 5, 5), "run_periods": (6, 20, 30),
                         "last_periods": (2, 5, 5)},
    "closed-loop-schemes": {"n_curves": (1, 3, 3), "n_seeds": (1, 2, 5), "pretrain_time": (5, 200, 2000),
                            "add_time": (3, 50, 1000), "eval_periods": (2, 10, 10), "scheme1_time": (3, 50, 2000)},
    "locomotion-closed-loop-20": {**_AGENT, "n_agents": (2, 20, 20)},
    "locomotion-perturbation": {**_AGENT, "n_agents": (2, 20, 20), "n_noise": (3, 100, 100),
                                "before_time": (1.0, 10.0, 20.0), "after_time": (2.0, 20.0, 80.0),
                                "max_agents": (1, 8, 20)},
    "locomotion-headwind": {**_AGENT, "switching_time": (4, 2000, 10000), "wind_period": (4.0, 20.0, 20.0),
                            "eval_periods": (1, 3, 5), "sweep_time": (2.0, 20.0, 50.0)},
}


def _as_code_had_it(value):
    return tuple(value) if isinstance(value, list) else value


@pytest.mark.parametrize("name", sorted(PLANTED))
@pytest.mark.parametrize("scale_index, scale", list(enumerate(("smoke", "short", "paper"))))
def test_packaged_settings_are_the_values_the_code_ran_with(name, scale_index, scale):
    loaded = resolve_settings(name, scale)
    expected = {key: _as_code_had_it(values[scale_index]) for key, values in PLANTED[name].items()}
    assert dict(loaded) == expected
    for key, value in expected.items():  # 4 stays an int, 4.0 a float (an agent's key hashes them)
        assert type(loaded[key]) is type(value), (name, scale, key)


def test_every_experiment_has_a_settings_file_and_every_file_an_experiment():
    names = set(experiments())
    assert names == set(PLANTED)
    assert {p.stem for p in SETTINGS_DIR.glob("*.yaml")} == names


# -- the reader's validation: the accepted edge and just past it ----------------------------------------------

class _Toy(ExperimentSettings):
    """A planted model: the settings of a toy experiment."""

    epochs: Int = Field(ge=1, le=1000, description="training epochs")
    n_train: Annotated[Int, Field(ge=1, le=1000)] | None = Field(description="images (null: all)")
    rate: Float = Field(ge=0, le=1, description="a share")
    hold: tuple[Annotated[Int, Field(ge=1, le=1000)], ...] = Field(min_length=2, max_length=2, description="range")
    config: Str = Field(description="packaged config")


class _ToyVariant(VariantSettings):
    """A planted variant model."""

    label: Str = Field(description="row label")
    hold: Annotated[tuple[Annotated[Int, Field(ge=1, le=1000)], ...], Field(min_length=2, max_length=2)] | None = \
        Field(description="periods (null: the scale's)")


class _ToyWithVariants(_Toy):
    variant_model: ClassVar[type[VariantSettings] | None] = _ToyVariant


_GOOD = {"epochs": 1, "n_train": None, "rate": 1, "hold": [1, 3], "config": "narma"}


def _doc(**scale_changes) -> dict:
    scales = {s: dict(_GOOD) for s in ("smoke", "short", "paper")}
    scales["short"].update(scale_changes)
    return scales


def test_reader_accepts_the_edges():
    parsed = parse_settings(_doc(), "x.yaml", _Toy)
    short = parsed.values["short"]
    assert short.epochs == 1 and short.n_train is None and short.hold == (1, 3)
    assert short.rate == 1.0 and type(short.rate) is float  # a float setting given as an int
    assert parse_settings(_doc(rate=0, n_train=1), "x.yaml", _Toy).values["short"].rate == 0.0


@pytest.mark.parametrize("changes, message", [
    ({"epochs": 0}, r"^x.yaml: short.epochs: Input should be greater than or equal to 1, got 0$"),
    ({"epochs": 1.5}, r"short.epochs: Input should be a valid integer, got 1.5"),
    ({"epochs": True}, r"short.epochs: Input should be a valid integer, got True"),
    ({"epochs": None}, r"short.epochs: Input should be a valid integer, got None"),
    ({"n_train": 0}, r"short.n_train: Input should be greater than or equal to 1"),
    ({"rate": 1.01}, r"short.rate: Input should be less than or equal to 1"),
    ({"rate": -0.01}, r"short.rate: Input should be greater than or equal to 0"),
    ({"rate": "0.5"}, r"short.rate: Input should be a valid number, got '0.5'"),
    ({"rate": float("inf")}, r"short.rate: Input should be a finite number"),
    ({"hold": [1, 3, 4]}, r"short.hold: List should have at most 2 items after validation, not 3"),
    ({"hold": [0, 3]}, r"short.hold\[0\]: Input should be greater than or equal to 1, got 0"),
    ({"hold": 3}, r"short.hold: Input should be a list, got 3"),
    ({"hold": {1, 3}}, r"short.hold: Input should be a list, not a set"),
    ({"config": 3}, r"short.config: Input should be a valid string, got 3"),
    ({"epoch": 1}, r"^x.yaml: short.epoch: unknown setting; did you mean epochs\?$"),
])
def test_reader_refuses_just_past_the_edge(changes, message):
    with pytest.raises(SettingsError, match=message) as err:
        parse_settings(_doc(**changes), "x.yaml", _Toy)
    assert "\n" not in str(err.value)


def test_reader_refuses_a_scale_that_lacks_a_setting_or_an_unknown_section():
    doc = _doc()
    del doc["paper"]["rate"]
    with pytest.raises(SettingsError, match="^x.yaml: paper lacks the setting rate$"):
        parse_settings(doc, "x.yaml", _Toy)
    doc = _doc()
    del doc["short"]
    with pytest.raises(SettingsError, match="x.yaml: no short settings"):
        parse_settings(doc, "x.yaml", _Toy)
    doc = _doc()
    doc["smoek"] = doc.pop("smoke")
    with pytest.raises(SettingsError, match="x.yaml: smoek: unknown section; did you mean smoke"):
        parse_settings(doc, "x.yaml", _Toy)
    with pytest.raises(SettingsError, match="x.yaml: settings: unknown section .* declared in _Toy"):
        parse_settings({**_doc(), "settings": {}}, "x.yaml", _Toy)  # the declarations of before: now the model
    with pytest.raises(SettingsError, match="x.yaml: variants: _Toy has no variant model"):
        parse_settings({**_doc(), "variants": {"a": {"label": "a"}}}, "x.yaml", _Toy)


def test_variants_are_checked_like_the_settings_and_kept_in_file_order():
    doc = {**_doc(), "variants": {"zeta": {"label": "z", "hold": None}, "alpha": {"label": "a", "hold": [50, 50]}}}
    parsed = parse_settings(doc, "x.yaml", _ToyWithVariants)
    assert list(parsed.variants) == ["zeta", "alpha"]
    assert parsed.variants["alpha"] == _ToyVariant(label="a", hold=(50, 50)) and parsed.variants["zeta"].hold is None
    bad = json.loads(json.dumps(doc))
    del bad["variants"]["alpha"]["label"]
    with pytest.raises(SettingsError, match="^x.yaml: variants.alpha lacks the variant setting label$"):
        parse_settings(bad, "x.yaml", _ToyWithVariants)
    bad = json.loads(json.dumps(doc))
    bad["variants"]["alpha"]["hodl"] = [1, 2]
    with pytest.raises(SettingsError, match="variants.alpha.hodl: unknown variant setting; did you mean hold"):
        parse_settings(bad, "x.yaml", _ToyWithVariants)
    bad = json.loads(json.dumps(doc))
    bad["variants"]["alpha"]["hold"] = [0, 2]
    with pytest.raises(SettingsError, match=r"variants.alpha.hold\[0\]: Input should be greater than or equal to 1"):
        parse_settings(bad, "x.yaml", _ToyWithVariants)
    bad = json.loads(json.dumps(doc))
    bad["variants"]["alpha"]["hold"] = [1]
    with pytest.raises(SettingsError, match=r"variants.alpha.hold: List should have at least 2 items"):
        parse_settings(bad, "x.yaml", _ToyWithVariants)
    bad = json.loads(json.dumps(doc))
    del bad["variants"]
    with pytest.raises(SettingsError, match="x.yaml: no variants"):
        parse_settings(bad, "x.yaml", _ToyWithVariants)
    bad = json.loads(json.dumps(doc))
    bad["variants"] = {"Bad-Name": {"label": "a", "hold": None}}
    with pytest.raises(SettingsError, match="variant names are lower-case words"):
        parse_settings(bad, "x.yaml", _ToyWithVariants)


def test_the_switching_experiments_declare_the_paper_and_the_authors_protocol():
    for name in ("lissajous-switching", "lissajous-bifurcation", "lissajous-timing"):
        v = resolve_settings(name, "smoke").variants
        assert list(v) == ["paper_wind", "published_wind", "authors"]
        a = v["authors"]  # the published code's protocol (published-code-facts.md), as planted by hand
        assert a["hold"] == (50, 50) and a["shift_of_size"] == 0.05 and a["lr_decay"] is True
        assert a["integrator"] == "published" and a["published_wind"] is True and a["lr"] == (1000, 100, 1, 1, 10)
        assert v["paper_wind"]["hold"] is None and v["paper_wind"]["published_wind"] is False
        expected_curve = (1, 3, 0) if name == "lissajous-timing" else (2, 1, 0.25)
        assert a["curve_on"] == expected_curve


def test_loader_refuses_a_file_that_is_not_plain_data(tmp_path):
    path = tmp_path / "x.yaml"
    path.write_text("settings: !!python/object/apply:os.system ['true']\n")
    with pytest.raises(SettingsError, match="x.yaml"):
        parse_settings(path.read_text(), str(path), _Toy)


# -- --set and --show-config -----------------------------------------------------------------------------------

def test_overrides_are_typed_as_the_setting_and_unknown_keys_refused():
    got = resolve_settings("memory-task", "smoke", ["epochs=7", "delays=[2, 3]", "config=narma"])
    assert got["epochs"] == 7 and got["delays"] == (2, 3) and got["config"] == "narma"
    assert got["eval_inputs"] == 150  # the rest as packaged
    assert resolve_settings("mnist-drawing", "short", {"n_train": 100})["n_train"] == 100
    assert resolve_settings("mnist-drawing", "smoke", ["n_train=null"])["n_train"] is None
    assert type(resolve_settings("locomotion-headwind", "smoke", ["wind_period=5"])["wind_period"]) is float
    for bad, message in (["epoch=7"], r"--set epoch: unknown setting of memory-task; did you mean epochs\?"), \
            (["epochs=7.5"], r"^--set epochs: Input should be a valid integer, got 7.5$"), \
            (["epochs=0"], r"^--set epochs: Input should be greater than or equal to 1, got 0$"), \
            (["epochs"], r"--set epochs must look like key=value"), \
            ({"epochs": "7"}, r"--set epochs: Input should be a valid integer, got '7'"), \
            (["washout=-1", "epochs=0"], r"^--set washout: Input should be greater than or equal to 0, got -1$"):
        # (the first --set as given is named, not the first setting of the model: epochs)
        with pytest.raises(SettingsError, match=message):
            resolve_settings("memory-task", "smoke", bad)


def test_a_rule_across_settings_is_checked_before_the_training(tmp_path):
    for stages, why in (("[1, 5]", r"stages\[0\] == 0 does not hold \(stages = \(1, 5\)\): the first stage is the "
                                   "untrained system"),
                        ("[0, 5, 3]", "stages must start at 0 .* and grow"), ("[0, 5, 5]", "and grow")):
        with pytest.raises(SettingsError, match=why):
            run_experiment("narma-ipc", scale="smoke", out_dir=tmp_path / "x", force=True, progress=False,
                           settings=[f"stages={stages}"])
    assert not (tmp_path / "x" / "sweep").exists()


def test_show_config_prints_the_resolved_settings_and_runs_nothing(capsys, tmp_path):
    out = tmp_path / "never"
    assert main(["reproduce", "narma-ipc", "--show-config", "--scale", "paper", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    shown = yaml.safe_load(text)
    assert shown == {"stages": [0, 400, 4000, 40000], "eval_inputs": 4000, "max_delay": 20,
                     "washout": 100, "config": "narma", "config_overrides": [], "ablations": True}
    assert re.search(r"^eval_inputs: 4000 +# held-out inputs", text, re.M)  # each setting with its help text
    assert not out.exists()
    assert main(["reproduce", "narma-ipc", "--show-config", "--scale", "smoke", "--set", "washout=3"]) == 0
    text = capsys.readouterr().out
    smoke = yaml.safe_load(text)
    assert smoke["washout"] == 3 and smoke["stages"] == [0, 1] and smoke["config_overrides"] == _NARMA_SMOKE
    assert re.search(r"^washout: 3 +# .*\(--set\)$", text, re.M) and re.search(r"^max_delay: 10 +# [^(]*$", text, re.M)
    assert main(["reproduce", "narma-ipc", "--show-config", "--set", "wahsout=3"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "unknown setting of narma-ipc; did you mean washout?" in err


# -- the record in result.json and the report ------------------------------------------------------------------

class _ToySettings(ExperimentSettings):
    """The planted model of the toy experiment."""

    gain: Int = Field(ge=1, le=100, description="what the seed is multiplied by")
    label: Str = Field(description="the row's system")


@pytest.fixture
def toy_with_settings(tmp_path, monkeypatch):
    """A toy experiment whose settings model and file are planted: it reports ``ctx.settings['gain'] · seed``."""
    folder = tmp_path / "settings"
    folder.mkdir()
    (folder / "toy-settings.yaml").write_text(
        "smoke: {gain: 2, label: toy}\nshort: {gain: 3, label: toy}\npaper: {gain: 5, label: toy}\n")
    monkeypatch.setattr("bptsb_ros.experiments.experiment_settings.SETTINGS_DIR", folder)
    monkeypatch.setitem(SETTINGS_MODELS, "toy-settings", _ToySettings)

    def run(ctx: Context) -> None:
        ctx.row(ctx.settings["label"], "gain × seed", "1", ctx.settings.gain * ctx.seed)  # both ways of reading

    experiment("toy-settings", paper_ref="Table 0", summary="planted settings")(run)
    yield "toy-settings"
    _REGISTRY.pop("toy-settings", None)


def test_result_json_records_the_settings_and_the_report_shows_them(tmp_path, toy_with_settings):
    runs = tmp_path / "runs"
    path, data = run_experiment(toy_with_settings, scale="short", seed=2, out_dir=runs / "a", progress=False,
                                settings=["gain=7"])
    on_disk = json.loads(path.read_text())
    assert on_disk["settings"] == {"gain": 7, "label": "toy"}
    assert on_disk["rows"][0]["ours"] == 14.0  # 7 × 2: the run used the override
    assert on_disk["provenance"]["command"].endswith("--set gain=7")
    _, plain = run_experiment(toy_with_settings, scale="paper", seed=2, out_dir=runs / "b", progress=False)
    assert plain["settings"] == {"gain": 5, "label": "toy"} and plain["rows"][0]["ours"] == 10.0
    assert main(["reproduce", toy_with_settings, "--scale", "smoke", "--seed", "3", "--out", str(runs / "c"),
                 "--set", "label=cli"]) == 0
    assert json.loads((runs / "c" / "result.json").read_text())["rows"][0] == {
        "system": "cli", "metric": "gain × seed", "unit": "1", "ours": 6.0, "paper": None}
    text = build_report(runs, tmp_path / "R.md").read_text()
    assert "- settings: gain = 7, label = toy" in text and "- settings: gain = 5, label = toy" in text


@pytest.mark.parametrize("settings, ok", [({"gain": 7, "hold": [1, 2], "n": None, "c": "x"}, True),
                                           ({"gain": {"nested": 1}}, False), ([1, 2], False),
                                           ({"gain": [[1]]}, False)])
def test_result_schema_checks_the_settings_record(settings, ok):
    good = {"experiment": "e", "paper_ref": "Fig. 1", "scale": "smoke", "seed": 0, "wall_s": 1.0,
            "rows": [], "claims": [], "figures": [], "settings": settings}
    if ok:
        validate_result(good)
    else:
        with pytest.raises(ResultError, match="settings"):
            validate_result(good)



@pytest.mark.parametrize("given, value, recorded", [
    ("0.00001", 1e-05, "wind_period=1.0e-05"),  # json would write 1e-05, which YAML 1.1 reads as a text
    ("2e1", 20.0, "wind_period=20.0"), ("-3E-2", None, None),  # exponent forms are numbers; below min refused
    ("12.5", 12.5, "wind_period=12.5"),
])
def test_float_settings_read_exponents_and_the_recorded_set_reads_back(given, value, recorded):
    from bptsb_ros.experiments.experiment_settings import SettingsError, resolve_settings

    if value is None:
        with pytest.raises(SettingsError, match="--set wind_period: Input should be greater than or equal to 0"):
            resolve_settings("locomotion-headwind", "smoke", [f"wind_period={given}"])
        return
    s = resolve_settings("locomotion-headwind", "smoke", [f"wind_period={given}"])
    assert s["wind_period"] == value and isinstance(s["wind_period"], float)
    (arg,) = s.override_args()
    assert arg == f"--set {recorded}"
    again = resolve_settings("locomotion-headwind", "smoke", [arg.removeprefix("--set ")])
    assert again["wind_period"] == value


# -- the models: every number bounded, bounds both sides, each type as it was ----------------------------------

def _numbers(annotation: Any, constraints: tuple = ()) -> Iterator[tuple[type, tuple]]:
    """(int or float, the constraints that apply to it) of every number a field's type holds: the field itself, the
    items of a list (whose bounds are their own, not the list's), each member of a union (Number, X | None)."""
    origin = get_origin(annotation)
    if origin is Annotated:
        inner, *meta = get_args(annotation)
        own = tuple(m for x in meta for m in (x.metadata if isinstance(x, FieldInfo) else [x]))
        yield from _numbers(inner, constraints + own)
    elif origin is tuple:
        yield from _numbers(get_args(annotation)[0])
    elif origin in (Union, UnionType):
        for member in get_args(annotation):
            yield from _numbers(member, constraints)
    elif annotation in (int, float):
        yield annotation, constraints


def _unbounded(model: type[BaseModel]) -> list[str]:
    """The fields of ``model`` holding a number without both a ``ge`` and an ``le``."""
    def bound(found: tuple, side: str) -> bool:  # annotated_types' Ge/Le carry their bound as .ge/.le
        return any(getattr(c, side, None) is not None for c in found)

    return list(dict.fromkeys(name for name, info in model.model_fields.items()
                              for _, found in _numbers(info.annotation, tuple(info.metadata))
                              if not (bound(found, "ge") and bound(found, "le"))))


def _numeric(model: type[BaseModel]) -> set[str]:
    return {name for name, info in model.model_fields.items() if any(_numbers(info.annotation, tuple(info.metadata)))}


_MODELS = sorted({m for model in SETTINGS_MODELS.values() for m in (model, model.variant_model) if m is not None},
                 key=lambda m: m.__name__)


@pytest.mark.parametrize("model", _MODELS, ids=lambda m: m.__name__)
def test_every_number_of_every_model_has_both_bounds(model):
    assert _unbounded(model) == []
    for name, info in model.model_fields.items():
        assert info.description, (model.__name__, name)  # the help text of --show-config


def test_the_bounds_check_finds_every_number_and_an_unbounded_one():
    # the walk reaches plain numbers, list items, nullable ones and the int-or-float Number (hand lists)
    assert _numeric(MemoryTaskSettings) == {"epochs", "delays", "n_seeds", "eval_inputs", "max_delay", "washout",
                                            "ipc_stages"}
    assert _numeric(SwitchingVariant) == {"curve_on", "hold", "shift_of_size", "lr"}
    assert _numeric(MnistReadoutSettings) == {"n_train", "n_test", "epochs", "guard_factor", "guard_window"}

    class Loose(ExperimentSettings):
        epochs: Int = Field(ge=1, description="no le")
        hold: tuple[Annotated[Int, Field(le=9)], ...] = Field(description="items without ge")
        share: Annotated[Number, Field(ge=0)] | None = Field(description="nullable, no le")
        rate: Float = Field(ge=0, le=1, description="bounded")
        lr: tuple[Float, ...] = Field(min_length=2, max_length=2, description="items without bounds")

    assert _unbounded(Loose) == ["epochs", "hold", "share", "lr"]


#: (experiment, setting, lowest and highest value taken, just below and just above), by hand from the settings files
_EDGES = [
    ("memory-task", "epochs", 1, 1_000_000, 0, 1_000_001),
    ("memory-task", "delays", [1, 1], [1000, 1000], [1, 0], [1001, 1]),
    ("locomotion-headwind", "wind_period", 0, 10_000, -0.001, 10_000.001),
    ("lissajous-closed-loop", "sim_time", 0, 100_000, -1, 100_000.5),
    ("mnist-drawing", "n_train", 1, 1_000_000, 0, 1_000_001),
    ("mnist-readout", "guard_factor", 0, 1000, -0.5, 1001),
    ("msdn-nonlinearity", "blocks", 200, 1_000_000, 199, 1_000_001),
    ("closed-loop-schemes", "n_curves", 1, 3, 0, 4),
]


@pytest.mark.parametrize("experiment, key, lowest, highest, below, above", _EDGES)
def test_bounds_hold_on_both_sides(experiment, key, lowest, highest, below, above):
    for value in (lowest, highest):
        got = resolve_settings(experiment, "smoke", {key: value})[key]
        assert got == (tuple(value) if isinstance(value, list) else value)
    item = next((f"\\[{i}\\]" for i, v in enumerate(below) if v != lowest[i]), "") if isinstance(below, list) else ""
    with pytest.raises(SettingsError, match=f"^--set {key}{item}: Input should be greater than or equal to "):
        resolve_settings(experiment, "smoke", {key: below})
    item = next((f"\\[{i}\\]" for i, v in enumerate(above) if v != highest[i]), "") if isinstance(above, list) else ""
    with pytest.raises(SettingsError, match=f"^--set {key}{item}: Input should be less than or equal to "):
        resolve_settings(experiment, "smoke", {key: above})


_SWITCHING_VARIANT = {"label": "v", "published_wind": False, "curve_on": [2, 1, 0.5], "hold": None,
                      "shift_of_size": None, "lr": [1000, 100, 1, 1, 10], "lr_decay": False, "integrator": "verlet"}
_HEADWIND_VARIANT = {"wind_force": -1.0, "wind_period": None, "lr": [1, 0.01, 0.001, 1e-5, 1e-4], "lr_decay": False}


@pytest.mark.parametrize("model, base, key, lowest, highest, below, above", [
    (SwitchingVariant, _SWITCHING_VARIANT, "hold", [1, 1], [10_000, 10_000], [0, 1], [1, 10_001]),
    (SwitchingVariant, _SWITCHING_VARIANT, "curve_on", [0, 0, 0], [100, 100, 100], [0, -0.5, 0], [0, 0, 100.5]),
    (SwitchingVariant, _SWITCHING_VARIANT, "shift_of_size", 0, 10, -0.01, 10.01),
    (SwitchingVariant, _SWITCHING_VARIANT, "lr", [0] * 5, [1_000_000] * 5, [-1, 0, 0, 0, 0], [0, 0, 0, 0, 1_000_001]),
    (LocomotionHeadwindVariant, _HEADWIND_VARIANT, "wind_force", -1000, 0, -1000.5, 0.5),
    (LocomotionHeadwindVariant, _HEADWIND_VARIANT, "wind_period", 0, 10_000, -1, 10_001),
])
def test_variant_bounds_hold_on_both_sides(model, base, key, lowest, highest, below, above):
    for value in (lowest, highest):
        assert getattr(model.model_validate({**base, key: value}), key) == \
            (tuple(value) if isinstance(value, list) else value)
    for value in (below, above):
        with pytest.raises(ValidationError):
            model.model_validate({**base, key: value})


@pytest.mark.parametrize("experiment, given, expected", [
    ("locomotion-headwind", {"wind_period": 5}, 5.0),  # float: an int is taken as a float
    ("locomotion-headwind", {"wind_period": "1e-05"}, 1e-05),  # YAML 1.1 reads 1e-05 as a text
    ("locomotion-headwind", {"wind_period": "2E+3"}, 2000.0),
    ("lissajous-closed-loop", {"sim_time": 20}, 20),  # number: an int stays an int
    ("lissajous-closed-loop", {"sim_time": 20.0}, 20.0),  # and a float a float
    ("lissajous-closed-loop", {"sim_time": "2e1"}, 20.0),
    ("memory-task", {"delays": (2, 3)}, (2, 3)),  # a list given as a tuple
    ("memory-task", {"delays": [2, 3]}, (2, 3)),
    ("memory-task", {"gangs": False}, False),
    ("memory-task", {"config": "narma"}, "narma"),
])
def test_each_type_takes_what_it_takes(experiment, given, expected):
    (key, _), = given.items()
    got = resolve_settings(experiment, "smoke", given)[key]
    assert got == expected and type(got) is type(expected)


@pytest.mark.parametrize("experiment, key, value, why", [
    ("memory-task", "epochs", True, "a valid integer"),  # int: no bool
    ("memory-task", "epochs", 3.0, "a valid integer"),  # no float, even a whole one
    ("memory-task", "epochs", "3", "a valid integer"),
    ("locomotion-headwind", "wind_period", True, "a valid number"),  # float: no bool
    ("locomotion-headwind", "wind_period", "5", "a valid number"),  # a text only in exponent form
    ("locomotion-headwind", "wind_period", math.inf, "a finite number"),
    ("locomotion-headwind", "wind_period", math.nan, "a finite number"),
    ("locomotion-headwind", "wind_period", 10**400, "a finite number"),
    ("lissajous-closed-loop", "sim_time", True, "a valid number"),  # number: no bool
    ("lissajous-closed-loop", "sim_time", "20", "a valid number"),
    ("lissajous-closed-loop", "sim_time", math.inf, "a finite number"),
    ("lissajous-closed-loop", "sim_time", -math.nan, "a finite number"),
    ("memory-task", "gangs", 1, "a valid boolean"),  # bool: strict
    ("memory-task", "gangs", "true", "a valid boolean"),
    ("memory-task", "config", 3, "a valid string"),  # str: strict
    ("memory-task", "delays", {2, 3}, "a list, not a set"),
    ("memory-task", "delays", "23", "a list"),
    ("memory-task", "delays", [2, 3.0], "a valid integer"),
])
def test_each_type_refuses_what_it_refuses(experiment, key, value, why):
    with pytest.raises(SettingsError, match=f"^--set {key}(\\[1\\])?: Input should be {why}") as err:
        resolve_settings(experiment, "smoke", {key: value})
    assert "\n" not in str(err.value)


def test_settings_read_as_a_mapping_and_as_attributes_and_stay_frozen():
    s = resolve_settings("memory-task", "smoke")
    assert s.epochs == s["epochs"] == 1 and s.delays == (1, 8, 17) and s.scale == "smoke"
    with pytest.raises(AttributeError, match="'epoch'"):
        _ = s.epoch
    with pytest.raises(KeyError, match="did you mean 'epochs'|did you mean epochs"):
        _ = s["epoch"]
    with pytest.raises(ValidationError, match="frozen"):
        s.model.epochs = 3
    assert resolve_settings("memory-task", "smoke", ["epochs=4"]).model == MemoryTaskSettings.model_validate(
        {**s.to_json(), "epochs": 4})


@pytest.mark.parametrize("name", sorted(SETTINGS_MODELS))
def test_no_setting_is_hidden_by_an_attribute_of_the_settings_object(name):
    resolved = resolve_settings(name, "smoke")
    assert not set(SETTINGS_MODELS[name].model_fields) & (set(dir(Settings)) | set(vars(resolved)))
    assert all(getattr(resolved, key) is resolved[key] for key in resolved)


#: the named variants of each experiment, by hand from the settings files (the others have none)
_VARIANTS = {"narma-emulation": ["main", "authors_init", "float64"], "narma-ipc": ["main", "authors_init"],
             "lissajous-perturbation": ["paper", "authors"], "locomotion-perturbation": ["paper", "authors"],
             "locomotion-headwind": ["paper", "authors"],
             **{name: ["paper_wind", "published_wind", "authors"]
                for name in ("lissajous-switching", "lissajous-bifurcation", "lissajous-timing")}}


@pytest.mark.parametrize("name", sorted(PLANTED))
def test_the_packaged_scales_and_variants_are_instances_of_the_models(name):
    parsed = load_settings_file(name)
    model = SETTINGS_MODELS[name]
    assert parsed.model is model and list(parsed.values) == ["smoke", "short", "paper"]
    assert all(type(values) is model for values in parsed.values.values())
    assert list(parsed.variants) == _VARIANTS.get(name, [])
    assert all(type(v) is model.variant_model for v in parsed.variants.values())
    assert (model.variant_model is None) == (name not in _VARIANTS)


@pytest.mark.parametrize("experiment, override, why", [
    ("lissajous-closed-loop", "sim_time=1e300", r"--set sim_time: Input should be less than or equal to 100000, got "
                                                r"1e\+300"),
    ("locomotion-closed-loop-20", "n_agents=1000000000", r"--set n_agents: Input should be less than or equal to "
                                                         r"1000, got 1000000000"),
    ("memory-task", "delays=[1000000000]", r"--set delays\[0\]: Input should be less than or equal to 1000, got "
                                           r"1000000000"),
    ("memory-task", "eval_inputs=10000000000", r"--set eval_inputs: Input should be less than or equal to 1000000"),
    ("memory-task", "washout=200", r"settings of memory-task at scale smoke \(with --set\): washout \+ max_delay < "
                                   r"eval_inputs does not hold \(eval_inputs = 150, max_delay = 10, washout = 200\)"),
    ("memory-task", "delays=[3]", r"len\(delays\) >= 2 does not hold \(delays = \(3,\)\): the claims compare"),
    ("mnist-labelmap", "grid=4", r"grid % 2 == 1 does not hold \(grid = 4\)"),
    ("lissajous-timing", "hold=[8, 3]", r"hold\[0\] <= hold\[1\] does not hold"),
    ("locomotion-headwind", "gait_time=5", r"gait_time <= eval_time does not hold \(eval_time = 2, gait_time = 5\)"),
])
def test_hostile_settings_are_one_line_before_any_work(experiment, override, why, tmp_path, capsys):
    with pytest.raises(SettingsError, match=why):
        resolve_settings(experiment, "smoke", [override])
    out = tmp_path / "run"
    assert main(["reproduce", experiment, "--scale", "smoke", "--set", override, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and not out.exists()


def test_settings_within_the_bounds_and_rules_are_taken():
    got = resolve_settings("memory-task", "smoke", ["washout=100", "delays=[2, 3]", "eval_inputs=1000000"])
    assert (got["washout"], got["delays"], got["eval_inputs"]) == (100, (2, 3), 1_000_000)
    assert resolve_settings("mnist-labelmap", "smoke", ["grid=1001"])["grid"] == 1001
    assert resolve_settings("lissajous-closed-loop", "smoke", ["sim_time=100000"])["sim_time"] == 100_000


# -- the rules across settings: each holds at its edge and fails just past it ----------------------------------

_GAIT = ({"gait_time": 2, "eval_time": 2}, {"gait_time": 2.5, "eval_time": 2}, "gait_time <= eval_time",
         "the stored gait is cut from the open-loop evaluation run")
_HOLD = ({"hold": [3, 3]}, {"hold": [4, 3]}, "hold[0] <= hold[1]", "the shortest hold comes first")
_ODD = ({"grid": 3}, {"grid": 4}, "grid % 2 == 1", "the label map has a cell at Δ = 0 (an odd grid)")

#: experiment → (settings where the rule holds at its edge, just past it, the rule, its help text); by hand
_RULES = [
    ("mnist-labelmap", *_ODD),
    ("mnist-specific100", *_ODD),
    ("narma-emulation", {"washout": 149, "eval_inputs": 150}, {"washout": 150, "eval_inputs": 150},
     "washout < eval_inputs", "the NMSE is taken over the held-out inputs after the washout"),
    ("narma-ipc", {"washout": 239, "max_delay": 10, "eval_inputs": 250},
     {"washout": 240, "max_delay": 10, "eval_inputs": 250}, "washout + max_delay < eval_inputs",
     "the IPC reads the held-out inputs after the washout, at delays up to max_delay"),
    ("narma-ipc", {"stages": [0, 5]}, {"stages": [1, 5]}, "stages[0] == 0", "the first stage is the untrained system"),
    ("memory-task", {"washout": 139, "max_delay": 10, "eval_inputs": 150},
     {"washout": 140, "max_delay": 10, "eval_inputs": 150}, "washout + max_delay < eval_inputs",
     "the NMSE and the IPC read the held-out inputs after the washout, at delays up to max_delay"),
    ("memory-task", {"delays": [1, 2]}, {"delays": [1]}, "len(delays) >= 2",
     "the claims compare the NMSE across delays"),
    ("memory-task", {"delays": [1] * 20, "n_seeds": 1000}, {"delays": [1] * 21, "n_seeds": 1000},
     "len(delays) * n_seeds <= 20000", "two bodies × delays × seeds trainings: at most 40,000 sweep jobs"),
    ("msdn-nonlinearity", {"max_delay": 199, "blocks": 200}, {"max_delay": 200, "blocks": 200}, "max_delay < blocks",
     "the IPC basis reaches max_delay blocks back"),
    ("lissajous-perturbation", {"eval_periods": 6, "run_periods": 6}, {"eval_periods": 7, "run_periods": 6},
     "eval_periods <= run_periods", "the error is measured over the last eval_periods of the run_periods run"),
    ("lissajous-switching", *_HOLD),
    ("lissajous-switching", {"transient_periods": 5, "segment_periods": 6},
     {"transient_periods": 6, "segment_periods": 6}, "transient_periods < segment_periods",
     "each test segment keeps periods after its transient"),
    ("lissajous-bifurcation", *_HOLD),
    ("lissajous-timing", *_HOLD),
    ("lissajous-timing", {"last_periods": 6, "run_periods": 6}, {"last_periods": 7, "run_periods": 6},
     "last_periods <= run_periods", "the last periods compared are periods of the run"),
    ("locomotion-closed-loop-20", *_GAIT),
    ("locomotion-perturbation", *_GAIT),
    ("locomotion-headwind", *_GAIT),
]


@pytest.mark.parametrize("experiment, holds, fails, check, why", _RULES)
def test_each_rule_holds_at_its_edge_and_fails_past_it_with_its_help(experiment, holds, fails, check, why):
    got = resolve_settings(experiment, "smoke", holds)
    assert {k: got[k] for k in holds} == {k: tuple(v) if isinstance(v, list) else v for k, v in holds.items()}
    with pytest.raises(SettingsError) as err:
        resolve_settings(experiment, "smoke", fails)
    message = str(err.value)
    assert message.startswith(f"settings of {experiment} at scale smoke (with --set): {check} does not hold (")
    assert message.endswith(f"): {why}") and "\n" not in message


def test_every_rule_is_tested_and_a_rule_that_bounds_cannot_break_still_fails_past_its_edge():
    # 19 rules in 14 experiments: 18 above, and closed-loop-schemes' n_curves * n_seeds <= 3000, which the bounds
    # (n_curves <= 3, n_seeds <= 1000) already keep: its validator is called on values built without validation
    validators = {(name, v) for name, model in SETTINGS_MODELS.items()
                  for v in model.__pydantic_decorators__.model_validators}
    assert len(_RULES) + 1 == len(validators) == 19
    assert {r[0] for r in _RULES} | {"closed-loop-schemes"} == {name for name, _ in validators}
    values = {"n_curves": 3, "n_seeds": 1000, "pretrain_time": 5, "add_time": 3, "eval_periods": 2, "scheme1_time": 3}
    assert ClosedLoopSchemesSettings.model_validate(values).n_seeds == 1000
    with pytest.raises(ValueError, match=r"^n_curves \* n_seeds <= 3000 does not hold \(n_curves = 3, "
                                         r"n_seeds = 1001\): a job per curve and seed$"):
        ClosedLoopSchemesSettings.model_construct(**{**values, "n_seeds": 1001})._jobs_bounded()


def test_an_empty_list_holds_a_rule_that_reads_its_first_item():
    assert resolve_settings("narma-ipc", "smoke", {"stages": []})["stages"] == ()  # the experiment refuses it itself


def test_a_packaged_scale_that_breaks_a_rule_names_the_file_and_the_scale():
    doc = {scale: {"n_train": 50, "n_test": 100, "epochs": 1, "grid": 3} for scale in ("smoke", "short", "paper")}
    doc["short"]["grid"] = 4
    with pytest.raises(SettingsError, match=r"^x.yaml: short: grid % 2 == 1 does not hold \(grid = 4\): the label "
                                            r"map has a cell at Δ = 0 \(an odd grid\)$"):
        parse_settings(doc, "x.yaml", SETTINGS_MODELS["mnist-labelmap"])
