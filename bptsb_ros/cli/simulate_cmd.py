"""``bptsb simulate``: headless simulation of a trained agent or a fresh body, written as a trajectory ``.npz``."""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from tqdm import tqdm

    from bptsb_ros.sim.rollout import Rollout
    from bptsb_ros.sim.trajectory import Trajectory

NAME = "simulate"
HELP = (
    "Simulate a trained agent (--agent RUN_DIR) or a fresh body (--shape) headless and write the trajectory as "
    ".npz (keys documented in bptsb_ros/sim/trajectory.py and the README); optionally a GIF.\n"
    "A fresh body starts at rest in its layout with k ~ U(1,100), d ~ U(0,10) drawn from --seed: --perturb "
    "displaces its movable masses at t = 0, --swg-amplitude modulates its rest lengths, --wind pushes it. "
    "--shape caterpillar runs in the locomotion environment (gravity, air drag, soft ground). An agent runs "
    "its trained brain (--loop open) or its feedback layer (--loop closed); LIL/MLP agents are driven by an "
    "input u ~ U(0, 1) from --seed, held for the config's narma.tau steps.\n"
    "Example: bptsb simulate --shape double_circle --nodes 25 --steps 1000 --perturb 0.1 --dtype float64 "
    "--out run.npz --gif run.gif"
)
DEFAULT_NODES = {"double_circle": 25, "multiple_circle": 17, "caterpillar": 10}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--agent", metavar="RUN_DIR", help="a training run directory (checkpoint + config)")
    source.add_argument("--shape", choices=sorted(DEFAULT_NODES), help="simulate a fresh body of this shape")
    parser.add_argument("--nodes", type=int, default=None,
                        help="--shape: number of masses, fixed ones included (default 25, 17 or 10 by shape)")
    parser.add_argument("--size", type=float, default=4.0, help="--shape: diameter of circular bodies [m]")
    parser.add_argument("--neighbours", type=int, default=3, help="--shape caterpillar: springs to the next K masses")
    parser.add_argument("--steps", type=int, required=True, help="number of integration steps T")
    parser.add_argument("--dt", type=float, default=None, help="time step [s] (default 0.01, or the agent's)")
    parser.add_argument("--dtype", choices=("float32", "float64"), default=None,
                        help="floating-point type (default float32, or the agent's)")
    parser.add_argument("--integrator", choices=("verlet", "published"), default=None,
                        help="verlet: the paper's velocity Verlet (default); published: the authors' code's update")
    parser.add_argument("--environment", choices=("auto", "none", "locomotion"), default="auto",
                        help="--shape: external physics; auto = locomotion for caterpillar, none otherwise")
    parser.add_argument("--ground-clamp", action="store_true",
                        help="--shape: the published code's hard floor (y < 0 → y = 0, v = 0)")
    parser.add_argument("--perturb", type=float, default=0.0, metavar="SIGMA",
                        help="displace movable masses at t = 0 by N(0, SIGMA²) per coordinate [m]")
    parser.add_argument("--swg-amplitude", type=float, default=0.0, metavar="A",
                        help="--shape: modulate every rest length by l·(1 + A sin(2πt + φ)), φ ~ U(0, 2π) from --seed")
    parser.add_argument("--wind", type=float, nargs=2, default=None, metavar=("FX", "FY"),
                        help="constant force on every movable mass [N]")
    parser.add_argument("--loop", choices=("open", "closed"), default="open",
                        help="--agent: open loop (the trained brain) or closed loop (the fitted feedback layer)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (body parameters, perturbation, phases)")
    parser.add_argument("--out", required=True, help="output trajectory file (.npz)")
    parser.add_argument("--gif", default=None, help="also write an animation (.gif)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def _fail(message: str) -> int:
    print(f"error: {message}", file=sys.stderr)
    return 2


def run(args: argparse.Namespace) -> int:
    if args.steps < 1:
        return _fail(f"--steps must be >= 1, got {args.steps}")
    if args.perturb < 0:
        return _fail(f"--perturb must be >= 0, got {args.perturb}")
    if args.dt is not None and args.dt <= 0:
        return _fail(f"--dt must be positive, got {args.dt}")
    if not str(args.out).endswith(".npz"):
        return _fail(f"--out must end in .npz, got {args.out}")
    if args.gif is not None and not str(args.gif).lower().endswith(".gif"):
        return _fail(f"--gif must end in .gif, got {args.gif}")

    from bptsb_ros.body.msdn import SimulationDiverged

    try:
        traj = _simulate_agent(args) if args.agent else _simulate_shape(args)
    except SimulationDiverged as exc:
        return _fail(str(exc))
    except ValueError as exc:
        return _fail(str(exc))
    path = traj.save_npz(args.out)
    print(f"wrote {path}: {traj.steps} steps of {traj.shape} ({traj.n_masses} masses, {traj.n_springs} springs, "
          f"{traj.dtype}, {traj.integrator})")
    if args.gif:
        from bptsb_ros.analysis.animate import animate_trajectory

        print(f"wrote {animate_trajectory(traj, args.gif)}")
    return 0


def _progress(args: argparse.Namespace) -> tqdm | None:
    if args.no_progress or args.steps < 2000:
        return None
    from tqdm import tqdm

    return tqdm(total=args.steps, unit="step", desc="simulate", file=sys.stderr, mininterval=0.5)


def _simulate_shape(args: argparse.Namespace) -> Trajectory:
    """A fresh body of ``--shape``: random k, d from the seed, rest lengths = the layout's distances."""
    import torch

    from bptsb_ros.body.msdn import MSDN, Environment
    from bptsb_ros.body.shapes import build_shape
    from bptsb_ros.brains.swg import SineWaveGenerator
    from bptsb_ros.sim.trajectory import simulate_and_record

    dtype = torch.float64 if args.dtype == "float64" else torch.float32
    nodes = DEFAULT_NODES[args.shape] if args.nodes is None else args.nodes
    topology = build_shape(args.shape, nodes, size=args.size, neighbours=args.neighbours)
    env_name = args.environment
    if env_name == "auto":
        env_name = "locomotion" if args.shape == "caterpillar" else "none"
    environment = Environment.locomotion() if env_name == "locomotion" else Environment()
    if args.ground_clamp:
        environment = Environment(environment.gravity, environment.air_drag, environment.ground_c, ground_clamp=True)
    gen = torch.Generator().manual_seed(args.seed)
    body = MSDN(topology, dt=0.01 if args.dt is None else args.dt, integrator=args.integrator or "verlet",
                environment=environment, generator=gen, dtype=dtype)
    m = body.n_movable
    displacement = None
    if args.perturb > 0:
        displacement = (args.perturb * torch.randn(1, m, 2, generator=gen, dtype=torch.float64)).to(dtype)
    rest_table = None
    if args.swg_amplitude:
        swg = SineWaveGenerator(topology.n_springs, amplitude=args.swg_amplitude, generator=gen, dtype=dtype)
        with torch.no_grad():
            times = torch.arange(args.steps + 1, dtype=dtype) * body.dt
            rest_table = swg.rest_length(body.l, times)  # (T+1, E)
    wind = None if args.wind is None else torch.tensor(args.wind, dtype=dtype).expand(m, 2)
    bar = _progress(args)
    try:
        return simulate_and_record(
            body, args.steps,
            rest_length_at=None if rest_table is None else rest_table.__getitem__,
            external_force_at=None if wind is None else (lambda _t: wind),
            displacement=displacement,
            progress=None if bar is None else (lambda _t: bar.update(1)),
        )
    finally:
        if bar is not None:
            bar.close()


def _simulate_agent(args: argparse.Namespace) -> Trajectory:
    """A trained agent from ``--agent RUN_DIR``, run open or closed loop by ``bptsb_ros.sim.rollout``.

    SWG agents modulate their rest lengths; LIL/MLP agents get a task input u ~ U(0, 1) from ``--seed``,
    held for the config's ``narma.tau`` steps and scaled by ``narma.input_scale`` (stored as the extra
    ``input``, the per-step brain input in force at each step).
    """
    import numpy as np
    import torch

    from bptsb_ros.brains import SineWaveGenerator
    from bptsb_ros.sim.rollout import simulate_closed_loop, simulate_open_loop
    from bptsb_ros.sim.trajectory import trajectory_from_rollout
    from bptsb_ros.training.checkpoint import CheckpointError, load_agent

    if args.swg_amplitude or args.ground_clamp or args.environment != "auto" or args.nodes is not None:
        raise ValueError("--nodes, --swg-amplitude, --ground-clamp and --environment apply to --shape only")
    dtype = {"float32": torch.float32, "float64": torch.float64, None: None}[args.dtype]
    try:
        agent = load_agent(args.agent, dtype=dtype)
    except CheckpointError as exc:
        raise ValueError(str(exc)) from None
    body = agent.body
    if args.dt is not None:
        body.dt = float(args.dt)
    if args.integrator is not None:
        body.integrator = args.integrator
    if args.loop == "closed" and agent.feedback is None:
        raise ValueError(f"{args.agent} has no feedback layer; run the open loop (--loop open)")
    real = body.l.dtype
    gen = torch.Generator().manual_seed(args.seed)
    displacement = None
    if args.perturb > 0:
        displacement = (args.perturb * torch.randn(1, body.n_movable, 2, generator=gen, dtype=torch.float64)).to(real)
    wind = None if args.wind is None else torch.tensor(args.wind, dtype=real)
    inputs = None
    extras: dict[str, np.ndarray] = {}
    if args.loop == "open" and not isinstance(agent.brain, SineWaveGenerator):
        narma = agent.config["narma"]
        tau = int(narma["tau"])
        u = torch.rand(args.steps // tau + 1, generator=gen, dtype=torch.float64)
        # Step 0 and steps 1..τ use u[0], steps τ+1..2τ use u[1], … (as the NARMA episodes).
        held = torch.cat([u[:1], u.repeat_interleave(tau)])[: args.steps + 1]
        inputs = (float(narma["input_scale"]) * held).to(real)
        extras["input"] = inputs.numpy().copy()

    chunk = 1000  # rollouts run in chunks so that long runs show progress
    bar = _progress(args)
    parts = []
    state = None
    done = 0
    try:
        while done < args.steps:
            n = min(chunk, args.steps - done)
            if args.loop == "closed":
                part = simulate_closed_loop(body, agent.feedback, n, state=state, wind=wind,
                                            displacement=displacement, check_every=1)
            else:
                part = simulate_open_loop(agent, n, state=state, wind=wind, displacement=displacement, check_every=1,
                                          inputs=None if inputs is None else inputs[done: done + n + 1])
            parts.append(part if state is None else _drop_first_row(part))
            state = part.final
            done += n
            if bar is not None:
                bar.update(n)
    finally:
        if bar is not None:
            bar.close()
    return trajectory_from_rollout(body, _concatenate(parts), shape=body.topology.name, extras=extras)


def _drop_first_row(part: Rollout) -> Rollout:
    from bptsb_ros.sim.rollout import Rollout

    return Rollout(part.r[1:], part.v[1:], part.a[1:], part.length[1:], part.rest_length[1:],
                   part.external_force[1:], part.final)


def _concatenate(parts: list[Rollout]) -> Rollout:
    import torch

    from bptsb_ros.sim.rollout import Rollout

    if len(parts) == 1:
        return parts[0]
    cat = [torch.cat([getattr(p, name) for p in parts]) for name in ("r", "v", "a", "length", "rest_length",
                                                                      "external_force")]
    return Rollout(*cat, parts[-1].final)
