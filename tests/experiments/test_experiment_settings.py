"""Experiment settings as data (``bptsb_ros/experiments/settings/<name>.yaml``): the values every experiment ran
with before they moved out of the code, the loader's validation, ``--show-config``, ``--set`` and the record in
result.json."""

from __future__ import annotations

import json
import re

import pytest
import yaml

from bptsb_ros.cli import main
from bptsb_ros.experiments import run_experiment
from bptsb_ros.experiments.experiment_settings import (
    SETTINGS_DIR,
    SettingsError,
    load_settings_file,
    parse_settings,
    resolve_settings,
)
from bptsb_ros.experiments.registry import _REGISTRY, Context, experiment, experiments
from bptsb_ros.experiments.report import build_report
from bptsb_ros.experiments.result import ResultError, validate_result

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


# -- the loader's validation: the accepted edge and just past it -----------------------------------------------

_SPEC = {"epochs": {"type": "int", "min": 1, "max": 1000, "help": "training epochs"},
         "n_train": {"type": "int", "nullable": True, "min": 1, "max": 1000, "help": "images (null: all)"},
         "rate": {"type": "float", "min": 0.0, "max": 1.0, "help": "a share"},
         "hold": {"type": "list[int]", "length": 2, "min": 1, "max": 1000, "help": "range"},
         "config": {"type": "str", "help": "packaged config"}}
_GOOD = {"epochs": 1, "n_train": None, "rate": 1, "hold": [1, 3], "config": "narma"}


def _doc(**scale_changes) -> dict:
    scales = {s: dict(_GOOD) for s in ("smoke", "short", "paper")}
    scales["short"].update(scale_changes)
    return {"settings": json.loads(json.dumps(_SPEC)), **scales}


def test_loader_accepts_the_edges():
    parsed = parse_settings(_doc(), "x.yaml")
    short = parsed.values["short"]
    assert short["epochs"] == 1 and short["n_train"] is None and short["hold"] == (1, 3)
    assert short["rate"] == 1.0 and type(short["rate"]) is float  # a float setting given as an int
    assert parse_settings(_doc(rate=0, n_train=1), "x.yaml").values["short"]["rate"] == 0.0


@pytest.mark.parametrize("changes, message", [
    ({"epochs": 0}, r"x.yaml: short.epochs must be ≥ 1, got 0"),
    ({"epochs": 1.5}, r"short.epochs must be an integer, got 1.5"),
    ({"epochs": True}, r"short.epochs must be an integer, got True"),
    ({"epochs": None}, r"short.epochs must be an integer, got None"),
    ({"n_train": 0}, r"short.n_train must be ≥ 1"),
    ({"rate": 1.01}, r"short.rate must be ≤ 1"),
    ({"rate": -0.01}, r"short.rate must be ≥ 0"),
    ({"rate": "0.5"}, r"short.rate must be a number"),
    ({"hold": [1, 3, 4]}, r"short.hold must be a list of 2 items, got 3"),
    ({"hold": [0, 3]}, r"short.hold\[0\] must be ≥ 1"),
    ({"hold": 3}, r"short.hold must be a list"),
    ({"config": 3}, r"short.config must be a text"),
    ({"epoch": 1}, r"short.epoch: unknown setting; did you mean epochs\?"),
])
def test_loader_refuses_just_past_the_edge(changes, message):
    with pytest.raises(SettingsError, match=message) as err:
        parse_settings(_doc(**changes), "x.yaml")
    assert "\n" not in str(err.value)


def test_loader_refuses_a_scale_that_lacks_a_setting_or_a_bad_declaration():
    doc = _doc()
    del doc["paper"]["rate"]
    with pytest.raises(SettingsError, match="x.yaml: paper lacks the setting rate"):
        parse_settings(doc, "x.yaml")
    doc = _doc()
    del doc["short"]
    with pytest.raises(SettingsError, match="x.yaml: no short settings"):
        parse_settings(doc, "x.yaml")
    doc = _doc()
    doc["smoek"] = doc.pop("smoke")
    with pytest.raises(SettingsError, match="x.yaml: smoek: unknown section; did you mean smoke"):
        parse_settings(doc, "x.yaml")
    doc = _doc()
    doc["settings"]["epochs"]["type"] = "integer"
    with pytest.raises(SettingsError, match="settings.epochs.type must be one of"):
        parse_settings(doc, "x.yaml")
    doc = _doc()
    del doc["settings"]["epochs"]["help"]
    with pytest.raises(SettingsError, match="settings.epochs needs a help text"):
        parse_settings(doc, "x.yaml")
    doc = _doc()
    doc["settings"]["epochs"]["mni"] = 1
    with pytest.raises(SettingsError, match="settings.epochs.mni: unknown key; did you mean min"):
        parse_settings(doc, "x.yaml")


_VSPEC = {"label": {"type": "str", "help": "row label"},
          "hold": {"type": "list[int]", "length": 2, "min": 1, "max": 1000, "nullable": True,
                   "help": "periods (null: the scale's)"}}


def test_variants_are_checked_like_the_settings_and_kept_in_file_order():
    doc = {**_doc(), "variant_settings": json.loads(json.dumps(_VSPEC)),
           "variants": {"zeta": {"label": "z", "hold": None}, "alpha": {"label": "a", "hold": [50, 50]}}}
    parsed = parse_settings(doc, "x.yaml")
    assert list(parsed.variants) == ["zeta", "alpha"]
    assert parsed.variants["alpha"] == {"label": "a", "hold": (50, 50)} and parsed.variants["zeta"]["hold"] is None
    bad = json.loads(json.dumps(doc))
    del bad["variants"]["alpha"]["label"]
    with pytest.raises(SettingsError, match="x.yaml: variants.alpha lacks the variant setting label"):
        parse_settings(bad, "x.yaml")
    bad = json.loads(json.dumps(doc))
    bad["variants"]["alpha"]["hodl"] = [1, 2]
    with pytest.raises(SettingsError, match="variants.alpha.hodl: unknown variant setting; did you mean hold"):
        parse_settings(bad, "x.yaml")
    bad = json.loads(json.dumps(doc))
    bad["variants"]["alpha"]["hold"] = [0, 2]
    with pytest.raises(SettingsError, match=r"variants.alpha.hold\[0\] must be ≥ 1"):
        parse_settings(bad, "x.yaml")
    bad = json.loads(json.dumps(doc))
    del bad["variant_settings"]
    with pytest.raises(SettingsError, match="x.yaml: variants need variant_settings"):
        parse_settings(bad, "x.yaml")
    bad = json.loads(json.dumps(doc))
    bad["variants"] = {"Bad-Name": {"label": "a", "hold": None}}
    with pytest.raises(SettingsError, match="variant names are lower-case words"):
        parse_settings(bad, "x.yaml")


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
        parse_settings(path.read_text(), str(path))


# -- --set and --show-config -----------------------------------------------------------------------------------

def test_overrides_are_typed_as_the_setting_and_unknown_keys_refused():
    got = resolve_settings("memory-task", "smoke", ["epochs=7", "delays=[2, 3]", "config=narma"])
    assert got["epochs"] == 7 and got["delays"] == (2, 3) and got["config"] == "narma"
    assert got["eval_inputs"] == 150  # the rest as packaged
    assert resolve_settings("mnist-drawing", "short", {"n_train": 100})["n_train"] == 100
    assert resolve_settings("mnist-drawing", "smoke", ["n_train=null"])["n_train"] is None
    assert type(resolve_settings("locomotion-headwind", "smoke", ["wind_period=5"])["wind_period"]) is float
    for bad, message in (["epoch=7"], r"--set epoch: unknown setting of memory-task; did you mean epochs\?"), \
            (["epochs=7.5"], r"--set epochs must be an integer, got 7.5"), \
            (["epochs=0"], r"--set epochs must be ≥ 1, got 0"), \
            (["epochs"], r"--set epochs must look like key=value"), \
            ({"epochs": "7"}, r"--set epochs must be an integer, got '7'"):
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

@pytest.fixture
def toy_with_settings(tmp_path, monkeypatch):
    """A toy experiment whose settings file is planted: it reports ``ctx.settings['gain'] · seed``."""
    folder = tmp_path / "settings"
    folder.mkdir()
    (folder / "toy-settings.yaml").write_text(
        "settings:\n  gain: {type: int, min: 1, max: 100, help: what the seed is multiplied by}\n"
        "  label: {type: str, help: the row's system}\n"
        "smoke: {gain: 2, label: toy}\nshort: {gain: 3, label: toy}\npaper: {gain: 5, label: toy}\n")
    monkeypatch.setattr("bptsb_ros.experiments.experiment_settings.SETTINGS_DIR", folder)

    def run(ctx: Context) -> None:
        ctx.row(ctx.settings["label"], "gain × seed", "1", ctx.settings["gain"] * ctx.seed)

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
        with pytest.raises(SettingsError, match="wind_period must be ≥ 0"):
            resolve_settings("locomotion-headwind", "smoke", [f"wind_period={given}"])
        return
    s = resolve_settings("locomotion-headwind", "smoke", [f"wind_period={given}"])
    assert s["wind_period"] == value and isinstance(s["wind_period"], float)
    (arg,) = s.override_args()
    assert arg == f"--set {recorded}"
    again = resolve_settings("locomotion-headwind", "smoke", [arg.removeprefix("--set ")])
    assert again["wind_period"] == value


# -- bounds of every setting and rules across settings -------------------------------------------------------------

@pytest.mark.parametrize("name", sorted(PLANTED))
def test_every_number_setting_has_bounds(name):
    parsed = load_settings_file(name)
    for spec in [*parsed.specs.values(), *parsed.variant_specs.values()]:
        if spec.type.removeprefix("list[").removesuffix("]") in ("int", "float", "number"):
            assert spec.min is not None and spec.max is not None, (name, spec.name)


def test_a_number_setting_without_bounds_is_refused():
    doc = _doc()
    del doc["settings"]["epochs"]["max"]
    with pytest.raises(SettingsError, match="x.yaml: settings.epochs needs a max: every number has bounds"):
        parse_settings(doc, "x.yaml")
    doc = _doc()
    doc["settings"]["hold"]["min"] = 2000
    with pytest.raises(SettingsError, match="x.yaml: settings.hold: min 2000 is above max 1000"):
        parse_settings(doc, "x.yaml")


@pytest.mark.parametrize("experiment, override, why", [
    ("lissajous-closed-loop", "sim_time=1e300", r"--set sim_time must be ≤ 100000, got '1e300'"),
    ("locomotion-closed-loop-20", "n_agents=1000000000", r"--set n_agents must be ≤ 1000, got 1000000000"),
    ("memory-task", "delays=[1000000000]", r"--set delays\[0\] must be ≤ 1000, got 1000000000"),
    ("memory-task", "eval_inputs=10000000000", r"--set eval_inputs must be ≤ 1000000, got 10000000000"),
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


@pytest.mark.parametrize("check, why", [
    ("epochs < nope", "names nope, which is not a setting"),
    ("config < 3", r"reads config \(str\) as a number"),
    ("epochs << 3", "is not a rule like"),
    ("epochs = 3", "cannot read ' = 3'"),
    ("max(epochs) < 3", r"reads epochs \(int\) as a list of numbers"),
    ("epochs + ", "is not a rule like"),
    ("epochs; import os", "cannot read"),
])
def test_malformed_rules_are_refused(check, why):
    doc = {**_doc(), "rules": [{"check": check, "help": "a reason"}]}
    with pytest.raises(SettingsError, match=why):
        parse_settings(doc, "x.yaml")
    doc = {**_doc(), "rules": [{"check": "hold[0] * 2 + epochs % 2 <= max(hold) + len(hold)", "help": "ok"}]}
    assert len(parse_settings(doc, "x.yaml").rules) == 1
    with pytest.raises(SettingsError, match=r"x.yaml: short: hold\[0\] \* 2 \+ epochs % 2 <= max\(hold\) \+ "
                                           r"len\(hold\) does not hold"):
        parse_settings({**doc, "short": {**_GOOD, "hold": [3, 3]}}, "x.yaml")
