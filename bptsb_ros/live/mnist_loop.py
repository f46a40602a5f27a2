"""The launch arguments of the live MNIST loop ``mnist_drawing`` (ROS-free): the system file, the image stream
and the episode length, checked before any node starts, and the node parameters they add.

``bptsb launch mnist_drawing --agent SYSTEM.pt --images IDX --labels IDX [--first N --count N]`` and
``ros2 launch bptsb_ros mnist_drawing.launch.py agent:=SYSTEM.pt images:=IDX labels:=IDX`` both go through
:func:`plan_stream` and :func:`stream_parameters`: ``body_sim`` gets ``reset_every`` = E (and, without a
duration, exactly count·E steps: steps 0..count·E − 1, every episode complete), ``image_streamer`` the stream,
the recorder ``episode_steps``, ``first`` and ``count`` in the bag's ``custom_data`` (``bptsb replay`` reads them).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from bptsb_ros.interface.params import ParamValue

LOOP = "mnist_drawing"
#: launch arguments of the loop besides the common ones: name -> (default, description)
STREAM_ARGUMENTS: dict[str, tuple[str, str]] = {
    "images": ("", "IDX file of the streamed images (n, 28, 28), gzipped if .gz (required)"),
    "labels": ("", "IDX file of their labels (required)"),
    "first": ("0", "index of the first image streamed"),
    "count": ("0", "images streamed, one per episode; 0: every image from first on"),
    "episode_steps": ("0", "steps per episode E (image i at step i*E); 0: the longest digit target's steps + 1"),
}


#: wall seconds the body waits for a reset command before it counts the brain silent. A reset goes through two
#: nodes (image_streamer -> mnist_brain) whose link the body cannot watch, so its first one may need longer than a
#: direct command's 2 s (body_sim's command_timeout) on a loaded machine.
RESET_COMMAND_TIMEOUT = 10.0


class StreamError(ValueError):
    """A launch argument of the MNIST loop is wrong; the message names it."""


@dataclass(frozen=True)
class StreamPlan:
    """The checked stream: absolute IDX paths, first image, number of images (resolved), episode length E."""

    images: str
    labels: str
    first: int
    count: int
    episode_steps: int

    @property
    def steps(self) -> int:
        """Last step of the run: count·E − 1 (every episode complete)."""
        return self.count * self.episode_steps - 1


def plan_stream(agent: str, images: str, labels: str, first: int = 0, count: int = 0,
                episode_steps: int = 0) -> StreamPlan:
    """Check the system file and the stream (read once here, so a bad file stops the launch before any node
    starts) and resolve ``count`` (0: all from ``first``) and ``episode_steps`` (0: the default of the system's
    time step). Raises StreamError naming the argument."""
    from bptsb_ros.data.mnist import MnistError
    from bptsb_ros.tasks.drawing import DigitTargets
    from bptsb_ros.tasks.mnist_live import SystemFileError, load_system_as, read_stream

    if not agent:
        raise StreamError(f"{LOOP} needs an MNIST system file as agent (systems/<name>.pt of the MNIST drawing "
                          "experiment)")
    try:
        system = load_system_as(agent)
    except SystemFileError as err:
        raise StreamError(f"agent {agent}: {err}") from None
    if not images or not labels:
        raise StreamError(f"{LOOP} needs the images and labels IDX files of the stream")
    if episode_steps < 0:
        raise StreamError(f"episode_steps {episode_steps}: must be >= 0")
    try:
        _x, y = read_stream(images, labels, first, count)
    except MnistError as err:
        raise StreamError(f"images/labels: {err}") from None
    targets = DigitTargets(system.spec.dt)
    need = int(targets.steps[y].max()) + 1
    steps = episode_steps or targets.t_max + 1
    if steps < need:
        raise StreamError(f"episode_steps {steps}: the stream's digits need at least {need} steps per episode "
                          "(their longest target's steps + 1)")
    return StreamPlan(str(Path(images).resolve()), str(Path(labels).resolve()), first, len(y), steps)


def stream_parameters(plan: StreamPlan, executable: str, params: dict[str, ParamValue], *, recording: bool,
                      duration: float) -> dict[str, ParamValue]:
    """``params`` of one node of the loop (from ``loops.node_parameters`` or ``recorder_parameters``) with
    what the stream adds."""
    out = dict(params)
    if executable == "body_sim":
        out["reset_every"] = plan.episode_steps
        out["command_timeout"] = max(float(out.get("command_timeout", 0.0)), RESET_COMMAND_TIMEOUT)  # type: ignore[arg-type]
        if duration <= 0:
            out["max_steps"] = plan.steps
    elif executable == "image_streamer":
        out.update(images=plan.images, labels=plan.labels, first=plan.first, count=plan.count,
                   episode_steps=plan.episode_steps, min_subscribers=1 + int(recording))
    elif executable == "recorder":
        out["custom_data"] = list(out.get("custom_data", [])) + [  # type: ignore[arg-type]
            f"episode_steps={plan.episode_steps}", f"first={plan.first}", f"count={plan.count}"]
    return out
