"""`bptsb train`: offline BPTSB training of one experiment config."""

from __future__ import annotations

import argparse
import json

NAME = "train"
HELP = ("Train a brain-body agent with BPTSB from an experiment config: a packaged config's name (bptsb config show "
        "NAME prints one) or a YAML file.")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("config", help="a packaged config's name (lissajous_single, narma, ...) or a YAML file")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="override a config key (dotted for sections): --set sim_time=20 --set training.lr.k=100")
    parser.add_argument("--seed", type=int, default=None, help="random seed (overrides the config's)")
    parser.add_argument("--out", required=True, help="run directory for checkpoint.pt, metrics.json and plots")
    parser.add_argument("--resume", action="store_true",
                        help="continue the run saved in --out (same config; a larger sim_time or epochs extends it)")
    parser.add_argument("--force", action="store_true",
                        help="train a new run into --out even if it already holds one (its files are replaced)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar and no phase lines")


def run(args: argparse.Namespace) -> int:
    from bptsb_ros.cli.options import USAGE, config_error_code, fail
    from bptsb_ros.config import ConfigError, load_config
    from bptsb_ros.experiments.common import config_source
    from bptsb_ros.files.run_dir_lock import RunDirLocked
    from bptsb_ros.training.checkpoint import CheckpointError
    from bptsb_ros.workflows.train import TrainingDiverged, train

    if args.resume and args.force:
        return fail(NAME, "--resume and --force exclude each other", USAGE)
    try:
        path = config_source(args.config)
    except ConfigError as err:  # an unknown packaged name, a missing file
        return fail(NAME, err)
    try:
        cfg = load_config(path, args.overrides, args.seed)
    except ConfigError as err:  # the file's fault (1), or the --set / --seed arguments' (2)
        return fail(NAME, err, config_error_code(path, args.overrides, args.seed))
    try:
        result = train(cfg, args.out, resume=args.resume, overwrite=args.force, progress=not args.no_progress)
    except (ConfigError, CheckpointError, TrainingDiverged, RunDirLocked) as err:  # --out's contents, divergence
        return fail(NAME, err)
    except OSError as err:
        where = f" {err.filename}" if err.filename else ""
        return fail(NAME, f"cannot write{where}: {err.strerror or err}")
    m = result.metrics
    ev = m["evaluation"]
    losses = m["loss"]
    summary = {
        "run_dir": str(result.run_dir),
        "updates": m["updates"],
        "first_loss": losses[0] if losses else None,
        "last_loss": losses[-1] if losses else None,
        "train_steps_per_second": round(m["train_steps_per_second"] or 0.0, 1),
        "updates_undone": m["guard"]["rejections"],
        "learning_rate_divisions": m["guard"]["divisions"],
        **{k: v for k, v in ev.items() if isinstance(v, (int, float, bool)) and not isinstance(v, list)},
    }
    print(json.dumps(summary, indent=2))
    print(ev.get("paper_reference", ""))
    print("files: " + ", ".join(str(f) for f in result.files))
    return 0
