"""Replay of a live ``mnist_drawing`` bag: each episode's drawing over its target, the per-digit error, and the
offline drawing of the same system and the same recorded images.

The run is split into episodes at the steps where ``camera/image`` showed an image (k_i = i·E, E =
``episode_steps`` from the bag's ``custom_data``): the CMP trajectory of rows k_i..k_i + E − 1 relative to its rest
position (its layout position, where every reset leaves it) is the episode's drawing, as
``ImageToBody.release`` returns it. The live error of an episode is the MSE against its label's target over the
target's own steps (``DigitTargets.errors``); the offline error is that of ``system.draw`` on the recorded images
in float64. They agree when the live loop equals the offline drawing (lockstep: to ~1e-12).
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch

from bptsb_ros.analysis.provenance import OwnMessages, Provenance
from bptsb_ros.bags.errors import BagError
from bptsb_ros.bags.reader import list_topics, read_published, topic_publishers
from bptsb_ros.files.safe_write import json_text, write_atomic
from bptsb_ros.interface.topics import NS_PER_S, TOPICS, absolute


def _topic(key: str) -> str:
    return absolute(TOPICS[key].name)


def _step(msg: Any, dt_ns: int) -> int:
    s = msg.header.stamp
    return int((int(s.sec) * NS_PER_S + int(s.nanosec) + dt_ns // 2) // dt_ns)


def read_stream_topics(bag: str | Path, dt: float, skip_damaged: bool = False, provenance: Provenance | None = None
                       ) -> tuple[dict[int, np.ndarray], dict[int, int], dict[int, np.ndarray]]:
    """{step: image (28, 28) uint8}, {step: label}, {step: reset displacement (2M,) [m]} recorded in ``bag``, from
    their owners only (``image_streamer``, ``mnist_brain``: :mod:`bptsb_ros.analysis.provenance`); what was left out
    is added to ``provenance``."""
    topics = list_topics(bag)
    need = [_topic("image"), _topic("label")]
    missing = [t for t in need if t not in topics]
    if missing:
        raise BagError(f"bag {bag} lacks {', '.join(missing)}: not a recording of the mnist_drawing loop")
    wanted = need + ([_topic("reset_cmd")] if _topic("reset_cmd") in topics else [])
    dt_ns = round(dt * NS_PER_S)
    images: dict[int, np.ndarray] = {}
    labels: dict[int, int] = {}
    resets: dict[int, np.ndarray] = {}
    own = OwnMessages(bag, {_topic("image"): "/image_streamer", _topic("label"): "/image_streamer",
                            _topic("reset_cmd"): "/mnist_brain"}, topic_publishers(bag))
    if provenance is not None:
        own.report = provenance
    for (topic, _type, _t, msg), publisher in read_published(bag, wanted, skip_damaged=skip_damaged):
        if not own.keep(topic, publisher):
            continue
        k = _step(msg, dt_ns)
        if topic == _topic("image"):
            if msg.encoding != "mono8" or (msg.height, msg.width) != (28, 28) or len(msg.data) != 784:
                raise BagError(f"bag {bag}: the image of step {k} is not mono8 28 x 28")
            own.put(images, k, np.frombuffer(bytes(msg.data), dtype=np.uint8).reshape(28, 28), topic, publisher)
        elif topic == _topic("label"):
            own.put(labels, k, int(round(msg.position[0])), topic, publisher)
        else:
            own.put(resets, k, np.asarray(msg.position, dtype=np.float64), topic, publisher)
    return images, labels, resets


def replay_mnist(bag: str | Path, out_dir: str | Path, system_path: str | Path | None = None, *, gif: bool = True,
                 skip_damaged: bool = False, body_node: str = "body_sim") -> dict[str, Any]:
    """Analyse a ``mnist_drawing`` bag; writes ``metrics.json`` and ``drawings.png`` (and ``replay.gif``) to
    ``out_dir`` and returns the metrics. With ``system_path`` (the system file, never a path from the bag) the
    recorded images are drawn offline too and compared."""
    from bptsb_ros.analysis.bag_run import animate_run, read_run, recording_summary
    from bptsb_ros.tasks.drawing import DigitTargets
    from bptsb_ros.tasks.mnist_live import load_system_as, pixels

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    system = load_system_as(system_path) if system_path is not None else None
    run = read_run(bag, dt=system.spec.dt if system is not None else None, skip_damaged=skip_damaged,
                   body_node=body_node, loop="mnist_drawing")
    images, labels, resets = read_stream_topics(bag, run.dt, skip_damaged, run.provenance)
    for line in run.provenance.warnings(bag):
        print(line, file=sys.stderr, flush=True)
    shown = sorted(set(images) & set(labels))
    if not shown:
        raise BagError(f"bag {bag} holds no image with its label")
    episode_steps = int(run.custom.get("episode_steps", 0)) or (int(np.diff(shown).min()) if len(shown) > 1 else 0)
    if episode_steps <= 0:
        raise BagError(f"bag {bag}: no episode_steps in its custom_data and a single image; cannot split episodes")
    if system is not None:
        cmp = system.body.topology.cmp_index
        rest = system.body.positions0[cmp].numpy()
    else:
        cmp = run.cmp_index
        if cmp < 0:
            raise BagError("the drawing needs the CMP (from body/markers) or the system (--agent)")
        rest = None
    row = {int(k): i for i, k in enumerate(run.steps)}
    complete = [k for k in shown if all(j in row for j in range(k, k + episode_steps))]
    if not complete:
        raise BagError(f"bag {bag}: no episode of {episode_steps} steps was recorded completely")
    live = np.stack([run.positions[[row[j] for j in range(k, k + episode_steps)], cmp] for k in complete])
    live = live - (rest if rest is not None else live[:, :1])  # relative to the CMP's rest position
    y = torch.as_tensor([labels[k] for k in complete])
    targets = DigitTargets(run.dt, torch.float64)
    live_t = torch.from_numpy(live)
    live_err = targets.errors(live_t, y).numpy()
    metrics: dict[str, Any] = {
        "bag": str(bag), "agent": str(system_path) if system_path is not None else None, "loop": "mnist_drawing",
        "mode": run.custom.get("mode"), "dt": run.dt, "recorded_steps": int(len(run.steps)),
        "missing_steps": len(run.missing_steps), "publishers": run.provenance.to_dict(),
        "recording": recording_summary(run.custom),
        "episode_steps": episode_steps, "episodes": len(complete),
        "incomplete_episodes": len(shown) - len(complete), "reset_steps": [int(k) for k in complete],
        "labels": y.tolist(),
        "live": {"metric": "drawing_mse", "errors": live_err.tolist(), "drawing_mse": float(live_err.mean()),
                 "per_digit": per_digit(live_err, y.numpy())},
    }
    offline = None
    if system is not None:
        x = pixels(np.stack([images[k] for k in complete]))
        with torch.no_grad():
            disp = system.displacement(x)
            offline = system.release(disp, episode_steps - 1, adjoint=False).numpy()
        off_err = targets.errors(torch.from_numpy(offline), y).numpy()
        metrics["offline"] = {"metric": "drawing_mse", "errors": off_err.tolist(), "drawing_mse": float(off_err.mean()),
                              "per_digit": per_digit(off_err, y.numpy())}
        comparison = {"max_abs_drawing_difference_m": float(np.abs(live - offline).max()),
                      "max_abs_error_difference_m2": float(np.abs(live_err - off_err).max()),
                      "episodes_compared": len(complete)}
        recorded = [k for k in complete if k in resets]
        if recorded:
            sent = np.stack([resets[k] for k in recorded])
            ref = disp[[complete.index(k) for k in recorded]].reshape(len(recorded), -1).numpy()
            comparison["max_abs_reset_difference_m"] = float(np.abs(sent - ref).max())
        metrics["offline_comparison"] = comparison
    from bptsb_ros.analysis.mnist_plots import plot_live_drawings

    files = [out_dir / "metrics.json",
             plot_live_drawings(out_dir / "drawings.png", live, offline, [targets.padded[d, : int(targets.steps[d]) + 1]
                                                                          .numpy() for d in range(10)],
                                y.numpy(), live_err, run.dt, [int(k) for k in complete])]
    if gif and len(run.springs):
        files.append(animate_run(out_dir / "replay.gif", run))
    metrics["files"] = [str(f) for f in files]
    write_atomic(out_dir / "metrics.json", json_text(metrics, indent=2))
    return metrics


def per_digit(errors: np.ndarray, labels: np.ndarray) -> dict[str, float]:
    """Mean error [m²] of each digit present: {"0": ..., ...}."""
    return {str(d): float(errors[labels == d].mean()) for d in sorted(set(labels.tolist()))}
