"""`bptsb config import`: the authors' flat YAML → our config. Every config of theirs here is written in the test
(the authors' form: flat camelCase keys); expected values are hand values from their meaning (README of the
shared reference: ``nodes`` counts every mass, ``simTime`` is seconds of simulated time, ``tau`` steps per
input, ``updateTimeScale`` the window in steps)."""

import math
from pathlib import Path

import pytest
import yaml
from conftest import REPO_ROOT

from bptsb_ros.body.shapes import build_shape
from bptsb_ros.cli import main
from bptsb_ros.config import load_config
from bptsb_ros.config.authors import MARKER, ImportFailure, import_config

CONFIG = REPO_ROOT / "config"

# the authors' form of our packaged config/lissajous_single.yaml, written by hand
THEIR_SINGLE = {
    "task": "Lissajous", "experiment": "SWG", "simTime": 2000, "timeStep": 0.01, "tau": 10, "brain": "SWG",
    "shape": "DoubleCircles", "size": 4, "nodes": 25, "neighbours": 3, "optim": "SGD", "updateTimeScale": 100,
    "lr_spring": 10000, "lr_damping": 1000, "lr_restlength": 10, "lr_amplitude": 10, "lr_phase": 100,
    "inputScale": 0, "wind": False, "lissajous1": [1, 2, 0, 1], "lissajous2": [], "noise": 0,
    "generatorDist": ["all"],
}
THEIR_NARMA = {
    "task": "expandedNARMA", "experiment": "train", "simTime": 30, "timeStep": 0.01, "tau": 20, "brain": "MLP",
    "shape": "DoubleCircles", "size": 4, "nodes": 33, "neighbours": 3, "epoch": 40000, "optim": "SGD",
    "lr_spring": 1000, "lr_damping": 100, "lr_restlength": 1, "lr_brain": 0.01, "delay": 2, "inputScale": 20,
}


def _write(path: Path, data) -> Path:
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def test_each_mapped_key_lands_at_ours_with_the_expected_value():
    r = import_config(dict(THEIR_SINGLE, simTime=300, timeStep=0.02, updateTimeScale=50, lr_spring=123.0,
                           lr_damping=4.5, lr_restlength=0.5, lr_amplitude=2, lr_phase=7, size=3,
                           lissajous1=[2, 1, 1, 4], optim="Adam"))
    c = r.config
    assert c.task == "lissajous" and c.brain.type == "swg"
    # simTime is seconds of simulated time, as our sim_time: 300 s at dt 0.02 s = 15,000 steps
    assert c.sim_time == 300.0 and c.body.dt == 0.02 and round(c.sim_time / c.body.dt) == 15_000
    assert c.training.update_steps == 50 and c.training.optimizer == "adam"
    lr = c.training.lr
    assert (lr.k, lr.d, lr.l, lr.amplitude, lr.phase) == (123.0, 4.5, 0.5, 2.0, 7.0)
    assert (c.body.shape, c.body.nodes, c.body.size, c.body.neighbours) == ("double_circle", 25, 3.0, 3)
    # [alpha, beta, p, q]: delta = pi * p / q
    assert (c.lissajous.alpha, c.lissajous.beta) == (2.0, 1.0) and c.lissajous.delta == pytest.approx(math.pi / 4)
    mapped = {m.their_key: dict(m.ours) for m in r.mapped}
    assert mapped["simTime"] == {"sim_time": 300.0} and mapped["lr_spring"] == {"training.lr.k": 123.0}
    assert mapped["lissajous1"]["lissajous.delta"] == pytest.approx(math.pi / 4)


def test_nodes_count_every_mass_multiple_circle_37_has_17_movable():
    r = import_config({"task": "Lissajous", "shape": "MultipleCircles", "nodes": 37, "size": 4})
    b = r.config.body
    assert (b.shape, b.nodes) == ("multiple_circle", 37)
    topo = build_shape(b.shape, b.nodes, b.size, b.neighbours)
    # c = 3 rings (37 = 4*3^2 + 1): the fixed outer ring holds (2*3 - 1)*4 = 20 masses, 17 movable (the paper's N_mov)
    assert topo.n_masses == 37 and int(topo.fixed.sum()) == 20 and int((~topo.fixed).sum()) == 17
    assert "37 masses (20 fixed, 17 movable)" in "\n".join(r.report_lines())


def test_time_series_simtime_is_the_episode_in_inputs_and_delay_is_order_or_delay():
    c = import_config(THEIR_NARMA).config
    # 30 s / (0.01 s x 20 steps per input) = 150 inputs
    assert c.task == "narma" and c.narma.target == "expanded" and c.narma.n_inputs == 150 and c.narma.tau == 20
    assert c.epochs == 40000 and c.narma.order == 2 and c.narma.input_scale == 20.0 and c.brain.type == "mlp"
    assert (c.training.lr.k, c.training.lr.d, c.training.lr.l, c.training.lr.brain) == (1000, 100, 1, 0.01)
    # 60 s / (0.02 s x 10) = 300 inputs
    assert import_config(dict(THEIR_NARMA, simTime=60, timeStep=0.02, tau=10)).config.narma.n_inputs == 300
    with pytest.raises(ImportFailure, match=r"simTime: 30.1 s is not a whole number of inputs .* = 150.5\)"):
        import_config(dict(THEIR_NARMA, simTime=30.1))
    memory = import_config(dict(THEIR_NARMA, task="memory", brain="LIL", delay=5, lr_readoutlayer=0,
                                cumulative=False))
    m = memory.config
    assert m.task == "narma" and m.narma.target == "memory" and m.narma.delay == 5 and m.brain.type == "lil"
    assert {u.their_key for u in memory.unmapped} == {"cumulative"}
    assert "lr_readoutlayer" in {u.their_key for u in memory.understood}
    trained_readout = import_config(dict(THEIR_NARMA, lr_readoutlayer=0.1))  # ours has none: unmapped
    assert {u.their_key for u in trained_readout.unmapped} == {"lr_readoutlayer"}


def test_every_unmapped_key_is_named_with_its_value():
    theirs = dict(THEIR_SINGLE, fooBar=3, lissajous2=[2, 1, 1, 4], wind=True, inputScale=1, generatorDist=[0, 2])
    r = import_config(theirs)
    assert r.task == "lissajous-switching"  # the second curve and the wind: the switching task
    unmapped = {u.their_key: u.their_value for u in r.unmapped}
    assert unmapped == {"tau": 10, "fooBar": 3, "lissajous2": [2, 1, 1, 4], "wind": True, "inputScale": 1,
                        "generatorDist": [0, 2]}
    report = "\n".join(r.report_lines())
    section = report.split("not mapped (named here, not in the config):\n", 1)[1]
    for line in ("tau: 10", "fooBar: 3", "lissajous2: [2, 1, 1, 4]", "wind: True", "inputScale: 1",
                 "generatorDist: [0, 2]"):
        assert f"  {line}  (" in section
    # every key of theirs is accounted for exactly once
    accounted = [m.their_key for m in r.mapped] + [u.their_key for u in r.understood] + list(unmapped)
    assert sorted(accounted) == sorted(theirs)


def test_defaults_are_reported_from_the_packaged_config():
    r = import_config({"task": "Lissajous", "simTime": 20})
    packaged = yaml.safe_load((CONFIG / "lissajous_single.yaml").read_text())
    defaults = {d.our_key: (d.value, d.source) for d in r.defaults}
    assert "sim_time" not in defaults  # theirs, not a default
    assert defaults["training.lr.k"] == (packaged["training"]["lr"]["k"], "config/lissajous_single.yaml")
    assert defaults["body.nodes"] == (25, "config/lissajous_single.yaml")
    assert defaults["feedback.noise"] == (packaged["feedback"]["noise"], "config/lissajous_single.yaml")
    assert "  training.lr.k = 10000.0" in r.report_lines()
    headwind = {d.our_key: d.value for d in import_config({"task": "locomotion", "wind": True}).defaults}
    assert headwind["locomotion.wind_period"] == 20.0 and "locomotion.wind_force" not in headwind


def test_round_trip_of_the_packaged_lissajous_single_config():
    ours = load_config(CONFIG / "lissajous_single.yaml").model_dump(mode="json")
    imported = import_config(THEIR_SINGLE).config.model_dump(mode="json")
    ours.pop("name"), imported.pop("name")
    assert imported == ours


def test_locomotion_forward_and_headwind():
    forward = import_config({"task": "locomotion", "shape": "CaterpillarRobot", "nodes": 10, "wind": False,
                             "updateTimeScale": 200, "generatorNum": [-1], "inputScale": 0})
    assert forward.task == "locomotion-forward" and forward.config.locomotion.wind_force == 0.0
    assert forward.config.body.shape == "caterpillar" and forward.unmapped == []
    headwind = import_config({"task": "locomotion", "wind": True, "inputScale": 2, "simTime": 10000})
    # F_wind = -1 N (the paper's headwind) x inputScale
    assert headwind.task == "locomotion-headwind" and headwind.config.locomotion.wind_force == -2.0
    assert headwind.config.sim_time == 10000.0


def test_the_task_from_keys_or_task_option():
    assert import_config({"lissajous1": [1, 3, 0, 1]}).task == "lissajous-single"
    assert import_config({"simTime": 2000}, task="lissajous-single").config.sim_time == 2000.0
    with pytest.raises(ImportFailure, match="cannot tell the task .* name it with --task"):
        import_config({"simTime": 30, "brain": "MLP"})
    assert import_config({"simTime": 30, "brain": "MLP"}, task="memory").config.narma.target == "memory"
    with pytest.raises(ImportFailure, match="--task narma does not fit the file's task: Lissajous"):
        import_config({"task": "Lissajous"}, task="narma")
    with pytest.raises(ImportFailure, match="task: unknown task 'Swimming'"):
        import_config({"task": "Swimming"})
    with pytest.raises(ImportFailure, match="no experiment config for the MNIST tasks"):
        import_config({"task": "MNIST", "batchSize": 100})


@pytest.mark.parametrize("text, message", [
    ("- a\n- b\n", "must be a mapping of keys, got list"),
    ("task: !!python/object/apply:os.system [echo hi]\n", "uses the YAML tag 'tag:yaml.org,2002:python/object"),
    ("task: Swimming\n", "task: unknown task 'Swimming'"),
    ("task: Lissajous\nsimTime: fast\n", "simTime: expected a finite number, got 'fast'"),
    ("task: Lissajous\nnodes: 25.5\n", "nodes: expected a whole number, got 25.5"),
    ("task: Lissajous\nwind: 'yes'\n", "wind: expected true or false, got 'yes'"),
    ("task: Lissajous\nshape: Blob\n", "shape: unknown value 'Blob'"),
    ("task: Lissajous\nlissajous1: [1, 2, 0]\n", "lissajous1: expected \\[alpha, beta, p, q\\]"),
    ("task: Lissajous\nnodes: 24\n", "does not validate: body: double_circle needs an odd number"),
])
def test_bad_input_is_one_line_and_exit_1(tmp_path, capsys, text, message):
    path = tmp_path / "theirs.yaml"
    path.write_text(text)
    assert main(["config", "import", str(path)]) == 1  # the file is at fault, not the arguments
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("bptsb config import: ")
    import re

    assert re.search(message, err), err


def test_output_validates_and_carries_the_report(tmp_path, capsys):
    out = tmp_path / "ours.yaml"
    theirs = _write(tmp_path / "theirs.yaml", dict(THEIR_SINGLE, simTime=40, fooBar=1))
    assert main(["config", "import", str(theirs), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    text = out.read_text()
    assert text.splitlines()[0] == MARKER
    header = [line[2:] for line in text.splitlines() if line.startswith("# ")]
    for line in ("simTime: 40 -> sim_time = 40.0", "fooBar: 1  (", "  training.log_every = 10", "tau: 10  ("):
        assert any(line in h for h in header), line
        assert line in printed
    cfg = load_config(out)
    assert cfg.sim_time == 40.0 and cfg.training.lr.k == 1e4 and cfg.task == "lissajous"
    # a key of theirs with a line break stays inside the comment header (their names are data)
    _write(theirs, dict(THEIR_SINGLE, **{"evil\ntask: narma": 1}))
    assert main(["config", "import", str(theirs), "--out", str(out), "--force"]) == 0
    head = out.read_text().split("\n\n", 1)[0].splitlines()
    assert all(line.startswith("#") for line in head) and any("'evil\\ntask: narma': 1" in h for h in head)
    assert load_config(out).task == "lissajous"
    capsys.readouterr()
    # without --out the same file goes to stdout
    assert main(["config", "import", str(theirs)]) == 0
    assert capsys.readouterr().out.splitlines()[0] == MARKER


def test_an_existing_out_is_replaced_only_with_force_and_only_if_ours(tmp_path, capsys):
    theirs = _write(tmp_path / "theirs.yaml", THEIR_SINGLE)
    foreign = tmp_path / "mine.yaml"
    foreign.write_text("task: lissajous\n")
    for extra in ([], ["--force"]):
        assert main(["config", "import", str(theirs), "--out", str(foreign), *extra]) == 1
        assert "was not written by bptsb config import" in capsys.readouterr().err
        assert foreign.read_text() == "task: lissajous\n"
    ours = tmp_path / "ours.yaml"
    assert main(["config", "import", str(theirs), "--out", str(ours)]) == 0
    first = ours.read_text()
    _write(theirs, dict(THEIR_SINGLE, simTime=10))
    assert main(["config", "import", str(theirs), "--out", str(ours)]) == 1
    assert "pass --force" in capsys.readouterr().err and ours.read_text() == first
    assert main(["config", "import", str(theirs), "--out", str(ours), "--force"]) == 0
    assert load_config(ours).sim_time == 10.0
    link = tmp_path / "link.yaml"
    link.symlink_to(ours)
    assert main(["config", "import", str(theirs), "--out", str(link), "--force"]) == 1
    assert "symbolic link" in capsys.readouterr().err


def test_config_show_prints_the_resolved_config(capsys):
    assert main(["config", "show", "narma", "--set", "epochs=3"]) == 0
    shown = yaml.safe_load(capsys.readouterr().out)
    assert shown["epochs"] == 3 and shown["narma"]["tau"] == 20 and shown["training"]["backend"] == "fused"
    assert main(["config", "show", "narma", "--set", "epocs=3"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "did you mean epochs?" in err
