"""The Python API (``import bptsb_ros as bp``): cheap to import, typed, and each function checked against an
independent value — the CLI's path, a ridge fit and a re-integration written here in numpy, a planted IPC —
and training in memory writes nothing."""

from __future__ import annotations

import argparse
import inspect
import json
import math
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import REPO_ROOT
from reintegrate import load_keys, reintegrate

import bptsb_ros as bp

QUICKSTART = REPO_ROOT / "docs" / "snippets" / "quickstart.py"
FUNCTIONS = ("packaged_configs", "load_config", "build_agent", "load_agent", "train", "simulate", "fit_feedback",
             "ipc", "experiment_names", "run_experiment")
#: a fast float64 Lissajous config: 3 updates, a 5 s feedback-layer fit, one evaluation period
SMALL = {"sim_time": 3, "dtype": "float64", "feedback.fit_time": 5, "lissajous.eval_periods": 1}


@pytest.fixture
def isolated(tmp_path, monkeypatch) -> tuple[Path, Path]:
    """An empty working directory and an empty temporary directory (``tempfile``'s) for one test."""
    cwd, tmp = tmp_path / "cwd", tmp_path / "tmp"
    cwd.mkdir()
    tmp.mkdir()
    monkeypatch.chdir(cwd)
    monkeypatch.setenv("TMPDIR", str(tmp))
    monkeypatch.setattr(tempfile, "tempdir", str(tmp))
    return cwd, tmp


def files_in(*dirs: Path) -> list[Path]:
    """Everything under ``dirs`` but torch's own compile cache: torch creates ``torchinductor_<user>`` in the
    temporary directory the first time any optimiser is built in a process (``bptsb train`` as well)."""
    return sorted(p for d in dirs for p in d.rglob("*")
                  if not p.relative_to(d).parts[0].startswith("torchinductor_"))


# -- the package surface ------------------------------------------------------------------------------------------

def test_import_is_cheap_and_torch_comes_with_the_first_call() -> None:
    probe = ("import sys\nimport bptsb_ros as bp\n"
             "heavy = lambda: sorted(m for m in ('torch', 'numba', 'matplotlib', 'rclpy') if m in sys.modules)\n"
             "print(heavy(), 'bptsb_ros.api' in sys.modules)\n"
             "bp.train, bp.simulate, bp.load_config('narma')\n"
             "print(heavy())\n"
             "bp.build_agent('narma')\n"
             "print('torch' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120, cwd=REPO_ROOT)
    assert out.returncode == 0, out.stderr
    assert out.stdout.splitlines() == ["[] False", "[]", "True"], out.stdout


def test_public_names_resolve_lazily() -> None:
    assert set(bp.__all__) == {"__version__", *bp._LAZY}
    assert set(bp.__all__) <= set(dir(bp))
    for name in bp.__all__:
        assert getattr(bp, name) is not None
    from bptsb_ros import simulate
    from bptsb_ros.sim.trajectory import Trajectory

    assert simulate is bp.simulate and bp.Trajectory is Trajectory
    with pytest.raises(AttributeError, match="no attribute 'nonexistent'"):
        bp.nonexistent  # noqa: B018


def test_api_functions_are_typed_and_documented() -> None:
    for name in FUNCTIONS:
        fn = getattr(bp, name)
        sig = inspect.signature(fn)
        untyped = [p for p, param in sig.parameters.items() if param.annotation is inspect.Parameter.empty]
        assert not untyped, f"bp.{name}: parameters without a type: {untyped}"
        assert sig.return_annotation is not inspect.Signature.empty, f"bp.{name} has no return type"
        doc = inspect.getdoc(fn) or ""
        assert "Returns:" in doc, f"bp.{name}: docstring lacks Returns:"
        if sig.parameters:
            assert "Args:" in doc, f"bp.{name}: docstring lacks Args:"
            documented = set(re.findall(r"^ {4}(\w+):", doc.split("Args:")[1], flags=re.M))
            assert set(sig.parameters) <= documented, f"bp.{name}: undocumented {set(sig.parameters) - documented}"


def test_py_typed_is_shipped() -> None:
    import ast

    assert (REPO_ROOT / "bptsb_ros" / "py.typed").is_file()
    tree = ast.parse((REPO_ROOT / "setup.py").read_text())
    setup_call = next(n for n in ast.walk(tree) if isinstance(n, ast.Call) and getattr(n.func, "id", "") == "setup")
    package_data = next(k.value for k in setup_call.keywords if k.arg == "package_data")
    files = [e.value for v in package_data.values for e in v.elts]
    assert "py.typed" in files, files


# -- configs ------------------------------------------------------------------------------------------------------

def test_packaged_configs_are_the_experiment_yamls() -> None:
    expected = sorted(p.stem for p in (REPO_ROOT / "config").glob("*.yaml")
                      if isinstance(data := yaml.safe_load(p.read_text()), dict) and "task" in data)
    assert bp.packaged_configs() == expected
    assert {"lissajous_single", "narma"} <= set(expected)


def test_load_config_by_name_or_path_with_overrides() -> None:
    from bptsb_ros.config import load_config

    path = REPO_ROOT / "config" / "narma.yaml"
    assert bp.load_config("narma") == load_config(path) == bp.load_config(path) == bp.load_config(str(path))
    assert bp.load_config("narma_adam").training.optimizer == "adam"  # the name's accepted edge: an underscore
    as_mapping = bp.load_config("narma", {"epochs": 3, "training.lr.k": 5.0, "profile": "paper_table"}, seed=4)
    as_texts = bp.load_config("narma", ["epochs=3", "training.lr.k=5.0", "profile=paper_table"], seed=4)
    assert as_mapping == as_texts
    # config/narma.yaml: the profile's learning rates (d 1e3, its k 1e4 then overridden), epochs and seed set
    lr = as_mapping.training.lr
    assert (lr.k, lr.d, as_mapping.epochs, as_mapping.seed, as_mapping.profile) == (5.0, 1e3, 3, 4, "paper_table")


@pytest.mark.parametrize("source, overrides, message", [
    ("no_such_config", None, r"no packaged config named 'no_such_config' \(packaged: lissajous_single, .*narma"),
    ("body_sim_params", None, "no packaged config named 'body_sim_params'"),  # a node parameter file
    ("..", None, "no packaged config named '..'"),
    ("../config/narma", None, "config file not found"),  # a path, not a name
    ("narma", "epochs=3", "must be a list of key=value texts or a mapping"),
    ("narma", [3], "must be a text key=value"),
    ("narma", {"": 1}, "override key '' is empty"),
    ("narma", {"epochs": 0}, r"epochs: Input should be greater than or equal to 1"),
    ("narma", {"training.nope": 1}, r"training.nope: unknown key"),
])
def test_load_config_refuses_bad_input_in_one_line(source, overrides, message) -> None:
    with pytest.raises(bp.ConfigError, match=message):
        bp.load_config(source, overrides)


# -- training ------------------------------------------------------------------------------------------------------

def test_train_in_memory_writes_nothing_and_calls_back_every_update(isolated) -> None:
    cfg = bp.load_config("lissajous_single", {"sim_time": 10, "feedback.enabled": False,
                                              "lissajous.eval_periods": 1})
    calls: list[tuple[int, float]] = []
    result = bp.train(cfg, callback=lambda update, loss: calls.append((update, loss)))
    assert files_in(*isolated) == [], "training in memory wrote files"
    assert result.run_dir is None and result.files == []
    assert [u for u, _ in calls] == list(range(10)) and [loss for _, loss in calls] == result.losses
    assert all(math.isfinite(loss) for _, loss in calls)
    first, last = np.mean(result.losses[:3]), np.mean(result.losses[-3:])
    assert last < 0.7 * first, result.losses  # measured: 0.0321 → 0.0121 m²
    assert isinstance(result.agent, bp.Agent) and result.state is not None
    assert result.state.step == 10 * cfg.training.update_steps
    with pytest.raises(bp.ConfigError, match="resume continues a run saved in a run directory"):
        bp.train(cfg, resume=True)


def test_train_in_memory_divergence_writes_nothing(isolated) -> None:
    # tests/training/test_training_last_good.py's storm: a 1e12 N headwind from t = 8.5 s that no parameters survive
    storm = {"sim_time": 12, "locomotion.warmup_windows": 0, "locomotion.wind_force": -1.0e12,
             "locomotion.wind_period": 17, "feedback.enabled": False, "dtype": "float64"}
    with pytest.raises(bp.TrainingDiverged, match=r"update 5: .*trained in memory: nothing was written"):
        bp.train(bp.load_config("locomotion_forward", storm))
    assert files_in(*isolated) == []


def simulate_cli(argv: list[str]) -> int:
    from bptsb_ros.cli import simulate_cmd

    parser = argparse.ArgumentParser()
    simulate_cmd.add_arguments(parser)
    return simulate_cmd.run(parser.parse_args(argv))


TRAJECTORY_KEYS = ("positions", "velocities", "rest_length", "external_force", "k", "d")


def test_train_in_memory_equals_the_run_directory_and_simulate_equals_the_cli(tmp_path) -> None:
    cfg = bp.load_config("lissajous_single", SMALL)
    in_memory = bp.train(cfg)
    run_dir = tmp_path / "run"
    on_disk = bp.train(cfg, out=run_dir)
    assert in_memory.losses == on_disk.losses and len(in_memory.losses) == 3
    assert {"checkpoint.pt", "config.yaml", "metrics.json"} <= {p.name for p in run_dir.iterdir()}
    assert on_disk.files and all(f.is_file() for f in on_disk.files)
    assert in_memory.metrics["evaluation"] == on_disk.metrics["evaluation"]
    loaded = bp.load_agent(run_dir)
    assert loaded.feedback_fitted and in_memory.agent.feedback_fitted
    for loop in ("open", "closed"):
        npz = tmp_path / f"{loop}.npz"
        assert simulate_cli(["--agent", str(run_dir), "--steps", "300", "--loop", loop, "--seed", "3", "--perturb",
                             "0.05", "--wind", "0.3", "0", "--out", str(npz), "--no-progress"]) == 0
        cli = load_keys(npz)
        for agent in (in_memory.agent, loaded):
            traj = bp.simulate(agent, 300, loop=loop, seed=3, perturb=0.05, wind=(0.3, 0.0))
            for key in TRAJECTORY_KEYS:
                np.testing.assert_allclose(getattr(traj, key), cli[key], rtol=0, atol=1e-12, err_msg=f"{loop} {key}")
    # independently of the package: the open loop solves the body's equations (tests/reintegrate.py)
    keys = load_keys(tmp_path / "open.npz")
    positions, velocities = reintegrate(keys)
    assert np.abs(positions - keys["positions"]).max() < 1e-8 and np.abs(velocities - keys["velocities"]).max() < 1e-8
    # from a given state: it starts there, on the SWG clock of that step
    traj = bp.simulate(in_memory.agent, 100, state=in_memory.state)
    np.testing.assert_array_equal(traj.positions[0][~traj.fixed], in_memory.state.r[0].numpy())
    brain, body = in_memory.agent.brain, in_memory.agent.body
    t = (in_memory.state.step + np.arange(101))[:, None] * traj.dt
    swg = body.l.detach().numpy() * (1 + brain.amplitude.detach().numpy() * np.sin(brain.omega * t
                                                                                  + brain.phase.detach().numpy()))
    np.testing.assert_allclose(traj.rest_length, swg, rtol=1e-12)


def test_simulate_mlp_agent_equals_the_cli(tmp_path) -> None:
    from bptsb_ros.training.checkpoint import save_checkpoint

    agent = bp.build_agent(bp.load_config("narma", {"dtype": "float64"}))
    save_checkpoint(tmp_path / "run", agent)
    assert simulate_cli(["--agent", str(tmp_path / "run"), "--steps", "60", "--seed", "7",
                         "--out", str(tmp_path / "n.npz")]) == 0
    cli = load_keys(tmp_path / "n.npz")
    traj = bp.simulate(agent, 60, seed=7)
    for key in TRAJECTORY_KEYS:
        np.testing.assert_allclose(getattr(traj, key), cli[key], rtol=0, atol=1e-12, err_msg=key)
    np.testing.assert_array_equal(traj.extras["input"], cli["extra_input"])


def test_simulate_refuses_bad_arguments() -> None:
    swg = bp.build_agent(bp.load_config("lissajous_single", {"dtype": "float64"}))
    mlp = bp.build_agent("narma")
    assert bp.simulate(swg, 1).steps == 1  # the accepted edges: one step, no perturbation
    for kwargs, message in [({"steps": 0}, "steps must be an integer >= 1"),
                            ({"steps": 2.5}, "steps must be an integer >= 1"),
                            ({"steps": 5, "perturb": -0.1}, "perturb must be a finite number >= 0"),
                            ({"steps": 5, "perturb": float("nan")}, "perturb must be a finite number >= 0"),
                            ({"steps": 5, "loop": "half"}, "loop must be 'open' or 'closed'"),
                            ({"steps": 5, "loop": "closed"}, "never fitted"),
                            ({"steps": 5, "perturb": 0.1, "state": swg.body.initial_state(1)}, "cannot apply")]:
        with pytest.raises(ValueError, match=message):
            bp.simulate(swg, **kwargs)
    with pytest.raises(ValueError, match="no feedback layer"):
        bp.simulate(mlp, 5, loop="closed")


# -- the feedback layer --------------------------------------------------------------------------------------------

def ridge_aic(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Ridge y ≈ [x, 1] W per column, λ from 49 values in 1e-8..1e4 by AIC = n log(RSS/n) + 2 df, unpenalised
    bias — by the normal equations (the package uses an SVD); returns (K, F + 1), bias last."""
    n, f = x.shape
    xc, yc = x - x.mean(0), y - y.mean(0)
    gram, xty = xc.T @ xc, xc.T @ yc
    best, weights = np.full(y.shape[1], np.inf), np.zeros((f, y.shape[1]))
    for lam in np.logspace(-8, 4, 49):
        w = np.linalg.solve(gram + lam * np.eye(f), xty)
        df = np.trace(np.linalg.solve(gram + lam * np.eye(f), gram))
        aic = n * np.log(((yc - xc @ w) ** 2).sum(0) / n) + 2 * df
        better = aic < best
        best[better], weights[:, better] = aic[better], w[:, better]
    bias = y.mean(0) - x.mean(0) @ weights
    return np.concatenate([weights.T, bias[:, None]], axis=1)


def test_fit_feedback_is_the_ridge_fit_of_the_open_loop() -> None:
    agent = bp.build_agent(bp.load_config("lissajous_single", {"dtype": "float64"}))
    fit = bp.FeedbackConfig(fit_time=10.0, noise=0.08, criterion="aic")
    traj = bp.simulate(agent, 1000)  # the open loop the fit runs: 10 s from rest
    info = bp.fit_feedback(agent, config=fit, seed=3)
    assert agent.feedback_fitted and info["fit_steps"] == 600
    # the fit's data by its definition: spring lengths at step k (from the positions), the SWG signal
    # A sin(ω (k+1) Δt + φ) at step k+1, the middle 60 % (k = 200..799), N(0, 0.08²) noise from seed 3
    x = traj.spring_lengths()[200:800]
    amplitude, phase = agent.brain.amplitude.detach().numpy(), agent.brain.phase.detach().numpy()
    t = (np.arange(200, 800) + 1)[:, None] * traj.dt
    y = amplitude * np.sin(agent.brain.omega * t + phase)
    x = x + 0.08 * np.random.default_rng(3).standard_normal(x.shape)
    np.testing.assert_allclose(agent.feedback.weight.detach().numpy(), ridge_aic(x, y), rtol=1e-6, atol=1e-9)
    assert bp.simulate(agent, 10, loop="closed").steps == 10  # a fitted layer closes the loop
    with pytest.raises(ValueError, match="needs an SWG agent"):
        bp.fit_feedback(bp.build_agent("narma"))


# -- IPC --------------------------------------------------------------------------------------------------------

def test_ipc_of_a_planted_system_is_its_closed_form() -> None:
    """States u(t−1), u(t−3) and P̃₂(u(t−2)) hold exactly the targets P̃₁(u(t−1)), P̃₁(u(t−3)) (capacity 1: each is
    in the states' span) and P̃₂(u(t−2)) (1 up to its in-sample overlap with the other delays' linear terms);
    nothing else: total 3 = the rank, 2 of degree 1 and 1 of degree 2."""
    rng = np.random.default_rng(0)
    u = rng.uniform(-1, 1, 4000)

    def lag(x: np.ndarray, d: int) -> np.ndarray:
        return np.concatenate([np.zeros(d), x[:-d]])

    p2 = np.sqrt(5) * (3 * u ** 2 - 1) / 2
    states = np.stack([lag(u, 1), lag(u, 3), lag(p2, 2)], axis=1)
    res = bp.ipc(u, states, max_degree=3, max_delay=5, washout=10, surrogates=20)
    cap = res.capacity[0]
    assert cap[res.index(((1, 1),))] == pytest.approx(1.0, abs=1e-9)
    assert cap[res.index(((3, 1),))] == pytest.approx(1.0, abs=1e-9)
    assert cap[res.index(((2, 2),))] == pytest.approx(1.0, abs=0.01)
    assert int(res.rank[0]) == 3
    np.testing.assert_allclose(res.by_degree()[0], [2.0, 1.0, 0.0], atol=0.02)
    assert res.total[0] == pytest.approx(3.0, abs=0.03)
    with pytest.raises(bp.IPCError, match=r"must lie in \[-1, 1\]"):
        bp.ipc(u + 1.5, states)


# -- experiments ---------------------------------------------------------------------------------------------------

def test_run_experiment_returns_its_result_and_writes_only_where_asked(isolated, tmp_path) -> None:
    """``target-ipc`` is the cheapest smoke experiment (≈ 2 s measured; lissajous-closed-loop ≈ 20 s)."""
    assert "target-ipc" in bp.experiment_names() and "lissajous-closed-loop" in bp.experiment_names()
    logged: list[str] = []
    result = bp.run_experiment("target-ipc", scale="smoke", workers=0, log=logged.append)
    assert files_in(*isolated) == [], "run_experiment without out= left files behind"
    assert isinstance(result, bp.ExperimentResult)
    assert (result.experiment, result.scale, result.seed, result.figures) == ("target-ipc", "smoke", 0, [])
    assert result.claims and all(c.holds in (True, False, None) for c in result.claims)
    assert result.rows and all(r.ours is None or math.isfinite(r.ours) for r in result.rows)
    out = tmp_path / "out"
    kept = bp.run_experiment("target-ipc", out=out, workers=0, log=logged.append)
    assert json.loads((out / "result.json").read_text()) == kept.to_json()
    assert kept.figures and all((out / f).is_file() for f in kept.figures)
    assert (kept.rows, kept.claims) == (result.rows, result.claims)  # the same run, seed 0
    with pytest.raises(bp.ExperimentError, match="unknown experiment 'nope'"):
        bp.run_experiment("nope")
    with pytest.raises(bp.ExperimentError, match="scale must be one of"):
        bp.run_experiment("target-ipc", scale="huge")  # type: ignore[arg-type]
    with pytest.raises(bp.ExperimentError, match="give out="):
        bp.run_experiment("target-ipc", resume=True)
    assert files_in(*isolated) == []


# -- the quickstart ------------------------------------------------------------------------------------------------

def test_quickstart_runs_and_writes_nothing(isolated, capsys) -> None:
    code = compile(QUICKSTART.read_text(encoding="utf-8"), str(QUICKSTART), "exec")
    exec(code, {"__name__": "__main__"})  # noqa: S102 - the repository's own example
    lines = capsys.readouterr().out.splitlines()
    updates = [line for line in lines if line.startswith("update ")]
    assert [line.split(":")[0] for line in updates] == [f"update {i}" for i in range(20)]
    assert re.fullmatch(r"CMP error \d\.\d{4} m² \(target mean square 0\.0200 m²\)", lines[-2]), lines[-2]
    assert lines[-1].startswith("closed loop, CMP after 5 s [m]:")
    assert files_in(*isolated) == []


def readme_python_block(readme: str) -> str | None:
    """The first ```python block of README's "## Python" section, or None when there is no such heading."""
    lines = readme.splitlines()
    start = next((i for i, line in enumerate(lines) if re.match(r"## Python\b", line)), None)
    if start is None:
        return None
    end = next((i for i in range(start + 1, len(lines)) if re.match(r"#{1,2} ", lines[i])), len(lines))
    section = lines[start + 1:end]
    opening = next((i for i, line in enumerate(section) if line.strip() == "```python"), None)
    assert opening is not None, "README.md's '## Python' section has no ```python block (the quickstart)"
    closing = next(i for i in range(opening + 1, len(section)) if section[i].strip() == "```")
    return "\n".join(section[opening + 1:closing]) + "\n"


def test_readme_python_example_is_the_quickstart() -> None:
    block = readme_python_block((REPO_ROOT / "README.md").read_text(encoding="utf-8"))
    if block is None:
        pytest.skip("README.md has no '## Python' section yet")
    assert block == QUICKSTART.read_text(encoding="utf-8"), "README's Python example differs from " \
                                                            "docs/snippets/quickstart.py"


def test_readme_block_reader() -> None:
    snippet = "import bptsb_ros as bp\nprint(bp.__version__)\n"
    readme = f"# T\n\n## Python\n\nText.\n\n```python\n{snippet}```\n\n## Next\n\n```python\nother\n```\n"
    assert readme_python_block(readme) == snippet
    assert readme_python_block("# T\n\n## Usage\n") is None
    with pytest.raises(AssertionError, match="no ```python block"):
        readme_python_block("## Python\n\ntext\n\n## Next\n```python\nx\n```\n")
