"""pytest plugin that reports how far the tolerance tests are from their limits (docs/testing.md quotes them).

It wraps, without changing what they assert, the helpers the tests already use and prints the largest values
seen at the end of the run:

* ``test_gradients.fd_relative_error``: finite-difference vs analytic gradient relative error (limit 1e-5);
* ``torch.testing.assert_close`` inside ``test_adjoint_equals_autograd``: max |adjoint − autograd| / max |autograd|
  (limit rtol 1e-9);
* ``test_physics.momenta`` in the momentum tests: drift of linear momentum (limit 1e-12) and, undamped, of
  angular momentum (limit 1e-11).

Usage::

    PYTHONPATH=scripts .venv/bin/python -m pytest -q -p margins_plugin tests/body/test_gradients.py \\
        tests/body/test_physics.py -k "gradients or adjoint or momentum"
"""

from __future__ import annotations

from typing import Any

import pytest
import torch

_records: list[tuple[str, str, float]] = []
_current: dict[str, str] = {"id": ""}


def pytest_runtest_setup(item: pytest.Item) -> None:
    _current["id"] = item.nodeid


def pytest_collection_modifyitems(session: pytest.Session, config: pytest.Config, items: list[pytest.Item]) -> None:
    del session, config
    modules = {item.module.__name__: item.module for item in items if isinstance(item, pytest.Function)}
    if "test_gradients" in modules:
        _wrap_gradients(modules["test_gradients"])
    if "test_physics" in modules:
        _wrap_momenta(modules["test_physics"])


def _wrap_gradients(tg: Any) -> None:
    fd = tg.fd_relative_error

    def fd_relative_error(*args: Any, **kwargs: Any) -> tuple[float, float]:
        err, norm = fd(*args, **kwargs)
        _records.append(("finite differences: relative gradient error (limit 1e-5)", _current["id"], err))
        return err, norm

    tg.fd_relative_error = fd_relative_error
    close = torch.testing.assert_close

    def assert_close(actual: Any, expected: Any, *args: Any, **kwargs: Any) -> None:
        if "adjoint_equals_autograd" in _current["id"]:
            rel = float((actual - expected).abs().max() / expected.abs().max())
            _records.append(("adjoint vs autograd: max relative difference (limit 1e-9)", _current["id"], rel))
        close(actual, expected, *args, **kwargs)

    tg.torch.testing.assert_close = assert_close


def _wrap_momenta(tp: Any) -> None:
    momenta = tp.momenta
    first: dict[str, tuple[torch.Tensor, torch.Tensor]] = {}

    def wrapped(body: Any, state: Any) -> tuple[torch.Tensor, torch.Tensor]:
        p, ang = momenta(body, state)
        key = _current["id"]
        if key not in first:
            first[key] = (p.clone(), ang.clone())
        elif "conserves_momentum" in key:
            _records.append(("linear momentum drift [kg·m/s] (limit 1e-12)", key,
                             float((p - first.pop(key)[0]).abs().max())))
        elif "conserves_angular" in key:
            _records.append(("angular momentum drift [kg·m²/s] (limit 1e-11)", key,
                             float((ang - first.pop(key)[1]).abs().max())))
        return p, ang

    tp.momenta = wrapped


def pytest_terminal_summary(terminalreporter: Any) -> None:
    kinds: dict[str, list[tuple[float, str]]] = {}
    for kind, node, value in _records:
        kinds.setdefault(kind, []).append((value, node))
    for kind, values in kinds.items():
        values.sort(reverse=True)
        terminalreporter.write_line(f"{kind}: {len(values)} checks, largest:")
        for value, node in values[:3]:
            terminalreporter.write_line(f"    {value:.3g}  {node}")
