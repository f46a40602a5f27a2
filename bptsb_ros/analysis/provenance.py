"""Which recorded messages an analysis may use: those of the node that owns the topic (ROS-free).

A bag records who published each message (:mod:`bptsb_ros.bags.publishers`). Replay uses only the messages of
the node expected on each topic (``body_sim`` for the body's state; ``task_input``, ``wind_source``,
``image_streamer``, ``mnist_brain`` for theirs), matched by node name; every other publisher's messages are
*foreign*: ignored, and counted by publisher in the report. Two messages of one step from the expected node are a
*duplicate* when equal (counted) and a conflict when not: :meth:`OwnMessages.put` raises :class:`BagError`,
since the body's own record no longer says what happened (a second publisher named like the body, or a broken
recording). A bag without publisher identities (recorded before they were kept, or by ``ros2 bag record``) is
read whole, with a warning that its publishers cannot be checked; a conflict in it fails the same way.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np

from bptsb_ros.bags.errors import BagError
from bptsb_ros.bags.publishers import PublisherId

V = TypeVar("V")


@dataclass
class Provenance:
    """What an analysis found about the publishers of the messages it read.

    checked: every message read named its publisher (False: the bag does not record them, so nothing could be
    checked). used: topic -> publisher name -> messages used. foreign: topic -> publisher name -> messages
    ignored. duplicates: topic -> repeated identical messages of one step from the expected node.
    """

    checked: bool = True
    used: dict[str, Counter] = field(default_factory=dict)
    foreign: dict[str, Counter] = field(default_factory=dict)
    duplicates: Counter = field(default_factory=Counter)

    def to_dict(self) -> dict[str, Any]:
        return {"checked": self.checked,
                "used": {t: dict(c) for t, c in self.used.items()},
                "foreign": {t: dict(c) for t, c in self.foreign.items()},
                "foreign_messages": sum(sum(c.values()) for c in self.foreign.values()),
                "duplicates": dict(self.duplicates)}

    def warnings(self, bag: object) -> list[str]:
        """One line per finding worth telling the user (unchecked publishers, foreign messages, duplicates)."""
        lines = []
        if not self.checked:
            lines.append(f"warning: bag {bag} does not record who published its messages (recorded before publisher "
                         "identities were kept, or by another recorder): their publishers cannot be checked")
        for topic, counts in self.foreign.items():
            names = ", ".join(f"{name} ({n})" for name, n in counts.most_common())
            lines.append(f"warning: bag {bag}: ignored {sum(counts.values())} {topic} messages from foreign "
                         f"publishers: {names}")
        for topic, n in self.duplicates.items():
            lines.append(f"warning: bag {bag}: {n} duplicate {topic} messages (the same step twice, equal) ignored")
        return lines


def _equal(a: Any, b: Any) -> bool:
    return bool(np.array_equal(a, b)) if isinstance(a, np.ndarray) or isinstance(b, np.ndarray) else a == b


class OwnMessages:
    """Keeps the messages of each topic's expected node and files them by step.

    ``expected`` maps a topic to the node name (without namespace) that owns it, or None to accept any
    publisher on it.
    """

    def __init__(self, bag: object, expected: dict[str, str | None]) -> None:
        self.bag = bag
        self.expected = dict(expected)
        self.report = Provenance()
        self._senders: dict[tuple[str, int], PublisherId | None] = {}

    def keep(self, topic: str, publisher: PublisherId | None) -> bool:
        """Whether a message of ``topic`` from ``publisher`` may be used (counts it either way)."""
        if publisher is None:
            self.report.checked = False
            self.report.used.setdefault(topic, Counter())["unknown publisher"] += 1
            return True
        owner = self.expected.get(topic)
        if owner is not None and publisher.node != owner:
            self.report.foreign.setdefault(topic, Counter())[publisher.name] += 1
            return False
        self.report.used.setdefault(topic, Counter())[publisher.name] += 1
        return True

    def put(self, store: dict[int, V], key: int, value: V, topic: str, publisher: PublisherId | None,
            equal: Callable[[Any, Any], bool] = _equal) -> None:
        """``store[key] = value`` for a kept message of step ``key``; a second message of the same step is counted
        as a duplicate when equal, else raises :class:`BagError` (one line)."""
        if key not in store:
            store[key] = value
            self._senders[(topic, key)] = publisher
            return
        if equal(store[key], value):
            self.report.duplicates[topic] += 1
            return
        first = self._senders.get((topic, key))
        who = ("the bag does not record their publishers" if first is None or publisher is None else
               f"from {first.name} [{first.gid}] and {publisher.name} [{publisher.gid}]")
        raise BagError(f"bag {self.bag}: two different {topic} messages for the same step (stamp {key} ns), {who}; "
                       "the run cannot be replayed from an ambiguous record")
