"""Tasks: what the agent must do, how its loss is computed per update, and the paper's metric."""

from __future__ import annotations

from bptsb_ros.tasks.base import Task


def get_task(name: str) -> type[Task]:
    """Task class by config name."""
    if name == "lissajous":
        from bptsb_ros.tasks.lissajous import LissajousTask

        return LissajousTask
    if name == "locomotion":
        from bptsb_ros.tasks.locomotion import LocomotionTask

        return LocomotionTask
    if name == "narma":
        from bptsb_ros.tasks.narma import NarmaTask

        return NarmaTask
    raise ValueError(f"unknown task {name!r}; choose lissajous, locomotion or narma")


__all__ = ["Task", "get_task"]
