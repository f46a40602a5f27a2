"""``bptsb simulate``: headless simulation of a trained agent or a fresh body, written as a trajectory ``.npz``.

Both sources run the one offline loop of ``bptsb_ros.sim.rollout`` and are written by
``bptsb_ros.sim.trajectory.trajectory_from_rollout``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING

from bptsb_ros.body.shapes import DEFAULT_NODES
from bptsb_ros.cli.options import USAGE, UsageError, fail, finite_float

if TYPE_CHECKING:
    from bptsb_ros.sim.trajectory import Trajectory

NAME = "simulate"
HELP = (
    "Simulate a trained agent (--agent RUN_DIR) or a fresh body (--shape) headless and write the trajectory as "
    ".npz (keys documented in bptsb_ros/sim/trajectory.py and docs/simulation-files.md); optionally a GIF.\n"
    "A fresh body starts at rest in its layout with k ~ U(1,100), d ~ U(0,10) drawn from --seed: --perturb "
    "displaces its movable masses at t = 0, --swg-amplitude modulates its rest lengths, --wind pushes it. "
    "--shape caterpillar runs in the locomotion environment (gravity, air drag, soft ground). An agent runs "
    "its trained brain (--loop open) or its fitted feedback layer (--loop closed); LIL/MLP agents are driven "
    "by the NARMA input series u ~ U(0, 1) of --seed (the series the evaluation uses for narma.eval_seed and "
    "the live task_input node streams for its seed), each held for the config's narma.tau steps.\n"
    "Example: bptsb simulate --shape double_circle --nodes 25 --steps 1000 --perturb 0.1 --dtype float64 "
    "--out run.npz --gif run.gif"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--agent", metavar="RUN_DIR", help="a training run directory (checkpoint + config)")
    source.add_argument("--shape", choices=sorted(DEFAULT_NODES), help="simulate a fresh body of this shape")
    parser.add_argument("--nodes", type=int, default=None,
                        help="--shape: number of masses, fixed ones included (default 25, 17 or 10 by shape)")
    parser.add_argument("--size", type=finite_float, default=4.0, help="--shape: diameter of circular bodies [m]")
    parser.add_argument("--neighbours", type=int, default=3, help="--shape caterpillar: springs to the next K masses")
    parser.add_argument("--steps", type=int, required=True, help="number of integration steps T")
    parser.add_argument("--dt", type=finite_float, default=None, help="time step [s] (default 0.01, or the agent's)")
    parser.add_argument("--dtype", choices=("float32", "float64"), default=None,
                        help="floating-point type (default float32, or the agent's)")
    parser.add_argument("--integrator", choices=("verlet", "published"), default=None,
                        help="verlet: the paper's velocity Verlet (default); published: the authors' code's update")
    parser.add_argument("--backend", choices=("numba", "torch"), default=None,
                        help="numba: the compiled window kernel (default; --agent: the agent's training.backend); "
                             "torch: torch ops (the reference)")
    parser.add_argument("--environment", choices=("auto", "none", "locomotion"), default="auto",
                        help="--shape: external physics; auto = locomotion for caterpillar, none otherwise")
    parser.add_argument("--ground-clamp", action="store_true",
                        help="--shape: the published code's hard floor (y < 0 → y = 0, v = 0)")
    parser.add_argument("--perturb", type=finite_float, default=0.0, metavar="SIGMA",
                        help="displace movable masses at t = 0 by N(0, SIGMA²) per coordinate [m]")
    parser.add_argument("--swg-amplitude", type=finite_float, default=0.0, metavar="A",
                        help="--shape: modulate every rest length by l·(1 + A sin(2πt + φ)), φ ~ U(0, 2π) from --seed")
    parser.add_argument("--wind", type=finite_float, nargs=2, default=None, metavar=("FX", "FY"),
                        help="constant force on every movable mass [N]")
    parser.add_argument("--loop", choices=("open", "closed"), default="open",
                        help="--agent: open loop (the trained brain) or closed loop (the fitted feedback layer)")
    parser.add_argument("--seed", type=int, default=0,
                        help="random seed (body parameters, perturbation, phases; the NARMA input series)")
    parser.add_argument("--out", required=True, help="output trajectory file (.npz)")
    parser.add_argument("--gif", default=None, help="also write an animation (.gif)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def _usage(message: str) -> int:
    return fail(NAME, message, USAGE)


def run(args: argparse.Namespace) -> int:
    if args.steps < 1:
        return _usage(f"--steps must be >= 1, got {args.steps}")
    if args.perturb < 0:
        return _usage(f"--perturb must be >= 0, got {args.perturb}")
    if args.dt is not None and args.dt <= 0:
        return _usage(f"--dt must be positive, got {args.dt}")
    if not str(args.out).endswith(".npz"):
        return _usage(f"--out must end in .npz, got {args.out}")
    if args.gif is not None and not str(args.gif).lower().endswith(".gif"):
        return _usage(f"--gif must end in .gif, got {args.gif}")
    if args.agent and (args.swg_amplitude or args.ground_clamp or args.environment != "auto" or args.nodes is not None):
        return _usage("--nodes, --swg-amplitude, --ground-clamp and --environment apply to --shape only")

    from bptsb_ros.body.msdn import SimulationDiverged
    from bptsb_ros.body.threads import configure_threads
    from bptsb_ros.training.checkpoint import CheckpointError

    configure_threads(1, args.backend or "torch")  # one body: one thread (the kernel runs a batch of 1 serially)
    try:
        traj = _simulate_agent(args) if args.agent else _simulate_shape(args)
    except UsageError as exc:  # --nodes / --size / --neighbours out of range for the shape
        return _usage(str(exc))
    except (SimulationDiverged, CheckpointError, ValueError) as exc:  # divergence; the agent's files
        return fail(NAME, exc)
    try:
        path = traj.save_npz(args.out)
    except OSError as exc:
        return fail(NAME, f"cannot write --out {args.out}: {exc.strerror or exc}")
    print(f"wrote {path}: {traj.steps} steps of {traj.shape} ({traj.n_masses} masses, {traj.n_springs} springs, "
          f"{traj.dtype}, {traj.integrator})")
    if args.gif:
        from bptsb_ros.analysis.animate import animate_trajectory

        try:
            gif = animate_trajectory(traj, args.gif)
        except OSError as exc:
            return fail(NAME, f"cannot write --gif {args.gif}: {exc.strerror or exc}")
        print(f"wrote {gif}")
    return 0


@contextmanager
def _progress(args: argparse.Namespace) -> Iterator[Callable[[int], None] | None]:
    """A progress callback (steps done) drawing a bar on stderr for long runs, or None."""
    if args.no_progress or args.steps < 2000:
        yield None
        return
    from tqdm import tqdm

    with tqdm(total=args.steps, unit="step", desc="simulate", file=sys.stderr, mininterval=0.5) as bar:
        yield lambda done: bar.update(done - bar.n)


def _simulate_shape(args: argparse.Namespace) -> Trajectory:
    """A fresh body of ``--shape``: random k, d from the seed, rest lengths = the layout's distances."""
    import dataclasses

    import torch

    from bptsb_ros.agent import dtype_of
    from bptsb_ros.body.msdn import MSDN, Environment
    from bptsb_ros.body.shapes import build_shape
    from bptsb_ros.brains.swg import SineWaveGenerator
    from bptsb_ros.sim.rollout import simulate_commands, swg_rest_lengths, wind_forces
    from bptsb_ros.sim.trajectory import trajectory_from_rollout

    dtype = dtype_of(args.dtype or "float32")
    nodes = DEFAULT_NODES[args.shape] if args.nodes is None else args.nodes
    try:
        topology = build_shape(args.shape, nodes, size=args.size, neighbours=args.neighbours)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    env_name = args.environment
    if env_name == "auto":
        env_name = "locomotion" if args.shape == "caterpillar" else "none"
    environment = Environment.locomotion() if env_name == "locomotion" else Environment()
    if args.ground_clamp:
        environment = dataclasses.replace(environment, ground_clamp=True)
    gen = torch.Generator().manual_seed(args.seed)
    body = MSDN(topology, dt=0.01 if args.dt is None else args.dt, integrator=args.integrator or "verlet",
                environment=environment, generator=gen, dtype=dtype, backend=args.backend or "numba")
    displacement = None
    if args.perturb > 0:
        displacement = (args.perturb * torch.randn(1, body.n_movable, 2, generator=gen, dtype=torch.float64)).to(dtype)
    with torch.no_grad():
        if args.swg_amplitude:
            swg = SineWaveGenerator(topology.n_springs, amplitude=args.swg_amplitude, generator=gen, dtype=dtype)
            rest = swg_rest_lengths(body, swg, 0, args.steps + 1)
        else:
            rest = body.l.expand(args.steps + 1, -1)
    wind = None if args.wind is None else torch.tensor(args.wind, dtype=dtype)
    with _progress(args) as progress:
        roll = simulate_commands(body, args.steps, rest, wind_forces(body, wind, args.steps),
                                 displacement=displacement, progress=progress)
    return trajectory_from_rollout(body, roll)


def _simulate_agent(args: argparse.Namespace) -> Trajectory:
    """A trained agent from ``--agent RUN_DIR``, run open or closed loop by
    :func:`bptsb_ros.sim.agent_run.simulate_agent` (LIL/MLP agents: the NARMA input series of ``--seed``)."""
    from bptsb_ros.agent import dtype_of
    from bptsb_ros.sim.agent_run import simulate_agent
    from bptsb_ros.training.checkpoint import CheckpointError, feedback_fitted, load_agent

    agent = load_agent(args.agent, dtype=None if args.dtype is None else dtype_of(args.dtype))
    if args.loop == "closed" and agent.feedback is None:
        raise CheckpointError(f"{args.agent} has no feedback layer; run the open loop (--loop open)")
    if args.loop == "closed" and not feedback_fitted(args.agent):
        raise CheckpointError(f"the feedback layer of {args.agent} was never fitted (bptsb train fits it for SWG "
                              "agents); run the open loop (--loop open)")
    body = agent.body
    if args.dt is not None:
        body.dt = float(args.dt)
    if args.integrator is not None:
        body.integrator = args.integrator
    if args.backend is not None:
        body.backend = args.backend
    with _progress(args) as progress:
        return simulate_agent(agent, args.steps, loop=args.loop, seed=args.seed, perturb=args.perturb,
                              wind=args.wind, progress=progress)
