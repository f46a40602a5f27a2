"""Every writer of the package writes only regular files and never writes through a symbolic link: a FIFO or a
device given as an output is refused with one line (never replaced by a file), and a symbolic link planted where a
writer used to put its temporary file (``NAME.tmp``, ``.NAME.tmp``) is never followed (the file it points to is
never written)."""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path

import pytest
from conftest import REPO_ROOT

from bptsb_ros.files.safe_write import UnsafeFileError, atomic_writer, open_for_writing, write_atomic

VICTIM_TEXT = "somebody else's file\n"


@pytest.fixture
def victim(tmp_path: Path) -> Path:
    path = tmp_path / "elsewhere" / "victim.txt"
    path.parent.mkdir()
    path.write_text(VICTIM_TEXT)
    return path


def _plant_links(folder: Path, name: str, victim: Path) -> None:
    """Symbolic links to ``victim`` under every temporary name the package's writers used to use for ``name``."""
    stem = Path(name).stem
    for tmp in {f"{name}.tmp", f".{name}.tmp", f"{stem}.tmp", f"{name}.part", f"{name}.recovering"}:
        if not (folder / tmp).is_symlink():
            (folder / tmp).symlink_to(victim)


def _fifo(path: Path) -> Path:
    os.mkfifo(path)
    return path


def test_the_helpers_refuse_non_regular_targets_and_never_follow_links(tmp_path, victim):
    fifo = _fifo(tmp_path / "out.json")
    link = tmp_path / "link.json"
    link.symlink_to(victim)
    for target in (fifo, link, tmp_path):
        with pytest.raises(UnsafeFileError, match="not a regular file|symbolic link"):
            write_atomic(target, "{}")
        with pytest.raises(UnsafeFileError, match="not a regular file|symbolic link"):
            open_for_writing(target)
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode) and link.is_symlink() and victim.read_text() == VICTIM_TEXT
    _plant_links(tmp_path, "new.json", victim)
    write_atomic(tmp_path / "new.json", "{}")
    assert (tmp_path / "new.json").read_text() == "{}" and not (tmp_path / "new.json").is_symlink()
    assert victim.read_text() == VICTIM_TEXT
    # a failure inside the block leaves the old file and no temporary file behind
    with pytest.raises(RuntimeError), atomic_writer(tmp_path / "new.json", "w") as f:
        f.write("half")
        raise RuntimeError("disk full")
    assert (tmp_path / "new.json").read_text() == "{}"
    assert sorted(p.name for p in tmp_path.iterdir() if not p.is_symlink()) == ["elsewhere", "new.json", "out.json"]
    mode = stat.S_IMODE(os.stat(tmp_path / "new.json").st_mode)
    assert mode == 0o666 & ~_umask()  # the usual permissions, not mkstemp's 0600


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_bench_out_never_replaces_a_fifo(tmp_path, victim, capsys):
    from bptsb_ros.cli import main

    fifo = _fifo(tmp_path / "bench.json")
    assert main(["bench", "--quick", "--out", str(fifo)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "is a FIFO (named pipe), not a regular file" in err, err
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)


def test_bench_workdir_that_is_a_file_is_one_line(tmp_path, capsys):
    from bptsb_ros.cli import main

    afile = tmp_path / "afile"
    afile.write_text("x")
    for mode in ("--soak", "--live", "--realtime"):
        assert main(["bench", mode, "--workdir", str(afile), "--out", str(tmp_path / "o.json")]) == 1
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "--workdir" in err and "not a directory" in err, (mode, err)
    assert afile.read_text() == "x" and not (tmp_path / "o.json").exists()


def test_the_package_writers_never_follow_planted_links(tmp_path, victim):
    """checkpoint.pt, metrics.json, config.yaml, job.json, sweep.json/csv, result.json, metadata.yaml, figures:
    each written beside links planted under the old temporary names, and each refused where it is a FIFO."""
    from bptsb_ros.analysis.style import save
    from bptsb_ros.bags.metadata import BagMetadata, write_metadata
    from bptsb_ros.config import load_config
    from bptsb_ros.experiments.result import ExperimentResult, write_result
    from bptsb_ros.jobs.sweep import Job, execute_job, write_tables
    from bptsb_ros.workflows.train import train

    run = tmp_path / "run"
    run.mkdir()
    for name in ("checkpoint.pt", "metrics.json", "config.yaml", "loss.png", "loss.pdf"):
        _plant_links(run, name, victim)
    cfg = load_config(REPO_ROOT / "config" / "narma.yaml",
                      ["epochs=2", "narma.n_inputs=30", "narma.washout=5", "narma.train_end=20"])
    train(cfg, run, overwrite=True, progress=False)
    for name in ("checkpoint.pt", "metrics.json", "config.yaml", "loss.png"):
        assert (run / name).is_file() and not (run / name).is_symlink()
    jobs = tmp_path / "jobs"
    jobs.mkdir()
    _plant_links(jobs, "job.json", victim)
    record = execute_job(Job("j", _result), jobs)
    _plant_links(tmp_path, "sweep.json", victim)
    _plant_links(tmp_path, "sweep.csv", victim)
    write_tables(tmp_path, [record])
    _plant_links(tmp_path, "result.json", victim)
    write_result(tmp_path, ExperimentResult("x", "ref", "smoke", 0))
    _plant_links(tmp_path, "metadata.yaml", victim)
    write_metadata(tmp_path, BagMetadata(0, 0, 0, [], []))
    assert victim.read_text() == VICTIM_TEXT
    assert json.loads((jobs / "job.json").read_text())["status"] == "done"
    for name in ("result.json", "metadata.yaml", "job.json"):  # now a FIFO where the file goes: refused
        folder = jobs if name == "job.json" else tmp_path
        (folder / name).unlink()
        _fifo(folder / name)
    with pytest.raises(UnsafeFileError, match="FIFO"):
        write_result(tmp_path, ExperimentResult("x", "ref", "smoke", 0))
    with pytest.raises(UnsafeFileError, match="FIFO"):
        write_metadata(tmp_path, BagMetadata(0, 0, 0, [], []))
    with pytest.raises(UnsafeFileError, match="FIFO"):  # the sweep counts the job as failed and reruns it
        execute_job(Job("j", _result), jobs)
    assert stat.S_ISFIFO(os.lstat(jobs / "job.json").st_mode)
    import matplotlib.pyplot as plt

    (tmp_path / "fig.png").symlink_to(victim)
    with pytest.raises(UnsafeFileError, match="symbolic link"):
        save(plt.figure(), tmp_path / "fig.png")
    assert victim.read_text() == VICTIM_TEXT


def _result(run_dir: Path) -> dict:
    return {"value": 1.0}
