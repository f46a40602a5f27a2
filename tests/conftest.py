"""Test-session environment shared by every test.

At import time (before any test module imports rclpy or torch) this pins DDS discovery to this host and
gives the session a private ROS domain, so parallel sessions and other machines never see its traffic:

* ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` always; ``ROS_STATIC_PEERS`` is cleared.
* ``ROS_DOMAIN_ID`` = ``BPTSB_TEST_DOMAIN_ID`` if set, else 100 + pid % 101 (a value in 100..200); under
  pytest-xdist each worker adds its number to that, so workers never share a domain.
* ``OMP_NUM_THREADS=1`` and ``MPLBACKEND=Agg`` unless already set (2 shared cores, no display).
* ``BPTSB_FIGURE_FORMATS=png`` unless already set: the experiments' figures skip their PDF copy (half of a
  figure's time); tests/analysis/test_figures.py unsets it and checks the PNG + PDF of every figure.
* ``BPTSB_COMPILE_NOTICE=0`` unless already set: no "compiling the numba kernels" line, which only a test that
  happens to meet a cold cache would print (tests/body/test_compile_notice.py turns it on for its own checks).
* ``FASTRTPS_DEFAULT_PROFILES_FILE=tests/fastdds_test_profile.xml`` unless a Fast DDS profile file is already set:
  reliable writers send a heartbeat every 0.1 s instead of every 3 s, so a wait for acknowledgements (every live
  run ends with one) takes milliseconds instead of up to 3 s. Nothing else about DDS changes (see the file).

Subprocesses started by tests inherit these through ``os.environ``; the ``ros_env`` fixture returns a copy
for tests that build their own environment.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parent.parent
DOMAIN_ID_MIN = 100
DOMAIN_ID_MAX = 200


def _xdist_worker_index() -> int:
    """Return this process's pytest-xdist worker number (``gw3`` → 3), or 0 outside a distributed run."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    return int(worker[2:]) if worker.startswith("gw") and worker[2:].isdigit() else 0


def _session_domain_id() -> int:
    """Return the ROS domain for this test process: ``BPTSB_TEST_DOMAIN_ID`` or one derived from a pid.

    Under pytest-xdist every worker gets its own domain: the session's base (the controller's pid, which all
    workers share as their parent, or the override) plus the worker's number, so two workers never meet.
    """
    worker = _xdist_worker_index()
    override = os.environ.get("BPTSB_TEST_DOMAIN_ID")
    if override is None:
        base_pid = os.getppid() if "PYTEST_XDIST_WORKER" in os.environ else os.getpid()
        return DOMAIN_ID_MIN + (base_pid + worker) % (DOMAIN_ID_MAX - DOMAIN_ID_MIN + 1)
    try:
        value = int(override)
    except ValueError:
        raise pytest.UsageError(f"BPTSB_TEST_DOMAIN_ID must be an integer in 0..232, got {override!r}") from None
    if not 0 <= value + worker <= 232:
        raise pytest.UsageError(f"BPTSB_TEST_DOMAIN_ID must be an integer in 0..{232 - worker}, got {value}")
    return value + worker


SESSION_DOMAIN_ID = _session_domain_id()
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.pop("ROS_STATIC_PEERS", None)
os.environ["ROS_DOMAIN_ID"] = str(SESSION_DOMAIN_ID)
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("BPTSB_FIGURE_FORMATS", "png")
os.environ.setdefault("BPTSB_COMPILE_NOTICE", "0")
FASTDDS_PROFILE = REPO_ROOT / "tests" / "fastdds_test_profile.xml"
if not (os.environ.get("FASTRTPS_DEFAULT_PROFILES_FILE") or os.environ.get("FASTDDS_DEFAULT_PROFILES_FILE")):
    os.environ["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(FASTDDS_PROFILE)


#: The fixtures that give a test a ROS domain: a test that asks for one (itself or through another fixture) runs ROS.
ROS_FIXTURES = frozenset({"ros_env", "ros_domain_id", "quarantine_ros", "fresh_ros"})
ROS_TESTS = REPO_ROOT / "tests" / "ros"


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Mark ``ros`` every test under ``tests/ros/`` and every test that uses a ROS domain fixture (before ``-m``
    selects). Tests elsewhere that need ROS 2 without such a fixture (rclpy's serializer, the message packages)
    carry the mark themselves."""
    del config
    for item in items:
        if item.path.is_relative_to(ROS_TESTS) or ROS_FIXTURES.intersection(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.ros)


def pytest_report_header(config: pytest.Config) -> str:
    return (
        f"bptsb_ros: python {sys.executable}, ROS_DOMAIN_ID={SESSION_DOMAIN_ID}, "
        f"ROS_AUTOMATIC_DISCOVERY_RANGE={os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE']}"
    )


@pytest.fixture(scope="session")
def repo_root() -> Path:
    """The repository root (the directory holding setup.py and package.xml)."""
    return REPO_ROOT


@pytest.fixture(scope="session")
def ros_domain_id() -> int:
    """This session's private ROS domain id (also exported as ``ROS_DOMAIN_ID``)."""
    return SESSION_DOMAIN_ID


def ros_subprocess_env(domain: int) -> dict[str, str]:
    """A copy of the environment for ROS subprocesses on ``domain``, with localhost discovery."""
    env = dict(os.environ)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env["ROS_DOMAIN_ID"] = str(domain)
    env.pop("ROS_STATIC_PEERS", None)
    return env


@pytest.fixture
def ros_env() -> dict[str, str]:
    """A copy of the environment for ROS subprocesses: localhost discovery, this session's domain."""
    return ros_subprocess_env(SESSION_DOMAIN_ID)


#: A second private domain for tests that leave stale DDS participants behind (a SIGKILLed node stays
#: discoverable until its lease expires, ~20 s), so later tests in the session domain never see them.
QUARANTINE_DOMAIN_ID = DOMAIN_ID_MIN + (SESSION_DOMAIN_ID - DOMAIN_ID_MIN + 50) % (DOMAIN_ID_MAX - DOMAIN_ID_MIN + 1)


@pytest.fixture
def quarantine_ros() -> tuple[int, dict[str, str]]:
    """(domain id, subprocess environment) of the quarantine domain."""
    return QUARANTINE_DOMAIN_ID, ros_subprocess_env(QUARANTINE_DOMAIN_ID)


#: A third private domain that nothing else in the session uses: for tests that judge which publishers the graph
#: shows (a participant left in the session domain by an earlier test would be listed, or crowd discovery).
FRESH_DOMAIN_ID = DOMAIN_ID_MIN + (SESSION_DOMAIN_ID - DOMAIN_ID_MIN + 25) % (DOMAIN_ID_MAX - DOMAIN_ID_MIN + 1)


@pytest.fixture
def fresh_ros() -> tuple[int, dict[str, str]]:
    """(domain id, subprocess environment) of the fresh domain."""
    return FRESH_DOMAIN_ID, ros_subprocess_env(FRESH_DOMAIN_ID)


#: A fourth private domain, for one launch whose startup must meet no participant but its own: a brain's publisher
#: left in the session domain by an earlier test (a SIGKILLed node, ~20 s) would stand in for the launch's brain.
ISOLATED_DOMAIN_ID = DOMAIN_ID_MIN + (SESSION_DOMAIN_ID - DOMAIN_ID_MIN + 75) % (DOMAIN_ID_MAX - DOMAIN_ID_MIN + 1)


@pytest.fixture(autouse=True)
def _restore_stop_signals():
    """Put SIGINT/SIGTERM back as they were after each test: their handlers and the thread's signal mask. A node
    or command run in the test process blocks SIGINT while it starts and ignores both once it has stopped
    (``ros.runtime``); a blocked or ignored signal stays so in every child the later tests start, and a Ctrl-C
    test would then see its interrupt vanish."""
    import signal

    saved = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, set())
    yield
    signal.pthread_sigmask(signal.SIG_SETMASK, mask)
    for sig, handler in saved.items():
        if signal.getsignal(sig) is not handler and handler is not None:
            signal.signal(sig, handler)


@pytest.fixture(autouse=True)
def _every_judged_run_judges_again(monkeypatch):
    """Every experiment run in a test that judged its claims through ``Context.judge`` must judge to the same
    claims again from its stored numbers (what ``bptsb reproduce --rejudge`` relies on): a run that mixes judged
    claims with claims made another way, or whose stored numbers decode to other values, fails the test that ran
    it, whichever test that is."""
    from bptsb_ros.experiments import registry

    real = registry._rejudges_to_itself

    def strict(result, log):
        ok = real(result, log)
        if result.measured and not ok:
            pytest.fail(f"{result.experiment}: its claims do not judge again to themselves from result.measured")
        return ok

    monkeypatch.setattr(registry, "_rejudges_to_itself", strict)
