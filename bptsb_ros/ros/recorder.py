"""Recorder node: records topics to a rosbag2 MCAP bag, like ``ros2 bag record`` (storage ``mcap``).

Run it as ``python -m bptsb_ros.ros.recorder --ros-args -p bag_path:=bags/run1 -p "topics:=[/clock, body/positions]"``
(or ``bptsb run recorder ...``, ``ros2 run bptsb_ros recorder ...``). Parameters: see
:data:`bptsb_ros.bags.recording.RECORDER_PARAMS`.

Every ``discovery_period`` it looks at the graph; each selected topic that has a publisher gets a raw subscription
(serialized CDR bytes, never re-encoded) with the QoS that matches all its publishers (reliable only if all are
reliable, transient-local only if all are) and a history of ``queue_depth``. The publishers' offered QoS profiles
and the type hash go into the bag. Each message is taken with its publisher's GID (:mod:`bptsb_ros.ros.take`) and
written to the MCAP channel of its (topic, publisher), named after the publisher's node as the ROS graph reports it
(:mod:`bptsb_ros.bags.publishers`): a message forged by another node on ``body/positions`` is in the bag, and
marked as that node's. Every message waiting on a subscription is taken in one executor call.

Each message is stamped with its receive time: the middleware's receive
timestamp (system clock, ns since the epoch), or, when ``use_sim_time`` is true (``ros2 bag record
--use-sim-time``; the launchers set it for lockstep runs), the node clock, which follows ``/clock``: the bag's
timeline is then sim time, so a 10 s lockstep run lasts 10 s in ``ros2 bag info``, ``ros2 bag play`` and
Foxglove however long it took. ``custom_data`` key ``log_time`` says which: ``sim`` or ``system``. A recorder on sim
time that records ``/clock`` itself sets its clock from the ticks it takes for the bag and drops rclpy's own ``/clock``
subscription (the clock publisher has one reader fewer, and no callback runs per tick): each tick is logged at its own
time, every other message at the newest tick taken by the time it is written, which is never older than the newest
tick that had arrived when the message was taken (the ticks waiting are taken before each batch of another topic is
written).

Losses are counted (:class:`bptsb_ros.bags.recording.LossCount`): a jump in a publisher's sequence numbers, and
the middleware's ``message_lost`` reports. With ``ack_topic`` set (lockstep runs of ``bptsb launch``) the recorder
also publishes how far it has recorded the run (:class:`~bptsb_ros.bags.recording.StepAck`); ``body_sim`` with
``wait_for_recorder`` does not run further ahead than ``recorder_window`` steps, so a lockstep recording cannot lose
a message however slow the recorder is (it slows the run instead).

On SIGINT or SIGTERM it stops discovery and the flush timer and keeps taking every message published before the
stop signal (publisher's source time; later ones are not part of the recording) until none has come for
``drain_quiet`` seconds; ``stop_timeout`` caps that, and a drain cut short counts as a loss. Then it finalizes the
bag (summary, indexes, ``metadata.yaml`` with ``custom_data`` ``dropped_messages`` and ``dropped_by_topic``) and
exits 0, or 1 when anything was lost (unless ``allow_loss``). Killed outright, it leaves the chunks written
so far (closed at least every ``flush_period``); ``bptsb bag recover`` restores them. Log lines
``Recording to ...`` and, with explicit ``topics``, ``All <n> requested topics subscribed`` tell a launcher when it
is ready; one ``Subscribed to <topic> [<type>]`` line per topic is logged at DEBUG (``-p log_level:=debug``).
"""

from __future__ import annotations

import functools
import signal
import sys
import time
from collections import Counter
from typing import Any

import rclpy
from rclpy.clock import Clock, ClockType
from rclpy.event_handler import QoSMessageLostInfo, SubscriptionEventCallbacks
from rclpy.exceptions import InvalidHandle
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import QoSDurabilityPolicy, QoSHistoryPolicy, QoSProfile, QoSReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rclpy.subscription import Subscription
from rclpy.time import Time

from bptsb_ros.bags.errors import BagError
from bptsb_ros.bags.msgdefs import get_message_class
from bptsb_ros.bags.publishers import UNKNOWN_NODE, PublisherId, gid_text
from bptsb_ros.bags.qos import QosProfile
from bptsb_ros.bags.recording import (
    RECORDER_PARAMS,
    RECORDING_RECORD,
    SEQUENCE_UNSUPPORTED,
    STAMPED_TYPES,
    LossCount,
    RecorderConfig,
    StepAck,
    cdr_stamp_ns,
    incompatible_offers,
    select_topics,
    subscription_policies,
    take_round,
)
from bptsb_ros.bags.writer import BagWriter
from bptsb_ros.interface.params import ParameterError
from bptsb_ros.ros.declare_params import declare_parameters
from bptsb_ros.ros.runtime import exit_process, ignore_stop_signals, unblock_interrupt
from bptsb_ros.ros.take import GidTaker, TakenInfo, batch_executor_class, gid_take_problem, rclpy_take

#: the type of the ticks a recorder on sim time can follow itself (:meth:`RecorderNode._follow_recorded_clock`)
CLOCK_TYPE = "rosgraph_msgs/msg/Clock"
#: most messages taken from one subscription in one executor call (then the other subscriptions and timers)
BATCH = 200
#: zero-timeout spins of a hosted recorder's executor per turn of service (:meth:`RecorderNode.serve`): each handles
#: at most one ready entity (a parameter request, a timer, a loss report)
HOSTED_SPINS = 3
EXIT_LOST = 1


class RecorderNode(Node):
    """Subscribes to the selected topics and writes every message it takes to a :class:`BagWriter`."""

    def __init__(self, hosted: bool = False, **kwargs: Any) -> None:
        """``hosted``: run in another node's loop (:meth:`serve`; ``bptsb_composed``): its executor (the batch one of
        the recorder process) is spun by :meth:`serve` instead of a loop of its own, and its sim time always follows
        the ``/clock`` it records."""
        super().__init__("recorder", **kwargs)
        self.hosted = hosted
        self.config = RecorderConfig.from_values(declare_parameters(self, RECORDER_PARAMS), self.get_namespace())
        self._use_sim_time = bool(self.get_parameter("use_sim_time").value)
        self.add_on_set_parameters_callback(self._keep_time_base)
        custom_data = {**self.config.custom_data, "log_time": "sim" if self._use_sim_time else "system"}
        self.writer = BagWriter(
            self.config.bag_path, chunk_size=self.config.chunk_size, compression=self.config.compression,
            flush_period_s=self.config.flush_period, custom_data=custom_data,
        )
        self._recorded: dict[str, Any] = {}
        self._skipped: set[str] = set()
        self._policies: dict[str, tuple[str, str]] = {}
        self._publisher_counts: dict[str, int] = {}
        self._warned: set[str] = set()
        self._identities: dict[str, dict[str, PublisherId]] = {}  # topic -> GID -> publisher (from the graph)
        self._takers: list[GidTaker] = []
        self._gid_problem = gid_take_problem()
        self.received = 0
        self.after_stop = 0  # messages published after the stop signal, not recorded
        self.loss = LossCount()
        self._loss_logs: Counter = Counter()
        self._stop_ns: int | None = None
        self._clock_topic: str | None = None  # the recorded /clock this node's sim time follows (else rclpy's)
        self._said_bad_tick = False
        self._next_take = self._next_service = 0.0  # when hosted (:meth:`serve`), monotonic seconds
        self.executor_: Any = None  # when hosted: the executor :meth:`serve` spins
        self.ack = StepAck(self.config.ack_topics)
        self._ack_pub = None
        try:
            if self.config.ack_topic:  # the latest acknowledgement, also for a body that subscribes late
                from rosgraph_msgs.msg import Clock as ClockMsg

                self._ack_class = ClockMsg
                self._ack_pub = self.create_publisher(ClockMsg, self.config.ack_topic, QoSProfile(
                    history=QoSHistoryPolicy.KEEP_LAST, depth=1, reliability=QoSReliabilityPolicy.RELIABLE,
                    durability=QoSDurabilityPolicy.TRANSIENT_LOCAL))
            self.get_logger().info(
                f"Recording to {self.writer.path} ("
                + (f"{len(self.config.topics)} topics" if self.config.topics else "all topics")
                + f"; log times: {'sim time from /clock' if self._use_sim_time else 'system time'})"
            )
            if self._gid_problem:
                self.get_logger().warning(f"publisher GIDs cannot be taken here ({self._gid_problem}): messages are "
                                          "recorded without their publishers' identities")
            self._discover()
            # steady-clock timers: on sim time the node clock stands still until the first /clock, and the body
            # publishes that only once the recorder has subscribed
            steady = Clock(clock_type=ClockType.STEADY_TIME)
            self._discovery_timer = self.create_timer(self.config.discovery_period, self._discover, clock=steady)
            self._flush_timer = self.create_timer(min(self.config.flush_period, 0.5), self.writer.flush_if_due,
                                                  clock=steady)
        except BaseException:
            self.writer.close()
            raise

    def _discover(self) -> None:
        for topic, types in select_topics(self.get_topic_names_and_types(), self.config).items():
            if topic in self._recorded:
                self._check_new_publishers(topic)
            elif topic not in self._skipped:
                self._subscribe(topic, types)

    def _learn_publishers(self, topic: str) -> None:
        """Map the GIDs of ``topic``'s publishers to their nodes (from the graph); a publisher whose node the graph
        names only now is renamed in the bag."""
        known = self._identities.setdefault(topic, {})
        for info in self.get_publishers_info_by_topic(topic):
            gid = gid_text(info.endpoint_gid)
            node = "" if info.node_name == UNKNOWN_NODE else info.node_name
            old = known.get(gid)
            if old is None or (node and not old.node):
                known[gid] = PublisherId(gid, node, info.node_namespace if node else "")
                if old is not None:
                    self.writer.name_publisher(known[gid])

    def _publisher(self, topic: str, raw_gid: bytes) -> PublisherId | None:
        """The publisher of a message from its GID bytes (None without them)."""
        if not raw_gid:
            return None
        gid = gid_text(raw_gid)
        publisher = self._identities.get(topic, {}).get(gid)
        if publisher is None:  # its first message: ask the graph
            self._learn_publishers(topic)
            publisher = self._identities[topic].setdefault(gid, PublisherId(gid))
        return publisher

    def _check_new_publishers(self, topic: str) -> None:
        """Learn the nodes of new publishers; warn once when one that joined later offers less than the
        subscription requests."""
        count = self.count_publishers(topic)
        unnamed = any(not p.node for p in self._identities.get(topic, {}).values())
        if count != self._publisher_counts.get(topic) or unnamed:
            self._learn_publishers(topic)
        if count == self._publisher_counts.get(topic) or topic in self._warned:
            return
        self._publisher_counts[topic] = count
        offered = [QosProfile.from_rclpy(p.qos_profile) for p in self.get_publishers_info_by_topic(topic)]
        requested = self._policies[topic]
        if incompatible_offers(offered, requested):
            self.get_logger().warning(
                f"A publisher on {topic} offers QoS incompatible with the recorder's subscription {requested}; "
                "its messages are not recorded. Give all publishers of a topic the same reliability/durability."
            )
            self._warned.add(topic)

    def _subscribe(self, topic: str, types: list[str]) -> None:
        if len(types) > 1:
            self.get_logger().error(f"Not recording {topic}: it has several types {types}")
            self._skipped.add(topic)
            return
        publishers = self.get_publishers_info_by_topic(topic)
        if not publishers:
            return  # only subscribers so far: wait for a publisher to learn the offered QoS
        msgtype = types[0]
        try:
            msg_class = get_message_class(msgtype)
            offered = [QosProfile.from_rclpy(p.qos_profile) for p in publishers]
            self.writer.add_topic(topic, msgtype, qos_profiles=offered)
        except BagError as exc:
            self.get_logger().error(f"Not recording {topic} [{msgtype}]: {exc}")
            self._skipped.add(topic)
            return
        reliability, durability = subscription_policies(offered)
        self._policies[topic] = (reliability, durability)
        self._publisher_counts[topic] = len(publishers)
        depth = self.config.queue_depth
        qos = QoSProfile(
            history=QoSHistoryPolicy.KEEP_ALL if depth == 0 else QoSHistoryPolicy.KEEP_LAST,
            depth=max(depth, 1),
            reliability=QoSReliabilityPolicy[reliability.upper()],
            durability=QoSDurabilityPolicy[durability.upper()],
        )
        if topic in self.config.ack_topics and msgtype not in STAMPED_TYPES:
            self.get_logger().error(f"ack_topics: {topic} [{msgtype}] carries no stamp; not acknowledged")
            self.ack.refuse(topic)
        events = SubscriptionEventCallbacks(message_lost=functools.partial(self._on_lost, topic))
        sub = self.create_subscription(msg_class, topic, functools.partial(self._on_batch, topic), qos, raw=True,
                                       event_callbacks=events)
        sub.bptsb_take_batch = self._batch_taker(sub)  # served by batch_executor_class()
        self._recorded[topic] = sub
        if self._use_sim_time and msgtype == CLOCK_TYPE:
            self._follow_recorded_clock(topic)
        self._learn_publishers(topic)
        self.get_logger().debug(f"Subscribed to {topic} [{msgtype}] ({reliability}, {durability})")
        if self.config.topics and all(t in self._recorded for t in self.config.topics):
            self.get_logger().info(f"All {len(self.config.topics)} requested topics subscribed")

    def _keep_time_base(self, params: list[Any]) -> Any:
        """Refuse a change of ``use_sim_time`` while recording: a bag's log times are sim time or system time
        throughout (``custom_data`` ``log_time``), and the clock this node follows is chosen once."""
        from rcl_interfaces.msg import SetParametersResult

        for param in params:
            if param.name == "use_sim_time" and bool(param.value) != self._use_sim_time:
                return SetParametersResult(successful=False, reason="use_sim_time is chosen once, at startup: the "
                                           "bag's log times are sim time or system time throughout")
        return SetParametersResult(successful=True)

    def _follow_recorded_clock(self, topic: str) -> None:
        """Sim time from the ticks of ``topic`` that this node records, instead of rclpy's time source: when its
        ``/clock`` subscription is on ``topic``, it is destroyed (as ``BrainNode.feed_sim_time`` does), and the ticks
        waiting on ``topic`` are taken before every batch of another topic is written (:meth:`_on_batch`), which is
        then logged at the newest tick. Where rclpy's time source is not as expected (or listens elsewhere), nothing
        changes, unless the recorder is hosted: no executor spins rclpy's subscription there, so the recorded ticks
        are its clock in any case."""
        source = getattr(self, "_time_source", None)
        sub = getattr(source, "_clock_sub", None)
        if sub is not None and sub.topic_name == topic:
            self.destroy_subscription(sub)
            source._clock_sub = None
        elif not self.hosted:  # rclpy's own subscription stays this node's clock
            return
        self._clock_topic = topic

    def _tick(self, data: bytes) -> int | None:
        """The tick in ``data`` (a ``/clock`` message) [ns]; None for bytes that hold no tick or a time before 0
        (logged once; the message is still recorded, at the sim time so far)."""
        try:
            ns = cdr_stamp_ns(data)
            if ns < 0:
                raise ValueError(f"a tick before time 0 ({ns} ns)")
        except ValueError as exc:
            if not self._said_bad_tick:
                self._said_bad_tick = True
                self.get_logger().warning(f"{self._clock_topic}: {exc}; the sim time stays where it was")
            return None
        return ns

    def _batch_taker(self, sub: Subscription) -> Any:
        """The function that takes up to :data:`BATCH` waiting messages of ``sub`` (with their GIDs if it can)."""
        taker: GidTaker | None = None
        if not self._gid_problem:
            taker = GidTaker(sub)
            self._takers.append(taker)

        def take_batch() -> list[tuple[bytes, TakenInfo]]:
            batch = []
            for _ in range(BATCH):
                got = taker.take() if taker is not None else rclpy_take(sub)
                if got is None:
                    break
                batch.append(got)
            return batch

        return take_batch

    def take_ready(self) -> None:
        """Take every message waiting on the recorded topics, topic by topic, outside the executor (one executor
        call per topic costs far more than the takes: rclpy rebuilds its wait set for each)."""
        for topic in list(self._recorded):
            self._take_waiting(topic)

    def _take_waiting(self, topic: str) -> None:
        """Take and record every message waiting on ``topic``'s subscription, in batches of :data:`BATCH`."""
        sub = self._recorded.get(topic)
        while sub is not None:
            try:
                with sub.handle:
                    batch = sub.bptsb_take_batch()
            except InvalidHandle:  # destroyed meanwhile
                break
            if not batch:
                break
            self._on_batch(topic, batch)
            if len(batch) < BATCH:
                break

    def _on_batch(self, topic: str, batch: list[tuple[bytes, TakenInfo]]) -> None:
        if self._clock_topic is not None and topic != self._clock_topic:
            self._take_waiting(self._clock_topic)  # the ticks first, whatever order the executor serves topics in
        sim_now = self.get_clock().now().nanoseconds if self._use_sim_time else 0  # sim time stands still here
        ticks = topic == self._clock_topic  # the ticks this node's sim time follows: each logged at its own time
        clock_moved = False
        for data, info in batch:
            if self._stop_ns is not None and info.source_timestamp > self._stop_ns:
                self.after_stop += 1  # published after the stop signal: not part of the recording
                continue
            if ticks:
                tick = self._tick(data)
                stamp = sim_now = tick if tick is not None else sim_now
                clock_moved = True
            elif self._use_sim_time:
                stamp = sim_now
            else:
                stamp = info.received_timestamp or time.time_ns()
            sequence = info.publication_sequence_number
            sequence = 0 if sequence == SEQUENCE_UNSUPPORTED else sequence
            publisher = self._publisher(topic, info.publisher_gid)
            self.writer.write(topic, data, stamp, info.source_timestamp or stamp, sequence, publisher)
            self.received += 1
            # sequence numbers are per publisher: without its GID (rclpy's take) only message_lost reports count
            skipped = self.loss.see(topic, publisher.gid, sequence) if publisher is not None else 0
            if skipped:
                self._warn_loss(topic, f"{skipped} messages of {publisher.name} before sequence number {sequence} "
                                       "were never recorded")
            if self._ack_pub is not None:
                try:
                    self.ack.see(topic, data)
                except ValueError as exc:
                    self.get_logger().error(f"ack_topics: {topic}: {exc}; not acknowledged any more")
                    self.ack.refuse(topic)
        if clock_moved:  # the node clock (log lines, the next batches) reads the newest tick taken
            self.get_clock().set_ros_time_override(Time(nanoseconds=sim_now, clock_type=ClockType.ROS_TIME))
        self._publish_ack()

    def _publish_ack(self) -> None:
        due = self.ack.due() if self._ack_pub is not None else None
        if due is not None:
            msg = self._ack_class()
            msg.clock.sec, msg.clock.nanosec = divmod(due, 1_000_000_000)
            self._ack_pub.publish(msg)

    def _on_lost(self, topic: str, info: QoSMessageLostInfo) -> None:
        self.loss.lost(topic, int(info.total_count_change))
        self._warn_loss(topic, f"the middleware lost {info.total_count_change} messages")

    def _warn_loss(self, topic: str, text: str) -> None:
        """Log a loss on ``topic`` (the first one of each topic, then every 100th time)."""
        self._loss_logs[topic] += 1
        if self._loss_logs[topic] % 100 == 1:
            self.get_logger().error(f"LOST messages on {topic}: {text} (lost so far on {topic}: "
                                    f"{self.loss.by_topic().get(topic, 0)})")

    def serve(self, now: float, idle: bool = False) -> None:
        """One turn of the recorder hosted in another node's loop (``bptsb_composed`` with ``recorder``; the host calls
        this around its spins): take everything waiting (:meth:`take_ready`) when the host is about to wait anyway
        (``idle``) or ``batch_wait`` has passed since the last take; and every ``batch_wait`` spin its own executor
        (:meth:`host`) without waiting, a few calls, for its parameter services, its discovery and flush timers and the
        middleware's loss reports. ``now``: monotonic seconds."""
        if idle or now >= self._next_take:
            self._next_take = now + self.config.batch_wait
            self.take_ready()
        if now >= self._next_service:
            self._next_service = now + self.config.batch_wait
            for _ in range(HOSTED_SPINS):
                self.executor_.spin_once(timeout_sec=0.0)

    def host(self) -> None:
        """Give the hosted recorder its executor (the recorder process's batch executor), spun by :meth:`serve`."""
        self.executor_ = batch_executor_class()(context=self.context)
        self.executor_.add_node(self)

    def drain_hosted(self) -> None:
        """The end of a hosted recording: :func:`_drain` on its own executor, as the recorder process drains. Messages
        published after this call began are not recorded."""
        _drain(self.executor_, self, time.time_ns())

    def begin_stop(self, stop_ns: int) -> None:
        """The stop sequence has begun (signal at ``stop_ns``, system time): stop looking for new topics and stop
        the flush timer (``BagWriter.write`` still flushes when ``flush_period`` is due); from now on messages
        published after ``stop_ns`` are not recorded."""
        self._stop_ns = stop_ns
        self._discovery_timer.cancel()
        self._flush_timer.cancel()

    def close(self) -> int:
        """Finalize the bag (with what was lost) and log what it holds; return the exit status: 0, or
        :data:`EXIT_LOST` when messages were lost and ``allow_loss`` is false."""
        missing = [t for t in self.config.topics if t not in self._recorded]
        if missing:
            self.get_logger().warning(f"Requested topics never recorded (no publisher seen): {', '.join(missing)}")
        lost = self.loss.custom_data()
        self.writer.set_custom_data(lost)
        metadata = self.writer.close(records={RECORDING_RECORD: lost})
        self.release()
        counts = "".join(f"\n  {t.message_count:>8}  {t.name}" for t in metadata.topics) or " (no topics)"
        self.get_logger().info(f"Bag {self.writer.path} closed: {metadata.message_count} messages{counts}"
                               + (f"\n  ({self.after_stop} published after the stop signal, not recorded)"
                                  if self.after_stop else ""))
        if not self.loss.any:
            return 0
        what = ", ".join(f"{t} {n}" for t, n in self.loss.by_topic().items())
        text = (f"the recording LOST {self.loss.total} messages" + (f" ({what})" if what else "")
                + ("; the final drain was cut short by stop_timeout, more may be missing" if self.loss.cut_short
                   else ""))
        if self.config.allow_loss:
            self.get_logger().warning(text + " (allowed: allow_loss)")
            return 0
        self.get_logger().error(text + "; exiting with status 1 (allow_loss:=true accepts a lossy recording)")
        return EXIT_LOST

    def release(self) -> None:
        """Free the take buffers."""
        for taker in self._takers:
            taker.close()


def _drain(executor: Any, node: RecorderNode, stop_ns: int) -> None:
    """Take the messages still waiting or in flight after the stop signal (at ``stop_ns``, system time).

    Every executor call takes all waiting messages of a subscription (:func:`bptsb_ros.ros.take.batch_executor_class`),
    so a backlog of thousands drains in a fraction of a second. The drain ends once no message published before the
    signal has come for ``drain_quiet`` seconds (wall time since the last one, whatever else the executor did);
    ``stop_timeout`` caps it, and a drain cut short is counted as a loss.
    """
    node.begin_stop(stop_ns)
    quiet, cap = node.config.drain_quiet, node.config.stop_timeout
    started = last = time.monotonic()
    taken = node.received
    while True:
        before = node.received
        executor.spin_once(timeout_sec=min(quiet, 0.05))
        now = time.monotonic()
        if node.received != before:
            last = now
        elif now - last >= quiet:
            return
        if now - started >= cap:
            node.loss.cut_short = True
            node.get_logger().error(
                f"stop_timeout: still taking messages published before the stop signal after {cap:g} s "
                f"({node.received - taken} taken since); closing the bag, the recording is incomplete")
            return


class StopRequest:
    """The recorder's SIGINT/SIGTERM handler: ``ns`` is the system time [ns] of the first stop signal (None until
    one comes); later ones change nothing.

    It only assigns an attribute. A handler that takes a lock (``threading.Event.set``) deadlocks when a second
    signal's handler runs inside it, holding the lock, and a group SIGINT followed by launch's own SIGINT and
    SIGTERM does that: the recorder then hung until launch's SIGKILL and its bag was never closed."""

    def __init__(self) -> None:
        self.ns: int | None = None

    def __call__(self, *_: object) -> None:
        if self.ns is None:
            self.ns = time.time_ns()


def main(args: list[str] | None = None) -> int:
    """Run the recorder until SIGINT/SIGTERM; return 0 on a clean stop, 1 when messages were lost (unless
    ``allow_loss``), 2 for bad parameters or arguments (``--help`` lists the parameters)."""
    from bptsb_ros.ros.runtime import check_cli

    code = check_cli("recorder", sys.argv[1:] if args is None else list(args), RECORDER_PARAMS, __doc__ or "")
    if code is not None:
        unblock_interrupt()
        return code
    on_stop = StopRequest()
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    previous = {sig: signal.signal(sig, on_stop) for sig in (signal.SIGINT, signal.SIGTERM)}
    unblock_interrupt()  # a stop requested during startup (held pending by the launcher) arrives now
    node: RecorderNode | None = None
    code: int | None = None  # set once the recorder has finished (an exception leaves it None and propagates)
    try:
        try:
            node = RecorderNode()
        except (ParameterError, BagError) as exc:
            print(f"recorder: {exc}", file=sys.stderr)
            code = 2
            return code
        executor = batch_executor_class()()
        executor.add_node(node)
        try:
            def spin(timeout: float) -> None:
                executor.spin_once(timeout_sec=timeout)

            while on_stop.ns is None:  # batches: one wake-up per batch_wait while messages arrive
                take_round(spin, lambda: node.received, time.monotonic, time.sleep, node.config.batch_wait,
                           take_ready=node.take_ready)
            _drain(executor, node, on_stop.ns)  # the loop ends only once a stop signal set it
        except ExternalShutdownException:
            pass
        code = node.close()
        return code
    finally:
        ignore_stop_signals()  # stopping already: a late SIGINT/SIGTERM must not kill the cleanup
        if node is not None:
            if not node.writer.closed:
                node.writer.close()
            node.release()
            node.destroy_node()
        rclpy.try_shutdown()
        if args is None and code is not None:  # run as a program: exit at once (see runtime.exit_process)
            exit_process(code)
        for sig, handler in previous.items():
            signal.signal(sig, handler)

if __name__ == "__main__":
    sys.exit(main())
