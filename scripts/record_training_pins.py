#!/usr/bin/env python3
"""Write tests/data/training_pins.json: the training pins, recorded from the code as it is now.

The pins are the losses and every trained tensor, bit for bit, of a tiny fixed-seed training of every training
family (the cases in ``tests/training_pin_cases.py``); ``tests/training/test_training_pins.py`` fails when any of
them moves.
They hold a refactoring to "behaviour unchanged".

Run this ONLY when a change is MEANT to change trainings (a fixed bug in a loss, a new default, a changed
optimiser step, a numeric library upgrade), never to make a failing pin test pass after a change that should have
kept them. Commit the new file together with that change, and say in the commit message which families moved and
why.

Usage::

    python scripts/record_training_pins.py            # every case → tests/data/training_pins.json
    python scripts/record_training_pins.py --check    # compare only (what the test does), write nothing
    python scripts/record_training_pins.py -k scheme  # re-record only the cases whose name contains "scheme"
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
os.environ.setdefault("BPTSB_COMPILE_NOTICE", "0")
os.environ.setdefault("OMP_NUM_THREADS", "1")  # as the test suite runs (tests/conftest.py)
os.environ.setdefault("MPLBACKEND", "Agg")
sys.path.insert(0, str(REPO / "tests"))

import training_pin_cases as cases  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-k", action="append", default=[], help="only the cases whose name contains this (repeatable)")
    ap.add_argument("--check", action="store_true", help="compare with the recorded file; write nothing")
    args = ap.parse_args(argv)
    path = REPO / cases.DATA
    old = json.loads(path.read_text()) if path.is_file() else {"environment": None, "cases": {}}
    names = [n for n in cases.CASES if not args.k or any(k in n for k in args.k)]
    if not names:
        print(f"no case matches {args.k}; the cases: {', '.join(cases.CASES)}", file=sys.stderr)
        return 2
    env = cases.environment()
    if args.k and old["environment"] not in (None, env):
        print(f"the recorded pins are from another environment ({old['environment']}); re-record every case",
              file=sys.stderr)
        return 2
    new = dict(old["cases"])
    moved = []
    for name in names:
        t0 = time.perf_counter()
        pin = cases.fingerprint(cases.CASES[name]())
        changed = old["cases"].get(name) != pin
        moved += [name] if changed else []
        print(f"{name:26s} {time.perf_counter() - t0:6.2f} s  {'CHANGED' if changed else 'same'}", file=sys.stderr)
        new[name] = pin
    if args.check:
        return 1 if moved or old["environment"] != env else 0
    new = {n: new[n] for n in cases.CASES if n in new}  # the cases' order; a case no longer listed is dropped
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(cases.dumps({"environment": env, "cases": new}))
    print(f"wrote {path.relative_to(REPO)} ({len(moved)} case(s) changed: {', '.join(moved) or 'none'})",
          file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
