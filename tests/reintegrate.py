"""An independent re-integration of a trajectory file from its own keys, in plain numpy.

Written from the paper's equations (Methods: spring-damper force Eq. (1), velocity Verlet; locomotion
environment) and the step semantics stated in the file format, without importing ``bptsb_ros``: a
force on every mass i from every spring (i, j) and the environment, accelerations of fixed masses
set to zero, then the integrator update. Used by ``test_simulate.py`` to check that a simulated
trajectory is the solution of the equations it claims to solve.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


def load_keys(path: str | Path) -> dict[str, np.ndarray]:
    """All arrays of an ``.npz`` trajectory file, as a plain dict."""
    with np.load(path, allow_pickle=False) as data:
        return {key: data[key] for key in data.files}


def total_force(keys: dict[str, np.ndarray], r: np.ndarray, v: np.ndarray, step: int) -> np.ndarray:
    """(N, 2) total force [N] on every mass at positions r, velocities v, with the rest lengths and
    external forces in force at ``step``."""
    springs = keys["springs"]
    i, j = springs[:, 0], springs[:, 1]
    k, d = keys["k"], keys["d"]
    rest = keys["rest_length"][step]
    delta = r[i] - r[j]  # (E, 2)
    dist = np.sqrt((delta**2).sum(axis=1))
    f_ij = -(k * (dist - rest) / dist)[:, None] * delta - d[:, None] * (v[i] - v[j])  # Eq. (1), on mass i
    force = np.zeros_like(r)
    np.add.at(force, i, f_ij)
    np.add.at(force, j, -f_ij)
    mass = keys["mass"]
    force += mass[:, None] * keys["gravity"][None, :]
    force += -float(keys["air_drag"]) * v
    c = float(keys["ground_c"])
    if c != 0.0:
        force[:, 1] += c * np.exp(-c * r[:, 1])
    force += keys["external_force"][step]
    return force


def reintegrate(keys: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Integrate from row 0 of ``positions``/``velocities`` for as many steps as the file holds.

    Returns:
        positions, velocities: (T+1, N, 2) re-integrated [m], [m/s].
    """
    dt = float(keys["dt"])
    integrator = str(keys["integrator"])
    if integrator not in ("verlet", "published"):
        raise ValueError(f"unknown integrator {integrator!r}")
    clamp = bool(keys["ground_clamp"])
    movable = ~keys["fixed"].astype(bool)
    inv_mass = (1.0 / keys["mass"])[:, None] * movable[:, None]  # fixed masses never accelerate
    steps = keys["positions"].shape[0] - 1
    r = keys["positions"][0].astype(np.float64).copy()
    v = keys["velocities"][0].astype(np.float64).copy()
    a = total_force(keys, r, v, 0) * inv_mass
    out_r, out_v = [r.copy()], [v.copy()]
    for t in range(1, steps + 1):
        if integrator == "verlet":
            r_new = r + v * dt + 0.5 * a * dt * dt
        else:
            r_new = r + v * dt
        if clamp:  # the published code's order: floor right after the position update, before the forces
            below = (r_new[:, 1] < 0) & movable
            r_new[below, 1] = 0.0
            v = v.copy()
            v[below] = 0.0
        a_new = total_force(keys, r_new, v, t) * inv_mass  # velocity-dependent forces see v(t) (clamped)
        if integrator == "verlet":
            v_new = v + 0.5 * (a + a_new) * dt
        else:
            v_new = v + 0.5 * a_new * dt
        r, v, a = r_new, v_new, a_new
        out_r.append(r.copy())
        out_v.append(v.copy())
    return np.stack(out_r), np.stack(out_v)
