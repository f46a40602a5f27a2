"""Reaching a Dask distributed scheduler for ``bptsb sweep --scheduler`` / ``reproduce --scheduler``, safely.

:func:`scheduler_address` accepts only ``tcp://HOST:PORT`` and ``HOST:PORT`` (other schemes, paths, user info,
ports outside 1 … 65535 are usage errors); :func:`connect` returns a ``distributed.Client`` or raises
:class:`~bptsb_ros.jobs.sweep.SchedulerError` with one line within about the timeout, whatever the other end sends
(junk, a frame announcing 2⁶⁰ bytes) or does not send.
"""

from __future__ import annotations

import ipaddress
import re
import threading
from typing import Any

from bptsb_ros.jobs.sweep_errors import SchedulerError, SweepError

_HOST_LABEL = re.compile(r"^(?!-)[A-Za-z0-9_-]{1,63}(?<!-)$")


def scheduler_address(text: str) -> str:
    """``tcp://HOST:PORT`` or ``HOST:PORT`` (HOST a host name, an IPv4 address or a bracketed IPv6 address;
    PORT 1 … 65535) → the ``tcp://`` address; anything else (other schemes, no port, a path) is a SweepError."""
    shown = repr(text[:80]) if isinstance(text, str) else repr(text)
    usage = f"--scheduler {shown}: expected tcp://HOST:PORT or HOST:PORT, e.g. tcp://10.0.0.5:8786"
    if not isinstance(text, str) or not text.isascii() or not text.isprintable():
        raise SweepError(usage)
    rest = text
    if "://" in text:
        scheme, rest = text.split("://", 1)
        if scheme.lower() != "tcp":
            raise SweepError(f"--scheduler {shown}: only tcp:// Dask schedulers are supported, not {scheme[:20]}://")
    m = re.fullmatch(r"(\[[0-9A-Fa-f:.]+\]|[^:/\[\]@?#\s]+):([0-9]{1,5})", rest)
    if not m:
        raise SweepError(usage)
    host, port = m.group(1), int(m.group(2))
    if not 1 <= port <= 65535:
        raise SweepError(f"--scheduler {shown}: port {port} is not in 1 … 65535")
    try:
        ipaddress.ip_address(host.strip("[]") if host.startswith("[") else host)
    except ValueError:
        labels = host.rstrip(".").split(".")
        if host.startswith("[") or len(host) > 253 or not all(_HOST_LABEL.match(p) for p in labels):
            raise SweepError(f"--scheduler {shown}: {host[:60]!r} is not a host name or IP address") from None
    return f"tcp://{host}:{port}"


def connect(address: str, timeout: float) -> Any:
    """A ``distributed.Client`` of the scheduler at ``address``, or :class:`SchedulerError` within about
    ``timeout`` seconds, whatever the other end does.

    ``Client(timeout=...)`` bounds the TCP connect but not distributed's handshake: a listener that accepts and
    never answers blocks it forever, and junk or a frame header announcing 2⁶⁰ bytes raise from deep inside it
    (and leave its shared event loop in a state that hangs the next Client). So a probe on a private event loop
    in a daemon thread first checks, under one deadline, that a Dask scheduler answers an ``identity`` request;
    only then is the Client made. ``inproc://`` addresses (an in-process cluster) skip the probe.
    """
    try:
        from distributed import Client
    except ImportError:
        raise SweepError("--scheduler needs the 'distributed' package (pip install distributed)") from None
    if not address.startswith("inproc://"):
        _probe_scheduler(address, timeout)
    try:
        return Client(address, timeout=f"{timeout}s")
    except Exception as err:  # noqa: BLE001 - it answered the probe and then failed: still one line
        raise SchedulerError(f"cannot connect to the Dask scheduler at {address}: {_first_line(err)}") from None


def _first_line(err: BaseException) -> str:
    text = str(err).strip()
    return f"{type(err).__name__}: {text.splitlines()[0][:200]}" if text else type(err).__name__


def _probe_scheduler(address: str, timeout: float) -> None:
    """Raise :class:`SchedulerError` unless a Dask scheduler at ``address`` answers within ``timeout`` s."""
    import asyncio
    import gc
    import logging

    from distributed.comm import connect

    async def ask() -> Any:
        # the TCP connect (retried while refused or hung up on) and the handshake; its own deadline comes
        # first, so that a scheduler that is down reads "cannot reach", one that never answers "no answer"
        comm = await connect(address, timeout=0.8 * timeout)
        try:
            await comm.write({"op": "identity", "reply": True})
            return await comm.read()
        finally:
            comm.abort()

    box: dict[str, Any] = {}

    def run() -> None:
        try:
            box["reply"] = asyncio.run(asyncio.wait_for(ask(), timeout))
        except TimeoutError:
            box["error"] = f"no Dask scheduler answered at {address} within {timeout:g} s"
        except OSError as err:  # refused, unreachable, closed (distributed's CommClosedError is one)
            box["error"] = f"cannot reach the Dask scheduler at {address}: {_first_line(err)}"
        except (MemoryError, OverflowError) as err:
            box["error"] = (f"{address} did not answer as a Dask scheduler (it announced a message too large to "
                            f"receive: {_first_line(err)})")
        except BaseException as err:  # noqa: BLE001 - junk: one line
            box["error"] = f"{address} did not answer as a Dask scheduler (it sent something else: {_first_line(err)})"
        # Only strings are kept: the exception's frames hold distributed's half-open comm, which dies here,
        # while its logger is quiet (it would say "Closing dangling stream" at exit otherwise).
        gc.collect()

    # distributed logs what it could not parse (CRITICAL, with a traceback): the one line below says it
    quiet = logging.getLogger("distributed")
    level = quiet.level
    quiet.setLevel(logging.CRITICAL + 1)
    try:
        thread = threading.Thread(target=run, name="bptsb-dask-probe", daemon=True)
        thread.start()
        thread.join(timeout + 2.0)  # wait_for's own deadline first; this one if the loop itself is stuck
    finally:
        quiet.setLevel(level)
    if thread.is_alive():
        raise SchedulerError(f"no Dask scheduler answered at {address} within {timeout:g} s")
    if "error" in box:
        raise SchedulerError(box["error"])
    reply = box.get("reply")
    if not isinstance(reply, dict) or reply.get("type") != "Scheduler":
        what = reply.get("type") if isinstance(reply, dict) else type(reply).__name__
        raise SchedulerError(f"{address} did not answer as a Dask scheduler (it says it is {str(what)[:40]!r})")
