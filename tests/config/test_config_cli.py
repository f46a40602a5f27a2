"""`bptsb config show/list` and `bptsb train` take a packaged config's name from any directory; a missing
package folder is one line, not a traceback."""

from __future__ import annotations

import pytest
import yaml
from conftest import REPO_ROOT as REPO

from bptsb_ros.cli import main


def _packaged_names() -> list[str]:
    return sorted(p.stem for p in (REPO / "config").glob("*.yaml") if not p.stem.endswith("_params"))


def test_config_list_names_the_experiment_configs(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["config", "list"]) == 0
    assert capsys.readouterr().out.split() == _packaged_names()


def test_config_show_resolves_a_packaged_name_from_anywhere(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["config", "show", "lissajous_single", "--set", "sim_time=7"]) == 0
    out = capsys.readouterr().out
    shown = yaml.safe_load(out)
    assert shown["sim_time"] == 7 and shown["task"] == "lissajous" and shown["brain"]["type"] == "swg"


def test_config_show_without_the_package_files_is_one_line(capsys, monkeypatch):
    from bptsb_ros.files import package_data

    monkeypatch.setattr(package_data, "checkout_root", lambda: None)
    monkeypatch.setattr(package_data, "_ament_share", lambda kind: None)
    assert main(["config", "show", "lissajous_single"]) == 1
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "config files are missing" in err


@pytest.mark.parametrize("argument, message", [
    ("config/lissajous_single.yaml", "give the name alone"),
    ("no_such_config", "no packaged config named 'no_such_config' (packaged: "),
    ("elsewhere/none.yaml", "config file not found: elsewhere/none.yaml"),
])
def test_train_names_what_is_wrong_with_its_config_argument(argument, message, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["train", argument, "--out", "run", "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and message in err, err
    assert not (tmp_path / "run").exists()


def test_train_takes_a_packaged_name(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["train", "lissajous_single", "--set", "sim_time=2", "--set", "feedback.fit_time=2", "--out", "run",
                 "--no-progress"]) == 0
    assert (tmp_path / "run" / "checkpoint.pt").is_file()
    assert yaml.safe_load((tmp_path / "run" / "config.yaml").read_text())["sim_time"] == 2
    assert "None" not in capsys.readouterr().out


def test_bptsb_help_is_a_short_page_of_one_line_per_command():
    import subprocess
    import sys

    from bptsb_ros.cli import SUBCOMMANDS, SUMMARIES

    assert set(SUMMARIES) == set(SUBCOMMANDS)
    out = subprocess.run([sys.executable, "-m", "bptsb_ros.cli", "--help"], capture_output=True, text=True,
                         timeout=60, cwd=REPO).stdout
    lines = out.splitlines()
    assert len(lines) <= 30, out
    for name in SUBCOMMANDS:
        row = next(line for line in lines if line.strip().startswith(name + " "))
        assert row.rstrip().endswith(SUMMARIES[name]), row  # the summary on the command's own line, whole


def test_a_missing_extra_is_one_line_naming_it(capsys, monkeypatch):
    from bptsb_ros.cli import main

    def needs_torch(args):
        raise ModuleNotFoundError("No module named 'torch'", name="torch")

    import bptsb_ros.cli.config_cmd as config_cmd

    monkeypatch.setattr(config_cmd, "run", needs_torch)
    assert main(["config", "list"]) == 1
    err = capsys.readouterr().err
    assert err.strip() == ('bptsb: torch is not installed, and this command needs it: pip install "bptsb_ros[train]" '
                           "(docs: Getting started, Install)")


def test_a_closed_pipe_ends_the_command_quietly(tmp_path):
    """`bptsb config list | true`: the reader is gone before the command writes; no traceback, the status of a
    process stopped by SIGPIPE (141)."""
    import shlex
    import subprocess
    import sys

    line = (f"{shlex.quote(sys.executable)} -m bptsb_ros.cli config list 2>err.txt | true; "
            "echo ${PIPESTATUS[0]} > status.txt")
    subprocess.run(["bash", "-c", line], cwd=tmp_path, timeout=60, check=True)
    assert (tmp_path / "err.txt").read_text() == ""
    assert (tmp_path / "status.txt").read_text().strip() == "141"
