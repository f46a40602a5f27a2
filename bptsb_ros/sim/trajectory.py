"""The trajectory file: one simulated run of one body, self-describing, re-integrable from its keys alone.

A ``.npz`` written by :meth:`Trajectory.save_npz` (``bptsb simulate``, from a
``bptsb_ros.sim.rollout`` simulation via :func:`trajectory_from_rollout`) holds these keys. T is the
number of steps, N the number of masses (fixed ones included), E the number of springs. Row t of
every time series belongs to time t·dt; row 0 is the initial state.

=================  ================  =====  ===========================================================
key                shape             unit   meaning
=================  ================  =====  ===========================================================
``dt``             ()                s      integration time step
``positions``      (T+1, N, 2)       m      position of every mass (fixed masses constant)
``velocities``     (T+1, N, 2)       m/s    velocity of every mass (0 for fixed masses)
``springs``        (E, 2) int64      –      mass indices (i, j) of each spring
``k``              (E,)              N/m    spring constants
``d``              (E,)              N·s/m  damping coefficients (on the full relative velocity v_i − v_j)
``rest_length``    (T+1, E)          m      rest length in force at step t, modulation included
``fixed``          (N,) bool         –      True for masses pinned in place
``mass``           (N,)              kg     masses (1 in the paper)
``external_force`` (T+1, N, 2)       N      brain forces plus wind in force at step t (0 on fixed masses)
``gravity``        (2,)              m/s²   gravitational acceleration vector, [0, −9.81] in locomotion
``air_drag``       ()                N·s/m  air drag a: force −a·v on every mass
``ground_c``       ()                1/m    soft ground c: force [0, c·exp(−c·y)] on every mass; 0 = none
``integrator``     () str            –      ``verlet`` (the paper) or ``published`` (the authors' code)
``ground_clamp``   () bool           –      hard floor after each position update: y < 0 → y = 0, v = 0
``cmp_index``      () int            –      index of the centre mass point, −1 if the shape has none
``shape``          () str            –      body shape name (``double_circle``, ``caterpillar``, …)
``dtype``          () str            –      floating-point type the simulation ran in
``format_version`` () int            –      version of this layout (1)
``extra_<name>``   any               –      optional task data (targets, inputs) kept alongside
=================  ================  =====  ===========================================================

Step semantics (those of ``bptsb_ros.body.msdn``): with F(r, v, l, f) the total force on the
movable masses (springs, ``mass``·``gravity``, −a·v, ground, f),

    a(0)   = F(r(0), v(0), l(0), f(0)) / m
    r(t+1) = r(t) + v(t)·dt + a(t)·dt²/2                 (``published``: r(t) + v(t)·dt)
    with ``ground_clamp``: every movable mass with y(t+1) < 0 gets y(t+1) = 0 and v(t) = 0 (the
    published code's order: before the forces and the velocity update)
    a(t+1) = F(r(t+1), v(t), l(t+1), f(t+1)) / m        (velocity-dependent forces use v(t))
    v(t+1) = v(t) + (a(t) + a(t+1))·dt/2                 (``published``: v(t) + a(t+1)·dt/2)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from bptsb_ros.files.safe_write import atomic_writer

if TYPE_CHECKING:
    from bptsb_ros.body.msdn import MSDN
    from bptsb_ros.sim.rollout import Rollout

FORMAT_VERSION = 1
INTEGRATORS = ("verlet", "published")
DTYPES = ("float32", "float64")
EXTRA_PREFIX = "extra_"


class TrajectoryError(ValueError):
    """A trajectory file or object is malformed; the message names the offending key."""


@dataclass
class Trajectory:
    """One run of one body; see the module docstring for every field's shape and unit."""

    dt: float
    positions: np.ndarray
    velocities: np.ndarray
    springs: np.ndarray
    k: np.ndarray
    d: np.ndarray
    rest_length: np.ndarray
    fixed: np.ndarray
    mass: np.ndarray
    external_force: np.ndarray
    gravity: np.ndarray
    air_drag: float = 0.0
    ground_c: float = 0.0
    integrator: str = "verlet"
    ground_clamp: bool = False
    cmp_index: int = -1
    shape: str = ""
    dtype: str = "float64"
    extras: dict[str, np.ndarray] = field(default_factory=dict)

    # -- derived quantities -------------------------------------------------------------------------
    @property
    def steps(self) -> int:
        """Number of integration steps T (the arrays hold T+1 rows)."""
        return int(self.positions.shape[0]) - 1

    @property
    def n_masses(self) -> int:
        return int(self.positions.shape[1])

    @property
    def n_springs(self) -> int:
        return int(self.springs.shape[0])

    def spring_lengths(self) -> np.ndarray:
        """(T+1, E) spring lengths [m]."""
        diff = self.positions[:, self.springs[:, 0]] - self.positions[:, self.springs[:, 1]]
        return np.linalg.norm(diff, axis=-1)

    def reference_point(self) -> np.ndarray:
        """(T+1, 2) the CMP's path [m], or the mean of all masses when the shape has no CMP."""
        if self.cmp_index >= 0:
            return self.positions[:, self.cmp_index]
        return self.positions.mean(axis=1)

    # -- validation and I/O ---------------------------------------------------------------------------
    def validate(self) -> None:
        """Raise :class:`TrajectoryError` naming the first key whose shape, type or value is wrong."""
        _check(np.isfinite(self.dt) and self.dt > 0, "dt", f"must be a positive finite number, got {self.dt}")
        pos = np.asarray(self.positions)
        _check(pos.ndim == 3 and pos.shape[0] >= 1 and pos.shape[2] == 2, "positions",
               f"must have shape (T+1, N, 2), got {pos.shape}")
        rows, n = pos.shape[0], pos.shape[1]
        springs = np.asarray(self.springs)
        _check(springs.ndim == 2 and springs.shape[0] >= 1 and springs.shape[1] == 2, "springs",
               f"must have shape (E, 2) with E >= 1, got {springs.shape}")
        e = springs.shape[0]
        expected: dict[str, tuple[int, ...]] = {
            "velocities": (rows, n, 2), "k": (e,), "d": (e,), "rest_length": (rows, e),
            "fixed": (n,), "mass": (n,), "external_force": (rows, n, 2), "gravity": (2,),
        }
        for key, shp in expected.items():
            arr = np.asarray(getattr(self, key))
            _check(arr.shape == shp, key, f"must have shape {shp}, got {arr.shape}")
        _check(np.issubdtype(self.springs.dtype, np.integer), "springs", f"must be integers, got {self.springs.dtype}")
        _check(bool((self.springs >= 0).all() and (self.springs < n).all()), "springs",
               f"mass indices must lie in [0, {n})")
        _check(bool((self.springs[:, 0] != self.springs[:, 1]).all()), "springs", "a spring connects a mass to itself")
        _check(self.fixed.dtype == np.bool_, "fixed", f"must be bool, got {self.fixed.dtype}")
        for key in ("positions", "velocities", "k", "d", "rest_length", "mass", "external_force", "gravity"):
            _check(bool(np.isfinite(getattr(self, key)).all()), key, "contains NaN or inf")
        for key in ("k", "d"):  # rest lengths may dip below 0 under a strong feedback command
            _check(bool((getattr(self, key) >= 0).all()), key, "must be non-negative")
        _check(bool((self.mass > 0).all()), "mass", "must be positive")
        for key in ("air_drag", "ground_c"):
            value = getattr(self, key)
            _check(np.isfinite(value) and value >= 0, key, f"must be a non-negative number, got {value}")
        _check(self.integrator in INTEGRATORS, "integrator", f"must be one of {INTEGRATORS}, got {self.integrator!r}")
        _check(self.dtype in DTYPES, "dtype", f"must be one of {DTYPES}, got {self.dtype!r}")
        _check(-1 <= self.cmp_index < n, "cmp_index", f"must be -1 or a mass index < {n}, got {self.cmp_index}")
        _check(self.cmp_index < 0 or not bool(self.fixed[self.cmp_index]), "cmp_index", "the CMP must be movable")
        still = pos[:, self.fixed]
        _check(bool((still == still[:1]).all()), "positions", "a fixed mass moved")
        _check(bool((self.velocities[:, self.fixed] == 0).all()), "velocities", "a fixed mass has non-zero velocity")
        for name in self.extras:
            _check(name.isidentifier(), f"{EXTRA_PREFIX}{name}", "extra names must be identifiers")

    def save_npz(self, path: str | Path) -> Path:
        """Validate and write the trajectory to ``path`` (compressed ``.npz``); returns the path."""
        self.validate()
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        arrays: dict[str, Any] = {
            "dt": np.float64(self.dt),
            "positions": self.positions, "velocities": self.velocities,
            "springs": self.springs.astype(np.int64), "k": self.k, "d": self.d,
            "rest_length": self.rest_length, "fixed": self.fixed.astype(bool), "mass": self.mass,
            "external_force": self.external_force, "gravity": self.gravity,
            "air_drag": np.float64(self.air_drag), "ground_c": np.float64(self.ground_c),
            "integrator": np.str_(self.integrator), "ground_clamp": np.bool_(self.ground_clamp),
            "cmp_index": np.int64(self.cmp_index), "shape": np.str_(self.shape), "dtype": np.str_(self.dtype),
            "format_version": np.int64(FORMAT_VERSION),
        }
        arrays.update({EXTRA_PREFIX + name: value for name, value in self.extras.items()})
        with atomic_writer(path) as fh:
            np.savez_compressed(fh, **arrays)
        return path


def _check(ok: bool, key: str, message: str) -> None:
    if not ok:
        raise TrajectoryError(f"trajectory key {key!r}: {message}")


def load_npz(path: str | Path) -> Trajectory:
    """Read and validate a trajectory file written by :meth:`Trajectory.save_npz`."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"trajectory file not found: {path}")
    with np.load(path, allow_pickle=False) as data:
        keys = set(data.files)
        required = ("dt", "positions", "velocities", "springs", "k", "d", "rest_length", "fixed", "mass",
                    "external_force", "gravity", "air_drag", "ground_c", "integrator", "ground_clamp",
                    "cmp_index", "shape", "dtype", "format_version")
        missing = [key for key in required if key not in keys]
        if missing:
            raise TrajectoryError(f"{path}: missing trajectory key(s) {', '.join(missing)}")
        version = int(data["format_version"])
        if version != FORMAT_VERSION:
            raise TrajectoryError(f"{path}: trajectory format_version {version}, this reader knows {FORMAT_VERSION}")
        traj = Trajectory(
            dt=float(data["dt"]), positions=data["positions"], velocities=data["velocities"],
            springs=data["springs"], k=data["k"], d=data["d"], rest_length=data["rest_length"],
            fixed=data["fixed"], mass=data["mass"], external_force=data["external_force"], gravity=data["gravity"],
            air_drag=float(data["air_drag"]), ground_c=float(data["ground_c"]), integrator=str(data["integrator"]),
            ground_clamp=bool(data["ground_clamp"]), cmp_index=int(data["cmp_index"]), shape=str(data["shape"]),
            dtype=str(data["dtype"]),
            extras={key[len(EXTRA_PREFIX):]: data[key] for key in keys if key.startswith(EXTRA_PREFIX)},
        )
        unknown = keys - set(required) - {key for key in keys if key.startswith(EXTRA_PREFIX)}
        if unknown:
            raise TrajectoryError(f"{path}: unknown trajectory key(s) {', '.join(sorted(unknown))}")
    traj.validate()
    return traj


def trajectory_from_rollout(body: MSDN, rollout: Rollout, *, batch_index: int = 0, shape: str | None = None,
                            extras: dict[str, np.ndarray] | None = None) -> Trajectory:
    """One batch row of a ``bptsb_ros.sim.rollout.Rollout`` (tensors (T+1, B, …) of the movable masses)
    as a :class:`Trajectory` over all masses."""
    b = batch_index
    rest = _np(rollout.rest_length)
    rest = rest[:, b] if rest.ndim == 3 else rest
    return _assemble(body, _np(rollout.r[:, b]), _np(rollout.v[:, b]), rest, _np(rollout.external_force[:, b]),
                     shape, extras)


def _assemble(body: MSDN, r: np.ndarray, v: np.ndarray, rest: np.ndarray, force: np.ndarray, shape: str | None,
              extras: dict[str, np.ndarray] | None) -> Trajectory:
    """Movable-mass series r, v, force (T+1, M, 2) and rest (T+1, E) → a validated Trajectory over all N masses."""
    topo = body.topology
    env = body.environment
    movable = _np(body.movable_index)
    rows, n = r.shape[0], topo.n_masses
    # The layout the body integrates with (a float32 agent cast to float64 keeps float32-rounded fixed masses).
    positions = np.broadcast_to(_np(body.positions0).astype(r.dtype), (rows, n, 2)).copy()
    positions[:, movable] = r
    velocities = np.zeros_like(positions)
    velocities[:, movable] = v
    external = np.zeros_like(positions)
    external[:, movable] = force
    mass = np.ones(n)
    mass[movable] = _np(body.mass)
    traj = Trajectory(
        dt=body.dt, positions=positions, velocities=velocities, springs=np.asarray(topo.springs, dtype=np.int64),
        k=_np(body.k), d=_np(body.d), rest_length=rest, fixed=np.asarray(topo.fixed, dtype=bool), mass=mass,
        external_force=external, gravity=np.array([0.0, -float(env.gravity)]), air_drag=float(env.air_drag),
        ground_c=float(env.ground_c), integrator=body.integrator, ground_clamp=bool(env.ground_clamp),
        cmp_index=int(topo.cmp_index), shape=topo.name if shape is None else shape,
        dtype=str(body.k.dtype).removeprefix("torch."), extras=dict(extras or {}),
    )
    traj.validate()
    return traj


def _np(t: Any) -> np.ndarray:
    return t.detach().cpu().numpy().copy()

