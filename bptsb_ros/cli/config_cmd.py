"""`bptsb config`: import the authors' YAML as our config (`import`), print a resolved config (`show`), print the
key mapping (`mapping`)."""

from __future__ import annotations

import argparse

NAME = "config"
HELP = (
    "Experiment configs.\n"
    "  bptsb config import THEIRS.yaml [--out OURS.yaml] [--task NAME]: translate the authors' flat YAML (simTime, "
    "lr_spring, nodes, ...) into our config; every key mapped, every default filled (from the task's packaged "
    "config) and every key left unmapped is printed and written as a comment header.\n"
    "  bptsb config show NAME|FILE [--set KEY=VALUE]: print the resolved config (NAME: a packaged config).\n"
    "  bptsb config mapping: print the table of the authors' keys and ours.\n"
    "  bptsb config list: print the names of the packaged configs."
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from bptsb_ros.config.authors import TASKS

    sub = parser.add_subparsers(dest="action", required=True, metavar="ACTION")
    imp = sub.add_parser("import", help="translate the authors' YAML into our config",
                         description="Translate the authors' flat YAML into our experiment config.")
    imp.add_argument("file", help="the authors' YAML (e.g. Lissajous/training_single.yaml)")
    imp.add_argument("--out", help="write our config here (default: print it)")
    imp.add_argument("--task", choices=list(TASKS),
                     help="the task, when the file's keys do not tell (default: from its task: and keys)")
    imp.add_argument("--force", action="store_true",
                     help="replace an existing --out that bptsb config import wrote (never any other file)")
    show = sub.add_parser("show", help="print a resolved config", description="Print a config with every key "
                          "resolved (profile, --set overrides and config.py's defaults applied).")
    show.add_argument("config", help="a packaged config's name (lissajous_single, narma, ...; bptsb config "
                                     "list names them) or a YAML file")
    show.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                      help="override a config key (dotted for sections), as for bptsb train")
    sub.add_parser("mapping", help="print the authors' keys and where they go in ours")
    sub.add_parser("list", help="print the names of the packaged experiment configs",
                   description="Print the names of the packaged experiment configs, one a line (bptsb train NAME, "
                               "bptsb config show NAME).")


def _import(args: argparse.Namespace) -> int:
    from bptsb_ros.cli.options import fail
    from bptsb_ros.config.authors import ImportFailure, import_file, write_output

    try:
        result = import_file(args.file, args.task)
        text = result.yaml_text()
        if args.out is None:
            print(text, end="")
            return 0
        path = write_output(text, args.out, force=args.force)
    except ImportFailure as err:  # the authors' file, or an --out that is not ours to replace
        return fail("config import", err)
    except OSError as err:
        return fail("config import", f"cannot write {args.out}: {err.strerror or err}")
    print("\n".join(result.report_lines()))
    print(f"wrote {path}")
    return 0


def _show(args: argparse.Namespace) -> int:
    import yaml

    from bptsb_ros.cli.options import config_error_code, fail
    from bptsb_ros.config import ConfigError, load_config
    from bptsb_ros.experiments.common import config_source

    try:
        path = config_source(args.config)
    except ConfigError as err:  # an unknown packaged name, a missing file
        return fail("config show", err)
    try:
        cfg = load_config(path, args.overrides)
    except ConfigError as err:  # the file's fault (1), or the --set arguments' (2)
        return fail("config show", err, config_error_code(path, args.overrides))
    print(f"# {path}, resolved" + (f" with --set {' '.join(args.overrides)}" if args.overrides else ""))
    print(yaml.safe_dump(cfg.model_dump(mode="json"), sort_keys=False, allow_unicode=True), end="")
    return 0


def run(args: argparse.Namespace) -> int:
    if args.action == "import":
        return _import(args)
    if args.action == "show":
        return _show(args)
    if args.action == "list":
        from bptsb_ros.cli.options import fail
        from bptsb_ros.config import ConfigError
        from bptsb_ros.experiments.common import packaged_configs

        try:
            print("\n".join(packaged_configs()))
        except ConfigError as err:
            return fail("config list", err)
        return 0
    from bptsb_ros.config.authors import mapping_table

    print("\n".join(mapping_table()))
    return 0
