"""Shared skeleton of the brain and task-input nodes: parameters, agent, publishing, spin loop, summary.

A brain is reactive: it answers ``/clock`` ticks or body states with commands stamped at the sim
time of the step they are in force at (``TOPICS.md``). It runs on sim time: ``use_sim_time`` defaults to
true for every brain (its log stamps and node clock follow the body's ``/clock``); ``-p use_sim_time:=false``
still sets it off. The commands themselves never depend on it: every step comes from a message stamp.

A brain that falls behind answers the newest tick only (:mod:`bptsb_ros.live.newest`): its loop handles every
message that is ready, then answers the newest of each subscription made with :meth:`BrainNode.subscribe_newest`;
the older ones are dropped (counted, and logged at the end).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from rclpy.clock import ClockType
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from rclpy.subscription import Subscription
from rclpy.time import Time
from sensor_msgs.msg import JointState

from bptsb_ros.interface.params import CPUS, EXECUTOR, LOG_LEVEL, RAW_OUTPUTS, OnChange, Param, ParameterError
from bptsb_ros.interface.source import SOURCE_PARAMS
from bptsb_ros.interface.topics import DEFAULT_QOS_DEPTH, TOPICS, dt_to_ns, stamp_to_step
from bptsb_ros.live.agent_source import load_source
from bptsb_ros.live.channels import RunningStats
from bptsb_ros.live.newest import IDLE_SPINS, Newest, pump
from bptsb_ros.ros import messages as m
from bptsb_ros.ros.cdr_in import stamp_ns
from bptsb_ros.ros.declare_params import declare_parameters
from bptsb_ros.ros.raw_out import RawTemplate, TemplateError
from bptsb_ros.ros.runtime import EXIT_OK, StopFlag, Throttle, executor_kind, make_executor, wait_acked

COMMON_PARAMS: tuple[Param, ...] = SOURCE_PARAMS + (
    Param("qos_depth", DEFAULT_QOS_DEPTH, "history depth of every topic (reliable)", "int", minimum=1),
    Param("min_subscribers", 1, "before its first message, wait until the output topic has this many matched "
          "subscribers (the body, the next brain, the recorder) so that nothing is sent into the void", "int",
          minimum=0),
    Param("startup_timeout", 30.0, "wall seconds to wait for a publisher on each input (before making the outputs) "
          "and for min_subscribers (before sending), each, before going on anyway", "float", positive=True),
    EXECUTOR,
    RAW_OUTPUTS,
    LOG_LEVEL,
    Param("rt_priority", 0, "run the node's thread under SCHED_FIFO at this priority (1-99) and its middleware threads "
          "one below (needs CAP_SYS_NICE or root, else a warning and the normal scheduler): a realtime body at a "
          "higher rate_scale than the other processes leave it CPU for gets its commands in time; 0: the normal "
          "scheduler", "int", minimum=0, maximum=99),
    CPUS,
)
#: ``use_sim_time`` of a brain unless given (rclpy's own default, false, is wrong for a node driven by /clock)
USE_SIM_TIME_DEFAULT = True
#: seconds a brain waits at its end for its subscribers to acknowledge its last messages
FINAL_ACK_TIMEOUT = 1.0


def topic_params(keys: Sequence[str]) -> tuple[Param, ...]:
    """``topics.<key>`` parameters (default names from ``TOPICS``)."""
    return tuple(Param(f"topics.{key}", TOPICS[key].name, f"topic name of {TOPICS[key].type}", "str")
                 for key in keys)


class BrainNode(Node):
    """Base class: declares ``COMMON_PARAMS + params``, loads the agent, counts what it publishes."""

    def __init__(self, name: str, stop: StopFlag, params: Sequence[Param], on_change: OnChange | None = None) -> None:
        super().__init__(name)
        if "use_sim_time" not in self._parameter_overrides:  # not given by -p or a params file
            self.set_parameters([Parameter("use_sim_time", Parameter.Type.BOOL, USE_SIM_TIME_DEFAULT)])
        self.stop = stop
        self.p: dict[str, Any] = declare_parameters(self, COMMON_PARAMS + tuple(params), on_change)
        self.agent, self.trained = load_source(self.p)
        try:
            self.dt_ns = dt_to_ns(self.agent.dt)
        except ValueError as err:
            raise ParameterError(f"parameter 'dt' (or the agent's time step): {err}") from None
        self.depth: int = self.p["qos_depth"]
        from bptsb_ros.live.scheduling import parse_cpus

        self.cpus = parse_cpus(self.p["cpus"])
        self.sent = 0
        self.outputs: list[Publisher] = []
        self.ready: set[Publisher] = set()
        self.compute = RunningStats()  # seconds per message; bounded memory in long runs
        self.throttle = Throttle(1.0)
        self.latches: list[Newest] = []
        self.executor_ = make_executor(self.p["executor"], self.context)
        self.executor_.add_node(self)
        self.sim_time_fed = False  # the node's ROS clock follows the stamps of the messages this node takes
        self.triggers = 0  # subscriptions that feed a latch (subscribe_newest), not destroyed
        if not self.get_parameter("use_sim_time").value:
            self.get_logger().info("use_sim_time is false (set): log stamps use wall time, not the body's /clock")

    def source_text(self) -> str:
        p = self.p
        return p["agent"] or p["config"] or f"fresh {self.agent.task} agent (seed {p['seed']})"

    def warn(self, key: str, text: str) -> None:
        """Log a warning at most once a second per ``key`` (bad inputs can arrive at every step)."""
        emit, held = self.throttle(key)
        if emit:
            self.get_logger().warning(text + (f" ({held} similar suppressed)" if held else ""))

    def await_inputs(self) -> None:
        """Wait until every subscription of this node has a matched publisher, matched from this node's side.

        Call it after creating the subscriptions and before the outputs. A publisher counts a subscriber as matched
        (what ``body_sim``'s startup and ``min_subscribers`` wait for) once *its* side has discovered the reader;
        the reader may match the publisher later, and a reliable volatile reader drops what was sent before that:
        the body's first ``/clock`` tick, whose answer a lockstep body then waits for in vain. Outputs made only
        after this wait tell the nodes downstream that this node hears its inputs (the body waits for a publisher
        on every command topic it awaits, so the whole chain of a loop is connected before its first step). Ends
        on stop, or after ``startup_timeout`` seconds (logged; the outputs are made anyway)."""
        began = time.monotonic()
        deadline, said = began + self.p["startup_timeout"], False
        while not self.stop:
            unheard = [s.topic_name for s in self.subscriptions if s.get_publisher_count() < 1]
            if not unheard:
                return
            if not said and time.monotonic() > began + 2.0:
                said = True
                self.get_logger().info(f"waiting for a publisher on {', '.join(unheard)} before publishing")
            if time.monotonic() > deadline:
                self.get_logger().warning(f"no publisher on {', '.join(unheard)} after "
                                          f"{self.p['startup_timeout']:g} s; publishing my outputs anyway")
                return
            time.sleep(0.005)

    def output(self, msg_type: type, topic: str, qos: Any) -> Publisher:
        """Create a publisher whose messages are waited for (acknowledged) at shutdown (after
        :meth:`await_inputs`)."""
        pub = self.create_publisher(msg_type, topic, qos)
        self.outputs.append(pub)
        return pub

    def joint_state_out(self, names: list[str], field: str) -> Callable[[int, np.ndarray], Any]:
        """``f(step, values)``: the JointState of ``step`` with ``values`` in ``field`` (position or effort) and the
        joint ``names``, as pre-serialized bytes (:mod:`bptsb_ros.ros.raw_out`; ``raw_outputs``) or, where the
        message cannot be templated, as a message object."""
        ns = self.dt_ns

        def build(step: int, values: np.ndarray) -> JointState:
            return m.joint_state(step, ns, names, **{field: values})

        if not self.p["raw_outputs"]:
            return build
        from rclpy.serialization import deserialize_message

        try:
            return RawTemplate(build, [(len(names),)], deserialize_message, ns).render
        except TemplateError as err:
            self.get_logger().warning(f"publishing message objects ({err})")
            return build

    def subscribe_newest(self, msg_type: type, topic: str, handler: Callable[[Any], None], qos: Any,
                         raw: bool = False) -> Subscription:
        """Subscribe ``handler`` to ``topic`` so that it answers only the newest of the messages ready at once;
        ``raw``: it gets the message's CDR bytes (:mod:`bptsb_ros.ros.cdr_in` reads them)."""
        latch = Newest(handler)
        self.latches.append(latch)
        self.triggers += 1
        return self.create_subscription(msg_type, topic, latch.offer, qos, raw=raw)

    def destroy_trigger(self, sub: Subscription) -> None:
        """Destroy a subscription of :meth:`subscribe_newest` that is no longer needed."""
        self.destroy_subscription(sub)
        self.triggers -= 1

    def idle_spins(self) -> int:
        """Zero-timeout spins in a row without a latch message that end a turn's handling
        (:func:`~bptsb_ros.live.newest.pump`): 2 while rclpy's own ``/clock`` callback takes turns with the latches; 0
        for a node on the EventsExecutor with one trigger subscription (one dispatch hands the latch every message
        waiting on it: a spin more would only find later ones); else 1."""
        if not self.sim_time_fed:
            return IDLE_SPINS
        return 0 if self.triggers == 1 and executor_kind(self.executor_) == "events" else 1

    def clock_step(self, data: bytes) -> int:
        """The step of a ``/clock`` tick taken raw (deserialized when its bytes are not plain little-endian CDR);
        with :meth:`feed_sim_time`, the node's clock is set to it."""
        ns = stamp_ns(data)
        if ns is None:
            from rclpy.serialization import deserialize_message
            from rosgraph_msgs.msg import Clock

            stamp = deserialize_message(data, Clock).clock
            ns = stamp.sec * 1_000_000_000 + stamp.nanosec
        self.sim_time(ns)
        return stamp_to_step(0, ns, self.dt_ns)

    def sim_time(self, ns: int) -> None:
        """With :meth:`feed_sim_time`: the node's clock reads sim time ``ns`` [ns] from now on."""
        if self.sim_time_fed:
            self.get_clock().set_ros_time_override(Time(nanoseconds=ns, clock_type=ClockType.ROS_TIME))

    def feed_sim_time(self) -> None:
        """``use_sim_time`` without a second ``/clock`` subscription: call it once the node has its triggers, whose
        handlers pass every message's stamp to :meth:`sim_time` (``/clock`` ticks through :meth:`clock_step`). rclpy's
        time source subscribes to ``/clock`` for a node on sim time and deserializes every tick in a callback of its
        own; a node that takes stamped messages of every step anyway sets its clock from them (what the time
        source's callback does with the ticks) and drops that subscription: one reader of ``/clock`` and one callback
        per step fewer, and every callback of the node feeds a latch (:meth:`idle_spins`). The node's clock then
        reads the sim time of the step it is answering. A later change of ``use_sim_time`` is the time source's again.
        Where rclpy's time source is not as expected, nothing changes."""
        source = getattr(self, "_time_source", None)
        sub = getattr(source, "_clock_sub", None)
        if sub is None or not self.get_parameter("use_sim_time").value:
            return
        self.destroy_subscription(sub)
        source._clock_sub = None
        self.sim_time_fed = True

    def publish_timed(self, pub: Publisher, msg: Any, started: float) -> None:
        """Record the compute time since ``started`` (monotonic seconds) and publish.

        The first message of a publisher waits for ``min_subscribers`` matched subscribers (matching
        runs in the middleware's threads, so polling without spinning is enough).
        """
        self.compute.append(time.monotonic() - started)
        if pub not in self.ready:
            self._wait_matched(pub)
            self.ready.add(pub)
        pub.publish(msg)
        self.sent += 1

    def _wait_matched(self, pub: Publisher) -> None:
        need, deadline = self.p["min_subscribers"], time.monotonic() + self.p["startup_timeout"]
        while pub.get_subscription_count() < need and not self.stop:
            if time.monotonic() > deadline:
                self.get_logger().warning(f"{pub.topic_name} has {pub.get_subscription_count()} of {need} "
                                          f"subscribers after {self.p['startup_timeout']:g} s; sending anyway")
                return
            time.sleep(0.005)

    def realtime_priority(self, priority: int) -> None:
        """This thread under SCHED_FIFO at ``priority``, the middleware's threads one below, and everything built so
        far out of the garbage collector's sight (a full collection does not walk it); a refusal is logged."""
        import gc

        from bptsb_ros.live.scheduling import set_fifo_priority_of_process

        gc.collect()
        gc.freeze()
        problem, others = set_fifo_priority_of_process(priority)
        if problem:
            self.get_logger().warning(f"{problem}; running under the normal scheduler")
            return
        self.get_logger().info(f"running under SCHED_FIFO priority {priority} ({others} middleware thread(s) at "
                               f"{max(1, priority - 1)})")

    def pin(self) -> None:
        """With ``cpus``: every thread of this process on those CPUs (a refusal is logged)."""
        if not self.cpus:
            return
        from bptsb_ros.live.scheduling import cpus_text, pin_threads

        problem = pin_threads(self.cpus)
        if problem:
            self.get_logger().warning(f"{problem}; running on the CPUs it was started on")
        else:
            self.get_logger().info(f"running on CPU(s) {cpus_text(self.cpus)}")

    def run(self) -> int:
        """Spin until SIGINT/SIGTERM, then log a summary and let subscribers acknowledge the last messages."""
        self.pin()
        if self.p["rt_priority"]:
            self.realtime_priority(self.p["rt_priority"])
        while not self.stop:
            pump(lambda timeout: self.executor_.spin_once(timeout_sec=timeout), self.latches, 0.1, self.idle_spins())
        return self.finish()

    def answer_newest(self) -> None:
        """Answer the newest pending message of each latch: what :meth:`run`'s loop does after handling what is
        ready, called by the host's loop when this node's callbacks run on another node's executor (composed)."""
        for latch in self.latches:
            latch.answer()

    def finish(self) -> int:
        """Log the run's summary and let subscribers acknowledge the last messages; the exit code."""
        mean = 1e3 * self.compute.mean
        worst = 1e3 * self.compute.max if self.compute.count else 0.0
        dropped = sum(latch.dropped for latch in self.latches)
        self.get_logger().info(f"stopped by {self.stop.reason}: published {self.sent} messages, compute mean "
                               f"{mean:.3f} ms, max {worst:.3f} ms; {dropped} stale messages dropped (fell behind)")
        wait_acked(self.get_logger(), self.outputs, FINAL_ACK_TIMEOUT)
        return EXIT_OK
