"""Jobs: independent trainings in a local process pool or on a Dask cluster, resumable sweeps of them, and gangs
(several trainings batched in one process)."""
