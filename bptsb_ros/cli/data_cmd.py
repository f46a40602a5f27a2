"""`bptsb data mnist --dir DIR`: download the MNIST IDX files from the standard mirrors and verify them."""

from __future__ import annotations

import argparse

NAME = "data"
HELP = ("Fetch and verify data sets. `bptsb data mnist --dir DIR` downloads the four MNIST IDX files "
        "(gzipped, MD5-checked) into DIR, or with --verify only checks what is there and prints the split.")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("dataset", choices=("mnist",), help="data set")
    parser.add_argument("--dir", required=True, help="directory for the files")
    parser.add_argument("--verify", action="store_true", help="do not download; verify the files in --dir")
    parser.add_argument("--test-only", action="store_true", help="fetch only the 10k test set")
    parser.add_argument("--split", default="auto", choices=("auto", "paper", "test-8k-2k"),
                        help="split to report after verifying (auto: paper if the training files exist, "
                             "else the first 8,000 / last 2,000 images of the test set)")


def run(args: argparse.Namespace) -> int:
    from bptsb_ros.cli.options import fail
    from bptsb_ros.data.mnist import MnistError, download, load_split

    try:
        if not args.verify:
            for path in download(args.dir, include_train=not args.test_only):
                print(f"ok {path}")
        split = load_split(args.dir, args.split)
    except MnistError as err:  # a failed download, a bad or missing file, an unwritable --dir
        return fail(NAME, err)
    print(f"verified ({'standard MNIST' if split.standard else 'custom IDX set'}): {split.description}")
    return 0
