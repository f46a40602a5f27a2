"""The live loops (ROS-free description): which nodes run, with which parameters, on which topics.

``bptsb launch <loop>`` and the ROS launch files ``launch/<loop>.launch.py`` both build their
processes from :data:`LOOPS`, so the two ways of starting a loop cannot drift apart.

Topic wiring (default names, ``bptsb_ros/ros/TOPICS.md``): ``body_sim`` publishes ``/clock`` and the
body state; time-driven brains (``swg_brain``, ``task_input``) answer ``/clock``; ``feedback_brain``
answers the body state; ``mlp_brain`` answers ``task/input``; commands go back to ``body_sim``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from bptsb_ros.ros.params import ParamValue, yaml_value
from bptsb_ros.ros.topics import BODY_OUTPUTS, COMMAND_SOURCES, TOPICS, absolute, feedback_state_key

__all__ = ["LOOPS", "BrainSpec", "Loop", "ParamValue", "agent_loop", "feedback_state_key", "format_parameter",
           "log_dir_of_bag", "node_parameters", "recorder_parameters", "ros_launch_description", "topic_names"]


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


SWG = BrainSpec("swg_brain", ("clock",), ("rest_length_cmd",))
FEEDBACK = BrainSpec("feedback_brain", ("clock", "spring_lengths"), ("rest_length_cmd",))
TASK_INPUT = BrainSpec("task_input", ("clock",), ("task_input",))
MLP = BrainSpec("mlp_brain", ("task_input",), ("force_cmd",))
WIND = BrainSpec("wind_source", ("clock",), ("wind",))

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
        Loop("narma", "expanded NARMA emulation: streamed input u → MLP (or LIL) forces on the masses",
             "narma", (TASK_INPUT, MLP), ("force",)),
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


def topic_names(keys: list[str], namespace: str = "/") -> list[str]:
    """Absolute default names of topic keys."""
    return [absolute(TOPICS[k].name, namespace) for k in keys]


def startup_subscribers(loop: Loop, *, recording: bool, sim_time: bool = True) -> list[str]:
    """``wait_for_subscribers`` entries for ``body_sim``: how many subscribers each topic must have.

    Body outputs count the recorder and every brain that subscribes (a node on sim time also has a
    ``/clock`` subscription); brain outputs count ``body_sim`` or the next brain, and the recorder.
    """
    counts: dict[str, int] = {}
    for key in loop.topics():
        counts[key] = int(recording)
    for brain in loop.brains:
        for key in brain.triggers:
            counts[key] = counts.get(key, 0) + 1
        if sim_time:
            counts["clock"] += 1
    for source in loop.wait_for:
        counts[COMMAND_SOURCES[source]] = counts.get(COMMAND_SOURCES[source], 0) + 1
    return [f"{absolute(TOPICS[k].name)}:{n}" for k, n in counts.items() if n > 0]


def output_subscribers(loop: Loop, executable: str, *, recording: bool) -> int:
    """Subscribers of a brain's output topic in ``loop``: body_sim or the next brain, and the recorder."""
    brain = next(b for b in loop.brains if b.executable == executable)
    counts = []
    for key in brain.publishes:
        n = int(recording) + sum(key in b.triggers for b in loop.brains)
        n += sum(COMMAND_SOURCES[s] == key for s in loop.wait_for)
        counts.append(n)
    return min(counts)


def node_parameters(loop: Loop, executable: str, *, agent: str = "", seed: int = 0, mode: str = "lockstep",
                    duration: float = 0.0, rate_scale: float = 1.0, recording: bool = False,
                    open_loop_steps: int = 0, summary_path: str = "") -> dict[str, ParamValue]:
    """ROS parameters of one node of ``loop`` (those that differ from the node's defaults).

    Args:
        agent: trained agent run directory; empty: a fresh agent of the loop's task with ``seed``.
        duration: ``body_sim`` run length: sim seconds in lockstep, wall seconds from the first step in realtime.
        open_loop_steps: feedback brain: SWG steps before the feedback layer takes over.
    """
    params: dict[str, ParamValue] = {"agent": agent} if agent else {"task": loop.task, "seed": seed}
    if executable == "body_sim":
        params.update({
            "mode": mode,
            "wait_for": list(loop.wait_for),
            "wait_for_subscribers": startup_subscribers(loop, recording=recording),
            "rate_scale": rate_scale,
        })
        if duration > 0:
            params["duration" if mode == "lockstep" else "wall_duration"] = duration
        if summary_path:
            params["summary_path"] = summary_path
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
                        open_loop_steps: int = 0) -> dict[str, ParamValue]:
    """ROS parameters of the recorder of ``loop``: every loop topic to ``bag``, and the run description in the
    bag's ``custom_data`` (keys ``loop``, ``mode``, ``agent`` — ``fresh`` without one — and ``open_loop_steps``,
    which ``bptsb replay`` reads for its offline comparison)."""
    return {
        "bag_path": bag,
        "topics": topic_names(loop.topics()),
        "custom_data": [f"loop={loop.name}", f"mode={mode}", f"agent={agent or 'fresh'}",
                        f"open_loop_steps={open_loop_steps}"],
    }


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
    "agent": ("", "trained agent run directory; empty: a fresh untrained agent of the loop's task"),
    "mode": ("lockstep", "timing mode: lockstep or realtime"),
    "duration": ("0", "run length: sim seconds (lockstep) or wall seconds (realtime); 0: until Ctrl-C"),
    "bag": ("", "record every loop topic to this rosbag2 MCAP bag directory; empty: no recording"),
    "seed": ("0", "seed of the fresh agent when no agent is given"),
    "rate_scale": ("1.0", "realtime: sim seconds per wall second"),
    "open_loop_steps": ("0", "closed loops: SWG steps before the feedback layer takes over"),
}


def ros_launch_description(loop_name: str):  # -> launch.LaunchDescription
    """``LaunchDescription`` of a loop for ``ros2 launch bptsb_ros <loop>.launch.py`` (needs launch, launch_ros).

    Same processes and parameters as ``bptsb launch``; the launch shuts down when ``body_sim`` exits. With
    ``bag:=DIR`` the body writes its run summary to ``DIR.launch/body_summary.json``, as ``bptsb launch`` does.
    """
    from launch.actions import DeclareLaunchArgument, EmitEvent, OpaqueFunction, RegisterEventHandler
    from launch.event_handlers import OnProcessExit
    from launch.events import Shutdown
    from launch.substitutions import LaunchConfiguration
    from launch_ros.actions import Node

    from launch import LaunchDescription

    def nodes(context, *args, **kwargs):
        del args, kwargs
        v = {name: LaunchConfiguration(name).perform(context) for name in LAUNCH_ARGUMENTS}
        loop = agent_loop(LOOPS[loop_name], v["agent"])
        common = dict(agent=v["agent"], seed=int(v["seed"]), mode=v["mode"], duration=float(v["duration"]),
                      rate_scale=float(v["rate_scale"]), recording=bool(v["bag"]),
                      open_loop_steps=int(v["open_loop_steps"]))

        def node(executable: str, params: dict[str, ParamValue]):
            params = {k: val for k, val in params.items() if val != []}  # launch_ros cannot type empty lists
            return Node(package="bptsb_ros", executable=executable, name=executable, output="screen",
                        parameters=[params])

        summary_path = str(log_dir_of_bag(v["bag"]) / "body_summary.json") if v["bag"] else ""
        body = node("body_sim", node_parameters(loop, "body_sim", summary_path=summary_path, **common))
        actions = [body] + [node(b.executable, node_parameters(loop, b.executable, **common)) for b in loop.brains]
        if v["bag"]:
            actions.append(node("recorder", recorder_parameters(loop, v["bag"], mode=v["mode"], agent=v["agent"],
                                                                open_loop_steps=common["open_loop_steps"])))
        actions.append(RegisterEventHandler(OnProcessExit(
            target_action=body, on_exit=[EmitEvent(event=Shutdown(reason="body_sim finished"))])))
        return actions

    arguments = [DeclareLaunchArgument(name, default_value=default, description=text)
                 for name, (default, text) in LAUNCH_ARGUMENTS.items()]
    return LaunchDescription([*arguments, OpaqueFunction(function=nodes)])
