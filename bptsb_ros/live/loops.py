"""The live loops (ROS-free description): which nodes run, with which parameters, on which topics.

``bptsb launch <loop>`` and the ROS launch files ``launch/<loop>.launch.py`` both build their
processes from :data:`LOOPS`, so the two ways of starting a loop cannot drift apart.

Topic wiring (default names, ``bptsb_ros/ros/TOPICS.md``): ``body_sim`` publishes ``/clock`` and the
body state; time-driven brains (``swg_brain``, ``task_input``) answer ``/clock``; ``feedback_brain``
answers the body state; ``mlp_brain`` answers ``task/input``; commands go back to ``body_sim``.

Namespaces (several robots in one ROS domain): a loop started in namespace ``/r1`` (``bptsb launch --namespace r1``,
``namespace:=r1`` or ``PushRosNamespace`` around a launch file) resolves every topic in it — also ``/clock`` and
``/diagnostics``, remapped to ``/r1/clock`` and ``/r1/diagnostics`` (:func:`namespace_remaps`), so each robot keeps
its own lockstep clock and its bag holds exactly its own topics. The startup waits and the recorder's topic list use
the resolved names (:func:`loop_topic`). The body's frame is namespaced too (``robot1/msdn``,
:func:`bptsb_ros.live.viewers.frame_id`), and :mod:`bptsb_ros.live.viewers` writes the RViz and Foxglove
configurations of that robot.
"""

from __future__ import annotations

import re
import tempfile
from dataclasses import dataclass
from pathlib import Path

from bptsb_ros.interface.nodes import BY_NAME
from bptsb_ros.interface.params import ParamValue, params_sections_text, yaml_value
from bptsb_ros.interface.topics import BODY_OUTPUTS, COMMAND_SOURCES, RECORDER_ACK, TOPICS, absolute, feedback_state_key
from bptsb_ros.live.body_params import SLOW_OUTPUTS

__all__ = ["LOOPS", "BrainSpec", "Loop", "ParamValue", "agent_loop", "body_process_nodes", "feedback_state_key",
           "format_parameter",
           "log_dir_of_bag", "node_parameters", "recorder_parameters", "topic_names"]


@dataclass(frozen=True)
class BrainSpec:
    """One brain-side node of a loop.

    Attributes:
        executable: node name (module ``bptsb_ros.ros.<executable>``).
        triggers: topic keys it subscribes to (reliably) besides the sim-time ``/clock`` subscription.
        publishes: topic keys it publishes.
    """

    executable: str
    triggers: tuple[str, ...]
    publishes: tuple[str, ...]


@dataclass(frozen=True)
class Loop:
    """A brain–body loop.

    Attributes:
        name: loop name (``bptsb launch <name>``, ``launch/<name>.launch.py``).
        summary: one line for ``bptsb launch --help``.
        task: task of the agent (a fresh agent is built for it when no agent is given).
        brains: the brain-side nodes.
        wait_for: command sources ``body_sim`` waits for in lockstep.
        needs_agent: True when a trained agent is required (the feedback layer must be fitted).
    """

    name: str
    summary: str
    task: str
    brains: tuple[BrainSpec, ...]
    wait_for: tuple[str, ...]
    needs_agent: bool = False

    def topics(self) -> list[str]:
        """Keys of every topic of the loop (recorded by ``--bag``): body outputs, then brain outputs."""
        keys = list(BODY_OUTPUTS)
        for brain in self.brains:
            keys += [k for k in brain.publishes if k not in keys]
        return keys

    def step_topics(self) -> list[str]:
        """Keys of the topics with one message every step (what the recorder acknowledges in lockstep)."""
        return [k for k in self.topics() if k not in NOT_EVERY_STEP]


#: loop topics without a message every step: markers every marker_every steps, the body's derived state topics
#: every state_every steps (unless a brain reads them), diagnostics every second, perturbations and the MNIST stream
#: per event or episode
NOT_EVERY_STEP = frozenset({"markers", "diagnostics", "perturbation", "image", "label", "reset_cmd", *SLOW_OUTPUTS})



def brain_spec(name: str) -> BrainSpec:
    """The brain-side node ``name`` of the node table (:data:`bptsb_ros.interface.nodes.NODES`) as a loop runs it."""
    node = BY_NAME[name]
    return BrainSpec(node.name, node.triggers, node.publishes)


SWG = brain_spec("swg_brain")
FEEDBACK = brain_spec("feedback_brain")
TASK_INPUT = brain_spec("task_input")
MLP = brain_spec("mlp_brain")
WIND = brain_spec("wind_source")
IMAGES = brain_spec("image_streamer")
MNIST_BRAIN = brain_spec("mnist_brain")

LOOPS: dict[str, Loop] = {
    loop.name: loop
    for loop in (
        Loop("lissajous_open", "Lissajous curve, open loop: SWG rest lengths drive a double-circle body",
             "lissajous", (SWG,), ("rest_length",)),
        Loop("lissajous_closed", "Lissajous curve, closed loop: the fitted feedback layer turns spring lengths "
             "into rest lengths", "lissajous", (FEEDBACK,), ("rest_length",), needs_agent=True),
        Loop("locomotion_open", "caterpillar locomotion, open loop: SWG rest lengths, gravity and ground",
             "locomotion", (SWG,), ("rest_length",)),
        Loop("locomotion_closed", "caterpillar locomotion, closed loop: the fitted feedback layer drives the body",
             "locomotion", (FEEDBACK,), ("rest_length",), needs_agent=True),
        Loop("locomotion_headwind", "caterpillar locomotion under a periodic headwind: SWG rest lengths and the "
             "wind of the agent's locomotion.wind_force / wind_period, both in lockstep", "locomotion",
             (SWG, WIND), ("rest_length", "wind")),
        Loop("lissajous_switching", "Lissajous switching by wind: SWG rest lengths and the wind schedule of the agent "
             "(switching agents: wind on and off at random times), both in lockstep", "lissajous", (SWG, WIND),
             ("rest_length", "wind")),
        Loop("narma", "expanded NARMA emulation: streamed input u → MLP (or LIL) forces on the masses",
             "narma", (TASK_INPUT, MLP), ("force",)),
        Loop("mnist_drawing", "see a digit, draw it: streamed MNIST images -> the system's brain -> initial "
             "displacements; the body is reset to them and released every episode (--agent SYSTEM.pt --images IDX "
             "--labels IDX)", "mnist_drawing", (IMAGES, MNIST_BRAIN), ("reset",), needs_agent=True),
    )
}


def with_feedback_state(loop: Loop, state_type: str) -> Loop:
    """The loop with the feedback brain's trigger set for ``state_type`` (spring lengths or mass states)."""
    key = feedback_state_key(state_type)
    brains = tuple(BrainSpec(b.executable, ("clock", key), b.publishes) if b.executable == "feedback_brain" else b
                   for b in loop.brains)
    return Loop(loop.name, loop.summary, loop.task, brains, loop.wait_for, loop.needs_agent)


def agent_loop(loop: Loop, agent: str) -> Loop:
    """``loop`` adapted to a trained agent: the feedback brain reads the state type its layer was fitted on.

    Raises ``bptsb_ros.training.checkpoint.CheckpointError`` if ``agent`` has no readable checkpoint.
    """
    if not agent or not any(b.executable == "feedback_brain" for b in loop.brains):
        return loop
    from bptsb_ros.training.checkpoint import read_checkpoint

    state = read_checkpoint(agent)["config"].get("feedback", {}).get("state", "spring_length")
    return with_feedback_state(loop, state)


_NAMESPACE = re.compile(r"^(/?[A-Za-z_][A-Za-z0-9_]*)(/[A-Za-z_][A-Za-z0-9_]*)*/?$")


class NamespaceError(ValueError):
    """A namespace that ROS would refuse; the message names it."""


def normalize_namespace(namespace: str) -> str:
    """``namespace`` as an absolute ROS namespace without a trailing slash (``r1`` → ``/r1``); '' or '/' → ''
    (the root). Raises NamespaceError for a name ROS refuses (tokens of letters, digits and ``_``, not starting with
    a digit, separated by single slashes)."""
    if namespace in ("", "/"):
        return ""
    if not _NAMESPACE.match(namespace):
        raise NamespaceError(f"namespace {namespace!r}: not a ROS namespace (names of letters, digits and _, not "
                             "starting with a digit, separated by /)")
    return "/" + namespace.strip("/")


def loop_topic(key: str, namespace: str = "") -> str:
    """Resolved name of topic ``key`` of a loop in ``namespace`` (normalized: '' or ``/r1``): relative names in it,
    and, in a namespace, ``/clock`` and ``/diagnostics`` too (the nodes remap them, :func:`namespace_remaps`)."""
    name = TOPICS[key].name
    if not namespace:
        return absolute(name)
    return f"{namespace}/{name.lstrip('/')}"


def namespace_remaps(namespace: str) -> list[tuple[str, str]]:
    """Remappings of every node of a loop in ``namespace`` (normalized): its absolute topics (``/clock``, also the
    sim-time subscription of every node, and ``/diagnostics``) into the namespace; none at the root."""
    if not namespace:
        return []
    return [(TOPICS[k].name, loop_topic(k, namespace)) for k in TOPICS if TOPICS[k].name.startswith("/")]


def topic_names(keys: list[str], namespace: str = "") -> list[str]:
    """Resolved names of topic keys in ``namespace`` (normalized, :func:`loop_topic`)."""
    return [loop_topic(k, namespace) for k in keys]


def body_process_nodes(loop: Loop, *, composed: bool, recorder_in_body: bool) -> list[str]:
    """The nodes ``body_sim``'s process builds, in order: ``body_sim``, the loop's brains with ``composed``, the
    recorder last with ``recorder_in_body``. More than one: that process is ``bptsb_composed --nodes ...``; the other
    nodes of the loop are processes of their own."""
    return (["body_sim"] + ([b.executable for b in loop.brains] if composed else [])
            + (["recorder"] if recorder_in_body else []))


def startup_subscribers(loop: Loop, *, recording: bool, namespace: str = "") -> list[str]:
    """``wait_for_subscribers`` entries for ``body_sim``: how many subscribers each topic must have.

    Body outputs count the recorder and every brain that subscribes (no brain has rclpy's own sim-time ``/clock``
    subscription: each sets its clock from the stamps of the messages it answers, ``BrainNode.feed_sim_time``);
    brain outputs count ``body_sim`` or the next brain, and the recorder.
    """
    counts: dict[str, int] = {}
    for key in loop.topics():
        counts[key] = int(recording)
    for brain in loop.brains:
        for key in brain.triggers:
            counts[key] = counts.get(key, 0) + 1
    for source in loop.wait_for:
        counts[COMMAND_SOURCES[source]] = counts.get(COMMAND_SOURCES[source], 0) + 1
    return [f"{loop_topic(k, namespace)}:{n}" for k, n in counts.items() if n > 0]


def output_subscribers(loop: Loop, executable: str, *, recording: bool) -> int:
    """Subscribers of a brain's output topic in ``loop``: body_sim or the next brain, and the recorder."""
    brain = next(b for b in loop.brains if b.executable == executable)
    counts = []
    for key in brain.publishes:
        n = int(recording) + sum(key in b.triggers for b in loop.brains)
        n += sum(COMMAND_SOURCES[s] == key for s in loop.wait_for)
        counts.append(n)
    return min(counts)


def perturbation_problem(perturb_at: float, perturb_sigma: float, *, duration: float, rate_scale: float,
                         mode: str) -> str:
    """Why a scheduled perturbation cannot be run ('' when it can): sigma < 0, sigma without a time, or a time
    after the run's end (the run's sim length: ``duration`` in lockstep, ``duration`` × ``rate_scale`` in
    realtime; 0: no end, then body_sim bounds the step). ``perturb_at`` < 0 means none."""
    if perturb_sigma < 0 or (perturb_sigma > 0 and perturb_at < 0):
        return f"perturb_sigma:={perturb_sigma:g} must be >= 0 and needs perturb_at:=T (sim seconds, >= 0)"
    length = duration * (rate_scale if mode == "realtime" else 1.0)
    if duration > 0 and perturb_at > length:
        return f"perturb_at:={perturb_at:g} is after the run's last step ({length:g} s of sim time, the duration)"
    return ""


def node_parameters(loop: Loop, executable: str, *, agent: str = "", seed: int = 0, mode: str = "lockstep",
                    duration: float = 0.0, rate_scale: float = 1.0, recording: bool = False,
                    open_loop_steps: int = 0, summary_path: str = "", perturb_at: float = -1.0,
                    perturb_sigma: float = 0.0, perturb_seed: int = 0, namespace: str = "",
                    recorder_in_body: bool = False) -> dict[str, ParamValue]:
    """ROS parameters of one node of ``loop`` (those that differ from the node's defaults).

    Args:
        agent: trained agent run directory; empty: a fresh agent of the loop's task with ``seed``.
        duration: ``body_sim`` run length: sim seconds in lockstep, wall seconds from the first step in realtime.
        open_loop_steps: feedback brain: SWG steps before the feedback layer takes over.
        perturb_at: ``body_sim`` displaces the movable masses at this sim time [s] (negative: never).
        perturb_sigma: standard deviation σ [m] of that displacement, N(0, σ²) per coordinate.
        perturb_seed: seed of its standard-normal pattern.
        namespace: the loop's namespace (normalized, :func:`normalize_namespace`): the names ``body_sim`` waits on.
        recorder_in_body: the recorder runs in the body's process (``bptsb_composed``, which serves it in the body's
            loop): the body does not wait for its acknowledgements.
    """
    params: dict[str, ParamValue] = {"agent": agent} if agent else {"task": loop.task, "seed": seed}
    if executable == "body_sim":
        read = [k for k in SLOW_OUTPUTS if any(k in b.triggers for b in loop.brains)]
        if namespace:  # robot1/msdn: two robots in one domain never share a frame
            from bptsb_ros.live.viewers import frame_id

            params["frame_id"] = frame_id(namespace)
        params.update({
            "mode": mode,
            "wait_for": list(loop.wait_for),
            **({"every_step": read} if read else {}),
            "wait_for_subscribers": startup_subscribers(loop, recording=recording, namespace=namespace),
            "rate_scale": rate_scale,
        })
        if recording and mode == "lockstep" and not recorder_in_body:  # its acknowledgements pace the run
            params["wait_for_recorder"] = True
        if duration > 0:
            params["duration" if mode == "lockstep" else "wall_duration"] = duration
        if summary_path:
            params["summary_path"] = summary_path
        if perturb_at >= 0:
            params.update(perturb_at=perturb_at, perturb_sigma=perturb_sigma, perturb_seed=perturb_seed)
        return params
    if executable not in {b.executable for b in loop.brains}:
        raise ValueError(f"loop {loop.name!r} has no node {executable!r}")
    params["use_sim_time"] = True
    params["min_subscribers"] = output_subscribers(loop, executable, recording=recording)
    if executable == "feedback_brain" and open_loop_steps:
        params["open_loop_steps"] = open_loop_steps
    return params


def log_dir_of_bag(bag: str | Path) -> Path:
    """Where a recorded run keeps its node logs and ``body_summary.json``: ``<bag>.launch`` next to the bag."""
    return Path(str(Path(bag)) + ".launch")


def recorder_parameters(loop: Loop, bag: str, *, mode: str = "lockstep", agent: str = "",
                        open_loop_steps: int = 0, allow_loss: bool = False, namespace: str = "",
                        recorder_in_body: bool = False) -> dict[str, ParamValue]:
    """ROS parameters of the recorder of ``loop``: every loop topic to ``bag``, log times from ``/clock`` in lockstep
    (``use_sim_time``: the bag's timeline is sim time; realtime keeps system time), and the run description in the
    bag's ``custom_data`` (keys ``loop``, ``mode``, ``agent`` — ``fresh`` without one — and ``open_loop_steps``,
    which ``bptsb replay`` reads for its offline comparison). In lockstep it acknowledges the per-step topics on
    ``recorder/ack`` (``body_sim``'s ``wait_for_recorder``); ``allow_loss``: exit 0 even if messages were lost.
    ``namespace`` (normalized): the loop's namespace, whose resolved topic names are recorded. ``recorder_in_body``:
    it runs in the body's process, in the body's loop (no acknowledgements: it cannot fall behind)."""
    params: dict[str, ParamValue] = {
        "bag_path": bag,
        "use_sim_time": mode == "lockstep",
        "topics": topic_names(loop.topics(), namespace),
        "custom_data": [f"loop={loop.name}", f"mode={mode}", f"agent={agent or 'fresh'}",
                        f"open_loop_steps={open_loop_steps}"] + ([f"namespace={namespace}"] if namespace else []),
    }
    if mode == "lockstep" and not recorder_in_body:
        params.update(ack_topic=loop_topic(RECORDER_ACK, namespace),
                      ack_topics=topic_names(loop.step_topics(), namespace))
    if allow_loss:
        params["allow_loss"] = True
    return params


def format_parameter(name: str, value: ParamValue) -> str:
    """``name:=value`` for ``--ros-args -p``: strings single-quoted so YAML keeps them strings."""
    return f"{name}:={yaml_value(value)}"


def loops_help() -> str:
    """The loop list for ``bptsb launch --help``."""
    width = max(len(n) for n in LOOPS)
    lines = ["loops:"]
    for loop in LOOPS.values():
        nodes = ", ".join(["body_sim"] + [b.executable for b in loop.brains])
        lines.append(f"  {loop.name:<{width}}  {loop.summary} [{nodes}]"
                     + (" (needs --agent)" if loop.needs_agent else ""))
    return "\n".join(lines)


LAUNCH_ARGUMENTS: dict[str, tuple[str, str]] = {
    "agent": ("", "trained agent run directory; empty: a fresh untrained agent of the loop's task (open loops; "
              "closed loops require it)"),
    "mode": ("lockstep", "timing mode: lockstep or realtime"),
    "duration": ("0", "run length: sim seconds (lockstep) or wall seconds (realtime); 0: until Ctrl-C"),
    "bag": ("", "record every loop topic to this rosbag2 MCAP bag directory (log times: sim time in lockstep, "
            "system time in realtime; custom_data log_time says which); empty: no recording"),
    "seed": ("0", "seed of the fresh agent when no agent is given"),
    "rate_scale": ("1.0", "realtime: sim seconds per wall second"),
    "open_loop_steps": ("0", "closed loops: SWG steps before the feedback layer takes over"),
    "perturb_at": ("-1", "sim time [s] at which body_sim displaces the movable masses by N(0, perturb_sigma²) "
                   "(the paper's perturbation); negative: none"),
    "perturb_sigma": ("0", "standard deviation of that perturbation [m]"),
    "perturb_seed": ("0", "seed of the perturbation's standard-normal pattern"),
    "allow_loss": ("false", "with bag: a recording that lost messages still ends the launch cleanly (the bag counts "
                   "them either way); false: the recorder exits 1 and the launch fails"),
    "namespace": ("", "ROS namespace of the loop (one robot of several in a domain), relative to any PushRosNamespace "
                  "around the launch: every node runs in it and every topic resolves in it, /clock and /diagnostics "
                  "remapped to NS/clock and NS/diagnostics; empty: the enclosing (default root) namespace"),
    "log_level": ("info", "log level of every node (--ros-args --log-level): debug, info, warn, error or fatal"),
    "params_file": ("", "a ROS 2 params file given to every node after the loop's own parameters (its values win; "
                    "keys /** or the node names); empty: none"),
    "composed": ("false", "true: body_sim and the loop's brains in one process on one executor (bptsb_composed; the "
                 "same nodes, parameters and messages, fewer hand-offs between processes); the recorder stays a "
                 "process of its own unless recorder_in_body:=true"),
    "recorder_in_body": ("false", "with bag: true runs the recorder in body_sim's process (bptsb_composed, with the "
                         "brains too under composed:=true), where it takes the messages in the body's loop while the "
                         "body waits for its commands: one process and one reader hand-off fewer, the same bag"),
    "rviz": ("false", "true: also start rviz2 with the package's config/bptsb.rviz (fixed frame msdn) in the loop's "
             "namespace, where rviz2 is installed (otherwise a log line and the loop runs without it)"),
}
#: log levels of ``log_level:=`` (rcutils' names)
LOG_LEVELS = ("debug", "info", "warn", "error", "fatal")
#: ``agent`` of a loop that needs a trained agent: required (no default), so ``ros2 launch`` refuses to start
#: without it
REQUIRED_AGENT = "trained agent run directory (required: the closed loop runs the agent's fitted feedback layer)"


class LaunchArgumentError(ValueError):
    """A launch argument is missing or wrong; the message names it."""


def launch_arguments(loop: Loop) -> dict[str, tuple[str | None, str]]:
    """(default, description) of every launch argument of ``loop``; default None: required."""
    args: dict[str, tuple[str | None, str]] = dict(LAUNCH_ARGUMENTS)
    if loop.needs_agent:
        args["agent"] = (None, REQUIRED_AGENT)
    if loop.name == "mnist_drawing":
        from bptsb_ros.live.mnist_loop import STREAM_ARGUMENTS

        args["agent"] = (None, "MNIST system file (systems/<name>.pt of the MNIST drawing experiment; required)")
        args.update(STREAM_ARGUMENTS)
    return args


def resolve_arguments(loop: Loop, values: dict[str, str]) -> tuple[Loop, dict]:
    """Check the launch arguments (strings, as ``ros2 launch`` holds them) of ``loop``; return the loop adapted to
    the agent (:func:`agent_loop`) and the keyword arguments of :func:`node_parameters`.

    Raises LaunchArgumentError naming the argument: a closed loop without ``agent``, an agent without a readable
    checkpoint (or, for a closed loop, without a fitted feedback layer), a bad mode or number, a ``bag`` that
    exists and is not empty.
    """
    import math

    agent = values.get("agent", "")
    if loop.name == "mnist_drawing":  # agent is a system file, not a run directory: mnist_loop checks it
        from bptsb_ros.live.mnist_loop import StreamError

        if values.get("mode", "lockstep") != "lockstep":
            raise LaunchArgumentError(f"mode:={values['mode']}: mnist_drawing resets the body at stated steps, "
                                      "which needs lockstep")
        try:
            mnist_stream_plan(values)
        except StreamError as err:
            raise LaunchArgumentError(str(err)) from None
        values = {**values, "agent": ""}  # skip the run-directory checks below
    elif loop.needs_agent and not agent:
        raise LaunchArgumentError(f"{loop.name} needs agent:=RUN_DIR, a trained agent with a fitted feedback layer "
                                  "(bptsb train fits it)")
    if values.get("mode", "lockstep") not in ("lockstep", "realtime"):
        raise LaunchArgumentError(f"mode:={values['mode']}: choose lockstep or realtime")
    for flag in ("allow_loss", "rviz", "composed", "recorder_in_body"):
        if values.get(flag, "false").lower() not in ("true", "false"):
            raise LaunchArgumentError(f"{flag}:={values[flag]}: choose true or false")
    if values.get("log_level", "info").lower() not in LOG_LEVELS:
        raise LaunchArgumentError(f"log_level:={values['log_level']}: choose {', '.join(LOG_LEVELS)}")
    if values.get("params_file") and not Path(values["params_file"]).is_file():
        raise LaunchArgumentError(f"params_file:={values['params_file']}: no such file")
    try:
        namespace = normalize_namespace(values.get("namespace", ""))
    except NamespaceError as err:
        raise LaunchArgumentError(f"namespace:={values['namespace']}: {err}") from None

    def number(name: str, kind: type, ok, rule: str):
        text = values.get(name, LAUNCH_ARGUMENTS[name][0])
        try:
            value = kind(text)
        except ValueError:
            raise LaunchArgumentError(f"{name}:={text}: not a number") from None
        if not (math.isfinite(value) and ok(value)):
            raise LaunchArgumentError(f"{name}:={text}: must be {rule}")
        return value

    in_body = values.get("recorder_in_body", "false").lower() == "true"
    if in_body and not values.get("bag"):
        raise LaunchArgumentError("recorder_in_body:=true needs bag:=DIR (there is no recorder without a bag)")
    common = dict(agent=agent, seed=number("seed", int, lambda v: True, "an integer"),
                  mode=values.get("mode", "lockstep"), duration=number("duration", float, lambda v: v >= 0, ">= 0"),
                  rate_scale=number("rate_scale", float, lambda v: v > 0, "> 0"),
                  recording=bool(values.get("bag")),
                  open_loop_steps=number("open_loop_steps", int, lambda v: v >= 0, ">= 0"),
                  perturb_at=number("perturb_at", float, lambda v: True, "a number"),
                  perturb_sigma=number("perturb_sigma", float, lambda v: v >= 0, ">= 0"),
                  perturb_seed=number("perturb_seed", int, lambda v: True, "an integer"), namespace=namespace,
                  recorder_in_body=in_body)
    problem = perturbation_problem(common["perturb_at"], common["perturb_sigma"], duration=common["duration"],
                                   rate_scale=common["rate_scale"], mode=common["mode"])
    if problem:
        raise LaunchArgumentError(problem)
    if values.get("agent"):
        from bptsb_ros.training.checkpoint import CheckpointError, feedback_fitted

        if not Path(agent).exists():
            raise LaunchArgumentError(f"agent:={agent}: no such run directory")
        try:
            loop = agent_loop(loop, agent)
            if loop.needs_agent and not feedback_fitted(agent):
                raise LaunchArgumentError(f"agent:={agent}: its feedback layer was never fitted (bptsb train fits it)")
        except CheckpointError as err:
            raise LaunchArgumentError(f"agent:={agent}: {err}") from None
    if values.get("bag"):
        problem = bag_target_problem(Path(values["bag"]))
        if problem:
            raise LaunchArgumentError(f"bag:={values['bag']}: {problem}")
    return loop, common


def bag_target_problem(bag: Path) -> str:
    """Why ``bag`` cannot receive a new recording ('' when it can): it exists and is not an empty directory,
    or its parent cannot be created or written (checked before any node starts)."""
    if bag.exists():
        if not bag.is_dir():
            return "exists and is not a directory"
        if any(bag.iterdir()):
            return "exists and is not empty"
    parent = bag.absolute().parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        return f"cannot create {parent}: {err.strerror or err}"
    where = bag if bag.is_dir() else parent
    try:  # a real write: permission bits say nothing for root or on a read-only file system
        with tempfile.TemporaryFile(dir=where):
            pass
    except OSError as err:
        return f"cannot write in {where}: {err.strerror or err}"
    return ""


def loop_node_parameters(loop_name: str, executable: str, values: dict[str, str]) -> dict[str, ParamValue]:
    """ROS parameters of one node of a ``ros2 launch`` of ``loop_name`` from the launch arguments ``values``:
    :func:`node_parameters` or, for ``recorder``, :func:`recorder_parameters`. With ``bag:=DIR`` the body writes its
    run summary to ``DIR.launch/body_summary.json``, as ``bptsb launch`` does."""
    loop, common = resolve_arguments(LOOPS[loop_name], values)
    bag = values.get("bag", "")
    if executable == "recorder":
        params = recorder_parameters(loop, bag, mode=common["mode"], agent=common["agent"],
                                     open_loop_steps=common["open_loop_steps"],
                                     allow_loss=values.get("allow_loss", "false").lower() == "true",
                                     namespace=common["namespace"], recorder_in_body=common["recorder_in_body"])
    else:
        summary_path = str(log_dir_of_bag(bag) / "body_summary.json") if bag and executable == "body_sim" else ""
        params = node_parameters(loop, executable, summary_path=summary_path, **common)
    if loop_name == "mnist_drawing":
        from bptsb_ros.live.mnist_loop import stream_parameters

        params = stream_parameters(mnist_stream_plan(values), executable, params, recording=bool(bag),
                                   duration=common["duration"])
    return params


def mnist_stream_plan(values: dict[str, str]):  # -> mnist_loop.StreamPlan
    """The checked stream of an ``mnist_drawing`` launch from its arguments (strings); raises StreamError."""
    from bptsb_ros.live.mnist_loop import StreamError, plan_stream

    numbers = {}
    for name in ("first", "count", "episode_steps"):
        text = values.get(name) or "0"
        try:
            numbers[name] = int(text)
        except ValueError:
            raise StreamError(f"{name}:={text}: not an integer") from None
    return plan_stream(values.get("agent", ""), values.get("images", ""), values.get("labels", ""), **numbers)


def params_file_text(executable: str, params: dict[str, ParamValue]) -> str:
    """A ROS 2 params file of one node (``/**: ros__parameters:``); empty lists are left out (the nodes' defaults
    are empty, and rcl cannot type an empty YAML list)."""
    return (f"# {executable}: written by bptsb_ros.live.loops from the launch arguments\n"
            + params_sections_text({"/**": params}))
