"""The serial and ``parallel=True`` builds of one kernel source keep separate Numba disk caches.

Numba names cache files after a function's module, qualified name and first line, not its options
(numba issue #6845): two builds of one function with ``cache=True`` shared one cache index, and the build
compiled first was loaded by both (measured before the fix: the "parallel" contact iteration of the chain
solver ran at the serial build's speed, 2 × slower with one Numba thread, the "serial" one as fast).
"""

from __future__ import annotations

import importlib
import pkgutil

from numba.core.registry import CPUDispatcher

import headsim


def _cached_dispatchers():
    """(module.name, dispatcher) of every cached Numba kernel in headsim's kernel modules."""
    found = []
    for info in pkgutil.walk_packages(headsim.__path__, "headsim."):
        if "_kernels" not in info.name:
            continue
        module = importlib.import_module(info.name)
        for name, obj in vars(module).items():
            if isinstance(obj, CPUDispatcher) and hasattr(obj._cache, "_cache_file"):
                found.append((f"{info.name}.{name}", obj))
    return found


def test_builds_with_different_options_have_different_cache_files():
    index = {}
    for name, disp in _cached_dispatchers():
        key = disp._cache._cache_file._index_name
        index.setdefault(key, {})[name] = bool(disp.targetoptions.get("parallel", False))
    shared = {k: v for k, v in index.items() if len(set(v.values())) > 1}
    assert not shared, f"serial and parallel builds share a cache index: {shared}"
    # the check sees the twins it is about (not vacuous)
    builds = {n: p for v in index.values() for n, p in v.items()}
    for serial in ("headsim.solvers._kernels.chains_coupled.coupled_iterate",
                   "headsim.solvers._kernels.chains_pairs.detect_rows",
                   "headsim.solvers._kernels.pbd.project_distance_coloured"):
        assert builds[serial] is False
        assert builds[serial + "_parallel"] is True
