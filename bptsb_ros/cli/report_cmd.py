"""`bptsb report`: gather every result.json under a runs directory into one Markdown page."""

from __future__ import annotations

import argparse
from pathlib import Path

NAME = "report"
HELP = ("Gather the result.json of every `bptsb reproduce` run under RUNS_DIR into one Markdown page with figures. "
        "The page goes where --out says (default RUNS_DIR/REPORT.md). An existing page is replaced only if it shows "
        "no result that the new one would lose (else --force), and a page shows one scale (else --mix-scales).\n"
        "Example: bptsb report reproduction/runs --out REPRODUCTION.md (the committed page of the paper-scale runs)")
PAGE_NAME = "REPORT.md"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("runs_dir", nargs="?", default="runs/reproduce", help="where to look (default runs/reproduce)")
    parser.add_argument("--out", default=None,
                        help=f"the page to write (default RUNS_DIR/{PAGE_NAME}); figures are copied into "
                             "<stem>_figures/ beside it. An existing page or folder is replaced only if bptsb report "
                             "wrote it (its marker line; the folder's manifest lists the files it wrote, files added "
                             "by hand are kept)")
    parser.add_argument("--force", action="store_true",
                        help="replace the page even if it shows results (other runs, other scales) that the new page "
                             "will not have")
    parser.add_argument("--mix-scales", action="store_true",
                        help="put results of several scales (smoke, short, paper) on one page")


def run(args: argparse.Namespace) -> int:
    from bptsb_ros.analysis.report_guard import ReplaceRefused, check_replace, check_scales
    from bptsb_ros.cli.options import fail
    from bptsb_ros.experiments import ResultError
    from bptsb_ros.experiments.report import ReportError, build_report

    out = Path(args.out) if args.out is not None else Path(args.runs_dir) / PAGE_NAME

    def check(results: list[dict]) -> None:
        check_scales(results, mix=args.mix_scales)
        check_replace(out, results, force=args.force)

    try:
        path = build_report(args.runs_dir, out, check=check)
    except (ResultError, ReportError, ReplaceRefused, OSError) as err:  # a broken result.json; a page not ours
        return fail(NAME, err)
    print(f"wrote {path}")
    return 0
