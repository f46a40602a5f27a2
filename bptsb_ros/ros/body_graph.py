"""What ``body_sim`` asks the ROS graph: the clients of its control services, the publishers on its input topics
(and which of them their rule does not allow), and what its first step still waits for. A part of
:class:`bptsb_ros.ros.body_sim.BodySim` (its methods, on the node's subscriptions and core).
"""

from __future__ import annotations

import math
import time

from bptsb_ros.interface.topics import absolute
from bptsb_ros.live.body_params import UNKNOWN_NODE
from bptsb_ros.ros.body_outputs import DIAGNOSTICS_OVERDUE

#: seconds after which the publishers of an input topic are looked up in the graph again (same publisher count)
GRAPH_PERIOD = 0.5


class BodyGraph:
    """The ROS-graph queries of ``body_sim`` (mixed into :class:`~bptsb_ros.ros.body_sim.BodySim`)."""

    def _service_clients(self, name: str, wait: float = 1.0) -> list[tuple[str, str]]:
        """(namespace, node name) of every client of ``~/<name>``: the writers of its request topic (DDS name
        ``rq<service>Request``), waiting up to ``wait`` seconds while the graph has not named one yet (a client that
        stays unnamed is reported as such, and so not allowed)."""
        service = next(s for s in self.control_services if s.service_name.endswith(f"/{name}"))
        topic = f"rq{service.service_name}Request"
        deadline = time.monotonic() + wait
        while True:
            clients = [(i.node_namespace, i.node_name)
                       for i in self.get_publishers_info_by_topic(topic, no_mangle=True)]
            if all(n != UNKNOWN_NODE for _, n in clients) or time.monotonic() > deadline:
                return clients
            time.sleep(0.02)

    def _untrusted(self, source: str, now: float) -> list[str]:
        """Publishers on ``source``'s topic that its publisher rule does not allow; the graph is queried again when
        the publisher count changes, and at least every ``GRAPH_PERIOD`` s (at once while a node name is still
        unknown). A realtime body leaves the periodic query to the slack after a step (:meth:`_refresh_graph`; a
        query takes 0.3 ms, at times over a millisecond), unless it is ``DIAGNOSTICS_OVERDUE`` periods late."""
        count = self.subs[source].get_publisher_count()
        cached = self._intruders.get(source)
        if cached is None or cached[0] != count:
            return self._query_untrusted(source, count, now)
        age = now - cached[1]
        if age > GRAPH_PERIOD:
            if self.p["mode"] != "realtime" or age > DIAGNOSTICS_OVERDUE * GRAPH_PERIOD:
                return self._query_untrusted(source, count, now)
            self._graph_due.add(source)
        return cached[2]

    def _query_untrusted(self, source: str, count: int, now: float) -> list[str]:
        names = self._publisher_names(self.subs[source].topic_name)
        cached = (count, now if UNKNOWN_NODE not in {n for _, n in names} else -math.inf,
                  self.core.publisher_rules[source].untrusted(names))
        self._intruders[source] = cached
        self._graph_due.discard(source)
        return cached[2]

    def _refresh_graph(self, slack: float) -> None:
        """Query the graph for one source whose periodic query :meth:`_untrusted` left for later, when ``slack``
        (seconds until the next step is due) exceeds twice what a query took lately (a slowly decaying maximum)."""
        if not self._graph_due or slack < self._graph_cost:
            return
        source = self._graph_due.pop()
        began = time.monotonic()
        self._query_untrusted(source, self.subs[source].get_publisher_count(), began)
        self._graph_cost = max(0.9 * self._graph_cost, 2 * (time.monotonic() - began))

    def _publisher_names(self, topic: str) -> list[tuple[str, str]]:
        """(namespace, node name) of every publisher on ``topic`` (``UNKNOWN_NODE`` while DDS has not named it)."""
        return [(i.node_namespace, i.node_name) for i in self.get_publishers_info_by_topic(topic)]

    def _startup_missing(self) -> list[str]:
        """What the first step still waits for: a publisher (with its node name known) on every awaited source's
        topic, the listed subscribers, the recorder's acknowledgements."""
        waited = [self.subs[s] for s in self.core.wait_sources]
        missing = [f"a publisher on {s.topic_name}" for s in waited if s.get_publisher_count() < 1]
        missing += [f"the node names of the publishers on {s.topic_name}" for s in waited
                    if any(name == UNKNOWN_NODE for _, name in self._publisher_names(s.topic_name))]
        missing += [f"{n} subscriber(s) on {t} (have {have})" for t, n in self.wait_subscribers
                    if (have := self._subscriber_count(t)) < n]
        if self.ack_sub is not None and self.ack_sub.get_publisher_count() < 1:
            missing.append(f"the recorder's acknowledgements on {self.ack_sub.topic_name}")
        return missing

    def _subscriber_count(self, topic: str) -> int:
        pub = self._own.get(absolute(topic, self.get_namespace()))  # our own publisher's count, if it is ours
        return pub.get_subscription_count() if pub else self.count_subscribers(topic)
