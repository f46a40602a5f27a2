"""One bptsb process per output directory: train, sweep and reproduce refuse a directory another process holds.

The holder in these tests is a separate Python process taking a plain ``fcntl.flock`` on ``DIR/.bptsb.lock``
(written out here, not imported, so the tests also pin the lock protocol other tools may rely on).
"""

from __future__ import annotations

import dataclasses
import fcntl
import hashlib
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import REPO_ROOT

from bptsb_ros.cli import main
from bptsb_ros.experiments.registry import _REGISTRY, ATTEMPTS_FILE, RUN_MARKER, Context, experiment

LOCK = ".bptsb.lock"  # bptsb_ros.files.run_dir_lock.LOCK_NAME, spelled out
TINY = ["--set", "sim_time=2", "--set", "locomotion.warmup_windows=0", "--set", "feedback.fit_time=2",
        "--set", "locomotion.eval_time=1"]

RAW_HOLDER = """
import fcntl, os, sys, time
fd = os.open(sys.argv[1], os.O_RDWR | os.O_CREAT, 0o644)
fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
print("held", flush=True)
time.sleep(120)
"""

OUR_HOLDER = """
import sys, time
from bptsb_ros.files.run_dir_lock import hold_run_dir
with hold_run_dir(sys.argv[1]):
    print("held", flush=True)
    time.sleep(120)
"""


@pytest.fixture
def holder():
    """start(code, arg) → a process that printed "held" (killed at the end of the test)."""
    procs: list[subprocess.Popen] = []

    def start(code: str, arg: Path) -> subprocess.Popen:
        proc = subprocess.Popen([sys.executable, "-c", code, str(arg)], stdout=subprocess.PIPE, text=True,
                                env={**os.environ, "PYTHONPATH": str(REPO_ROOT)})
        procs.append(proc)
        assert proc.stdout.readline().strip() == "held"
        return proc

    yield start
    for proc in procs:
        proc.kill()
        proc.wait()
        proc.stdout.close()


def _snapshot(root: Path) -> dict[str, tuple[int, int, str]]:
    """relative path → (size, mtime in ns, sha256) of every file and directory under ``root``."""
    out = {}
    for path in sorted(root.rglob("*")):
        st = path.stat()
        digest = hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else "dir"
        out[path.relative_to(root).as_posix()] = (st.st_size, st.st_mtime_ns, digest)
    return out


def _one_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, lines
    return lines[0]


def test_train_refuses_a_held_directory_and_touches_nothing(tmp_path, repo_root, holder, capsys):
    out = tmp_path / "run"
    out.mkdir()
    holder(RAW_HOLDER, out / LOCK)
    before = _snapshot(out)
    # --force first: without the lock it replaced the holder's run while that one was writing it; --resume
    # would read a checkpoint being written; plain: refused however the holder's files look right now
    for extra in (["--force"], ["--resume"], []):
        code = main(["train", str(repo_root / "config" / "locomotion_forward.yaml"), "--out", str(out),
                     "--no-progress", *TINY, *extra])
        line = _one_line(capsys.readouterr().err)
        assert code == 1, line
        assert str(out) in line and "another bptsb process holds it" in line
        assert _snapshot(out) == before


def test_sweep_refuses_a_held_directory_and_touches_nothing(tmp_path, repo_root, holder, capsys):
    out = tmp_path / "sweep"
    (out / "jobs" / "seed-0").mkdir(parents=True)
    (out / "notes.txt").write_text("the user's")
    holder(RAW_HOLDER, out / LOCK)
    before = _snapshot(out)
    code = main(["sweep", str(repo_root / "config" / "locomotion_forward.yaml"), "--seeds", "0", "--out", str(out),
                 "--workers", "0", *TINY])
    line = _one_line(capsys.readouterr().err)
    assert code == 1
    assert str(out) in line and "another bptsb process holds it" in line
    assert _snapshot(out) == before


def _toy(ctx: Context) -> None:
    ctx.row("toy", "value", "m", 1.0, 2.0)
    ctx.claim("one is less than two", 1.0 < 2.0, "1 < 2")


@pytest.fixture
def toy_experiment():
    experiment("toy-lock", paper_ref="Table 0", summary="planted")(_toy)
    yield "toy-lock"
    _REGISTRY.pop("toy-lock", None)


def test_reproduce_refuses_a_held_directory_and_touches_nothing(tmp_path, holder, toy_experiment, capsys):
    out = tmp_path / "repro"
    out.mkdir()
    (out / RUN_MARKER).write_text("bptsb reproduce toy-lock\n")  # an earlier run, which --force would replace
    (out / "result.json").write_text("{}")
    holder(RAW_HOLDER, out / LOCK)
    before = _snapshot(out)
    for extra in ([], ["--force"]):
        code = main(["reproduce", toy_experiment, "--scale", "smoke", "--out", str(out), "--no-progress", *extra])
        line = _one_line(capsys.readouterr().err)
        assert code == 1, line
        assert str(out) in line and "another bptsb process holds it" in line
        assert _snapshot(out) == before


def test_reproduce_force_keeps_the_lock_it_holds(tmp_path, toy_experiment):
    """--force clears the earlier run but not the lock file: a second process must still find it held."""
    from bptsb_ros.experiments import run_experiment

    out = tmp_path / "repro"
    run_experiment(toy_experiment, out_dir=out, progress=False)
    seen, attempts = [], []

    def probe(ctx: Context) -> None:
        fd = os.open(ctx.out_dir / LOCK, os.O_RDWR)
        try:
            with pytest.raises(BlockingIOError):
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # another open file description: conflicts
        finally:
            os.close(fd)
        seen.append(sorted(p.name for p in ctx.out_dir.iterdir()))
        attempts.append(json.loads((ctx.out_dir / ATTEMPTS_FILE).read_text()))
        _toy(ctx)

    _REGISTRY["toy-lock"] = dataclasses.replace(_REGISTRY["toy-lock"], run=probe)
    run_experiment(toy_experiment, out_dir=out, force=True, progress=False)
    assert seen == [sorted([ATTEMPTS_FILE, LOCK, RUN_MARKER])]  # the earlier run's files are gone
    assert len(attempts) == 1 and len(attempts[0]) == 1  # only this attempt: the earlier one was cleared too
    assert not (out / LOCK).exists()  # released at the end


def test_our_lock_is_an_flock_and_a_killed_holder_blocks_nobody(tmp_path, holder):
    from bptsb_ros.files.run_dir_lock import RunDirLocked, dir_is_empty, hold_run_dir

    out = tmp_path / "run"
    proc = holder(OUR_HOLDER, out)
    fd = os.open(out / LOCK, os.O_RDWR)
    with pytest.raises(BlockingIOError):  # an independent flock sees the holder's lock
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    os.close(fd)
    assert (out / LOCK).read_text().strip() == str(proc.pid)
    with pytest.raises(RunDirLocked, match=f"pid {proc.pid}"), hold_run_dir(out):
        pass
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert (out / LOCK).exists()  # the stale lock file of the killed process ...
    assert dir_is_empty(out)  # ... does not make the directory look used
    with hold_run_dir(out):  # ... and blocks nobody
        assert (out / LOCK).read_text().strip() == str(os.getpid())
        with hold_run_dir(out):  # re-entrant in the same thread (a sweep inside a reproduce run)
            pass
        assert (out / LOCK).exists()
    assert list(out.iterdir()) == []  # a holder that ends normally removes its lock file


def test_a_refused_start_creates_no_directory(tmp_path, holder):
    from bptsb_ros.files.run_dir_lock import hold_run_dir

    new = tmp_path / "new"
    with hold_run_dir(new):
        (new / "result.txt").write_text("kept")
    assert sorted(p.name for p in new.iterdir()) == ["result.txt"]
    empty = tmp_path / "empty"
    with hold_run_dir(empty):
        pass
    assert not empty.exists()  # created here, left empty: removed
