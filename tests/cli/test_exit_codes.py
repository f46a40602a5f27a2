"""Exit codes of the ``bptsb`` subcommands: 2 for an invalid command line only, 1 for a runtime failure (a bad
file, divergence, an unwritable output), each a single line ``bptsb <command>: ...`` on stderr.

Every case is fast: bad files and temporary directories, no training; the ``launch`` and ``run`` cases are refused
before any node starts.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import REPO_ROOT as REPO

from bptsb_ros.cli import main
from bptsb_ros.cli.options import FAILURE, USAGE, config_error_code, fail

CONFIG = str(REPO / "config" / "lissajous_single.yaml")


def _files(tmp: Path) -> dict[str, str]:
    """Planted inputs: a file where a directory is expected, a config the file itself breaks, a broken result."""
    (tmp / "afile").write_text("keep me")
    (tmp / "bad.yaml").write_text("task: lissajous\nnokey: 1\n")  # an unknown key: the file's fault
    (tmp / "theirs.yaml").write_text("- a\n- b\n")  # the authors' format is a mapping
    (tmp / "runs" / "x").mkdir(parents=True)
    (tmp / "runs" / "x" / "result.json").write_text('{"experiment": "x"}')
    (tmp / "workdir").mkdir()
    (tmp / "workdir" / "left.txt").write_text("x")
    (tmp / "mnist").mkdir()
    names = ("afile", "bad.yaml", "theirs.yaml", "runs", "workdir", "mnist")
    return {name.removesuffix(".yaml"): str(tmp / name) for name in names}


# (command as printed, argv with {name} placeholders for _files' paths and {tmp}, code, a fragment of the line)
CASES = [
    ("train", ["train", CONFIG, "--out", "{tmp}/r", "--resume", "--force"], USAGE, "exclude each other"),
    ("train", ["train", CONFIG, "--out", "{tmp}/r", "--set", "nokey=1"], USAGE, "override nokey: unknown key"),
    ("train", ["train", CONFIG, "--out", "{tmp}/r", "--set", "sim_time=fast"], USAGE, "sim_time"),
    ("train", ["train", "{tmp}/missing.yaml", "--out", "{tmp}/r"], FAILURE, "config file not found"),
    ("train", ["train", "{bad}", "--out", "{tmp}/r", "--set", "sim_time=20"], FAILURE, "nokey"),
    ("simulate", ["simulate", "--shape", "double_circle", "--steps", "0", "--out", "{tmp}/x.npz"], USAGE,
     "--steps must be >= 1"),
    ("simulate", ["simulate", "--shape", "double_circle", "--nodes", "2", "--steps", "1", "--out", "{tmp}/x.npz"],
     USAGE, "double_circle"),
    ("simulate", ["simulate", "--agent", "{tmp}/none", "--steps", "1", "--nodes", "5", "--out", "{tmp}/x.npz"],
     USAGE, "apply to --shape only"),
    ("simulate", ["simulate", "--agent", "{tmp}/none", "--steps", "1", "--out", "{tmp}/x.npz"], FAILURE,
     "no checkpoint"),
    ("simulate", ["simulate", "--shape", "double_circle", "--steps", "1", "--out", "{afile}/x.npz"], FAILURE,
     "cannot write --out"),
    ("render", ["render", "--shape", "double_circle", "--out", "{tmp}/b.txt"], USAGE, "--out must end in"),
    ("render", ["render", "--shape", "double_circle", "--nodes", "2", "--out", "{tmp}/b.png"], USAGE,
     "double_circle"),
    ("render", ["render", "--shape", "double_circle", "--out", "{afile}/b.png"], FAILURE, "cannot write --out"),
    ("bench", ["bench", "--soak", "--realtime-seconds", "-1", "--out", "{tmp}/b.json"], USAGE,
     "--realtime-seconds must be >= 0"),
    ("bench", ["bench", "--soak", "--workdir", "{workdir}", "--out", "{tmp}/b.json"], FAILURE, "is not empty"),
    ("replay", ["replay", "{tmp}/nobag", "--out", "{tmp}/o", "--no-gif"], FAILURE, "nobag"),
    ("bag info", ["bag", "info", "{tmp}/nobag"], FAILURE, "bag not found"),
    ("bag recover", ["bag", "recover", "{tmp}/nobag"], FAILURE, "bag not found"),
    ("reproduce", ["reproduce"], USAGE, "name an experiment"),
    ("reproduce", ["reproduce", "no-such-experiment"], USAGE, "unknown experiment 'no-such-experiment'"),
    ("reproduce", ["reproduce", "narma-ipc", "--set", "wahsout=3"], USAGE, "wahsout"),
    ("reproduce", ["reproduce", "narma-ipc", "--workers", "-1", "--out", "{tmp}/o"], USAGE, "--workers"),
    ("reproduce", ["reproduce", "narma-ipc", "--scheduler", "udp://h:1", "--out", "{tmp}/o"], USAGE,
     "only tcp://"),
    ("reproduce", ["reproduce", "narma-ipc", "--scale", "smoke", "--out", "{afile}"], FAILURE,
     "exists and is not a directory"),
    ("reproduce", ["reproduce", "narma-ipc", "--scale", "smoke", "--resume", "--out", "{tmp}/o"], FAILURE,
     "is not one"),
    ("report", ["report", "{runs}", "--out", "{tmp}/R.md"], FAILURE, "missing key"),
    ("sweep", ["sweep", CONFIG, "--seeds", "5-1", "--out", "{tmp}/s"], USAGE, "runs backwards"),
    ("sweep", ["sweep", CONFIG, "--seeds", "0", "--connect-timeout", "5", "--out", "{tmp}/s"], USAGE,
     "--connect-timeout applies to --scheduler only"),
    ("sweep", ["sweep", CONFIG, "--seeds", "0", "--gang", "0", "--out", "{tmp}/s"], USAGE, "--gang must be >= 1"),
    ("sweep", ["sweep", CONFIG, "--seeds", "0", "--set", "nokey=1", "--out", "{tmp}/s"], USAGE, "nokey"),
    ("sweep", ["sweep", "{bad}", "--seeds", "0", "--out", "{tmp}/s"], FAILURE, "nokey"),
    ("sweep", ["sweep", "{tmp}/missing.yaml", "--seeds", "0", "--out", "{tmp}/s"], FAILURE, "config file not found"),
    ("data", ["data", "mnist", "--dir", "{mnist}", "--verify"], FAILURE, "mnist"),
    ("ipc", ["ipc", "--input", "{tmp}/u.npz", "--out", "{tmp}/o", "--max-degree", "0"], USAGE,
     "--max-degree must be >= 1"),
    ("ipc", ["ipc", "--input", "{tmp}/u.npz", "--out", "{tmp}/o", "--min-delay", "5", "--max-delay", "4"], USAGE,
     "must not exceed --max-delay"),
    ("ipc", ["ipc", "--input", "{tmp}/u.npz", "--out", "{tmp}/o"], FAILURE, "u.npz"),
    ("ipc", ["ipc", "--input", "{tmp}/u.npz", "--out", "{afile}"], FAILURE, "cannot write --out"),
    ("config show", ["config", "show", "narma", "--set", "epocs=3"], USAGE, "did you mean epochs?"),
    ("config show", ["config", "show", "{tmp}/missing.yaml"], FAILURE, "config file not found"),
    ("config show", ["config", "show", "{bad}", "--set", "epochs=3"], FAILURE, "nokey"),
    ("config import", ["config", "import", "{theirs}"], FAILURE, "must be a mapping"),
    ("config import", ["config", "import", "{tmp}/missing.yaml"], FAILURE, "no such file"),
    ("launch", ["launch", "lissajous_closed", "--duration", "1"], USAGE, "needs --agent"),
    ("launch", ["launch", "lissajous_open", "--duration", "-1"], USAGE, "--duration must be >= 0"),
    ("launch", ["launch", "narma", "--param", "swg_brain:x:=1"], USAGE, "not part of this loop"),
    ("launch", ["launch", "lissajous_open", "--namespace", "r1/2x"], USAGE, "'r1/2x': not a ROS"),
    ("launch", ["launch", "lissajous_open", "--agent", "{tmp}/none"], FAILURE, "no such run directory"),
    ("launch", ["launch", "lissajous_open", "--agent", "{afile}"], FAILURE, "--agent:"),
    ("launch", ["launch", "lissajous_open", "--duration", "1", "--bag", "{afile}/bag"], FAILURE, "--bag"),
    ("run", ["run", "body_sim", "-p", "x:=1"], USAGE, "must start with --ros-args"),
]


@pytest.mark.parametrize("command, argv, code, fragment", CASES,
                         ids=[f"{c[0]}-{'usage' if c[2] == USAGE else 'runtime'}-{i}" for i, c in enumerate(CASES)])
def test_exit_code_and_one_line(tmp_path, capsys, command, argv, code, fragment):
    files = _files(tmp_path)
    args = [a.format(tmp=tmp_path, **files) for a in argv]
    capsys.readouterr()
    assert main(args) == code
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert err.startswith(f"bptsb {command}: ") and fragment in err, err
    assert (tmp_path / "afile").read_text() == "keep me"


# argparse's own errors, in every kind: a bad option, a missing required argument, a bad value or choice, an
# unknown subcommand; arguments left over are blamed on the (sub)command parsed last, not on ``bptsb``.
ARGPARSE = [
    ("bptsb replay", ["replay", "bag", "--out", "o", "--task", "juggling"], "invalid choice: 'juggling'"),
    ("bptsb bag", ["bag", "inspect", "bag"], "invalid choice: 'inspect'"),
    ("bptsb report", ["report", "--out"], "expected one argument"),
    ("bptsb data", ["data", "cifar", "--dir", "d"], "invalid choice: 'cifar'"),
    ("bptsb config import", ["config", "import", "f.yaml", "--task", "juggling"], "invalid choice"),
    ("bptsb sweep", ["sweep", CONFIG, "--seeds", "0", "--out", "s", "--connect-timeout", "0"], "--connect-timeout"),
    ("bptsb train", ["train", CONFIG, "--out", "o", "--no-such-option"], "unrecognized arguments: --no-such-option"),
    ("bptsb config import", ["config", "import", "f.yaml", "--bogus", "1"], "unrecognized arguments: --bogus 1"),
    ("bptsb bench", ["bench", "--quick"], "the following arguments are required: --out"),
    ("bptsb train", ["train"], "the following arguments are required: config, --out"),
    ("bptsb bag info", ["bag", "info"], "the following arguments are required: bag"),
    ("bptsb simulate", ["simulate", "--steps", "x", "--out", "o.npz"], "invalid int value: 'x'"),
    ("bptsb", ["no-such-command"], "invalid choice: 'no-such-command'"),
    ("bptsb", [], "the following arguments are required: COMMAND"),
]


@pytest.mark.parametrize("prog, argv, fragment", ARGPARSE, ids=[" ".join(c[1][:2]) or "none" for c in ARGPARSE])
def test_argparse_errors_are_one_line_and_exit_2(capsys, prog, argv, fragment):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == USAGE
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.startswith(f"{prog}: error: ") and captured.err.count("\n") == 1, captured.err  # no usage
    line = captured.err.rstrip("\n")
    assert fragment in line, line
    assert line.endswith(f" (see {prog} --help)"), line


def test_fail_prints_one_line(capsys):
    assert fail("train", "invalid configuration c.yaml:\n  sim_time: bad\n\n  seed: bad\n") == FAILURE
    assert fail("x y", ValueError("no"), USAGE) == USAGE
    assert capsys.readouterr().err == ("bptsb train: invalid configuration c.yaml:; sim_time: bad; seed: bad\n"
                                       "bptsb x y: no\n")
    assert (USAGE, FAILURE) == (2, 1)


def test_a_config_error_is_blamed_on_its_source(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("task: lissajous\nnokey: 1\n")
    assert config_error_code(CONFIG, ["nokey=1"]) == USAGE  # the file loads alone: --set broke it
    assert config_error_code(CONFIG, [], seed=-1) == USAGE
    assert config_error_code(bad, ["sim_time=20"]) == FAILURE  # the file does not load alone
    assert config_error_code(tmp_path / "missing.yaml", ["sim_time=20"]) == FAILURE
    assert config_error_code(CONFIG) == FAILURE  # no arguments to blame


def test_an_experiment_that_fails_in_its_own_code_is_one_last_line(tmp_path, capsys):
    """Jobs that all fail raise inside the experiment (not a CLI-checked error): exit 1, the failure as the last
    line after the progress lines, no traceback, no result.json."""
    args = ["reproduce", "narma-emulation", "--scale", "smoke", "--set", "config=nosuch", "--out", str(tmp_path / "o")]
    assert main(args) == FAILURE
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert err.strip().splitlines()[-1].startswith("bptsb reproduce: narma-emulation failed: 4 of 4 jobs failed")
    assert "no packaged config named 'nosuch'" in err and not (tmp_path / "o" / "result.json").exists()
