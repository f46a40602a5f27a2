"""Seeds as an axis: ``bptsb reproduce NAME --seeds 0-9`` runs the experiment once per seed and aggregates.

One run is one draw: trainings at the paper's rates amplify rounding, so a verdict read off one seed is a coin
flip. :func:`run_seeds` runs one experiment per seed as independent jobs of the one runner (a local process
pool or a Dask cluster; :mod:`bptsb_ros.jobs.runner`), each seed in ``OUT/seed-N/`` with its own ``result.json``
exactly as ``--seed N`` would write it, then writes the aggregate ``OUT/result.json``
(:func:`~bptsb_ros.experiments.result.validate_aggregate` gives its schema):

- each row: the mean over the seeds with a value, the sample standard deviation, the minimum, the maximum and
  the per-seed values; where the paper gives a number, whether it lies inside our seeds' range;
- each claim: in how many seeds it holds of those that could test it (``holds_in: [k, n]``), how many could not,
  the per-seed verdicts, and the verdict over seeds of
  :func:`~bptsb_ros.experiments.claim_rules.verdict_over_seeds` (95 % Wilson interval of k/n above ½: holds,
  below: fails, else split; not testable when fewer than half the seeds could test it).

``--resume`` keeps every seed that finished, resumes the unfinished ones and starts the rest; a seed that fails
does not stop the others, and the run then exits naming the failed seeds, with no aggregate, until a
``--resume`` finishes them. :func:`rejudge_run` judges a finished run's claims again from its stored numbers
(:mod:`~bptsb_ros.experiments.measured`) and aggregates again, without training.
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bptsb_ros.experiments.claim_rules import verdict_over_seeds, wilson_interval
from bptsb_ros.experiments.result import (
    MAX_SEEDS,
    RESULT_FILE,
    ResultError,
    read_result,
    validate_result,
)
from bptsb_ros.experiments.seed_dirs import (
    MAX_SEED,
    SEEDS_MARKER,
    SeedsError,
    format_seeds,
    seed_dir_name,
)

# ----------------------------------------------------------------------------------------------- aggregation


def _mean_sd(values: list[float]) -> tuple[float, float]:
    arr = np.asarray(values, dtype=float)
    return float(arr.mean()), float(arr.std(ddof=1)) if len(arr) > 1 else 0.0


def _row_key(row: Mapping[str, Any]) -> tuple[str, str, str]:
    return row["system"], row["metric"], row["unit"]


def aggregate_rows(per_seed: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """The rows of several seeds' results, matched by (system, metric, unit) and, where one result repeats that
    key, by its occurrence; in the first seed's order, then rows only later seeds have."""
    keyed: list[dict[tuple, Mapping[str, Any]]] = []
    order: list[tuple] = []
    for res in per_seed:
        seen: dict[tuple, int] = {}
        rows = {}
        for row in res["rows"]:
            base = _row_key(row)
            seen[base] = seen.get(base, 0) + 1
            key = (*base, seen[base])
            rows[key] = row
            if key not in order:
                order.append(key)
        keyed.append(rows)
    out = []
    for key in order:
        values = [rows[key]["ours"] if key in rows else None for rows in keyed]
        have = [v for v in values if v is not None]
        paper = next((rows[key]["paper"] for rows in keyed if key in rows and rows[key]["paper"] is not None), None)
        row: dict[str, Any] = {"system": key[0], "metric": key[1], "unit": key[2], "n": len(have),
                               "per_seed": values, "paper": paper}
        if have:
            mean, sd = _mean_sd(have)
            lo, hi = min(have), max(have)
            row.update(ours=min(max(mean, lo), hi), ours_sd=sd, ours_min=lo, ours_max=hi)
        else:
            row.update(ours=None, ours_sd=None, ours_min=None, ours_max=None)
        numeric_paper = isinstance(paper, (int, float)) and not isinstance(paper, bool)
        row["paper_in_range"] = bool(lo <= paper <= hi) if have and numeric_paper else None
        out.append(row)
    return out


def aggregate_claims(per_seed: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """The claims of several seeds' results, matched by their text (in the first seed's order, then claims only
    later seeds made; a seed that made no such claim counts as not testable for it), each with its verdict over
    the seeds (:func:`~bptsb_ros.experiments.claim_rules.verdict_over_seeds`)."""
    order: list[str] = []
    keyed: list[dict[str, Mapping[str, Any]]] = []
    for res in per_seed:
        claims = {}
        for c in res["claims"]:
            claims.setdefault(c["claim"], c)
            if c["claim"] not in order:
                order.append(c["claim"])
        keyed.append(claims)
    n_seeds = len(per_seed)
    out = []
    for text in order:
        verdicts = [claims[text]["holds"] if text in claims else None for claims in keyed]
        evidence = [claims[text]["evidence"] if text in claims else "this seed's run made no such claim"
                    for claims in keyed]
        k, n = sum(v is True for v in verdicts), sum(v is not None for v in verdicts)
        verdict = verdict_over_seeds(k, n, n_seeds)
        interval = list(wilson_interval(k, n)) if n else None
        words = f"holds in {k} of {n} seeds that could test it"
        if interval:
            words += f" (95 % Wilson interval {interval[0]:.2f}–{interval[1]:.2f})"
        if n < n_seeds:
            reasons = list(dict.fromkeys(_short(e) for v, e in zip(verdicts, evidence, strict=True) if v is None))
            words += f"; not testable in {n_seeds - n}, e.g. " + reasons[0] + (
                f" (and {len(reasons) - 1} other reason{'s' if len(reasons) > 2 else ''})" if len(reasons) > 1 else "")
        out.append({"claim": text, "verdict": verdict, "holds_in": [k, n], "not_testable_in": n_seeds - n,
                    "per_seed": verdicts, "interval": interval, "evidence": words, "per_seed_evidence": evidence})
    return out


def _short(text: str, limit: int = 240) -> str:
    return text if len(text) <= limit else text[:limit - 1].rstrip() + "…"


def aggregate(per_seed: Sequence[Mapping[str, Any]], seeds: Sequence[int], *, wall_s: float,
              figures: Sequence[str] = (), provenance: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The aggregate result.json of ``per_seed`` (each a valid single-seed result of one experiment and scale, in
    the order of ``seeds``); ResultError when they are not results of one experiment, scale and settings."""
    if not per_seed or len(per_seed) != len(seeds):
        raise ResultError(f"{len(per_seed)} results for {len(seeds)} seeds")
    first = per_seed[0]
    for seed, res in zip(seeds, per_seed, strict=True):
        if res["seed"] != seed:
            raise ResultError(f"the result of seed {seed} was made with seed {res['seed']}")
        for key in ("experiment", "scale", "settings"):
            if res.get(key) != first.get(key):
                raise ResultError(f"seed {seed}'s result has another {key} than seed {seeds[0]}'s "
                                  f"({str(res.get(key))[:60]} vs {str(first.get(key))[:60]})")
    commits = sorted({str((r.get("provenance") or {}).get("git_commit")) for r in per_seed})
    judges = sorted({str((r.get("judged") or {}).get("code_digest")) for r in per_seed})
    data: dict[str, Any] = {
        "experiment": first["experiment"], "paper_ref": first["paper_ref"], "scale": first["scale"],
        "seeds": list(seeds), "wall_s": round(float(wall_s), 2), "rows": aggregate_rows(per_seed),
        "claims": aggregate_claims(per_seed), "figures": list(figures),
        "seed_runs": {str(s): seed_dir_name(s) for s in seeds},
        "settings": first.get("settings", {}),
        "details": {"seed_wall_s": {str(s): r["wall_s"] for s, r in zip(seeds, per_seed, strict=True)},
                    "seed_commits": commits, "claim_code": judges},
        "provenance": dict(provenance or {}),
    }
    validate_result(data, "aggregate")
    return data


# ------------------------------------------------------------------------------------------------ running

#: experiment → its across-seed figures: ``fn(out_dir, per_seed_results, seeds) -> [paths written in out_dir]``
SeedFigures = Callable[[Path, Sequence[Mapping[str, Any]], Sequence[int]], list[Path]]
_SEED_FIGURES: dict[str, SeedFigures] = {}


def seed_figure(experiment: str) -> Callable[[SeedFigures], SeedFigures]:
    """Register ``fn(out_dir, per_seed, seeds)`` as ``experiment``'s across-seed figures (drawn into the
    multi-seed run's folder from the seeds' result.json; :func:`~bptsb_ros.experiments.measured.stored_calls`
    gives back the numbers a claim function was called with)."""
    def register(fn: SeedFigures) -> SeedFigures:
        _SEED_FIGURES[experiment] = fn
        return fn

    return register



def _seed_job(name: str, scale: str, seed: int, out: str, resume: bool, overrides: dict[str, Any],
              data_dir: str | None, split: str, workers: int | None, scheduler: str | None,
              progress: bool) -> dict[str, Any]:
    """One seed's run (in a worker or this process): ``{"seed", "error": None | text, "wall_s"}``; an error is
    returned, not raised, so one failed seed does not stop the others."""
    from bptsb_ros.experiments.registry import execute_experiment

    t0 = time.perf_counter()

    def log(msg: str) -> None:
        print(f"[seed {seed}] {msg}", file=sys.stderr, flush=True)

    try:
        execute_experiment(name, scale=scale, seed=seed, out_dir=out, resume=resume, progress=progress, log=log,
                           workers=workers, scheduler=scheduler, data_dir=data_dir, split=split,
                           settings=overrides or None)
    except Exception as err:  # noqa: BLE001 - a failed seed is reported by name; the others go on
        return {"seed": seed, "error": f"{type(err).__name__}: {err}", "wall_s": time.perf_counter() - t0}
    return {"seed": seed, "error": None, "wall_s": time.perf_counter() - t0}


def seed_state(seed_dir: Path, *, experiment: str, scale: str, seed: int,
               settings: Mapping[str, Any]) -> str:
    """``"finished"`` (a valid result.json of this experiment, scale, seed and settings), ``"unfinished"`` (a
    reproduce run without one: resume it) or ``"new"``; SeedsError for a folder that is none of these."""
    from bptsb_ros.experiments.registry import RUN_MARKER
    from bptsb_ros.files.run_dir_lock import dir_is_empty

    if seed_dir.is_symlink() or (seed_dir.exists() and not seed_dir.is_dir()):
        raise SeedsError(f"{seed_dir} is not a directory of this run")
    if not seed_dir.exists() or dir_is_empty(seed_dir):
        return "new"
    if not (seed_dir / RUN_MARKER).is_file():
        raise SeedsError(f"{seed_dir} holds files that are not a `bptsb reproduce` run; move them away")
    if not (seed_dir / RESULT_FILE).exists():
        return "unfinished"
    try:
        res = read_result(seed_dir / RESULT_FILE)
    except ResultError as err:
        raise SeedsError(str(err)) from None
    if (res.get("seeds") is not None or res["experiment"] != experiment or res["scale"] != scale
            or res["seed"] != seed or res.get("settings") != dict(settings)):
        raise SeedsError(f"{seed_dir / RESULT_FILE} is a run of other settings (experiment, scale, seed or --set); "
                         "move it away or choose another --out")
    return "finished"


def plan_placement(parallel: bool, workers: int | None, scheduler: str | None, scale: str,
                   n_seeds: int) -> tuple[Any, int | None]:
    """Where the seeds run and with how many workers each seed's own trainings run: (the seeds' placement, the
    ``workers`` each seed's experiment gets). On a Dask cluster every seed is a job and runs its trainings in its
    worker; locally an experiment whose run spreads several trainings over ``--workers`` (``parallel``) takes the
    seeds one after another, each with every worker, and any other runs its seeds side by side in the pool, each
    in one process — so the cores stay busy either way (at smoke scale everything runs in this process)."""
    from bptsb_ros.jobs.runner import Placement

    if scheduler:
        return Placement(None, scheduler), 0
    if workers == 0 or (workers is None and scale == "smoke") or n_seeds == 1:
        return Placement(0), workers
    if parallel:
        return Placement(0), workers
    return Placement(workers), 0


def run_seeds(name: str, seeds: Sequence[int], *, scale: str = "smoke", out_dir: str | Path | None = None,
              force: bool = False, resume: bool = False, progress: bool = True,
              log: Callable[[str], None] | None = None, workers: int | None = None, scheduler: str | None = None,
              data_dir: str | Path | None = None, split: str = "auto",
              settings: Any = None) -> tuple[Path, dict[str, Any]]:
    """Run experiment ``name`` once per seed of ``seeds`` into ``OUT/seed-N/`` and write the aggregate
    ``OUT/result.json``; returns (its path, its content). Arguments as
    :func:`~bptsb_ros.experiments.registry.run_experiment`. ``resume`` reuses the seeds that finished, resumes
    the unfinished and runs the rest (a finished run's seeds list may be extended this way); ``force`` replaces
    an earlier reproduce run in ``OUT``. Raises SeedsError naming the seeds that failed (no aggregate is
    written; ``--resume`` finishes them)."""
    from contextlib import ExitStack

    from bptsb_ros.experiments.experiment_settings import resolve_settings
    from bptsb_ros.experiments.registry import (
        RUN_MARKER,
        ExperimentError,
        _clear_run,
        _start_attempt,
        _write_attempts,
        base_provenance,
        get_experiment,
    )
    from bptsb_ros.files.run_dir_lock import dir_is_empty, hold_run_dir

    log = log or (lambda msg: print(msg, file=sys.stderr, flush=True))
    exp = get_experiment(name)
    seeds = list(seeds)
    if not seeds or len(seeds) > MAX_SEEDS or len(set(seeds)) != len(seeds) or not all(
            isinstance(s, int) and not isinstance(s, bool) and 0 <= s <= MAX_SEED for s in seeds):
        raise SeedsError(f"seeds must be 1 to {MAX_SEEDS} distinct whole numbers in 0..{MAX_SEED}")
    resolved = resolve_settings(exp.name, scale, settings)
    overrides = {k: resolved.to_json()[k] for k in resolved.overridden}
    out = Path(out_dir) if out_dir is not None else Path("runs") / "reproduce" / name
    if out.exists() and not out.is_dir():
        raise ExperimentError(f"{out} exists and is not a directory; choose another --out")
    identity = {"experiment": exp.name, "scale": scale, "settings": resolved.to_json(),
                "data": None if data_dir is None else str(data_dir), "split": split}
    with ExitStack() as held:
        try:
            held.enter_context(hold_run_dir(out))
        except OSError as err:
            raise ExperimentError(f"cannot create the output directory {out}: {err.strerror or err}") from None
        marker = out / SEEDS_MARKER
        if resume:
            if not (out / RUN_MARKER).is_file() or not marker.is_file():
                raise ExperimentError(f"--resume continues an unfinished `bptsb reproduce --seeds` run, and {out} is "
                                      f"not one (no {SEEDS_MARKER})")
            try:
                before = json.loads(marker.read_text(encoding="utf-8"))
            except (OSError, ValueError) as err:
                raise ExperimentError(f"{marker}: unreadable ({err})") from None
            if not isinstance(before, dict) or any(before.get(k) != identity[k]
                                                   for k in ("experiment", "scale", "settings")):
                raise ExperimentError(f"{out} holds a run of other settings (experiment, scale or --set); --resume "
                                      "needs the same command")
            if (out / RESULT_FILE).exists() and before.get("seeds") == seeds:
                raise ExperimentError(f"{out / RESULT_FILE} exists: that run finished (pass --force to run it "
                                      "again, or more --seeds to extend it)")
        elif not dir_is_empty(out):
            if not force:
                raise ExperimentError(f"{out} exists; choose another --out, pass --resume to continue it or --force "
                                      "to replace it")
            if not (out / RUN_MARKER).is_file():
                raise ExperimentError(f"--force replaces only an earlier `bptsb reproduce` run, and {out} is not one "
                                      f"(no {RUN_MARKER}); remove it yourself or choose another --out")
            _clear_run(out)
        try:
            (out / RUN_MARKER).write_text(f"bptsb reproduce {name} --seeds\n")
            marker.write_text(json.dumps({**identity, "seeds": seeds}, indent=1) + "\n")
        except OSError as err:
            raise ExperimentError(f"cannot write in {out}: {err.strerror or err}") from None
        (out / RESULT_FILE).unlink(missing_ok=True)  # a finished aggregate of fewer seeds is ours to replace
        states = {s: seed_state(out / seed_dir_name(s), experiment=exp.name, scale=scale, seed=s,
                                settings=resolved.to_json()) for s in seeds}
        placement, inner = plan_placement(exp.parallel, workers, scheduler, scale, len(seeds))
        todo = [s for s in seeds if states[s] != "finished"]
        reused = len(seeds) - len(todo)
        log(f"{name}: {len(seeds)} seeds ({format_seeds(seeds)}) at {scale} scale in {out}"
            + (f", {reused} finished before" if reused else "")
            + (f"; {len(todo)} to run {_where_text(placement, len(todo))}" if todo else ""))
        attempts = _start_attempt(out, resume=resume)
        t0 = time.perf_counter()
        try:
            failed = _run_seed_jobs(name, todo, states, out, scale=scale, overrides=overrides, data_dir=data_dir,
                                    split=split, placement=placement, inner=inner, scheduler=scheduler,
                                    progress=progress, log=log)
        finally:
            attempts[-1]["wall_s"] = round(time.perf_counter() - t0, 2)
            _write_attempts(out, attempts)
        if failed:
            raise SeedsError(f"{len(failed)} of {len(seeds)} seeds failed (" + "; ".join(
                f"seed {s}: {failed[s][:300]}" for s in sorted(failed)) + f"); `--resume --out {out}` with the same "
                "command runs them again and keeps the others")
        per_seed = [read_result(out / seed_dir_name(s) / RESULT_FILE) for s in seeds]
        prov = base_provenance()
        prov["command"] = (f"bptsb reproduce {name} --scale {scale} --seeds {format_seeds(seeds)} --out {out}"
                           + "".join(f" {a}" for a in resolved.override_args())
                           + (f" --data {data_dir}" if data_dir is not None else "")
                           + (f" --split {split}" if split != "auto" else "")
                           + (f" --scheduler {scheduler}" if scheduler else f" --workers {workers}"
                              if workers is not None else ""))
        prov["attempts"] = attempts
        prov["seeds_reused"] = reused
        wall = sum(a["wall_s"] for a in attempts)
        figures = _figures(out, seeds, per_seed, log)
        data = aggregate(per_seed, seeds, wall_s=wall, figures=figures, provenance=prov)
        from bptsb_ros.experiments.result import write_json_result

        path = write_json_result(out, data)
        return path, data


def _where_text(placement: Any, n: int) -> str:
    if placement.scheduler:
        return f"as jobs on the Dask scheduler {placement.scheduler}"
    size = placement.pool_size(n)
    return "one after another in this process" if size == 0 else f"side by side in a local pool of {size}"


def _run_seed_jobs(name: str, todo: list[int], states: Mapping[int, str], out: Path, *, scale: str,
                   overrides: dict[str, Any], data_dir: str | Path | None, split: str, placement: Any,
                   inner: int | None, scheduler: str | None, progress: bool,
                   log: Callable[[str], None]) -> dict[int, str]:
    """Run the seeds ``todo``; returns seed → error text for those that failed (empty: all finished)."""
    from bptsb_ros.jobs.runner import connect_placement, run_calls

    if not todo:
        return {}
    side_by_side = placement.scheduler is not None or placement.pool_size(len(todo)) > 0
    calls = [(f"seed-{s}", _seed_job,
              (name, scale, s, str(out / seed_dir_name(s)), states[s] == "unfinished", overrides,
               None if data_dir is None else str(data_dir), split, inner, None,
               progress and not side_by_side)) for s in todo]
    failed: dict[int, str] = {}
    done = [0]

    def on_done(i: int, value: Any, where: Any, error: BaseException | None) -> None:
        seed = todo[i]
        done[0] += 1
        err = f"{type(error).__name__}: {error}" if error is not None else (value or {}).get("error")
        if err:
            failed[seed] = str(err)
            log(f"{name}: seed {seed} failed ({done[0]} of {len(todo)} ended): {str(err)[:300]}")
        else:
            log(f"{name}: seed {seed} finished in {value['wall_s']:.0f} s ({done[0]} of {len(todo)} ended)")

    client = connect_placement(placement, 20.0)
    try:
        run_calls(calls, placement, threads=1 if side_by_side else None, client=client, on_done=on_done)
    finally:
        if client is not None:
            client.close()
    return failed


def _figures(out: Path, seeds: Sequence[int], per_seed: Sequence[Mapping[str, Any]],
             log: Callable[[str], None]) -> list[str]:
    """The aggregate's figures: the across-seed summary (:mod:`bptsb_ros.analysis.seed_plots`), the experiment's
    own across-seed figures where it has them, then the first seed's figures (its trained systems)."""
    from bptsb_ros.analysis.seed_plots import plot_seed_summary

    figs: list[str] = []
    try:
        figs.append(plot_seed_summary(out / "seeds.png", aggregate_claims(per_seed), seeds,
                                      per_seed[0]["experiment"] if per_seed else "").name)
        hook = _SEED_FIGURES.get(per_seed[0]["experiment"])
        for path in hook(out, per_seed, seeds) if hook else []:
            figs.append(Path(path).relative_to(out).as_posix())
    except (ValueError, ResultError, OSError) as err:  # a figure is not worth losing the aggregate for
        log(f"warning: an across-seed figure was not drawn ({err})")
    first = seed_dir_name(seeds[0])
    figs += [f"{first}/{f}" for f in per_seed[0]["figures"]]
    return figs


# ----------------------------------------------------------------------------------------------- rejudging


def rejudge_run(run_dir: str | Path, log: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Judge the claims of the finished run in ``run_dir`` again with the installed claim code, from the numbers
    it stored (``measured``), and write its result.json again (an aggregate: every seed, then the aggregate);
    returns the new content. Only a ``bptsb reproduce`` run's own result.json is rewritten; a run whose numbers
    were not stored (made before they were) is left as it is, with a warning line."""
    from bptsb_ros.experiments.measured import rejudge
    from bptsb_ros.experiments.registry import RUN_MARKER, judged_by
    from bptsb_ros.experiments.result import write_json_result

    log = log or (lambda msg: print(msg, file=sys.stderr, flush=True))
    run_dir = Path(run_dir)
    if not (run_dir / RUN_MARKER).is_file():
        raise ResultError(f"{run_dir} is not a `bptsb reproduce` run (no {RUN_MARKER}); its result.json is not "
                          "rewritten")
    data = read_result(run_dir / RESULT_FILE)
    if "seeds" in data:
        seeds = data["seeds"]
        per_seed = [rejudge_run(run_dir / seed_dir_name(s), log) for s in seeds]
        new = aggregate(per_seed, seeds, wall_s=data["wall_s"], figures=data["figures"],
                        provenance=data.get("provenance"))
        new["judged"] = judged_by(complete=True, rejudged=True)
        write_json_result(run_dir, new)
        return new
    old = data.get("judged") or {}
    if not data.get("measured") or old.get("complete") is False:
        log(f"{run_dir}: warning: its numbers were not stored in a form that can be judged again; kept as it is")
        return data
    claims = rejudge(data["measured"])
    data["claims"] = [{"claim": c.claim, "holds": c.holds, "evidence": c.evidence} for c in claims]
    # at_run: the judgement made when the run was made, kept through any number of later judgements
    at_run = old.get("at_run") or {k: v for k, v in old.items() if k != "at_run"}
    data["judged"] = {**judged_by(complete=True, rejudged=True), "at_run": at_run}
    write_json_result(run_dir, data)
    return data

