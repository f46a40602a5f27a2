"""The live "see a digit, draw it" loop (``bptsb launch mnist_drawing``), ROS-free: what its nodes compute.

* An MNIST system file (written by :func:`bptsb_ros.tasks.drawing.save_system`) is an *agent* of the live
  nodes: :func:`system_agent` wraps its body and the whole :class:`ImageToBody` (as the brain) so that every node
  of the loop gets the same body in the same dtype (``live.agent_source.load_source`` calls it).
* Episodes have a fixed length of ``episode_steps`` E steps (default :func:`default_episode_steps`: the longest
  digit target's steps + 1). Image i of the stream is shown at step k_i = i·E (:func:`shown_image`); the body is
  reset at k_i to the image's displacement and released, and draws for E steps (rows k_i..k_i + E − 1), which is
  ``ImageToBody.release(displacement, E − 1)``.
* The stream is a pair of IDX files (images (n, 28, 28) uint8, labels (n,)), gz or not (:func:`read_stream`).
  Pixels become the brain's input exactly as in training: uint8 / 255 in float32 (:func:`pixels`).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from bptsb_ros.data.mnist import MnistError, read_idx

if TYPE_CHECKING:
    from bptsb_ros.agent import Agent
    from bptsb_ros.tasks.drawing import ImageToBody

#: ``task`` of the agent :func:`system_agent` builds
TASK = "mnist_drawing"
IMAGE_SIDE = 28


class SystemFileError(ValueError):
    """An MNIST system file is missing, unreadable or not a system; the message names the file."""


def _read_payload(path: str | Path) -> tuple[dict[str, Any] | None, str]:
    """(payload of a system file, '') or (None, why it is not one). Loaded as data only (``weights_only``): a file
    that holds anything but tensors, numbers, strings, lists and dicts is refused, and never runs."""
    import pickle

    path = Path(path)
    if path.is_dir():
        return None, "a directory without a system file (systems/<name>.pt)"
    if not path.is_file():
        return None, "no such file"
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as err:
        from bptsb_ros.training.checkpoint import _unpickler_detail

        detail = _unpickler_detail(str(err))
        if "Unsupported global" in detail:
            return None, (f"refused: it holds objects other than tensors, numbers, strings, lists and dicts "
                          f"({detail}); system files are loaded as data only, never as code")
        return None, f"unreadable ({detail})"
    except Exception as err:  # noqa: BLE001 - torch raises many types for a damaged file
        return None, f"unreadable ({str(err)[:200]})"
    if isinstance(payload, dict) and {"spec", "state"} <= set(payload):
        return payload, ""
    return None, "not an MNIST system file (save_system writes them: systems/<name>.pt of the drawing experiments)"


def system_file(path: str | Path) -> Path | None:
    """The system file ``path`` names: the file itself, or, for a run directory of the MNIST experiments (no
    training ``checkpoint.pt``), its only system file (``*.pt`` or ``systems/*.pt``); None when there is none.
    Raises SystemFileError when the directory holds several (name one)."""
    path = Path(path)
    if not path.is_dir():
        return path
    if (path / "checkpoint.pt").is_file():
        return None  # a training run directory
    found = [p for p in sorted(path.glob("*.pt")) + sorted(path.glob("systems/*.pt")) if system_payload(p) is not None]
    if len(found) > 1:
        raise SystemFileError(f"{path} holds {len(found)} system files ({', '.join(p.name for p in found)}); "
                              "name one of them")
    return found[0] if found else None


def system_payload(path: str | Path) -> dict[str, Any] | None:
    """The payload of a system file (keys ``spec``, ``state``, ``extra``), or None when ``path`` is not a file
    holding one (a run directory, a training checkpoint, a refused or damaged file)."""
    return _read_payload(path)[0]


def is_system_file(path: str | Path) -> bool:
    """True when ``path`` is an MNIST system file or a run directory holding exactly one (:func:`system_file`;
    SystemFileError when it holds several)."""
    found = system_file(path)
    return found is not None and system_payload(found) is not None


def load_system_as(path: str | Path, dtype: torch.dtype = torch.float64) -> ImageToBody:
    """The system of ``path`` (a system file, or a run directory holding one: :func:`system_file`) in ``dtype``,
    parameters frozen. Raises :class:`SystemFileError` naming the file."""
    from bptsb_ros.tasks.drawing import ImageToBody, SystemSpec

    path = system_file(path) or Path(path)
    payload, why = _read_payload(path)
    if payload is None:
        raise SystemFileError(f"system file {path}: {why}")
    try:
        system = ImageToBody(SystemSpec.from_json(json.loads(payload["spec"])))
        system.load_state_dict(payload["state"])
    except (TypeError, ValueError, KeyError, RuntimeError) as err:
        raise SystemFileError(f"{path}: not a valid MNIST system ({str(err)[:300]})") from None
    system.to(dtype)
    system.requires_grad_(False)
    return system


def system_agent(path: str | Path, dtype: torch.dtype = torch.float64) -> Agent:
    """An :class:`~bptsb_ros.agent.Agent` of the system in ``path``: its body, the whole ImageToBody as brain,
    no feedback layer; ``config`` names the task, the body (shape, nodes, size, dt) and the system spec."""
    from bptsb_ros.agent import Agent

    system = load_system_as(path, dtype)
    spec = system.spec
    config = {"task": TASK, "dtype": {torch.float64: "float64", torch.float32: "float32"}[dtype],
              "body": {"shape": spec.shape, "nodes": spec.nodes, "size": spec.size, "dt": spec.dt},
              "mnist": spec.to_json()}
    return Agent(config, system.body, system, None)


def default_episode_steps(dt: float) -> int:
    """E: the longest digit target's steps + 1, so that every digit's drawing fits in one episode."""
    from bptsb_ros.tasks.drawing import DigitTargets

    return DigitTargets(dt).t_max + 1


def image_step(index: int, episode_steps: int) -> int:
    """k_i = i·E: the step at which image ``index`` of the stream is shown and the body reset."""
    return index * episode_steps


def shown_image(step: int, episode_steps: int, count: int) -> int | None:
    """Index of the stream image shown at ``step`` (``step`` = i·E with i < ``count``), else None."""
    if episode_steps < 1:
        raise ValueError(f"episode_steps must be >= 1, got {episode_steps}")
    if step < 0 or step % episode_steps:
        return None
    index = step // episode_steps
    return index if index < count else None


def read_stream(images: str | Path, labels: str | Path, first: int = 0,
                count: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Images (n, 28, 28) uint8 and labels (n,) int64 of a stream: ``count`` items (0: all) from ``first`` on.

    Raises MnistError naming the file: unreadable, not IDX, wrong shapes, labels outside 0-9, or fewer items
    than ``first`` + ``count``.
    """
    x = read_idx(images)
    y = read_idx(labels)
    if x.ndim != 3 or x.shape[1:] != (IMAGE_SIDE, IMAGE_SIDE):
        raise MnistError(f"{images}: expected images of shape (n, 28, 28), got {x.shape}")
    if y.ndim != 1 or y.shape[0] != x.shape[0]:
        raise MnistError(f"{labels}: expected {x.shape[0]} labels (one per image), got shape {y.shape}")
    if y.size and int(y.max()) > 9:
        raise MnistError(f"{labels}: labels must be digits 0-9, found {int(y.max())}")
    if first < 0 or count < 0:
        raise MnistError(f"first and count must be >= 0, got {first} and {count}")
    end = x.shape[0] if count == 0 else first + count
    if first >= x.shape[0] or end > x.shape[0]:
        raise MnistError(f"{images} holds {x.shape[0]} images; first {first} and count {count} ask for images "
                         f"{first}..{end - 1}")
    return np.ascontiguousarray(x[first:end]), y[first:end].astype(np.int64)


def pixels(images: np.ndarray) -> torch.Tensor:
    """(B, 28, 28) or (B, 784) uint8 → (B, 784) float32 in [0, 1], pixel / 255 (as ``data.mnist`` loads them)."""
    x = np.asarray(images)
    if x.dtype != np.uint8:
        raise ValueError(f"images must be uint8 pixels, got {x.dtype}")
    return torch.from_numpy(x.reshape(x.shape[0], -1).astype(np.float32) / 255.0)
