"""Serial and ``parallel=True`` builds of one kernel source, each with its own Numba disk cache.

Numba names a function's cache files after its module, qualified name and first line, not after its
target options (numba issue #6845, open in 0.68): ``njit(cache=True)(f)`` and
``njit(cache=True, parallel=True)(f)`` share one cache index, and whichever build is compiled first is
loaded by both from then on. A process that first ran a small scene (serial kernels) then ran the large
scenes' "parallel" kernels on one thread, and the other way round the small scenes paid the thread
launches they are meant to avoid. :func:`parallel_twin` compiles a renamed copy of the function instead
(``<qualname>_parallel``), whose cache files are its own.
"""

from __future__ import annotations

import types

from numba import njit


def _renamed_copy(func, suffix):
    """A copy of ``func`` (a dispatcher's Python function or a plain function) named ``<name><suffix>``: same
    code, globals, defaults and closure; compiled, it gets cache files of its own."""
    f = getattr(func, "py_func", func)
    twin = types.FunctionType(f.__code__, f.__globals__, f.__name__ + suffix, f.__defaults__, f.__closure__)
    twin.__qualname__ = f.__qualname__ + suffix
    twin.__doc__ = f.__doc__
    return twin


def parallel_twin(func):
    """``njit(cache=True, parallel=True)`` build of a copy of ``func`` named ``<name>_parallel`` (same code,
    globals, defaults and closure; its own cache files)."""
    return njit(cache=True, parallel=True)(_renamed_copy(func, "_parallel"))


def serial_and_parallel(func):
    """(serial, parallel) dispatchers of ``func``: ``njit(cache=True)`` and :func:`parallel_twin`."""
    return njit(cache=True)(func), parallel_twin(func)
