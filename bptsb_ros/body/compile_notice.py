"""One line on stderr before numba compiles a kernel whose on-disk cache is cold.

The compiled kernels (:mod:`bptsb_ros.body.kernel`, :mod:`bptsb_ros.training.fused_kernel`) are built with
``cache=True``: the first call in a process loads them from numba's on-disk cache in about a second, or, when
the cache holds no build for that function, these argument types and this CPU (a fresh install, an edited
kernel, another numba version, another dtype), compiles them, which takes seconds to tens of seconds without any
output. :func:`announce_if_cold` says so first, once per process.

The cache is cold when numba's index file for the function (``<module>.<function>-<line>.pyXY.nbi``, in the
``__pycache__`` beside the module, or under ``$NUMBA_CACHE_DIR``) is missing, was written by another numba
version, records another source stamp (the file changed) or has no entry for the key numba would look up
(the argument types, the CPU, the function's bytecode). That is exactly the lookup numba's dispatcher does
before it compiles, so the line appears when, and only when, a compile follows.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence
from typing import Any, TextIO

#: whether :func:`announce_if_cold` prints at all: not with ``BPTSB_COMPILE_NOTICE=0`` in the environment (the
#: test suite's, whose stderr must not depend on the cache's state), nor in the processes where ``bptsb bench``
#: times the compile itself (its progress line says so)
enabled = os.environ.get("BPTSB_COMPILE_NOTICE", "1") != "0"
_announced = False


def cache_is_cold(dispatcher: Any, args: Sequence[Any]) -> bool:
    """True when calling ``dispatcher`` (a numba ``njit(cache=True)`` function) with ``args`` will compile it:
    it has no build in this process and numba's on-disk cache holds none for these argument types, this CPU
    and the function's current source. False when it will not, and also when the dispatcher has no on-disk cache
    or numba's cache internals are not as this function expects (no line rather than a wrong one)."""
    if getattr(dispatcher, "overloads", None):  # built or loaded in this process already
        return False
    try:
        from numba.core.caching import FunctionCache

        cache = dispatcher._cache
        if not isinstance(cache, FunctionCache):
            return False
        signature = tuple(dispatcher.typeof_pyval(a) for a in args)
        key = cache._index_key(signature, dispatcher.targetctx.codegen())
        return key not in cache._cache_file._load_index()
    except Exception:  # noqa: BLE001 - a numba whose internals moved: say nothing
        return False


def announce_if_cold(dispatcher: Any, args: Sequence[Any], seconds: float, stream: TextIO | None = None) -> bool:
    """Print ``compiling the numba kernels (about N s, once; later runs use the cache)`` to ``stream``
    (default stderr) when :func:`cache_is_cold` says the call ``dispatcher(*args)`` is about to compile, at most
    once per process; ``seconds`` is the compile time measured for that kernel on 2 cores. Returns whether it
    printed. Callers guard it with ``if not dispatcher.overloads`` so that a warm call costs one attribute test."""
    global _announced
    if _announced or not enabled or not cache_is_cold(dispatcher, args):
        return False
    _announced = True
    print(f"compiling the numba kernels (about {seconds:.0f} s, once; later runs use the cache)",
          file=stream if stream is not None else sys.stderr, flush=True)
    return True


__all__ = ["announce_if_cold", "cache_is_cold", "enabled"]
