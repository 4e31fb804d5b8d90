"""The simulation state machine of Monkin 2016 §5.4 (NULL, READY, PROCESS, COMPLETE, RESET, DELETE)."""

from __future__ import annotations

import time

import numpy as np
import pytest

from headsim.graft import GraftOptions, GraftSession, SimulationState as S, StateError

# a solve that never meets its stop rule: it runs until it is interrupted (time stepping, whose Σ|x| keeps
# changing in the last bits; the Anderson path's cancel is tested in tests/solvers/test_pbd_anderson.py)
ENDLESS = GraftOptions(acceleration="none", stop_tolerance=1e-300, max_steps=10**9)


def _wait_for_steps(session, n=5, timeout=60.0):
    t0 = time.monotonic()
    while session.progress_steps < n:
        assert time.monotonic() - t0 < timeout, "the worker made no progress"
        time.sleep(0.01)


def test_prepare_start_complete_and_rerun(left_cheek, face):
    saved = []
    s = GraftSession(on_result=saved.append)
    assert s.state is S.NULL
    setup = s.prepare(left_cheek)
    assert s.state is S.READY
    s.start(2e-6)
    assert s.state in (S.PROCESS, S.COMPLETE)
    assert s.wait(timeout=120) is S.READY
    assert len(saved) == 1 and s.results == saved
    assert saved[0].volume_after - saved[0].volume_before == pytest.approx(2e-6, rel=1e-6)
    # re-run with other parameters on the same prepared data (seed §5.2)
    s.start(4e-6, GraftOptions(damping=0.2))
    assert s.wait(timeout=120) is S.READY
    assert len(s.results) == 2 and s.results[1].setup is setup is s.setup
    assert s.results[1].volume_after - s.results[1].volume_before == pytest.approx(4e-6, rel=1e-6)
    assert s.history == [S.NULL, S.READY, S.PROCESS, S.COMPLETE, S.READY, S.PROCESS, S.COMPLETE, S.READY]


def test_reset_mid_solve_keeps_data_saves_nothing_and_leaves_the_input_untouched(left_cheek, face):
    before = face.vertices.copy()
    s = GraftSession()
    s.prepare(left_cheek)
    s.start(5e-6, ENDLESS)
    _wait_for_steps(s)
    assert s.state is S.PROCESS
    s.reset()
    assert s.state in (S.RESET, S.READY)
    assert s.wait(timeout=60) is S.READY
    assert s.results == [] and s.setup is not None
    np.testing.assert_array_equal(face.vertices, before)
    np.testing.assert_array_equal(s.setup.closed.vertices[s.setup.closed.face_ids >= 0],
                                  before[s.setup.closed.face_ids[s.setup.closed.face_ids >= 0]])
    assert s.history[-3:] == [S.PROCESS, S.RESET, S.READY]
    s.start(1e-6)  # the prepared data is still usable
    assert s.wait(timeout=120) is S.READY and len(s.results) == 1


def test_delete_mid_solve_drops_the_data(left_cheek):
    s = GraftSession()
    s.prepare(left_cheek)
    s.start(5e-6, ENDLESS)
    _wait_for_steps(s)
    s.delete()
    assert s.wait(timeout=60) is S.NULL
    assert s.setup is None and s.results == []
    assert s.history[-3:] == [S.PROCESS, S.DELETE, S.NULL]


def test_delete_when_ready_and_forbidden_transitions(left_cheek):
    s = GraftSession()
    with pytest.raises(StateError):
        s.start(1e-6)  # NULL: no data
    with pytest.raises(StateError):
        s.reset()
    s.prepare(left_cheek)
    with pytest.raises(StateError):
        s.reset()  # nothing running
    s.delete()
    assert s.state is S.NULL and s.setup is None
    s.prepare(left_cheek)
    s.start(5e-6, ENDLESS)
    _wait_for_steps(s, 1)
    with pytest.raises(StateError):
        s.start(1e-6)  # already running
    with pytest.raises(StateError):
        s.prepare(left_cheek)
    s.reset()
    with pytest.raises(StateError):
        s.reset()  # already interrupting
    assert s.wait(timeout=60) is S.READY


def test_worker_error_returns_to_ready(left_cheek):
    s = GraftSession()
    s.prepare(left_cheek)
    s.start(5e-6, GraftOptions(max_steps=2))  # cannot meet the stop rule in 2 steps
    from headsim.errors import ConvergenceError

    with pytest.raises(ConvergenceError):
        s.wait(timeout=60)
    assert s.state is S.READY and s.results == []
