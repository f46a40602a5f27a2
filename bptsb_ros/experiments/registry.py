"""Every paper experiment that ``bptsb reproduce`` can run, by name.

An experiment is a function ``run(ctx: Context) -> None`` registered with :func:`experiment`. It reads its
settings for the chosen scale from ``ctx.settings`` (its packaged ``settings/<name>.yaml`` with the run's
``--set`` overrides: :mod:`~bptsb_ros.experiments.experiment_settings`), writes its figures into ``ctx.out_dir``
and records rows, claims and figures on ``ctx.result``. The runner (:func:`run_experiment`) times it and
writes ``result.json``.

Experiment modules are listed in :data:`MODULES` and imported on first use, so ``--list`` stays fast and
each module registers itself on import.
"""

from __future__ import annotations

import importlib
import json
import math
import platform
import shutil
import stat
import subprocess
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bptsb_ros.experiments.experiment_settings import Overrides, Settings, resolve_settings
from bptsb_ros.experiments.result import (
    EXPERIMENT_SLUG,
    MAX_SLUG_LEN,
    RESULT_FILE,
    SCALES,
    Claim,
    ExperimentResult,
    ResultError,
    Row,
    write_result,
)
from bptsb_ros.experiments.seed_dirs import SEEDS_MARKER
from bptsb_ros.files.run_dir_lock import LOCK_NAME, dir_is_empty, hold_run_dir
from bptsb_ros.files.safe_write import UnsafeFileError, write_atomic
from bptsb_ros.jobs.runner import Placement

#: modules holding experiments, in the order of the paper
MODULES: tuple[str, ...] = (
    # "Division of functional roles" (Fig. 2) and the MNIST supplement
    "bptsb_ros.experiments.mnist_drawing",
    "bptsb_ros.experiments.mnist_pca",
    "bptsb_ros.experiments.mnist_labelmap",
    "bptsb_ros.experiments.mnist_specific100",
    "bptsb_ros.experiments.mnist_readout",
    # "Distribution of computational properties" (Fig. 3) and the time-series supplement
    "bptsb_ros.experiments.narma_emulation",
    "bptsb_ros.experiments.narma_ipc",
    "bptsb_ros.experiments.memory_task",
    "bptsb_ros.experiments.target_ipc",
    "bptsb_ros.experiments.msdn_nonlinearity",
    # "Autonomous behavior through brain function transfer" (Fig. 4) and the SWG supplement
    "bptsb_ros.experiments.lissajous_closed_loop",
    "bptsb_ros.experiments.lissajous_perturbation",
    "bptsb_ros.experiments.lissajous_switching",
    "bptsb_ros.experiments.closed_loop_schemes",
    "bptsb_ros.experiments.locomotion_closed_loop",
    "bptsb_ros.experiments.locomotion_perturbation",
    "bptsb_ros.experiments.locomotion_headwind",
)

#: written into every run directory; ``--force`` replaces only directories that hold it
RUN_MARKER = ".bptsb-reproduce"
#: one record per attempt of a run (the first and each ``--resume``), so the result's wall time spans them all
ATTEMPTS_FILE = ".bptsb-attempts.json"


class ExperimentError(RuntimeError):
    """An experiment cannot run (unknown name, bad scale, output exists); one line for the user."""


@dataclass
class Context:
    """What an experiment run gets: the scale, the seed, where to write, and the result to fill."""

    scale: str
    seed: int
    out_dir: Path
    result: ExperimentResult
    progress: bool = True
    #: where independent trainings run (:mod:`bptsb_ros.jobs.runner`): local worker processes (None: the CPUs
    #: available, at smoke scale this process; 0: this process) or a Dask scheduler address
    workers: int | None = None
    scheduler: str | None = None
    log: Callable[[str], None] = field(default=lambda msg: print(msg, file=sys.stderr, flush=True))
    #: the data directory an experiment reads (``--data DIR``), or None: the experiment's own default
    data_dir: Path | None = None
    #: the train/test split to use (``--split``; what it means is the experiment's data loader's business)
    split: str = "auto"
    #: the experiment's settings at this scale, ``--set`` overrides applied (``ctx.settings["epochs"]``)
    settings: Mapping[str, Any] = field(default_factory=dict)

    def placement(self) -> Placement:
        """Where this run's independent jobs go: ``--scheduler``, else ``--workers`` processes; without either,
        one per CPU, except at smoke scale, where the jobs run in this process (they take less time than
        starting a worker)."""
        workers = self.workers
        if workers is None and self.scheduler is None and self.scale == "smoke":
            workers = 0
        return Placement(workers, self.scheduler)

    def run_jobs(self, fn: Callable[..., Any], jobs: Sequence[tuple], *, names: Sequence[str] | None = None,
                 what: str | None = None) -> list[Any]:
        """``fn(*args)`` for every ``args`` of ``jobs`` where :meth:`placement` says (one BLAS and torch thread
        each); results in job order; a failure raises ``JobFailed`` naming the job. ``what`` names the batch in
        the provenance, which records where the jobs ran (default: the function's name)."""
        from bptsb_ros.jobs.runner import run_jobs

        what = what or getattr(fn, "__name__", "jobs")
        placement = self.placement()
        if len(jobs) > 1 or placement.scheduler:
            self.log(f"{what}: {len(jobs)} jobs on {self._where(placement, len(jobs))}")
        results, info = run_jobs(fn, jobs, placement, names=names)
        self.result.provenance.setdefault("jobs", []).append({"what": what, **info.to_json()})
        return results

    def sweep(self, jobs: Sequence[Any], out_dir: Path, *, what: str = "jobs", gangs: bool = False) -> Any:
        """Run ``jobs`` (``bptsb_ros.jobs.sweep.Job``) as a resumable sweep in ``out_dir`` where :meth:`placement`
        says; progress lines go to :attr:`log`; the provenance records where they ran. Returns the
        ``SweepResult`` (failed jobs are in its records, not raised).

        ``gangs``: the jobs run as one gang per worker (:mod:`bptsb_ros.jobs.gang`, their held-force windows as one
        batched simulation): runs of ⌈jobs / workers⌉ consecutive jobs, so jobs of one body next to each other
        share a gang."""
        from bptsb_ros.jobs.sweep import run_sweep

        placement = self.placement()
        n_gangs = self.slots(len(jobs)) if gangs and jobs else None
        where = self._where(placement, len(jobs))
        self.log(f"{what}: {len(jobs)} jobs in {out_dir} on {where}" + (f", as {n_gangs} gangs" if n_gangs else ""))
        last = [""]

        def show(p) -> None:
            if p.line() != last[0]:
                last[0] = p.line()
                self.log(p.line())

        res = run_sweep(jobs, out_dir, workers=placement.workers, scheduler=placement.scheduler, progress=show,
                        n_gangs=n_gangs)
        self.result.provenance.setdefault("jobs", []).append({"what": what, **res.provenance()})
        return res

    def slots(self, jobs: int) -> int:
        """How many of ``jobs`` jobs run at once where :meth:`placement` says (≥ 1): the local pool's processes,
        or on a cluster (whose worker count is unknown before connecting) ``--workers``, else the local CPUs."""
        from bptsb_ros.jobs.runner import cpus

        placement = self.placement()
        return max(1, (placement.workers or cpus()) if placement.scheduler else placement.pool_size(jobs))

    @staticmethod
    def _where(placement: Placement, jobs: int) -> str:
        if placement.scheduler:
            return f"the Dask scheduler {placement.scheduler}"
        n = placement.pool_size(jobs)
        return "this process" if n == 0 else f"a local pool of {n} process{'es' if n > 1 else ''}"

    def phase(self, what: str) -> None:
        """One line, ``<experiment>: <what> ...``, as a phase of seconds that shows no progress of its own starts
        (a test simulation, the plots); progress, like the bars: not with ``progress`` off (``--no-progress``)."""
        if self.progress:
            self.log(f"{self.result.experiment}: {what} ...")

    def row(self, system: str, metric: str, unit: str, ours: float | None, paper: float | str | None = None) -> None:
        self.result.rows.append(Row(system, metric, unit, ours, paper))

    def judge(self, fn: Callable[..., list[Claim]], *args: Any, label: str = "", **kwargs: Any) -> list[Claim]:
        """The claims of the registered claim function ``fn(*args, **kwargs)`` (:func:`~bptsb_ros.experiments.
        measured.judge`), each prefixed with ``label``, appended to the result; the call and its arguments are
        recorded in ``result.measured`` so the claims can be judged again from the stored numbers
        (:func:`~bptsb_ros.experiments.measured.rejudge`). Returns the claims as recorded."""
        from bptsb_ros.experiments.measured import record

        entry = record(fn, args, kwargs, label)
        claims = [Claim(label + c.claim, c.holds, c.evidence) for c in fn(*args, **kwargs)]
        self.result.measured.append(entry)
        self.result.claims.extend(claims)
        return claims

    def sibling_run(self, experiment: str) -> Path:
        """Where a run of ``experiment`` beside this one lies, for the same seed: ``OUT/../EXPERIMENT`` for a
        single run, ``OUT/../../EXPERIMENT/seed-N`` when this run is seed N of a multi-seed run
        (``bptsb reproduce --seeds``). The path may not exist; what lies there is checked by whoever reads it."""
        from bptsb_ros.experiments.seed_dirs import in_multi_seed_run

        here = self.out_dir
        if in_multi_seed_run(here):
            return here.parent.parent / experiment / here.name
        return here.parent / experiment

    def claim(self, claim: str, holds: bool | None, evidence: str) -> bool | None:
        """Record a paper claim with the computed verdict (None: not testable, ``evidence`` names the failed
        premise); returns the verdict as recorded (True, False or None)."""
        recorded = Claim(claim, holds, evidence)
        self.result.claims.append(recorded)
        return recorded.holds

    def not_testable(self, claim: str, premise: str) -> None:
        """Record a paper claim that cannot be tested because ``premise`` (what failed, in words) failed."""
        self.result.claims.append(Claim.not_testable(claim, premise))

    def figure(self, path: Path) -> Path:
        """Register a figure written inside ``out_dir``."""
        self.result.figures.append(str(Path(path).resolve().relative_to(self.out_dir.resolve())))
        return path


@dataclass(frozen=True)
class Experiment:
    name: str
    paper_ref: str
    summary: str
    run: Callable[[Context], None]
    #: the run spreads several independent trainings over ``--workers`` (so ``--seeds`` runs its seeds one after
    #: another, each with every worker, rather than side by side)
    parallel: bool = False


_REGISTRY: dict[str, Experiment] = {}


def experiment(name: str, *, paper_ref: str, summary: str, parallel: bool = False):
    """Decorator registering ``run(ctx)`` as the paper experiment ``name`` (a slug: its result.json must
    pass :func:`~bptsb_ros.experiments.result.validate_result`, so a bad name fails here, not after the run).
    How long it takes at each scale is data: :mod:`~bptsb_ros.experiments.durations`."""
    if len(name) > MAX_SLUG_LEN or not EXPERIMENT_SLUG.fullmatch(name):
        raise ValueError(f"experiment name {name!r} is not a slug ([a-z0-9][a-z0-9_-]*)")

    def register(fn: Callable[[Context], None]) -> Callable[[Context], None]:
        if name in _REGISTRY and _REGISTRY[name].run is not fn:
            raise ValueError(f"experiment {name!r} registered twice")
        _REGISTRY[name] = Experiment(name, paper_ref, summary, fn, parallel)
        return fn

    return register


def experiments() -> dict[str, Experiment]:
    """All experiments, in paper order: the order of :data:`MODULES` (whatever order the modules were imported
    in), then registration order within a module; experiments of other modules (tests, plug-ins) follow."""
    for module in MODULES:
        importlib.import_module(module)
    rank = {module: i for i, module in enumerate(MODULES)}
    ordered = sorted(enumerate(_REGISTRY.items()),
                     key=lambda item: (rank.get(item[1][1].run.__module__, len(rank)), item[0]))
    return {name: exp for _, (name, exp) in ordered}


def get_experiment(name: str) -> Experiment:
    found = experiments()
    if name not in found:
        raise ExperimentError(f"unknown experiment {name!r}; `bptsb reproduce --list` names them all")
    return found[name]


def _git_commit() -> str | None:
    """The package checkout's commit (``-dirty`` when tracked files differ from it); None outside a checkout."""
    here = Path(__file__).resolve().parent
    try:
        out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, timeout=5,
                             cwd=here)
        commit = out.stdout.strip() if out.returncode == 0 else ""
        if not commit:
            return None
        status = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], capture_output=True,
                                text=True, timeout=10, cwd=here)
    except (OSError, subprocess.SubprocessError):
        return None
    return commit + ("-dirty" if status.returncode == 0 and status.stdout.strip() else "")


def _package_version() -> str:
    from bptsb_ros import __version__

    return __version__


def _library_versions() -> dict[str, str | None]:
    """The versions of the libraries a result's numbers depend on (None: not installed)."""
    from importlib.metadata import PackageNotFoundError, version

    found: dict[str, str | None] = {}
    for dist in ("numpy", "torch", "numba", "scipy", "scikit-learn"):
        try:
            found[dist] = version(dist)
        except PackageNotFoundError:
            found[dist] = None
    return found


def run_experiment(name: str, *, scale: str = "smoke", seed: int = 0, out_dir: str | Path | None = None,
                   force: bool = False, resume: bool = False, progress: bool = True,
                   log: Callable[[str], None] | None = None, workers: int | None = None,
                   scheduler: str | None = None, data_dir: str | Path | None = None,
                   split: str = "auto", settings: Overrides | None = None) -> tuple[Path, dict[str, Any]]:
    """Run one experiment and write ``out_dir/result.json``; returns (its path, its content).

    Arguments as :func:`execute_experiment`, which returns the :class:`ExperimentResult` itself.
    """
    path, result = execute_experiment(name, scale=scale, seed=seed, out_dir=out_dir, force=force, resume=resume,
                                      progress=progress, log=log, workers=workers, scheduler=scheduler,
                                      data_dir=data_dir, split=split, settings=settings)
    return path, result.to_json()


def execute_experiment(name: str, *, scale: str = "smoke", seed: int = 0, out_dir: str | Path | None = None,
                       force: bool = False, resume: bool = False, progress: bool = True,
                       log: Callable[[str], None] | None = None, workers: int | None = None,
                       scheduler: str | None = None, data_dir: str | Path | None = None,
                       split: str = "auto", settings: Overrides | None = None) -> tuple[Path, ExperimentResult]:
    """Run one experiment and write ``out_dir/result.json``; returns (its path, the result).

    ``workers``/``scheduler`` say where experiments with independent trainings run them (``bptsb_ros.jobs.sweep``);
    ``data_dir`` and ``split`` are passed to experiments that read a data set (MNIST). A non-empty ``out_dir``
    (an earlier run) is kept unless ``force``, which removes it first, and only if it is an earlier run (it holds
    :data:`RUN_MARKER`); a failed run writes no result.json. ``resume`` continues such an unfinished run in place
    (experiments whose trainings are sweep jobs keep the finished jobs; mnist-readout's trainings continue after
    their last epoch). ``settings`` overrides the experiment's
    packaged settings (``--set`` texts ``key=value`` or a mapping; SettingsError before anything is touched).
    """
    exp = get_experiment(name)
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 0):
        raise ExperimentError(f"--workers must be a whole number >= 0 (0: in this process), got {workers!r}")
    if scale not in SCALES:
        raise ExperimentError(f"scale must be one of {', '.join(SCALES)}, got {scale!r}")
    resolved = resolve_settings(exp.name, scale, settings)
    out = Path(out_dir) if out_dir is not None else Path("runs") / "reproduce" / name
    if resume and not (out / RUN_MARKER).is_file():
        raise ExperimentError(f"--resume continues an unfinished `bptsb reproduce` run, and {out} is not one "
                              f"(no {RUN_MARKER})")
    if out.exists() and not out.is_dir():
        raise ExperimentError(f"{out} exists and is not a directory; choose another --out")
    with ExitStack() as held:
        try:  # RunDirLocked (not an OSError): another bptsb process works in out; nothing was touched
            held.enter_context(hold_run_dir(out))
        except OSError as err:
            raise ExperimentError(f"cannot create the output directory {out}: {err.strerror or err}") from None
        return _run_locked(exp, out, scale=scale, seed=seed, force=force, resume=resume, progress=progress,
                           log=log, workers=workers, scheduler=scheduler, data_dir=data_dir, split=split,
                           settings=resolved)


def _run_locked(exp: Experiment, out: Path, *, scale: str, seed: int, force: bool, resume: bool, progress: bool,
                log: Callable[[str], None] | None, workers: int | None, scheduler: str | None,
                data_dir: str | Path | None, split: str, settings: Settings) -> tuple[Path, ExperimentResult]:
    """:func:`run_experiment` once this process holds ``out``'s lock."""
    name = exp.name
    if resume:
        if not (out / RUN_MARKER).is_file():
            raise ExperimentError(f"--resume continues an unfinished `bptsb reproduce` run, and {out} is not one "
                                  f"(no {RUN_MARKER})")
        if (out / RESULT_FILE).exists():
            raise ExperimentError(f"{out / RESULT_FILE} exists: that run finished (pass --force to run it again)")
    elif not dir_is_empty(out):
        what = out / RESULT_FILE if (out / RESULT_FILE).exists() else out
        if not force:
            raise ExperimentError(f"{what} exists; choose another --out or pass --force to replace the run there")
        if not (out / RUN_MARKER).is_file():
            raise ExperimentError(f"--force replaces only an earlier `bptsb reproduce` run, and {out} is not one "
                                  f"(no {RUN_MARKER}); remove it yourself or choose another --out")
        _clear_run(out)  # nothing of the earlier run (jobs of another scale, say) may leak into this one
    try:
        write_atomic(out / RUN_MARKER, f"bptsb reproduce {name}\n")
    except (OSError, UnsafeFileError) as err:
        raise ExperimentError(f"cannot create the output directory {out}: {getattr(err, 'strerror', None) or err}") \
            from None
    result = ExperimentResult(exp.name, exp.paper_ref, scale, int(seed), settings=settings.to_json())
    command = f"bptsb reproduce {name} --scale {scale} --seed {seed} --out {out}" + (" --resume" if resume else "")
    if data_dir is not None:
        command += f" --data {data_dir}"
    if split != "auto":
        command += f" --split {split}"
    command += "".join(f" {arg}" for arg in settings.override_args())
    result.provenance = {
        "command": command + (f" --scheduler {scheduler}" if scheduler else f" --workers {workers}"
                              if workers is not None else ""),
        **base_provenance(),
        # what the independent jobs really used, one entry per batch (Context.run_jobs / Context.sweep):
        # scheduler (its address, "local pool" or "this process"), workers, jobs, ran_in (distinct processes)
        "jobs": [],
    }
    ctx = Context(scale, int(seed), out, result, progress=progress, workers=workers, scheduler=scheduler,
                  data_dir=None if data_dir is None else Path(data_dir), split=split, settings=settings)
    if log is not None:
        ctx.log = log
    attempts = _start_attempt(out, resume=resume)
    t0 = time.perf_counter()
    try:
        exp.run(ctx)
    except BaseException:
        if not resume and _holds_only_bookkeeping(out):
            _clear_run(out)  # it failed before it made anything: the same command can run again as it is
        raise
    finally:  # a failed or interrupted attempt that made something records its time, for the --resume that follows
        if (out / RUN_MARKER).is_file():
            attempts[-1]["wall_s"] = round(time.perf_counter() - t0, 2)
            _write_attempts(out, attempts)
    result.wall_s = round(sum(a["wall_s"] for a in attempts), 2)
    result.provenance["attempts"] = attempts
    result.judged = judged_by(complete=_rejudges_to_itself(result, ctx.log))
    path = write_result(out, result)
    return path, result


def base_provenance() -> dict[str, Any]:
    """What every result records of where it was made: Python, package and library versions, machine, commit."""
    return {"python": platform.python_version(), "package_version": _package_version(),
            "versions": _library_versions(), "machine": f"{platform.machine()}, {_cpu_count()} cores",
            "git_commit": _git_commit()}


def judged_by(*, complete: bool, rejudged: bool = False) -> dict[str, Any]:
    """Which code judged a result's claims: the package version, its git commit, a digest of the experiments'
    code (:func:`~bptsb_ros.experiments.measured.claim_code_digest`), whether every claim can be judged again
    from the stored numbers (``complete``) and whether this is such a judgement (``rejudged``)."""
    from bptsb_ros.experiments.measured import claim_code_digest

    return {"package_version": _package_version(), "git_commit": _git_commit(), "code_digest": claim_code_digest(),
            "complete": bool(complete), "rejudged": bool(rejudged),
            "at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}


def _rejudges_to_itself(result: ExperimentResult, log: Callable[[str], None]) -> bool:
    """True when judging ``result.measured`` again gives exactly ``result.claims`` (every claim went through
    :meth:`Context.judge`); else a warning line, and a later ``--rejudge`` cannot recompute this run's claims."""
    from bptsb_ros.experiments.measured import rejudge

    try:
        again = rejudge(result.measured)
    except (ResultError, ValueError, TypeError) as err:
        log(f"{result.experiment}: warning: the stored numbers do not judge again ({err})")
        return False
    if again != result.claims:
        log(f"{result.experiment}: warning: {len(result.claims)} claims, but the stored numbers judge "
            f"{len(again)} (or others); `--rejudge` cannot recompute this run's claims")
        return False
    return True


def _start_attempt(out: Path, *, resume: bool) -> list[dict[str, Any]]:
    """The attempts of this run so far (the earlier ones only on ``--resume``) plus this one, written to
    :data:`ATTEMPTS_FILE`. An earlier attempt that was killed before it could record its time gets the span
    from its start to the newest file it left in ``out`` (a lower bound; ``"wall_s_estimated": true``)."""
    earlier: list[dict[str, Any]] = []
    if resume:
        earlier = _read_attempts(out)
        for i, att in enumerate(earlier):
            if "wall_s" not in att:
                until = earlier[i + 1]["started_unix"] if i + 1 < len(earlier) else time.time()
                newest = _newest_mtime(out, after=att["started_unix"], before=until)
                att["wall_s"] = round(max(0.0, newest - att["started_unix"]), 2)
                att["wall_s_estimated"] = True
    now = time.time()
    attempts = [*earlier, {"started": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(now)),
                           "started_unix": round(now, 3), "resume": bool(resume)}]
    _write_attempts(out, attempts)
    return attempts


def _read_attempts(out: Path) -> list[dict[str, Any]]:
    """The attempts recorded in ``out``; an absent or unreadable record (a run from before attempts were
    recorded, a damaged file) counts as none, so the wall time is then this attempt's alone."""
    try:
        data = json.loads((out / ATTEMPTS_FILE).read_text())
    except (OSError, ValueError):
        return []
    if not isinstance(data, list):
        return []
    good = []
    now = time.time()
    for att in data:
        if not isinstance(att, dict) or not _seconds(att.get("started_unix")) or not 0 < att["started_unix"] <= now:
            continue  # an attempt needs a real start, in the past
        if "wall_s" in att and not (_seconds(att["wall_s"]) and att["wall_s"] >= 0):
            continue
        kept = {k: att[k] for k in ("started", "started_unix", "resume", "wall_s") if k in att}
        if att.get("wall_s_estimated") is True:
            kept["wall_s_estimated"] = True  # an estimate stays one through later resumes
        good.append(kept)
    return sorted(good, key=lambda a: a["started_unix"])


def _seconds(value: Any) -> bool:
    """``value`` is a finite number of seconds (not a bool, not NaN or infinite, which JSON files may hold)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _write_attempts(out: Path, attempts: list[dict[str, Any]]) -> None:
    try:
        write_atomic(out / ATTEMPTS_FILE, json.dumps(attempts, indent=1) + "\n")
    except (OSError, UnsafeFileError):
        pass  # the record only improves the wall time of a later --resume; the run itself goes on


def _newest_mtime(out: Path, *, after: float, before: float) -> float:
    """The newest modification time in [after, before] of a file under ``out`` (``after`` if there is none).
    Only what the experiment wrote counts: not the run's bookkeeping files (marker, attempts, lock, the seeds
    marker), which the next attempt rewrites before it times the killed one, and not folders, whose times also
    change when anything is removed from them (a tidy-up after the kill is not the attempt's work)."""
    newest = after
    for path in out.rglob("*"):
        if path.name in (ATTEMPTS_FILE, RUN_MARKER, LOCK_NAME, SEEDS_MARKER):
            continue
        try:
            st = path.stat()
        except OSError:
            continue
        if stat.S_ISREG(st.st_mode) and after <= st.st_mtime <= before:
            newest = max(newest, st.st_mtime)
    return newest


def _holds_only_bookkeeping(out: Path) -> bool:
    """``out`` holds nothing but this run's marker, attempts record and lock (the experiment wrote nothing yet)."""
    return all(entry.name in (RUN_MARKER, ATTEMPTS_FILE, LOCK_NAME) for entry in out.iterdir())


def _clear_run(out: Path) -> None:
    """Remove an earlier reproduce run's contents, keeping ``out`` itself and the lock this process holds."""
    for entry in out.iterdir():
        if entry.name == LOCK_NAME:
            continue
        if entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry)
        else:
            entry.unlink()


def _cpu_count() -> int:
    import os

    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
