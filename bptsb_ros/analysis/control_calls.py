"""The simulator-service calls a bag recorded: every ``~/pause``, ``~/resume``, ``~/step`` and ``~/reset`` call of
the body, with the nodes that called it, from the ``<node>: control`` statuses ``body_sim`` publishes on
``/diagnostics`` (:mod:`bptsb_ros.live.sim_control`).

A call is *foreign* when, at the call, a node not allowed by the body's ``control_callers`` had a client of the
service (``untrusted_callers``: the body refused it), or when the statuses were published by a node other than the
run's body (a forger on ``/diagnostics``). ``bptsb replay`` lists the calls in ``metrics.json`` and warns about foreign
ones.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

#: the diagnostics topic key and the status name suffix of a control call
CONTROL_STATUS = ": control"


def _split(text: str) -> list[str]:
    return [part.strip() for part in text.split(",") if part.strip()]


def control_calls(bag: str | Path, namespace: str = "", body_node: str = "body_sim") -> list[dict[str, Any]]:
    """Every control call of the bag, in the order recorded: ``call``, ``step``, ``accepted``, ``callers`` and
    ``untrusted_callers`` (lists of node names), ``publisher`` (the node that published the status, when the bag
    knows it) and ``foreign`` (see the module docstring). Raises BagError for a bag that cannot be read."""
    from bptsb_ros.bags.reader import list_topics, read_published

    topic = f"{namespace}/diagnostics" if namespace else "/diagnostics"
    if topic not in list_topics(bag):
        return []
    body = f"{namespace}/{body_node}" if namespace else f"/{body_node}"
    out = []
    for (_topic, _type, _t, msg), publisher in read_published(bag, [topic]):
        name = publisher.name if publisher is not None and publisher.node else ""  # '' : the bag does not know
        for status in msg.status:
            if not str(status.name).endswith(CONTROL_STATUS):
                continue
            values = {str(kv.key): str(kv.value) for kv in status.values}
            untrusted = _split(values.get("untrusted_callers", ""))
            forged = bool(name) and name != body
            out.append({"call": values.get("call", ""), "step": int(values.get("step", "-1") or -1),
                        "accepted": values.get("accepted") == "True", "callers": _split(values.get("callers", "")),
                        "untrusted_callers": untrusted, "publisher": name or None,
                        "foreign": bool(untrusted) or forged})
    return out


def summary(calls: list[dict[str, Any]]) -> dict[str, Any]:
    """``metrics.json``'s ``control_calls``: the count, the foreign ones, and every call."""
    return {"count": len(calls), "foreign": sum(c["foreign"] for c in calls), "calls": calls}


def warnings(calls: list[dict[str, Any]], bag: str | Path) -> list[str]:
    """One line per foreign call (for stderr)."""
    lines = []
    for c in calls:
        if not c["foreign"]:
            continue
        who = ", ".join(c["untrusted_callers"]) or f"a status published by {c['publisher']}"
        lines.append(f"replay: {bag}: a ~/{c['call']} call after step {c['step']} came from outside the loop ({who}); "
                     f"the body {'accepted' if c['accepted'] else 'refused'} it")
    return lines
