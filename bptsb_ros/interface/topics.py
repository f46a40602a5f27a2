"""Topic names, message types and the sim-time ↔ step arithmetic of the live loop (ROS-free).

Every topic of the loop is listed in ``TOPICS`` (key → default name, type, publisher). Node parameters
``topics.<key>`` override a name; relative names resolve in the node's namespace. ``TOPICS.md`` in
this folder documents each topic's fields, units, frame and QoS.

Sim time of step k is exactly k·dt_ns nanoseconds (dt_ns = dt in whole nanoseconds), so a stamp
converts back to its step index without rounding error.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

NS_PER_S = 1_000_000_000


@dataclass(frozen=True)
class Topic:
    """One topic of the loop: key, default name and ROS type (``pkg/msg/Name``); ``TOPICS.md`` names the
    publishing node of each."""

    key: str
    name: str
    type: str


TOPICS: dict[str, Topic] = {
    t.key: t
    for t in (
        Topic("clock", "/clock", "rosgraph_msgs/msg/Clock"),
        Topic("positions", "body/positions", "geometry_msgs/msg/PoseArray"),
        Topic("mass_states", "body/mass_states", "sensor_msgs/msg/JointState"),
        Topic("spring_lengths", "body/spring_lengths", "sensor_msgs/msg/JointState"),
        Topic("rest_length", "body/rest_length", "sensor_msgs/msg/JointState"),
        Topic("external_force", "body/external_force", "sensor_msgs/msg/JointState"),
        Topic("markers", "body/markers", "visualization_msgs/msg/MarkerArray"),
        Topic("diagnostics", "/diagnostics", "diagnostic_msgs/msg/DiagnosticArray"),
        Topic("rest_length_cmd", "brain/rest_length", "sensor_msgs/msg/JointState"),
        Topic("force_cmd", "brain/force", "sensor_msgs/msg/JointState"),
        Topic("wind", "env/wind", "geometry_msgs/msg/Vector3Stamped"),
        Topic("task_input", "task/input", "sensor_msgs/msg/JointState"),
        Topic("perturb_cmd", "body/perturb", "sensor_msgs/msg/JointState"),
        Topic("perturbation", "body/perturbation", "sensor_msgs/msg/JointState"),
        Topic("image", "camera/image", "sensor_msgs/msg/Image"),
        Topic("label", "camera/label", "sensor_msgs/msg/JointState"),
        Topic("reset_cmd", "body/reset", "sensor_msgs/msg/JointState"),
        Topic("recorder_ack", "recorder/ack", "rosgraph_msgs/msg/Clock"),
    )
}

#: Keys of the topics ``body_sim`` publishes, and of those it subscribes to.
BODY_OUTPUTS: tuple[str, ...] = ("clock", "positions", "mass_states", "spring_lengths", "rest_length",
                                 "external_force", "markers", "diagnostics", "perturbation")
BODY_INPUTS: tuple[str, ...] = ("rest_length_cmd", "force_cmd", "wind", "perturb_cmd", "reset_cmd")

#: Key of the recorder's acknowledgements (``body_sim`` with ``wait_for_recorder`` subscribes to it).
RECORDER_ACK = "recorder_ack"

#: Command sources the body can wait for in lockstep, by the topic key they arrive on.
COMMAND_SOURCES: dict[str, str] = {"rest_length": "rest_length_cmd", "force": "force_cmd", "wind": "wind",
                                   "reset": "reset_cmd"}


def feedback_state_key(state_type: str) -> str:
    """Topic key the feedback brain reads for a feedback-layer state type: ``positions`` for ``spring_length`` (the
    brain takes the spring lengths from the mass positions, as the body computes them), else ``mass_states``
    (position, velocity, effort)."""
    return "positions" if state_type == "spring_length" else "mass_states"

#: Default history depth of every loop topic: 10 s of steps at dt = 0.01 s.
DEFAULT_QOS_DEPTH = 1000


def absolute(name: str, namespace: str = "/") -> str:
    """Resolve a topic name the way ROS does for a node in ``namespace`` (no remapping, no ``~``)."""
    if name.startswith("/"):
        return name
    ns = namespace.rstrip("/")
    return f"{ns}/{name}"


def dt_to_ns(dt: float) -> int:
    """Time step [s] → whole nanoseconds; raises ValueError unless dt is a finite positive multiple of 1 ns."""
    if not (math.isfinite(dt) and dt > 0 and math.isfinite(dt * NS_PER_S)):
        raise ValueError(f"dt must be finite and positive, got {dt}")
    ns = round(dt * NS_PER_S)
    if ns <= 0 or abs(dt * NS_PER_S - ns) > 1e-3:
        raise ValueError(f"dt must be a whole number of nanoseconds, got {dt!r} s")
    return ns


def step_to_stamp(step: int, dt_ns: int) -> tuple[int, int]:
    """Step index k → (sec, nanosec) of sim time k·dt_ns."""
    if step < 0:
        raise ValueError(f"step must be >= 0, got {step}")
    ns = step * dt_ns
    return ns // NS_PER_S, ns % NS_PER_S


def stamp_to_step(sec: int, nanosec: int, dt_ns: int) -> int:
    """(sec, nanosec) → nearest step index (a stamp k·dt_ns maps back to k exactly)."""
    ns = sec * NS_PER_S + nanosec
    return (ns + dt_ns // 2) // dt_ns


def spring_names(n_springs: int) -> list[str]:
    """Joint names of the springs in ``JointState`` messages: ``spring_<e>``."""
    return [f"spring_{e}" for e in range(n_springs)]


def mass_dof_names(mass_indices: list[int]) -> list[str]:
    """Joint names of the x and y degrees of freedom of masses (global indices): ``mass_<i>/x``, ``mass_<i>/y``."""
    return [f"mass_{i}/{axis}" for i in mass_indices for axis in ("x", "y")]


def input_names(n_inputs: int) -> list[str]:
    """Names of the task input channels in ``task/input``: ``u_<j>``."""
    return [f"u_{j}" for j in range(n_inputs)]
