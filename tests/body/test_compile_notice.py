"""The line before a numba compile (``body/compile_notice.py``): printed when numba's on-disk cache holds no build
of the kernel about to be called, never when it does.

Real numba on planted modules (a one-line ``njit(cache=True)`` function written into a temporary directory, whose
cache lands in its own ``__pycache__``; each compile takes a fraction of a second), and the project's own kernels
with the arguments the code passes them, against the cache the rest of the suite uses.
"""

from __future__ import annotations

import importlib.util
import io
import os
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from bptsb_ros.body import compile_notice, kernel

SOURCE = "from numba import njit\n\n\n@njit(cache={cache})\ndef f(x):\n    return x + {n}\n"
LINE = "compiling the numba kernels (about 8 s, once; later runs use the cache)\n"


def _load(path: Path, name: str):
    """Import (again) the module at ``path`` as ``name``: a fresh dispatcher, nothing built in this process."""
    sys.modules.pop(name, None)
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture
def planted(tmp_path, monkeypatch):
    """A module with ``f(x) = x + 1`` cached beside itself, and a fresh notice state (nothing printed yet)."""
    monkeypatch.setattr(compile_notice, "_announced", False)
    monkeypatch.setattr(compile_notice, "enabled", True)
    name = f"planted_kernel_{abs(hash(tmp_path)) % 10**8}"
    path = tmp_path / f"{name}.py"
    path.write_text(SOURCE.format(cache=True, n=1))
    yield path, name
    sys.modules.pop(name, None)


def test_cold_then_warm_then_stale(planted):
    path, name = planted
    f = _load(path, name).f
    assert compile_notice.cache_is_cold(f, (1.0,))  # no index file yet
    assert f(1.0) == 2.0  # compiles and writes the cache
    assert list((path.parent / "__pycache__").glob(f"{name}.f-*.nbi"))
    assert not compile_notice.cache_is_cold(f, (1.0,))  # built in this process
    f = _load(path, name).f
    assert not f.overloads and not compile_notice.cache_is_cold(f, (1.0,))  # a fresh process would load it
    assert compile_notice.cache_is_cold(f, (1,))  # another argument type: numba compiles an int64 build
    assert compile_notice.cache_is_cold(f, (np.float32(1.0),))
    path.write_text(SOURCE.format(cache=True, n=2))  # the source changed: its stamp no longer matches
    f = _load(path, name).f
    assert compile_notice.cache_is_cold(f, (1.0,))
    assert f(1.0) == 3.0 and not compile_notice.cache_is_cold(_load(path, name).f, (1.0,))


def test_a_removed_index_file_is_cold_again(planted):
    path, name = planted
    _load(path, name).f(1.0)
    assert not compile_notice.cache_is_cold(_load(path, name).f, (1.0,))
    for index in (path.parent / "__pycache__").glob(f"{name}.f-*.nbi"):
        index.unlink()
    assert compile_notice.cache_is_cold(_load(path, name).f, (1.0,))


def test_an_uncached_function_is_never_announced(planted):
    path, name = planted
    path.write_text(SOURCE.format(cache=False, n=1))
    assert not compile_notice.cache_is_cold(_load(path, name).f, (1.0,))  # it compiles in every process
    assert not compile_notice.cache_is_cold(len, (1.0,))  # not a dispatcher at all


def test_the_line_once_per_process_and_only_when_cold(planted, monkeypatch):
    path, name = planted
    f = _load(path, name).f
    f(1.0)
    out = io.StringIO()
    assert not compile_notice.announce_if_cold(_load(path, name).f, (1.0,), 8.0, out)  # warm: no line
    assert out.getvalue() == ""
    monkeypatch.setattr(compile_notice, "enabled", False)
    assert not compile_notice.announce_if_cold(_load(path, name).f, (1,), 8.0, out)  # cold, but switched off
    monkeypatch.setattr(compile_notice, "enabled", True)
    assert compile_notice.announce_if_cold(_load(path, name).f, (1,), 8.0, out)  # cold
    assert not compile_notice.announce_if_cold(_load(path, name).f, (np.float32(1),), 8.0, out)  # once only
    assert out.getvalue() == LINE


def test_kernel_forward_prints_the_line_before_its_first_cold_call(planted, monkeypatch, capsys):
    """``kernel.forward`` with its serial kernel replaced by a planted one of the same arity (cold, then built)."""
    path, name = planted
    path.write_text("from numba import njit\n\n\n@njit(cache=True)\ndef f(" + ", ".join(f"a{i}" for i in range(18))
                    + "):\n    a14[0] = a0[0] + 1.0\n")
    f = _load(path, name).f
    monkeypatch.setattr(kernel, "_forward_serial", f)
    args = [np.zeros(1)] * 14 + [np.zeros(1), np.zeros(1), np.zeros(1), np.zeros(1)]
    kernel.forward(*args)
    kernel.forward(*args)
    assert capsys.readouterr().err == f"compiling the numba kernels (about {kernel.COMPILE_S['forward']:.0f} s, " \
                                      "once; later runs use the cache)\n"
    assert args[14][0] == 1.0  # the replaced kernel ran
    monkeypatch.setattr(compile_notice, "_announced", False)
    monkeypatch.setattr(kernel, "_forward_serial", _load(path, name).f)
    kernel.forward(*args)  # a fresh dispatcher of the now cached function: no line
    assert capsys.readouterr().err == ""


class _Recorder:
    """A stand-in for a kernel dispatcher that records the arguments the code passes and calls the real one."""

    def __init__(self, real) -> None:
        self.real, self.calls = real, []
        self.overloads: dict = {}  # as if nothing were built in this process: the callers check the cache

    def __call__(self, *args):
        self.calls.append(args)
        return self.real(*args)


def test_the_project_kernels_are_warm_once_cached_for_the_arguments_the_code_passes(monkeypatch):
    """A short Lissajous training window on the numba path and on the fused path (float64, as most of the suite:
    they load numba's cache, or compile once and write it); then a fresh dispatcher of each kernel, nothing built
    in it, finds its build on disk for exactly the arguments the code passed, and a kernel under a name never
    cached is cold (without compiling it)."""
    import torch
    from numba import njit

    from bptsb_ros.bench import suite as bench
    from bptsb_ros.training import fused_kernel

    w = replace(bench.WORKLOADS["lissajous"], window=10)
    asked: list[tuple] = []
    monkeypatch.setattr(compile_notice, "announce_if_cold", lambda fn, args, seconds: asked.append((fn, args, seconds)))
    recorders = {name: _Recorder(getattr(kernel, name)) for name in ("_forward_serial", "_adjoint_serial")}
    for name, recorder in recorders.items():
        monkeypatch.setattr(kernel, name, recorder)
    _body, _opt, state, run_window = bench._setup(w, True, torch.float64, "numba")
    loss, _ = run_window(state)
    loss.backward()
    for name, recorder in recorders.items():  # the fused window calls the real ones from compiled code
        monkeypatch.setattr(kernel, name, recorder.real)
    recorders["swg_window"] = _Recorder(fused_kernel.swg_window)
    monkeypatch.setattr(fused_kernel, "swg_window", recorders["swg_window"])
    window, _step, state = bench.fused_runner(w, torch.float64)
    window(state)
    estimates = {"_forward_serial": kernel.COMPILE_S["forward"], "_adjoint_serial": kernel.COMPILE_S["adjoint"],
                 "swg_window": fused_kernel.COMPILE_S}
    assert [(fn, seconds) for fn, _args, seconds in asked] == [(r, estimates[n]) for n, r in recorders.items()]
    for (_fn, args, _seconds), (name, recorder) in zip(asked, recorders.items(), strict=True):
        assert len(recorder.calls) == 1 and all(a is b for a, b in zip(args, recorder.calls[0], strict=True)), name
        fresh = njit(**kernel._JIT)(recorder.real.py_func)
        assert not fresh.overloads
        assert not compile_notice.cache_is_cold(fresh, recorder.calls[0]), name
        never = njit(**kernel._JIT)(kernel._renamed(recorder.real.py_func, f"_never_cached_{os.getpid()}"))
        assert compile_notice.cache_is_cold(never, recorder.calls[0]), name
        assert not never.overloads
