"""Which recorded messages an analysis may use: those of the node that owns the topic (ROS-free).

A bag records who published each message (:mod:`bptsb_ros.bags.publishers`). Replay uses only the messages of
the node expected on each topic (``body_sim`` for the body's state; ``task_input``, ``wind_source``,
``image_streamer``, ``mnist_brain`` for theirs), matched by *fully qualified* node name (``/ns/body_sim``: a node
of the same name in another namespace is someone else) and by publisher id (GID); every other publisher's
messages are *foreign*: ignored, and counted by publisher in the report.

Node names are not authenticated: a second process can name its node ``body_sim`` in the body's namespace. Its
publisher on the body's topic has another GID, and the bag records both. When one name has two publishers on a
topic, the owner is the one in the same DDS participant (the process: the first 12 bytes of a GID, the
participant's GUID prefix) as that name's publishers on the owner's other topics (the body publishes positions,
spring lengths, rest lengths and markers from one process); the others are foreign, and a warning names them
all. When that cannot tell them apart (the same count of topics), the bag is refused (:class:`BagError`): the
owner's record is ambiguous.

Two messages of one step from the owner are a *duplicate* when equal (counted) and a conflict when not:
:meth:`OwnMessages.put` raises :class:`BagError`, since the body's own record no longer says what happened. A bag
without publisher identities (recorded before they were kept, or by ``ros2 bag record``) is read whole, with a
warning that its publishers cannot be checked; a conflict in it fails the same way.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np

from bptsb_ros.bags.errors import BagError
from bptsb_ros.bags.publishers import PublisherId
from bptsb_ros.files.untrusted_yaml import printable

V = TypeVar("V")


@dataclass
class Provenance:
    """What an analysis found about the publishers of the messages it read.

    checked: every message read named its publisher (False: the bag does not record them, so nothing could be
    checked). used: topic -> publisher name -> messages used. foreign: topic -> publisher name -> messages
    ignored (a same-named publisher that is not the owner: ``name [gid]``). duplicates: topic -> repeated identical
    messages of one step from the expected node. shared_names: topic -> one line on each owner name that had
    several publishers there (which GID was used, which were ignored).
    """

    checked: bool = True
    used: dict[str, Counter] = field(default_factory=dict)
    foreign: dict[str, Counter] = field(default_factory=dict)
    duplicates: Counter = field(default_factory=Counter)
    shared_names: dict[str, str] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {"checked": self.checked,
                "used": {t: dict(c) for t, c in self.used.items()},
                "foreign": {t: dict(c) for t, c in self.foreign.items()},
                "foreign_messages": sum(sum(c.values()) for c in self.foreign.values()),
                "duplicates": dict(self.duplicates), "shared_names": dict(self.shared_names)}

    def warnings(self, bag: object) -> list[str]:
        """One line per finding worth telling the user (unchecked publishers, foreign messages, duplicates); the
        bag's names in them have their control characters escaped."""
        return [printable(line) for line in self._warnings(bag)]

    def _warnings(self, bag: object) -> list[str]:
        lines = []
        if not self.checked:
            lines.append(f"warning: bag {bag} does not record who published its messages (recorded before publisher "
                         "identities were kept, or by another recorder): their publishers cannot be checked")
        for topic, counts in self.foreign.items():
            names = ", ".join(f"{name} ({n})" for name, n in counts.most_common())
            lines.append(f"warning: bag {bag}: ignored {sum(counts.values())} {topic} messages from foreign "
                         f"publishers: {names}")
        for topic, line in self.shared_names.items():
            lines.append(f"warning: bag {bag}: {topic}: {line}")
        for topic, n in self.duplicates.items():
            lines.append(f"warning: bag {bag}: {n} duplicate {topic} messages (the same step twice, equal) ignored")
        return lines


def _equal(a: Any, b: Any) -> bool:
    return bool(np.array_equal(a, b)) if isinstance(a, np.ndarray) or isinstance(b, np.ndarray) else a == b


def participant(gid: str) -> str:
    """The DDS participant (process) part of a GID in dotted hex: its first 12 bytes, the GUID prefix."""
    return gid[:35]


def owner_name(name: str) -> str:
    """A node name as a fully qualified one (``body_sim`` -> ``/body_sim``; ``/ns/body_sim`` as it is)."""
    return name if name.startswith("/") else f"/{name}"


class OwnMessages:
    """Keeps the messages of each topic's expected node and files them by step.

    ``expected`` maps a topic to the fully qualified name of the node that owns it (``/ns/node``; a name without a
    leading ``/`` is in the root namespace), or None to accept any publisher on it. ``publishers``: topic -> GID ->
    (publisher, message count) of every publisher the bag records (:func:`~bptsb_ros.bags.reader.topic_publishers`);
    with it, an owner name with several publishers on a topic is resolved to one GID (module docstring).
    """

    def __init__(self, bag: object, expected: dict[str, str | None],
                 publishers: Mapping[str, Mapping[str, tuple[PublisherId, int]]] | None = None) -> None:
        self.bag = bag
        self.expected = {t: None if n is None else owner_name(n) for t, n in expected.items()}
        self.report = Provenance()
        self._senders: dict[tuple[str, int], PublisherId | None] = {}
        #: topic -> the owner's GID there, for topics where the owner's name has several publishers
        self.owner_gid: dict[str, str] = self._resolve_shared_names(publishers or {})

    def _resolve_shared_names(self, publishers: Mapping[str, Mapping[str, tuple[PublisherId, int]]]) -> dict[str, str]:
        named = {t: {gid: n for gid, (p, n) in publishers.get(t, {}).items() if p.name == owner}
                 for t, owner in self.expected.items() if owner is not None}
        votes: dict[str, Counter] = {}  # owner name -> participant -> topics it publishes under that name
        for topic, gids in named.items():
            votes.setdefault(self.expected[topic], Counter()).update({participant(g) for g in gids})
        chosen: dict[str, str] = {}
        for topic, gids in named.items():
            if len(gids) < 2:
                continue
            owner = self.expected[topic]
            ranked = votes[owner].most_common()
            counts = ", ".join(f"{g} ({n} messages)" for g, n in gids.items())
            best = ranked[0][0] if len(ranked) == 1 or ranked[0][1] > ranked[1][1] else None
            mine = [g for g in gids if best is not None and participant(g) == best]
            if len(mine) != 1:
                raise BagError(f"bag {self.bag}: {len(gids)} publishers named {owner} sent {topic}: {counts}; which "
                               f"one is {owner} cannot be told (none shares its process with {owner}'s publishers "
                               "of more other topics than the rest): the run cannot be replayed from an ambiguous "
                               "record")
            chosen[topic] = mine[0]
            others = ", ".join(f"{g} ({n} messages)" for g, n in gids.items() if g != mine[0])
            self.report.shared_names[topic] = (
                f"{len(gids)} publishers are named {owner}; used {mine[0]} ({gids[mine[0]]} messages, the process "
                f"that publishes {owner}'s other topics), ignored {others}")
        return chosen

    def keep(self, topic: str, publisher: PublisherId | None) -> bool:
        """Whether a message of ``topic`` from ``publisher`` may be used (counts it either way)."""
        if publisher is None:
            self.report.checked = False
            self.report.used.setdefault(topic, Counter())["unknown publisher"] += 1
            return True
        owner = self.expected.get(topic)
        if owner is not None and publisher.name != owner:
            self.report.foreign.setdefault(topic, Counter())[publisher.name] += 1
            return False
        gid = self.owner_gid.get(topic)
        if gid is not None and publisher.gid != gid:
            self.report.foreign.setdefault(topic, Counter())[f"{publisher.name} [{publisher.gid}]"] += 1
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
