"""What a recorded run lost (ROS-free): the recorder's own count, checked against what the body published.

The recorder counts the messages it knows it missed (gaps in each publisher's sequence numbers, middleware reports,
a final drain cut short: :class:`bptsb_ros.bags.recording.LossCount`) and writes them into the bag's
``custom_data``. It cannot see messages that never reached it at the very end of a run; ``body_sim`` counts what it
published per topic (``published_messages`` in its summary), so for the body's topics the loss is also the
difference between that and the bag's messages from ``body_sim``. :func:`recording_loss` takes the larger of the two
per topic; ``bptsb launch`` fails the run when it is not zero (unless ``--allow-loss``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from bptsb_ros.bags.metadata import read_metadata
from bptsb_ros.bags.reader import bag_info
from bptsb_ros.bags.recording import recorded_loss


@dataclass
class RecordingLoss:
    """Messages lost per topic; ``counted``: the recorder's own total (None: the bag has no count, recorded by an
    older recorder); ``complete``: False when the recorder's final drain was cut short (more may be missing)."""

    by_topic: dict[str, int] = field(default_factory=dict)
    counted: int | None = None
    complete: bool = True

    @property
    def total(self) -> int:
        return sum(self.by_topic.values())

    @property
    def any(self) -> bool:
        return self.total > 0 or not self.complete

    def describe(self) -> str:
        """``lost 12 messages (/clock 9, /body/positions 3)``, and whether the drain was cut short."""
        parts = ", ".join(f"{t} {n}" for t, n in self.by_topic.items() if n)
        text = f"lost {self.total} messages" + (f" ({parts})" if parts else "")
        return text + ("; the recorder's final drain was cut short, more may be missing" if not self.complete else "")

    def to_dict(self) -> dict:
        return {"dropped_messages": self.total, "dropped_by_topic": dict(self.by_topic),
                "recorder_counted": self.counted, "recording_complete": self.complete}


def recording_loss(bag: str | Path, published: dict[str, int] | None = None,
                   body_node: str = "body_sim") -> RecordingLoss:
    """The loss of a recorded run: per topic the larger of the recorder's count and, for the topics in
    ``published`` (topic -> messages the body published), how many of them the bag lacks from ``body_node``
    (from any publisher when the bag does not record publishers). Raises BagError for an unreadable bag."""
    counted, per_topic, complete = recorded_loss(read_metadata(bag).custom_data)
    by_topic = dict(per_topic)
    if published:
        recorded: dict[str, int] = {}
        for c in bag_info(bag).publishers:
            if c.publisher is None or c.publisher.node == body_node:
                recorded[c.topic] = recorded.get(c.topic, 0) + c.count
        for topic, n in published.items():
            missing = max(0, int(n) - recorded.get(topic, 0))
            by_topic[topic] = max(by_topic.get(topic, 0), missing)
    return RecordingLoss({t: n for t, n in sorted(by_topic.items()) if n}, counted, complete)
