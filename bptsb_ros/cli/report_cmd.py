"""`bptsb report`: gather every result.json into REPRODUCTION.md."""

from __future__ import annotations

import argparse

NAME = "report"
HELP = "Gather the result.json of every `bptsb reproduce` run into one Markdown page with figures."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("runs_dir", nargs="?", default="runs/reproduce", help="where to look (default runs/reproduce)")
    parser.add_argument("--out", default="REPRODUCTION.md",
                        help="the page to write; figures are copied into <stem>_figures/ beside it. An existing "
                             "page or folder is replaced only if bptsb report wrote it (its marker line; the "
                             "folder's manifest lists the files it wrote, files added by hand are kept)")


def run(args: argparse.Namespace) -> int:
    from bptsb_ros.analysis.report import ReportError, build_report
    from bptsb_ros.cli.common import fail
    from bptsb_ros.experiments import ResultError

    try:
        path = build_report(args.runs_dir, args.out)
    except (ResultError, ReportError, OSError) as err:  # a broken result.json; a page or folder that is not ours
        return fail(NAME, err)
    print(f"wrote {path}")
    return 0
