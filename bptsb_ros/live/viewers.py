"""Viewer configurations of one robot: the RViz config and the Foxglove layout of the package (``config/bptsb.rviz``,
``config/foxglove_layout.json``) for a loop in a namespace.

A loop in namespace ``/robot1`` has its topics under ``/robot1/...`` and stamps its body in frame ``robot1/msdn``
(:func:`frame_id`; the launchers set ``body_sim``'s ``frame_id``), so two robots in one domain never share a frame.
The package's files name the root loop (fixed frame ``msdn``, topics ``/body/...``); :func:`rviz_config_text` and
:func:`foxglove_layout` rewrite them for a namespace. ``bptsb launch`` writes both into its log folder
(``BAG.launch/`` with ``--bag``), and ``rviz:=true`` of the launch files starts rviz2 with the namespace's config.

No TF is needed: every message of the body is stamped in its own frame, which is the viewer's fixed frame. To show
two robots in one view, publish a static transform from a common frame to each robot's frame and make that common
frame the fixed frame.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from bptsb_ros.interface.topics import TOPICS, absolute

#: the body's frame at the root namespace (``body_sim``'s ``frame_id`` default)
BODY_FRAME = "msdn"


def frame_id(namespace: str) -> str:
    """The body frame of a loop in ``namespace`` (normalized, '' for the root): ``robot1/msdn`` for ``/robot1``."""
    ns = namespace.strip("/")
    return f"{ns}/{BODY_FRAME}" if ns else BODY_FRAME


def _loop_topic_prefixes() -> tuple[str, ...]:
    return tuple(sorted({absolute(t.name) for t in TOPICS.values()}, key=len, reverse=True))


def namespaced_topic(text: str, namespace: str) -> str:
    """``text`` with a leading loop topic (``/body/positions``, ``/clock``, ... maybe followed by a message path such
    as ``.poses[-1].position.x``) moved into ``namespace``; any other text as it is."""
    ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
    if not ns:
        return text
    for topic in _loop_topic_prefixes():
        if text == topic or text.startswith(topic + ".") or text.startswith(topic + "["):
            return ns + text
    return text


def foxglove_layout(layout: Any, namespace: str) -> Any:
    """The Foxglove layout (parsed JSON) for a loop in ``namespace``: every loop topic (keys and values, plotted
    message paths included) in the namespace, every ``msdn`` frame the namespace's body frame."""
    if isinstance(layout, dict):
        return {namespaced_topic(k, namespace): foxglove_layout(v, namespace) for k, v in layout.items()}
    if isinstance(layout, list):
        return [foxglove_layout(v, namespace) for v in layout]
    if isinstance(layout, str):
        return frame_id(namespace) if layout == BODY_FRAME else namespaced_topic(layout, namespace)
    return layout


def rviz_config_text(text: str, namespace: str) -> str:
    """The RViz config ``text`` for a loop in ``namespace``: its fixed frame the namespace's body frame (its topics
    are relative: rviz2 started in the namespace resolves them there)."""
    return re.sub(r"^(\s*Fixed Frame:)\s*\S+\s*$", rf"\1 {frame_id(namespace)}", text, flags=re.M)


def write_viewer_configs(out_dir: str | Path, namespace: str) -> list[Path]:
    """Write ``bptsb.rviz`` and ``foxglove_layout.json`` for a loop in ``namespace`` into ``out_dir`` (new files
    only: one that exists is left as it is); returns the paths written."""
    import json

    from bptsb_ros.files.package_data import config_dir

    out, src = Path(out_dir), config_dir()
    texts = {}
    if (src / "bptsb.rviz").is_file():
        texts["bptsb.rviz"] = rviz_config_text((src / "bptsb.rviz").read_text(), namespace)
    if (src / "foxglove_layout.json").is_file():
        layout = json.loads((src / "foxglove_layout.json").read_text())
        texts["foxglove_layout.json"] = json.dumps(foxglove_layout(layout, namespace), indent=2) + "\n"
    written = []
    for name, text in texts.items():
        try:
            with (out / name).open("x") as stream:
                stream.write(text)
        except FileExistsError:
            continue
        written.append(out / name)
    return written
