"""QoS profiles and message conversion for the live nodes (float64 arrays ↔ common_interfaces messages).

All conversions keep float64 values bit-exact: arrays go into ``float64[]`` fields as raw bytes and
come back with ``np.frombuffer``.
"""

from __future__ import annotations

import array

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Pose, PoseArray
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from bptsb_ros.interface.topics import stamp_to_step, step_to_stamp


def state_qos(depth: int) -> QoSProfile:
    """Body outputs and every subscription of the loop: reliable, volatile, keep-last ``depth``.

    Volatile: a late joiner (``ros2 topic echo``, a viewer, a second recorder) receives what is published after it
    joined, never a backlog of states that are no longer current. ``depth`` (default 1000 = 10 s of steps) is the
    reliable retransmission window and the subscription queue: a reliable subscriber that falls behind by up to
    ``depth`` messages (the recorder on a loaded machine) still gets every one.
    """
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


def command_qos(depth: int) -> QoSProfile:
    """Publishers of commands and task input: reliable, volatile, keep-last ``depth`` — the same as
    :func:`state_qos`.

    Not transient-local: a command is in force for one step, so a late joiner must not be handed up to ``depth``
    old ones (``ros2 topic echo brain/rest_length`` would start with ~10 s of stale commands and report lost
    messages). Nothing is lost at startup without it: a brain sends its first command only once its output has
    ``min_subscribers`` matched subscribers (the body, the next brain, the recorder).
    """
    return state_qos(depth)


def ack_qos() -> QoSProfile:
    """The recorder's acknowledgements (``recorder/ack``): reliable, transient-local, keep-last 1 — only the latest
    counts, and a body that subscribes after the recorder's last one still gets it."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


def stamp(step: int, dt_ns: int) -> Time:
    """builtin_interfaces/Time of step ``step``."""
    sec, nanosec = step_to_stamp(step, dt_ns)
    return Time(sec=sec, nanosec=nanosec)


def stamp_ns(time_msg: Time) -> int:
    """A builtin_interfaces/Time in nanoseconds."""
    return time_msg.sec * 1_000_000_000 + time_msg.nanosec


def step_of(time_msg: Time, dt_ns: int) -> int:
    """Step index of a stamp."""
    return stamp_to_step(time_msg.sec, time_msg.nanosec, dt_ns)


def f64(values: np.ndarray) -> array.array:
    """A float64 array as ``array('d')`` (what rclpy stores in ``float64[]`` fields, without per-item checks)."""
    out = array.array("d")
    out.frombytes(np.ascontiguousarray(values, dtype=np.float64).tobytes())
    return out


def as_array(field: array.array | list[float]) -> np.ndarray:
    """A ``float64[]`` message field as a float64 numpy array (a copy)."""
    if isinstance(field, array.array):
        return np.frombuffer(field, dtype=np.float64).copy()
    return np.asarray(field, dtype=np.float64)


def clock_msg(step: int, dt_ns: int) -> Clock:
    return Clock(clock=stamp(step, dt_ns))


def joint_state(step: int, dt_ns: int, names: list[str], *, position: np.ndarray | None = None,
                velocity: np.ndarray | None = None, effort: np.ndarray | None = None,
                frame_id: str = "") -> JointState:
    """A JointState stamped at step ``step`` with the given float64 arrays (others left empty)."""
    msg = JointState()
    msg.header.stamp = stamp(step, dt_ns)
    msg.header.frame_id = frame_id
    msg.name = names
    if position is not None:
        msg.position = f64(position)
    if velocity is not None:
        msg.velocity = f64(velocity)
    if effort is not None:
        msg.effort = f64(effort)
    return msg


def effort_from_acceleration(a: np.ndarray, mass: np.ndarray) -> np.ndarray:
    """``body/mass_states`` effort [N] of the movable masses: F = m·a, (M, 2) accelerations → flat (2M,)."""
    return (np.asarray(a, dtype=np.float64).reshape(-1, 2) * np.asarray(mass, dtype=np.float64)[:, None]).reshape(-1)


def acceleration_from_effort(effort: np.ndarray, mass: np.ndarray) -> np.ndarray:
    """Inverse of :func:`effort_from_acceleration`: a = F / m, flat (2M,) effort → flat (2M,) accelerations
    (laid out like the feedback layer's ``acceleration`` features). Exact for the paper's unit masses."""
    effort = np.asarray(effort, dtype=np.float64).reshape(-1, 2)
    return (effort / np.asarray(mass, dtype=np.float64)[:, None]).reshape(-1)


def pose_array(step: int, dt_ns: int, positions: np.ndarray, frame_id: str) -> PoseArray:
    """PoseArray of mass positions (N, 2) [m] in the body plane (z = 0, identity orientation)."""
    msg = PoseArray()
    msg.header.stamp = stamp(step, dt_ns)
    msg.header.frame_id = frame_id
    poses = []
    for x, y in positions.tolist():
        pose = Pose()
        pose.position.x = x
        pose.position.y = y
        poses.append(pose)
    msg.poses = poses
    return msg


def pose_array_positions(msg: PoseArray) -> np.ndarray:
    """(N, 2) positions [m] from a PoseArray."""
    return np.array([(p.position.x, p.position.y) for p in msg.poses], dtype=np.float64).reshape(-1, 2)


_FIXED = ColorRGBA(r=0.55, g=0.55, b=0.55, a=1.0)
_MOVABLE = ColorRGBA(r=0.15, g=0.45, b=0.85, a=1.0)
_CMP = ColorRGBA(r=0.9, g=0.2, b=0.15, a=1.0)


def _strain_color(strain: float) -> ColorRGBA:
    """Blue when compressed, grey at rest, red when stretched; saturates at ±20 % strain."""
    s = max(-1.0, min(1.0, strain / 0.2))
    if s >= 0:
        return ColorRGBA(r=0.6 + 0.4 * s, g=0.6 - 0.45 * s, b=0.6 - 0.45 * s, a=1.0)
    return ColorRGBA(r=0.6 + 0.45 * s, g=0.6 + 0.2 * s, b=0.6 - 0.4 * s, a=1.0)


def strain_colors(strain: np.ndarray) -> np.ndarray:
    """:func:`_strain_color` of every spring at once: (E,) strains → (E, 4) RGBA, float64 (the same arithmetic; the
    message stores float32)."""
    s = np.clip(np.asarray(strain, dtype=np.float64) / 0.2, -1.0, 1.0)
    pos = s >= 0
    rgba = np.empty((s.size, 4))
    rgba[:, 0] = np.where(pos, 0.6 + 0.4 * s, 0.6 + 0.45 * s)
    rgba[:, 1] = np.where(pos, 0.6 - 0.45 * s, 0.6 + 0.2 * s)
    rgba[:, 2] = np.where(pos, 0.6 - 0.45 * s, 0.6 - 0.4 * s)
    rgba[:, 3] = 1.0
    return rgba


def body_markers(step: int, dt_ns: int, positions: np.ndarray, springs: np.ndarray, fixed: np.ndarray,
                 cmp_index: int, strain: np.ndarray, frame_id: str, mass_diameter: float) -> MarkerArray:
    """Masses as one SPHERE_LIST (grey fixed, blue movable, red CMP) and springs as one LINE_LIST
    coloured by strain (length / rest length − 1).

    Args:
        positions: (N, 2) [m]; springs: (E, 2) mass indices; fixed: (N,) bool; strain: (E,).
    """
    ends = np.asarray(positions)[np.asarray(springs).reshape(-1)]
    return markers_of(step, dt_ns, positions, ends, np.repeat(strain_colors(strain), 2, axis=0),
                      mass_colors(fixed, cmp_index), frame_id, mass_diameter)


def mass_colors(fixed: np.ndarray, cmp_index: int) -> list[ColorRGBA]:
    """Colour of every mass: red the CMP, grey the fixed ones, blue the movable ones."""
    return [_CMP if i == cmp_index else (_FIXED if f else _MOVABLE) for i, f in enumerate(np.asarray(fixed).tolist())]


def markers_of(step: int, dt_ns: int, positions: np.ndarray, ends: np.ndarray, line_colors: np.ndarray,
               masses_rgba: list[ColorRGBA], frame_id: str, mass_diameter: float) -> MarkerArray:
    """The MarkerArray of :func:`body_markers` from its arrays: mass positions (N, 2) [m], spring end points
    (2E, 2) [m] (both ends of spring 0, then of spring 1, ...), their colours (2E, 4) RGBA and the masses' colours."""
    header_stamp = stamp(step, dt_ns)
    masses = Marker()
    masses.header.stamp = header_stamp
    masses.header.frame_id = frame_id
    masses.ns, masses.id, masses.type, masses.action = "masses", 0, Marker.SPHERE_LIST, Marker.ADD
    masses.pose.orientation.w = 1.0
    masses.scale.x = masses.scale.y = masses.scale.z = mass_diameter
    masses.points = [Point(x=x, y=y, z=0.0) for x, y in np.asarray(positions).tolist()]
    masses.colors = masses_rgba
    lines = Marker()
    lines.header.stamp = header_stamp
    lines.header.frame_id = frame_id
    lines.ns, lines.id, lines.type, lines.action = "springs", 1, Marker.LINE_LIST, Marker.ADD
    lines.pose.orientation.w = 1.0
    lines.scale.x = mass_diameter / 4
    lines.points = [Point(x=x, y=y, z=0.0) for x, y in np.asarray(ends).tolist()]
    lines.colors = [ColorRGBA(r=r, g=g, b=b, a=a) for r, g, b, a in np.asarray(line_colors).tolist()]
    return MarkerArray(markers=[masses, lines])
