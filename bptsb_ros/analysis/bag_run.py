"""A live run read back from a rosbag2 MCAP bag (:class:`BagRun`, :func:`read_run`): the body's trajectories,
spring and rest lengths, the inputs, wind and perturbations of each step, its layout from the markers, and the
recorder's own account of what it lost. Shared by the replays of every loop (:mod:`bptsb_ros.analysis.replay`,
:mod:`bptsb_ros.analysis.mnist_replay`) and the IPC analysis of a bag.

Only the messages of the node that owns each topic are used (``body_sim`` for the body's state;
:mod:`bptsb_ros.analysis.provenance`): messages of other publishers are ignored and reported.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bptsb_ros.analysis.provenance import OwnMessages, Provenance
from bptsb_ros.bags.errors import BagError
from bptsb_ros.bags.metadata import read_metadata
from bptsb_ros.bags.msgdefs import normalize_type
from bptsb_ros.bags.reader import list_topics, read_published, topic_publishers
from bptsb_ros.files.untrusted_yaml import printable
from bptsb_ros.interface.topics import NS_PER_S, TOPICS, absolute, dt_to_ns

#: closed loops: the feedback layer drives the body (the offline comparison runs the closed loop)
LOOPS_CLOSED = ("lissajous_closed", "locomotion_closed")
#: loops whose body awaits the wind of every step from ``wind_source``
LOOPS_WIND = ("locomotion_headwind", "lissajous_switching")
#: node name of the body simulator, the owner of the body's topics (in the run's namespace)
BODY_NODE = "body_sim"


@dataclass
class BagRun:
    """A live run read back from a bag. Rows are the recorded steps, in order.

    steps: (T,) step indices; positions: (T, N, 2) [m]; spring_lengths, rest_length: (T, E) [m] (spring lengths:
    from ``body/spring_lengths`` where it has every step, else from the positions and the springs of the markers);
    springs: (E, 2); fixed: (N,) bool; cmp_index: −1 if none; inputs: {step: u} task inputs;
    custom: the bag's custom_data (loop, mode, agent); wind: {step: (F_x, F_y) [N]} from ``env/wind``;
    perturbations: {step: (M, 2) displacement [m]} from ``body/perturbation`` (what the body applied).
    """

    dt: float
    steps: np.ndarray
    positions: np.ndarray
    spring_lengths: np.ndarray | None
    rest_length: np.ndarray | None
    springs: np.ndarray
    fixed: np.ndarray
    cmp_index: int
    inputs: dict[int, float] = field(default_factory=dict)
    custom: dict[str, str] = field(default_factory=dict)
    wind: dict[int, tuple[float, float]] = field(default_factory=dict)
    perturbations: dict[int, np.ndarray] = field(default_factory=dict)
    provenance: Provenance = field(default_factory=Provenance)

    @property
    def missing_steps(self) -> list[int]:
        full = np.arange(self.steps[0], self.steps[-1] + 1)
        return sorted(set(full.tolist()) - set(self.steps.tolist()))

    def longest_contiguous(self) -> slice:
        """Rows of the longest run of consecutive steps (metrics need a gap-free time grid)."""
        breaks = np.flatnonzero(np.diff(self.steps) != 1) + 1
        bounds = np.concatenate([[0], breaks, [len(self.steps)]])
        i = int(np.argmax(np.diff(bounds)))
        return slice(int(bounds[i]), int(bounds[i + 1]))

    def rows(self, sl: slice) -> BagRun:
        """The same run restricted to rows ``sl``."""
        lengths = None if self.spring_lengths is None else self.spring_lengths[sl]
        rest = None if self.rest_length is None else self.rest_length[sl]
        return BagRun(self.dt, self.steps[sl], self.positions[sl], lengths, rest, self.springs, self.fixed,
                      self.cmp_index, self.inputs, self.custom, self.wind, self.perturbations, self.provenance)

    def wind_series(self, last: int) -> np.ndarray | None:
        """(last + 1, 2) wind [N] in force at steps 0..last from ``env/wind``, or None without wind messages;
        raises BagError if a step's wind is missing (the offline comparison needs every one)."""
        if not self.wind:
            return None
        missing = [k for k in range(last + 1) if k not in self.wind]
        if missing:
            raise BagError(f"env/wind lacks {len(missing)} of steps 0..{last} (first: {missing[0]}); the offline "
                           "comparison needs the wind of every step")
        return np.array([self.wind[k] for k in range(last + 1)], dtype=np.float64)


def _stamp_ns(msg: Any) -> int:
    s = msg.header.stamp
    return int(s.sec) * NS_PER_S + int(s.nanosec)


def _topic(key: str, namespace: str = "") -> str:
    """Name of topic ``key`` in a bag of a loop run in ``namespace`` (the bag's ``custom_data`` ``namespace``)."""
    return f"{namespace}/{TOPICS[key].name.lstrip('/')}" if namespace else absolute(TOPICS[key].name)


def node_in(namespace: str, node: str) -> str:
    """The fully qualified name of ``node`` in ``namespace`` (a name that starts with ``/`` is one already)."""
    return node if node.startswith("/") else f"{namespace.rstrip('/')}/{node}"


def expected_publishers(loop: str | None, body_node: str = BODY_NODE, namespace: str = "") -> dict[str, str | None]:
    """Topic -> the fully qualified node that owns it in ``loop`` (None: any publisher), every node in the run's
    ``namespace``: the body's topics are ``body_node``'s, ``task/input`` is ``task_input``'s, and ``env/wind`` is
    ``wind_source``'s in the loops that await it (a user may publish wind in the others)."""
    owners: dict[str, str | None] = {_topic(k, namespace): node_in(namespace, body_node) for k in (
        "positions", "spring_lengths", "rest_length", "markers", "perturbation")}
    owners[_topic("task_input", namespace)] = node_in(namespace, "task_input")
    owners[_topic("wind", namespace)] = node_in(namespace, "wind_source") if loop in LOOPS_WIND else None
    return owners


def read_run(bag: str | Path, dt: float | None = None, skip_damaged: bool = False, body_node: str = BODY_NODE,
             loop: str | None = None) -> BagRun:
    """Read the body topics of a bag into a :class:`BagRun` (``skip_damaged``: skip chunks failing their CRC).

    Only the messages of each topic's owner are used (:func:`expected_publishers` for ``loop``, default the bag's
    ``custom_data`` loop; the body is the node named ``body_node`` in the run's namespace, and where that name has
    several publishers, the one :class:`~bptsb_ros.analysis.provenance.OwnMessages` resolves); ``provenance`` reports
    the others. Raises
    :class:`BagError` when a step has two different messages from the owner.
    """
    topics = list_topics(bag)
    custom = bag_custom_data(bag)
    ns = custom.get("namespace", "")  # a loop run in a namespace (bptsb launch --namespace) has its topics in it
    names = {key: _topic(key, ns) for key in TOPICS}
    pos_topic = names["positions"]
    if pos_topic not in topics:
        raise BagError(f"bag {bag} has no {pos_topic} topic (geometry_msgs/PoseArray); topics: {', '.join(topics)}")
    wanted = [t for t in (names[k] for k in ("positions", "spring_lengths", "rest_length", "markers", "task_input",
                                              "wind", "perturbation")) if t in topics]
    for key, topic in names.items():
        if topic in wanted and normalize_type(topics[topic] or "x/msg/none") != TOPICS[key].type:
            raise BagError(f"bag {bag}: {topic} is of type {printable(topics[topic][:80])}, not "
                           f"{TOPICS[key].type}: not a recording of this package's loop")
    own = OwnMessages(bag, expected_publishers(loop or custom.get("loop"), body_node, ns), topic_publishers(bag))
    wind_ns: dict[int, tuple[float, float]] = {}
    kicks_ns: dict[int, np.ndarray] = {}
    pos: dict[int, np.ndarray] = {}
    lengths: dict[int, np.ndarray] = {}
    rests: dict[int, np.ndarray] = {}
    inputs_ns: dict[int, float] = {}
    markers = None
    for (topic, _type, _t, msg), publisher in read_published(bag, wanted, skip_damaged=skip_damaged):
        if not own.keep(topic, publisher):
            continue
        try:  # a message of the right type name may still lack its fields (a schema of the bag's own)
            if topic == pos_topic:
                own.put(pos, _stamp_ns(msg), np.array([(p.position.x, p.position.y) for p in msg.poses]), topic,
                        publisher)
            elif topic == names["spring_lengths"]:
                own.put(lengths, _stamp_ns(msg), np.asarray(msg.position, dtype=np.float64), topic, publisher)
            elif topic == names["rest_length"]:
                own.put(rests, _stamp_ns(msg), np.asarray(msg.position, dtype=np.float64), topic, publisher)
            elif topic == names["markers"] and markers is None:
                markers = msg
            elif topic == names["task_input"] and len(msg.position):
                own.put(inputs_ns, _stamp_ns(msg), float(msg.position[0]), topic, publisher)
            elif topic == names["wind"]:
                own.put(wind_ns, _stamp_ns(msg), (float(msg.vector.x), float(msg.vector.y)), topic, publisher)
            elif topic == names["perturbation"]:
                kick = np.asarray(msg.position, dtype=np.float64)
                if kick.size % 2 or not np.isfinite(kick).all():
                    raise BagError(f"bag {bag}: a {topic} message holds {kick.size} values (x, y per movable mass "
                                   "expected, all finite)")
                own.put(kicks_ns, _stamp_ns(msg), kick.reshape(-1, 2), topic, publisher)
        except (AttributeError, TypeError, ValueError, IndexError) as err:
            raise BagError(f"bag {bag}: a {topic} message does not hold what a {_type} holds "
                           f"({type(err).__name__}: {printable(str(err)[:120])})") from None
    if not pos and own.report.foreign.get(pos_topic):
        raise BagError(f"bag {bag} has no {pos_topic} messages from {node_in(ns, body_node)}, only from "
                       + ", ".join(f"{name} ({n})" for name, n in own.report.foreign[pos_topic].most_common()))
    if not pos:
        raise BagError(f"bag {bag} has no messages on {pos_topic}")
    stamps = np.array(sorted(pos))
    if dt is None:
        diffs = np.diff(stamps)
        if not len(diffs):
            raise BagError(f"bag {bag} holds a single step; give the agent (its config has the time step)")
        dt_ns = int(diffs.min())
    else:
        dt_ns = dt_to_ns(dt)
    steps = (stamps + dt_ns // 2) // dt_ns  # nearest step, as ros.topics.stamp_to_step
    positions = np.stack([pos[s] for s in stamps])
    try:
        springs, fixed, cmp = _layout_from_markers(markers, positions)
    except (AttributeError, TypeError, ValueError, IndexError) as err:
        raise BagError(f"bag {bag}: its {names['markers']} message does not hold what a MarkerArray holds "
                       f"({type(err).__name__}: {printable(str(err)[:120])})") from None

    def stack(d: dict[int, np.ndarray]) -> np.ndarray | None:
        return np.stack([d[s] for s in stamps]) if d and all(s in d for s in stamps) else None

    spring_lengths = stack(lengths)
    if spring_lengths is None and len(springs):  # body/spring_lengths every state_every steps only: the geometry
        d = positions[:, springs[:, 0]] - positions[:, springs[:, 1]]
        spring_lengths = np.sqrt(d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1])
    return BagRun(dt_ns / NS_PER_S, steps, positions, spring_lengths, stack(rests), springs, fixed, cmp,
                  {int((s + dt_ns // 2) // dt_ns): u for s, u in inputs_ns.items()}, custom,
                  {int((s + dt_ns // 2) // dt_ns): w for s, w in wind_ns.items()},
                  {int((s + dt_ns // 2) // dt_ns): d for s, d in kicks_ns.items()}, own.report)


def recording_summary(custom: dict[str, str]) -> dict[str, Any]:
    """What the recorder says it lost (``dropped_messages`` None: it did not count, an older recorder)."""
    from bptsb_ros.bags.recording import recorded_loss

    total, by_topic, complete = recorded_loss(custom)
    return {"dropped_messages": total, "dropped_by_topic": by_topic, "recording_complete": complete}


def bag_custom_data(bag: str | Path) -> dict[str, str]:
    """The bag's ``custom_data`` (loop, mode, agent, open_loop_steps from ``bptsb launch``); {} if none."""
    try:
        return {str(k): str(v) for k, v in (read_metadata(bag).custom_data or {}).items()}
    except (BagError, OSError, AttributeError):
        return {}


def _layout_from_markers(markers: Any, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Springs (E, 2), fixed (N,), CMP index from the body marker array.

    Spring endpoints are matched to the mass points of the same MarkerArray (they are copies of them);
    without markers: no springs, and the masses that never move count as fixed.
    """
    n = positions.shape[1]
    fixed = np.all(np.abs(positions - positions[0]) < 1e-12, axis=(0, 2))
    springs = np.zeros((0, 2), dtype=np.int64)
    cmp = -1
    if markers is None:
        return springs, fixed, cmp
    by_ns = {m.ns: m for m in markers.markers}
    masses, lines = by_ns.get("masses"), by_ns.get("springs")
    if masses is None or len(masses.points) != n:
        return springs, fixed, cmp
    mass_pts = np.array([(p.x, p.y) for p in masses.points])
    colours = [(c.r, c.g, c.b) for c in masses.colors]
    fixed = np.array([abs(r - g) < 1e-6 and abs(g - b) < 1e-6 for r, g, b in colours]) if colours else fixed
    reds = [i for i, (r, g, _b) in enumerate(colours) if r > 0.8 and g < 0.3]
    cmp = reds[0] if len(reds) == 1 else -1
    if lines is not None and len(lines.points):
        pts = np.array([(p.x, p.y) for p in lines.points])
        idx = np.argmin(np.linalg.norm(pts[:, None, :] - mass_pts[None], axis=-1), axis=1)
        springs = idx.reshape(-1, 2).astype(np.int64)
    return springs, fixed, cmp


def animate_run(path: Path, run: BagRun) -> Path:
    """An animation (GIF) of the replayed run at ``path``: the recorded positions and rest lengths."""
    from bptsb_ros.analysis.animate import animate_trajectory
    from bptsb_ros.sim.trajectory import Trajectory

    n, e = run.positions.shape[1], len(run.springs)
    rest = run.rest_length if run.rest_length is not None else (
        run.spring_lengths if run.spring_lengths is not None else np.ones((len(run.steps), e)))
    traj = Trajectory(dt=run.dt, positions=run.positions, velocities=np.zeros_like(run.positions),
                      springs=run.springs, k=np.zeros(e), d=np.zeros(e), rest_length=rest, fixed=run.fixed,
                      mass=np.ones(n), external_force=np.zeros_like(run.positions), gravity=np.zeros(2),
                      cmp_index=run.cmp_index, shape="replay")
    return animate_trajectory(traj, path, title="replayed bag")
