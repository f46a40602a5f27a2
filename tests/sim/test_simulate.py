"""``bptsb simulate`` and the trajectory file: re-integration by an independent implementation to 1e-8
(the acceptance bound), validation, the GIF, divergence reporting, and the ``--agent`` wiring."""

from __future__ import annotations

import argparse

import numpy as np
import pytest
from conftest import REPO_ROOT
from reintegrate import load_keys, reintegrate

from bptsb_ros.sim.trajectory import Trajectory, TrajectoryError, load_npz

ACCEPTANCE = 1e-8


def simulate_cli(argv: list[str]) -> int:
    from bptsb_ros.cli import simulate_cmd

    parser = argparse.ArgumentParser()
    simulate_cmd.add_arguments(parser)
    return simulate_cmd.run(parser.parse_args(argv))


def simulate(tmp_path, name: str, *args: str) -> dict[str, np.ndarray]:
    out = tmp_path / f"{name}.npz"
    assert simulate_cli([*args, "--dtype", "float64", "--out", str(out)]) == 0
    return load_keys(out)


def assert_reintegrates(keys: dict[str, np.ndarray]) -> None:
    positions, velocities = reintegrate(keys)
    err_r = float(np.abs(positions - keys["positions"]).max())
    err_v = float(np.abs(velocities - keys["velocities"]).max())
    assert err_r < ACCEPTANCE and err_v < ACCEPTANCE, (err_r, err_v)  # measured ≈ 1e-15


def test_double_circle_with_perturbation_reintegrates(tmp_path) -> None:
    keys = simulate(tmp_path, "dc", "--shape", "double_circle", "--nodes", "25", "--steps", "400",
                    "--perturb", "0.1", "--seed", "3")
    assert keys["positions"].shape == (401, 25, 2) and keys["rest_length"].shape == (401, 48)
    assert np.abs(keys["positions"][1:] - keys["positions"][0]).max() > 0.05, "the body must move"
    assert str(keys["integrator"]) == "verlet" and str(keys["dtype"]) == "float64"
    assert float(keys["ground_c"]) == 0 and not keys["gravity"].any()
    assert_reintegrates(keys)


def test_modulated_and_pushed_double_circle_reintegrates(tmp_path) -> None:
    keys = simulate(tmp_path, "dc_swg", "--shape", "double_circle", "--nodes", "33", "--steps", "300",
                    "--perturb", "0.05", "--swg-amplitude", "0.3", "--wind", "0.5", "-0.2", "--seed", "4")
    rest = keys["rest_length"]
    assert np.ptp(rest, axis=0).min() > 0.1 * rest[0].min(), "rest lengths are modulated"
    force = keys["external_force"]
    assert np.allclose(force[:, ~keys["fixed"]], [0.5, -0.2]) and not force[:, keys["fixed"]].any()
    assert_reintegrates(keys)


def test_caterpillar_in_the_locomotion_environment_reintegrates(tmp_path) -> None:
    keys = simulate(tmp_path, "cat", "--shape", "caterpillar", "--steps", "300", "--swg-amplitude", "0.4")
    np.testing.assert_array_equal(keys["gravity"], [0.0, -9.81])
    assert float(keys["air_drag"]) == 0.1 and float(keys["ground_c"]) == 10.0
    assert not keys["fixed"].any() and int(keys["cmp_index"]) == -1
    y = keys["positions"][..., 1]
    assert y[-1].mean() < y[0].mean() - 0.05, "the body settles under gravity"
    assert_reintegrates(keys)


def test_published_integrator_with_ground_clamp_reintegrates(tmp_path) -> None:
    keys = simulate(tmp_path, "cat_pub", "--shape", "caterpillar", "--steps", "300", "--integrator", "published",
                    "--ground-clamp", "--perturb", "0.05", "--swg-amplitude", "0.4", "--seed", "5")
    assert str(keys["integrator"]) == "published" and bool(keys["ground_clamp"])
    assert (keys["positions"][0, :, 1] < 0).any() and (keys["positions"][1:, :, 1] >= 0).all()  # clamp after steps
    assert (keys["positions"][1:, :, 1] == 0).any(), "the clamp acted at least once"
    assert_reintegrates(keys)


def test_reintegration_detects_a_wrong_key(tmp_path) -> None:
    keys = simulate(tmp_path, "dc_wrong", "--shape", "double_circle", "--steps", "200", "--perturb", "0.1")
    for key, scale in (("k", 1.001), ("d", 1.001)):
        tampered = dict(keys)
        tampered[key] = keys[key] * scale
        positions, _ = reintegrate(tampered)
        assert np.abs(positions - keys["positions"]).max() > 1e3 * ACCEPTANCE, key
    tampered = dict(keys, integrator=np.str_("published"))
    assert np.abs(reintegrate(tampered)[0] - keys["positions"]).max() > 1e3 * ACCEPTANCE


def test_trajectory_loads_and_validates(tmp_path) -> None:
    out = tmp_path / "t.npz"
    assert simulate_cli(["--shape", "double_circle", "--steps", "20", "--perturb", "0.1", "--out", str(out)]) == 0
    traj = load_npz(out)
    assert traj.dtype == "float32" and traj.steps == 20 and traj.n_masses == 25 and traj.n_springs == 48
    assert traj.cmp_index == 24 and traj.shape == "double_circle" and traj.dt == pytest.approx(0.01)
    np.testing.assert_array_equal(traj.positions[:, traj.fixed], np.broadcast_to(traj.positions[0, traj.fixed],
                                                                                 (21, 12, 2)))
    assert traj.spring_lengths().shape == (21, 48) and traj.reference_point().shape == (21, 2)
    # A round trip keeps every key, extras included.
    traj.extras["target"] = np.arange(6.0).reshape(3, 2)
    again = load_npz(traj.save_npz(tmp_path / "again.npz"))
    for name in ("positions", "velocities", "springs", "k", "d", "rest_length", "fixed", "mass", "external_force",
                 "gravity"):
        np.testing.assert_array_equal(getattr(again, name), getattr(traj, name))
    np.testing.assert_array_equal(again.extras["target"], traj.extras["target"])


def _mutated(traj: Trajectory, **changes: object) -> Trajectory:
    fields = {name: getattr(traj, name) for name in traj.__dataclass_fields__}
    fields.update(changes)
    return Trajectory(**fields)


def test_validation_names_the_bad_key(tmp_path) -> None:
    out = tmp_path / "t.npz"
    assert simulate_cli(["--shape", "double_circle", "--steps", "10", "--perturb", "0.1", "--out", str(out)]) == 0
    traj = load_npz(out)
    moved = traj.positions.copy()
    moved[5, 0] += 0.1
    nan = traj.velocities.copy()
    nan[3, 20, 1] = np.nan
    cases = {
        "positions": dict(positions=moved),
        "velocities": dict(velocities=nan),
        "rest_length": dict(rest_length=traj.rest_length[:, :-1]),
        "springs": dict(springs=np.where(np.arange(48)[:, None] == 7, 3, traj.springs)),  # a self-spring
        "k": dict(k=-traj.k),
        "integrator": dict(integrator="euler"),
        "cmp_index": dict(cmp_index=0),
        "dt": dict(dt=0.0),
    }
    for key, change in cases.items():
        with pytest.raises(TrajectoryError, match=f"'{key}'"):
            _mutated(traj, **change).validate()
    raw = load_keys(out)
    raw.pop("external_force")
    np.savez(tmp_path / "missing.npz", **raw)
    with pytest.raises(TrajectoryError, match="missing trajectory key.*external_force"):
        load_npz(tmp_path / "missing.npz")


def test_gif_is_written(tmp_path) -> None:
    from PIL import Image

    gif = tmp_path / "run.gif"
    assert simulate_cli(["--shape", "caterpillar", "--steps", "40", "--out", str(tmp_path / "c.npz"),
                         "--gif", str(gif)]) == 0
    with Image.open(gif) as image:
        assert image.format == "GIF" and image.n_frames == 41


def test_divergence_is_an_error_naming_the_step(tmp_path, capsys) -> None:
    out = tmp_path / "bad.npz"
    code = simulate_cli(["--shape", "double_circle", "--steps", "500", "--dt", "0.5", "--perturb", "0.1",
                         "--out", str(out)])
    assert code == 1  # a runtime failure: the arguments were valid
    assert "diverged at step" in capsys.readouterr().err
    assert not out.exists()


def test_bad_arguments_are_rejected(tmp_path, capsys) -> None:
    out = str(tmp_path / "x.npz")
    assert simulate_cli(["--shape", "double_circle", "--steps", "0", "--out", out]) == 2
    assert "--steps" in capsys.readouterr().err
    assert simulate_cli(["--shape", "double_circle", "--nodes", "24", "--steps", "5", "--out", out]) == 2
    assert "odd" in capsys.readouterr().err
    assert simulate_cli(["--shape", "caterpillar", "--steps", "5", "--out", str(tmp_path / "x.csv")]) == 2
    assert ".npz" in capsys.readouterr().err


def save_agent(tmp_path, config: str, *overrides: str, feedback_fitted: bool = False):
    """A fresh (untrained) agent from a shipped config, saved as a run directory; ``feedback_fitted``
    marks its (initial) feedback layer as fitted, as ``bptsb train`` does after fitting it."""
    from bptsb_ros.agent import build_agent
    from bptsb_ros.config import load_config
    from bptsb_ros.training.checkpoint import save_checkpoint

    cfg = load_config(REPO_ROOT / "config" / config, list(overrides))
    run_dir = tmp_path / cfg.name
    save_checkpoint(run_dir, build_agent(cfg), extra={"feedback_fitted": True} if feedback_fitted else None)
    return run_dir


def test_swg_agent_open_loop_reintegrates(tmp_path) -> None:
    run_dir = save_agent(tmp_path, "lissajous_single.yaml")
    keys = simulate(tmp_path, "agent", "--agent", str(run_dir), "--steps", "1500", "--perturb", "0.05")
    assert keys["positions"].shape == (1501, 25, 2)  # past the divergence-check interval (1000 steps)
    assert np.ptp(keys["rest_length"], axis=0).min() > 0, "the SWG modulates every spring"
    assert_reintegrates(keys)


def test_mlp_agent_and_closed_loop_reintegrate(tmp_path) -> None:
    run_dir = save_agent(tmp_path, "narma.yaml")
    keys = simulate(tmp_path, "narma", "--agent", str(run_dir), "--steps", "200")
    force = keys["external_force"]
    assert np.abs(force).max() > 0.1 and not force[:, int(keys["cmp_index"])].any()  # no force on the CMP
    assert keys["extra_input"].shape == (201,)
    assert_reintegrates(keys)
    run_dir = save_agent(tmp_path, "lissajous_single.yaml", feedback_fitted=True)
    keys = simulate(tmp_path, "closed", "--agent", str(run_dir), "--steps", "200", "--loop", "closed",
                    "--perturb", "0.05", "--wind", "0.3", "0.0")
    assert_reintegrates(keys)


def test_agent_errors_are_clear(tmp_path, capsys) -> None:
    out = str(tmp_path / "x.npz")
    assert simulate_cli(["--agent", str(tmp_path / "nothing"), "--steps", "5", "--out", out]) == 1
    assert "no checkpoint" in capsys.readouterr().err
    run_dir = save_agent(tmp_path, "narma.yaml")
    assert simulate_cli(["--agent", str(run_dir), "--steps", "5", "--loop", "closed", "--out", out]) == 1
    assert "no feedback layer" in capsys.readouterr().err
    assert simulate_cli(["--agent", str(run_dir), "--steps", "5", "--swg-amplitude", "0.2", "--out", out]) == 2  # usage
    assert "--shape only" in capsys.readouterr().err
    run_dir = save_agent(tmp_path, "lissajous_single.yaml")  # feedback layer never fitted
    assert simulate_cli(["--agent", str(run_dir), "--steps", "5", "--loop", "closed", "--out", out]) == 1
    assert "never fitted" in capsys.readouterr().err
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    assert simulate_cli(["--agent", str(run_dir), "--steps", "5", "--out", str(blocker / "x.npz")]) == 1
    assert "cannot write --out" in capsys.readouterr().err
    assert simulate_cli(["--agent", str(run_dir), "--steps", "5", "--out", out,
                         "--gif", str(blocker / "x.gif")]) == 1
    assert "cannot write --gif" in capsys.readouterr().err


def test_narma_agent_input_is_the_held_narma_series(tmp_path) -> None:
    """``--seed S`` feeds narma_inputs(S, ·) held for τ steps: step 0 and 1..τ carry u_0, jτ+1..(j+1)τ u_j."""
    import torch

    from bptsb_ros.sim.inputs import narma_inputs
    from bptsb_ros.sim.rollout import held_inputs

    u = np.array([0.1, 0.2, 0.3])
    np.testing.assert_array_equal(held_inputs(u, 2, 6), [0.1, 0.1, 0.1, 0.2, 0.2, 0.3, 0.3])
    np.testing.assert_array_equal(held_inputs(torch.from_numpy(u), 2, 5).numpy(), [0.1, 0.1, 0.1, 0.2, 0.2, 0.3])
    with pytest.raises(ValueError, match="need 3 inputs"):
        held_inputs(u[:2], 2, 5)
    run_dir = save_agent(tmp_path, "narma.yaml")
    keys = simulate(tmp_path, "narma", "--agent", str(run_dir), "--steps", "50", "--seed", "7")
    from bptsb_ros.training.checkpoint import read_checkpoint

    narma = read_checkpoint(run_dir)["config"]["narma"]
    tau, scale = int(narma["tau"]), float(narma["input_scale"])
    series = narma_inputs(7, 50 // tau + 1)
    expected = scale * series[np.maximum(np.arange(51) - 1, 0) // tau]
    np.testing.assert_allclose(keys["extra_input"], expected, rtol=0, atol=1e-12)
