"""`bptsb sweep` against hostile input: scheduler addresses and servers, seed ranges, planted job records."""

from __future__ import annotations

import functools
import json
import socket
import struct
import threading
import time
from pathlib import Path

import pytest
from conftest import REPO_ROOT

from bptsb_ros.cli import main
from bptsb_ros.jobs.sweep import JOB_FILE, Job, SweepError, TrainJob, parse_seeds, run_sweep

CONFIG = REPO_ROOT / "config" / "locomotion_forward.yaml"


def _one_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, lines
    return lines[0]


# ------------------------------------------------------------------------------------------ scheduler address
@pytest.mark.parametrize("address", [
    "not a url", "file:///etc/passwd", "tls://10.0.0.5:8786", "inproc://10.0.0.5/1/2", "ws://h:1", "tcp://h",
    "h", "h:0", "h:65536", "h:123456", "tcp://h:1/path", "tcp://user@h:1", "tcp://[zz]:1", "tcp://-h:1",
    "tcp://h:1:2", "", "tcp://", "tcp://h:٣", "tcp://h\n:1", "tcp://é:1",
])
def test_bad_scheduler_addresses_are_one_usage_line(tmp_path, address, capsys):
    out = tmp_path / "sweep"
    code = main(["sweep", str(CONFIG), "--seeds", "0", "--out", str(out), "--scheduler", address])
    line = _one_line(capsys.readouterr().err)
    assert code == 2 and "--scheduler" in line
    assert not out.exists()  # refused before anything was created
    from bptsb_ros.jobs.dask_cluster import scheduler_address

    with pytest.raises(SweepError):
        scheduler_address(address)


def test_good_scheduler_addresses():
    from bptsb_ros.jobs.dask_cluster import scheduler_address

    assert scheduler_address("tcp://127.0.0.1:8786") == "tcp://127.0.0.1:8786"
    assert scheduler_address("10.0.0.5:1") == "tcp://10.0.0.5:1"
    assert scheduler_address("TCP://node-3.cluster.local:65535") == "tcp://node-3.cluster.local:65535"
    assert scheduler_address("[::1]:8786") == "tcp://[::1]:8786"
    assert scheduler_address("localhost:8786") == "tcp://localhost:8786"


class _Server:
    """A listener on 127.0.0.1 that sends ``payload`` to every connection (None: closes it at once) and keeps
    it open until :meth:`close`."""

    def __init__(self, payload: bytes | None):
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        self.payload = payload
        self.conns: list[socket.socket] = []
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            if self.payload is None:
                conn.close()
                continue
            try:
                conn.sendall(self.payload)
            except OSError:
                pass
            self.conns.append(conn)

    def close(self) -> None:
        self.sock.close()
        for conn in self.conns:
            conn.close()


def _frame(body: bytes) -> bytes:
    """distributed's TCP framing: total length, then the frames (here: one frame holding ``body``)."""
    frames = struct.pack("<Q", 1) + struct.pack("<Q", len(body)) + body
    return struct.pack("<Q", len(frames)) + frames


@pytest.mark.parametrize("payload, expect", [
    (b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n", "did not answer as a Dask scheduler"),
    (struct.pack("<Q", 2**60), "too large"),  # a frame header announcing 2^60 bytes
    (struct.pack("<Q", 40 * 2**30), "too large"),  # 40 GiB: numpy may even allocate it lazily
    (_frame(b"\xc1 not msgpack"), "did not answer as a Dask scheduler"),
    (_frame(b"\x05"), "did not answer as a Dask scheduler"),  # valid msgpack, not a handshake
    (b"", "within 1 s"),  # accepts and never answers
    (None, "cannot reach"),  # accepts and hangs up
])
def test_hostile_scheduler_is_one_runtime_line_within_the_timeout(tmp_path, payload, expect, capfd):
    server = _Server(payload)
    out = tmp_path / "sweep"
    try:
        t0 = time.monotonic()
        code = main(["sweep", str(CONFIG), "--seeds", "0", "--out", str(out), "--scheduler",
                     f"127.0.0.1:{server.port}", "--connect-timeout", "1"])
        took = time.monotonic() - t0
    finally:
        server.close()
    line = _one_line(capfd.readouterr().err)  # fd level: distributed's own log lines would show here
    assert code == 1, line
    assert f"tcp://127.0.0.1:{server.port}" in line and expect in line
    assert took < 10.0  # --connect-timeout 1 (+ the probe's 2 s), far below distributed's own 30 s
    assert not out.exists()  # the lock's directory, created for this sweep, is gone again


def test_connect_timeout_is_validated(tmp_path, capsys):
    for bad in ("0", "-1", "nan", "3601", "x"):
        with pytest.raises(SystemExit) as exc:
            main(["sweep", str(CONFIG), "--seeds", "0", "--out", str(tmp_path), "--scheduler", "h:1",
                  "--connect-timeout", bad])
        assert exc.value.code == 2
        assert "--connect-timeout" in _one_line(capsys.readouterr().err)  # argparse's error, one line
    assert main(["sweep", str(CONFIG), "--seeds", "0", "--out", str(tmp_path), "--connect-timeout", "5"]) == 2
    assert "--scheduler only" in _one_line(capsys.readouterr().err)


# ------------------------------------------------------------------------------------------ seeds
def test_seed_ranges_are_bounded():
    assert len(parse_seeds("0-99999")) == 100_000  # the bound itself
    assert len(parse_seeds("0-49999,50000-99999")) == 100_000
    assert parse_seeds("0-99999,5")[-1] == 99_999  # repeats do not count twice
    with pytest.raises(SweepError, match="100,000"):
        parse_seeds("0-100000")  # one past the bound
    with pytest.raises(SweepError, match="100,000"):
        parse_seeds("0-99999,100000")
    t0 = time.monotonic()
    with pytest.raises(SweepError, match="100,000"):
        parse_seeds("0-9999999999")
    with pytest.raises(SweepError, match="100,000"):
        parse_seeds("5-9223372036854775807")
    assert time.monotonic() - t0 < 1.0  # refused before building anything
    assert parse_seeds("9223372036854775807") == [2**63 - 1]  # the largest seed
    with pytest.raises(SweepError, match="largest"):
        parse_seeds("9223372036854775808")


@pytest.mark.parametrize("text", [
    "5-3", "-3", "-3-5", "3--5", "3-", "a", "1.5", "1e3", "0x10", "", ",", "1,,2", "٣", "１２", "0-٩", "²",
    "1" * 5000, "0-" + "9" * 5000,
])
def test_malformed_seed_ranges(text):
    with pytest.raises(SweepError):  # a SweepError, not int()'s own ValueError (5000 digits) nor a hang
        parse_seeds(text)


def test_cli_refuses_a_huge_seed_range_at_once(tmp_path, capsys):
    t0 = time.monotonic()
    assert main(["sweep", str(CONFIG), "--seeds", "0-9999999999", "--out", str(tmp_path / "s")]) == 2
    assert "100,000" in _one_line(capsys.readouterr().err)
    assert time.monotonic() - t0 < 10.0 and not (tmp_path / "s").exists()  # 10^10 seeds would never end


# ------------------------------------------------------------------------------------------ job records
def _counting_job(x: int, run_dir: Path) -> dict:
    """Planted job: appends to run_dir/calls.txt (its result file), returns x²."""
    with (run_dir / "calls.txt").open("a") as fh:
        fh.write("run\n")
    return {"square": x * x}


def _jobs(values) -> list[Job]:
    return [Job(f"x{v}", functools.partial(_counting_job, v)) for v in values]


def _calls(out: Path, name: str) -> int:
    return len((out / "jobs" / name / "calls.txt").read_text().splitlines())


def _record(out: Path, name: str) -> dict:
    return json.loads((out / "jobs" / name / JOB_FILE).read_text())


def test_only_a_genuine_finished_record_is_reused(tmp_path):
    out = tmp_path
    values = list(range(12))
    run_sweep(_jobs(values), out, workers=0, threads=None)
    assert all(_calls(out, f"x{v}") == 1 for v in values)
    good = _record(out, "x0")
    assert set(good) >= {"name", "key", "status", "wall_s", "result", "files"}

    def plant(name: str, record) -> None:
        text = record if isinstance(record, str) else json.dumps(record)
        (out / "jobs" / name / JOB_FILE).write_text(text)

    plant("x1", {"status": "done"})  # the tester's record: nothing but a status
    plant("x2", {**_record(out, "x3"), "name": "x2"})  # another job's record (its key) under this name
    plant("x3", {**good, "name": "x3", "key": _record(out, "x3")["key"], "wall_s": "fast"})  # wrong type
    plant("x4", {k: v for k, v in _record(out, "x4").items() if k != "files"})  # a field missing
    plant("x5", {**_record(out, "x5"), "result": [25]})  # result not a mapping
    plant("x6", {**_record(out, "x6"), "files": {"calls.txt": "4"}})  # sizes not numbers
    plant("x7", "{not json")
    plant("x8", [_record(out, "x8")])  # not an object
    (out / "jobs" / "x9" / "calls.txt").write_text("")  # its result file changed behind its back
    plant("x10", {**_record(out, "x10"), "name": "x0"})  # names another job
    (out / "jobs" / "x12").mkdir()
    plant("x12", {"status": "done", "name": "x12", "wall_s": 1, "result": {}})  # a job that never ran
    notices: list[str] = []
    res = run_sweep(_jobs([*values, 12]), out, workers=0, threads=None, notice=notices.append)
    rerun = [f"x{v}" for v in range(1, 11)] + ["x12"]
    assert sorted(res.skipped) == ["x0", "x11"]  # the genuine records, reused
    assert sorted(n.split(":")[0] for n in notices) == sorted(rerun)  # one line per untrusted record
    assert all("running the job again" in n and "\n" not in n for n in notices)
    assert _calls(out, "x0") == _calls(out, "x11") == 1
    assert [_calls(out, n) for n in rerun] == [2] * 8 + [1, 2, 1]  # x9's emptied file started afresh
    assert all(r["status"] == "done" for r in res.records)
    assert res.results()["x1"] == {"square": 1} and res.results()["x12"] == {"square": 144}


def test_a_bare_done_status_is_not_trusted(tmp_path, capsys):
    (tmp_path / "jobs" / "x4").mkdir(parents=True)
    (tmp_path / "jobs" / "x4" / JOB_FILE).write_text('{"status": "done"}')
    res = run_sweep(_jobs([4]), tmp_path, workers=0, threads=None)
    assert res.skipped == [] and res.results()["x4"] == {"square": 16}
    assert _calls(tmp_path, "x4") == 1
    line = _one_line(capsys.readouterr().err)  # the default notice: one line on stderr
    assert line.startswith("x4: ") and "not trusted" in line and "running the job again" in line


def test_a_record_of_other_arguments_is_not_reused(tmp_path):
    run_sweep(_jobs([2]), tmp_path, workers=0, threads=None)
    # the same name, another argument (as another --set or --seed would be): its record is not this job's
    res = run_sweep([Job("x2", functools.partial(_counting_job, 3))], tmp_path, workers=0, threads=None)
    assert res.skipped == [] and res.results()["x2"] == {"square": 9}
    assert _calls(tmp_path, "x2") == 2


def test_train_job_key_covers_config_content_overrides_and_seed(tmp_path):
    from bptsb_ros.jobs.sweep import job_key

    cfg = tmp_path / "c.yaml"
    cfg.write_text("task: locomotion\n")
    base = job_key(Job("seed-0", TrainJob(str(cfg), ("sim_time=2",), 0)))
    assert job_key(Job("seed-0", TrainJob(str(cfg), ("sim_time=2",), 0))) == base  # stable
    assert job_key(Job("seed-0", TrainJob(str(cfg), ("sim_time=3",), 0))) != base
    assert job_key(Job("seed-0", TrainJob(str(cfg), ("sim_time=2",), 1))) != base
    # the same file spelled another way: the same job
    assert job_key(Job("seed-0", TrainJob(str(tmp_path / "." / "c.yaml"), ("sim_time=2",), 0))) == base
    assert job_key(Job("seed-1", TrainJob(str(cfg), ("sim_time=2",), 0))) != base  # another name
    cfg.write_text("task: locomotion\nsim_time: 5\n")  # the same path, an edited config
    assert job_key(Job("seed-0", TrainJob(str(cfg), ("sim_time=2",), 0))) != base
