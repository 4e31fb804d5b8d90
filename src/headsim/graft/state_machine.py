"""The simulation process state machine of Monkin 2016 (seed 001) §5.4, fig. 7.

States: NULL (no data), READY (data prepared, can start), PROCESS (the solve runs in a worker thread),
COMPLETE (finished: the main thread saves the result and goes to READY), RESET (interrupted: back to
READY without saving), DELETE (cancelled: back to NULL without saving, data dropped).

NULL and READY are only entered by the main thread; PROCESS on the way into the worker and while it
runs; COMPLETE, RESET and DELETE on the way back. The main thread calls :meth:`GraftSession.poll`
(or :meth:`GraftSession.wait`) to perform the transitions back. The prepared data (closed region model,
initial area and volume) is kept in READY, so the solve can be re-run with other parameters (§5.2).
"""

from __future__ import annotations

import enum
import threading
from typing import Callable

from headsim.errors import HeadsimError, ParameterError
from headsim.graft.plan import GraftOptions, GraftResult, GraftSetup, inject_volume, prepare_graft
from headsim.graft.region import FaceRegion

__all__ = ["SimulationState", "GraftSession", "StateError"]


class SimulationState(enum.Enum):
    NULL = "NULL"
    READY = "READY"
    PROCESS = "PROCESS"
    COMPLETE = "COMPLETE"
    RESET = "RESET"
    DELETE = "DELETE"


class StateError(HeadsimError, RuntimeError):
    """An action is not allowed in the current simulation state."""


class GraftSession:
    """Drives preparation, the worker-thread solve, cancellation and re-runs (seed §5.2–5.4).

    ``on_result(result)`` is called in the main thread (from :meth:`poll`) when a run completes; the
    results are also appended to :attr:`results`. Thread-safe: the state is guarded by a lock.
    """

    def __init__(self, on_result: Callable[[GraftResult], None] | None = None):
        self._lock = threading.Lock()
        self._state = SimulationState.NULL
        self._setup: GraftSetup | None = None
        self._thread: threading.Thread | None = None
        self._cancel = threading.Event()
        self._pending: GraftResult | None = None
        self._error: BaseException | None = None
        self._on_result = on_result
        self.results: list[GraftResult] = []
        self.history: list[SimulationState] = [SimulationState.NULL]
        self.progress_steps = 0

    # --- state --------------------------------------------------------------------------------------
    @property
    def state(self) -> SimulationState:
        with self._lock:
            return self._state

    @property
    def setup(self) -> GraftSetup | None:
        return self._setup

    def _set(self, state: SimulationState) -> None:  # call with the lock held
        self._state = state
        self.history.append(state)

    def _require(self, *allowed: SimulationState) -> None:
        if self._state not in allowed:
            raise StateError(f"not allowed in state {self._state.value} (needs {', '.join(a.value for a in allowed)})")

    # --- main-thread actions ------------------------------------------------------------------------
    def prepare(self, region: FaceRegion, closure: str = "centroid") -> GraftSetup:
        """NULL/READY → READY: build the closed model of ``region`` (seed step 2 → 3)."""
        with self._lock:
            self._require(SimulationState.NULL, SimulationState.READY)
        setup = prepare_graft(region, closure)
        with self._lock:
            self._require(SimulationState.NULL, SimulationState.READY)
            self._setup = setup
            if self._state is SimulationState.NULL:
                self._set(SimulationState.READY)
        return setup

    def start(self, volume: float, options: GraftOptions = GraftOptions()) -> None:
        """READY → PROCESS: run the injection of ``volume`` m³ in a worker thread (seed step 3 → 4)."""
        if not volume > 0:
            raise ParameterError(f"volume to inject must be > 0 m³, got {volume}")
        with self._lock:
            self._require(SimulationState.READY)
            self._cancel.clear()
            self._pending = None
            self._error = None
            self.progress_steps = 0
            self._set(SimulationState.PROCESS)
            setup = self._setup
            self._thread = threading.Thread(target=self._work, args=(setup, volume, options), daemon=True,
                                            name="headsim-graft")
            self._thread.start()

    def reset(self) -> None:
        """PROCESS → RESET (→ READY on :meth:`poll`): interrupt the run, keep the data, save nothing."""
        with self._lock:
            self._require(SimulationState.PROCESS)
            self._set(SimulationState.RESET)
            self._cancel.set()

    def delete(self) -> None:
        """PROCESS → DELETE (→ NULL on :meth:`poll`), or READY → NULL: cancel and drop the data."""
        with self._lock:
            self._require(SimulationState.PROCESS, SimulationState.READY)
            if self._state is SimulationState.READY:
                self._setup = None
                self._set(SimulationState.NULL)
                return
            self._set(SimulationState.DELETE)
            self._cancel.set()

    def poll(self) -> SimulationState:
        """Main thread: finish a transition back from the worker once it has ended; return the state.

        COMPLETE → READY (result saved), RESET → READY, DELETE → NULL. Re-raises an error of the worker
        (the state then returns to READY).
        """
        with self._lock:
            thread = self._thread
            if thread is not None and thread.is_alive():
                return self._state
            self._thread = None
            state = self._state
            error, self._error = self._error, None
            result, self._pending = self._pending, None
            if state is SimulationState.COMPLETE:
                self.results.append(result)
                self._set(SimulationState.READY)
            elif state is SimulationState.RESET:
                self._set(SimulationState.READY)
            elif state is SimulationState.DELETE:
                self._setup = None
                self._set(SimulationState.NULL)
            elif state is SimulationState.PROCESS and error is not None:
                self._set(SimulationState.READY)
            new_state = self._state
        if state is SimulationState.COMPLETE and self._on_result is not None:
            self._on_result(result)
        if error is not None:
            raise error
        return new_state

    def wait(self, timeout: float | None = None) -> SimulationState:
        """Join the worker (up to ``timeout`` s), then :meth:`poll`."""
        thread = self._thread
        if thread is not None:
            thread.join(timeout)
        return self.poll()

    # --- worker -------------------------------------------------------------------------------------
    def _work(self, setup: GraftSetup, volume: float, options: GraftOptions) -> None:
        def progress(state, change):
            self.progress_steps = state.steps

        try:
            result = inject_volume(setup, volume, options, callback=progress, cancel=self._cancel.is_set)
        except BaseException as e:  # handed to the main thread by poll()
            with self._lock:
                if self._state is SimulationState.PROCESS:
                    self._error = e
            return
        with self._lock:
            if self._state is SimulationState.PROCESS and result is not None:
                self._pending = result
                self._set(SimulationState.COMPLETE)
