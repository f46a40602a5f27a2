"""The errors of a sweep, apart from the runner so that the Dask connection code (:mod:`bptsb_ros.jobs.dask_cluster`)
and :mod:`bptsb_ros.jobs.sweep` can both raise them without importing each other."""

from __future__ import annotations


class SweepError(ValueError):
    """A sweep cannot start (bad job names, bad seeds, bad or unreachable scheduler); one line for the user."""


class SchedulerError(SweepError):
    """The Dask scheduler could not be reached or did not answer as one (a runtime failure, not a usage error)."""
