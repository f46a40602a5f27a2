"""Checkpoints: ``<run_dir>/checkpoint.pt`` holds the resolved config, every module's state_dict, the
optimiser state and the trainer position, so a run can resume and an agent can be reloaded anywhere
(offline simulation, the live ROS nodes, replay analysis).

A checkpoint is data, never code: it holds only tensors, numbers, strings, lists and dicts and is read
with ``torch.load(weights_only=True)``, which refuses any other pickled object (a crafted file whose
``__reduce__`` would run code is rejected before anything in it runs). Every reader in the package goes
through :func:`read_checkpoint`.
"""

from __future__ import annotations

import pickle
from pathlib import Path
from typing import Any

import torch

from bptsb_ros.agent import Agent, build_agent
from bptsb_ros.config import validate
from bptsb_ros.files.safe_write import atomic_writer

CHECKPOINT = "checkpoint.pt"


class CheckpointError(RuntimeError):
    """A run directory has no readable checkpoint."""


def checkpoint_path(run_dir: str | Path) -> Path:
    path = Path(run_dir)
    return path if path.suffix == ".pt" else path / CHECKPOINT


def save_checkpoint(run_dir: str | Path, agent: Agent, extra: dict[str, Any] | None = None,
                    modules: dict[str, dict[str, torch.Tensor]] | None = None) -> Path:
    """Write the checkpoint atomically (temp file + rename: a crash never leaves half a file).

    ``modules`` (name → state_dict) replaces the agent's current state dicts, e.g. a snapshot of the last
    parameters known to be good. Everything written is plain data that ``weights_only=True`` loads.
    """
    path = checkpoint_path(run_dir)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "format": 1,
        "config": agent.config,
        "modules": modules if modules is not None else {name: m.state_dict() for name, m in agent.modules().items()},
        "extra": extra or {},
    }
    with atomic_writer(path) as f:
        torch.save(payload, f)
    return path


def read_checkpoint(run_dir: str | Path) -> dict[str, Any]:
    path = checkpoint_path(run_dir)
    if not path.is_file():
        raise CheckpointError(f"no checkpoint at {path} (train one with `bptsb train CONFIG --out RUN_DIR`)")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as err:
        detail = _unpickler_detail(str(err))
        if "Unsupported global" in detail:
            raise CheckpointError(
                f"checkpoint {path} is refused: it holds objects other than tensors, numbers, strings, lists and "
                f"dicts ({detail}); checkpoints are loaded as data only, never as code") from None
        raise CheckpointError(f"checkpoint {path} is unreadable: {detail}") from None
    except Exception as err:  # noqa: BLE001 - torch raises many types for a damaged file
        raise CheckpointError(f"checkpoint {path} is unreadable: {str(err)[:300]}") from None
    if not isinstance(payload, dict) or payload.get("format") != 1:
        raise CheckpointError(f"{path} is not a bptsb_ros checkpoint")
    return payload


def _unpickler_detail(message: str) -> str:
    """The one informative line of torch's weights-only error (its advice to load unsafely is left out)."""
    marker = "WeightsUnpickler error:"
    text = message.split(marker, 1)[1] if marker in message else message
    line = next((part.strip() for part in text.strip().splitlines() if part.strip()), "")
    return line.split(" was not an allowed global")[0][:200]


def load_agent(run_dir: str | Path, dtype: torch.dtype | None = None) -> Agent:
    """Rebuild the agent saved in ``run_dir`` (parameters frozen: requires_grad False).

    ``dtype`` converts the whole agent (e.g. float64 for exact comparisons).
    """
    payload = read_checkpoint(run_dir)
    agent = build_agent(validate(payload["config"], f"in {checkpoint_path(run_dir)}"))
    for name, module in agent.modules().items():
        state = payload["modules"].get(name)
        if state is None:
            raise CheckpointError(f"checkpoint {checkpoint_path(run_dir)} lacks the {name!r} module")
        module.load_state_dict(state)
    for module in agent.modules().values():
        module.requires_grad_(False)
        if dtype is not None:
            module.to(dtype)
    extra = payload.get("extra")
    agent.feedback_fitted = agent.feedback is not None and isinstance(extra, dict) and \
        bool(extra.get("feedback_fitted", False))
    return agent


def feedback_fitted(run_dir: str | Path) -> bool:
    """True when the checkpoint holds a fitted feedback layer."""
    return bool(read_checkpoint(run_dir)["extra"].get("feedback_fitted", False))
