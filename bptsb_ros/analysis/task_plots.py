"""The figures a training run writes for its task (``bptsb train --out DIR``): the Lissajous trajectories, the
locomotion speed, the NARMA / memory series of the held-out sequence.

Each reads the task's evaluation (``task.evaluate()``, run here if the task has not evaluated yet) and draws it with
:mod:`bptsb_ros.analysis.plots`; the task classes themselves draw nothing.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any


def _evaluation(task: Any) -> dict[str, Any]:
    if not hasattr(task, "_eval"):
        task.evaluate()
    return task._eval


def lissajous_figures(task: Any, out_dir: Path) -> list[Path]:
    """``lissajous.png``: the open-loop (SWG) and, where fitted, closed-loop trajectories against the target."""
    from bptsb_ros.analysis.plots import plot_lissajous

    e = _evaluation(task)
    path = out_dir / "lissajous.png"
    curves = {"open loop (SWG)": e["open"]}
    if "closed" in e:
        curves["closed loop (FL), next run"] = e["closed"]
    plot_lissajous(path, e["t"], curves, task.target(e["t"]))
    return [path]


def locomotion_figures(task: Any, out_dir: Path) -> list[Path]:
    """``speed.png``: the forward speed of the open and closed loops against the target speed."""
    from bptsb_ros.analysis.plots import plot_speed

    e = _evaluation(task)
    labels = {"open": "open loop (SWG)", "closed": "closed loop (FL), next run"}
    path = out_dir / "speed.png"
    plot_speed(path, e["t"], {labels[k]: v for k, v in e.items() if k != "t"}, task.target_speed_now(),
               window=task.block)
    return [path]


def narma_figures(task: Any, out_dir: Path) -> list[Path]:
    """``narma.png``: input, target and output over the held-out sequence, the test part shaded."""
    from bptsb_ros.analysis.plots import plot_series

    e = _evaluation(task)
    n = task.cfg.narma
    path = out_dir / "narma.png"
    title = (f"memory task Δt = {n.delay}" if n.target == "memory" else f"expanded NARMA{n.order}")
    plot_series(path, {"input u": e["u"], "target y": e["y"], "output (CMP y)": e["out"]},
                "sample [τ steps]", "u [-]; target y, output (CMP y) [m]", title=f"{title}, held-out sequence",
                shade=(n.train_end, n.n_inputs))
    return [path]


#: task name (``Task.name``) → the function that writes its figures into a folder and returns their paths
TASK_FIGURES: dict[str, Callable[[Any, Path], list[Path]]] = {
    "lissajous": lissajous_figures,
    "locomotion": locomotion_figures,
    "narma": narma_figures,
}


def task_figures(task: Any, out_dir: Path) -> list[Path]:
    """The figures of ``task`` (by its ``name``) written into ``out_dir``; none for a task without figures."""
    draw = TASK_FIGURES.get(getattr(task, "name", ""))
    return draw(task, out_dir) if draw is not None else []
