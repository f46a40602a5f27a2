"""Workflows: a config turned into a training run — the task built from ``cfg.task``, the training, the run
directory (checkpoints, ``metrics.json``, the task's figures) — for one agent (:mod:`~bptsb_ros.workflows.train`,
behind ``bptsb train`` and ``bp.train``) or a population of agents trained side by side
(:mod:`~bptsb_ros.workflows.population`).

This room sits above :mod:`bptsb_ros.training` (the update machinery, which knows no task), :mod:`bptsb_ros.tasks`
and :mod:`bptsb_ros.analysis` (the figures); experiments, sweeps and the CLI call it.
"""
