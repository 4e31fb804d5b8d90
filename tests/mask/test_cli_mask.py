"""`headsim mask ...` and `headsim demo`: commands, bad input -> one-line error + exit 2, no partial output."""

import json

import pytest

from headsim.cli import main
from headsim.mesh.io import save_surface
from headsim.mesh.primitives import icosphere


def _run(argv, capsys):
    with pytest.raises(SystemExit) as e:
        main(argv)
    out = capsys.readouterr()
    return e.value.code, out.out, out.err


def test_mask_list(capsys):
    code, out, _ = _run(["mask", "list"], capsys)
    assert code in (0, None)
    for name in ("nasal-S", "nasal-M", "nasal-L", "oronasal-M"):
        assert name in out


def test_demo_is_registered(capsys):
    code, out, _ = _run(["demo", "--help"], capsys)
    assert code in (0, None) and "--out" in out


@pytest.mark.parametrize("force", ["0", "-5", "500"])
def test_bad_force_gives_exit_2_and_no_output(tmp_path, capsys, force):
    out = tmp_path / "fit"
    code, _, err = _run(["mask", "fit", "--force", force, "--out", str(out)], capsys)
    assert code == 2 and "error:" in err and "force" in err
    assert not out.exists()


def test_not_a_face_gives_exit_2_and_no_output(tmp_path, capsys):
    ball = tmp_path / "ball.stl"
    save_surface(icosphere(0.3, 2), ball)
    out = tmp_path / "fit"
    code, _, err = _run(["mask", "fit", "--face", str(ball), "--force", "10", "--out", str(out)], capsys)
    assert code == 2 and "error:" in err
    assert not out.exists()
    assert not list(tmp_path.glob(".fit.tmp-*"))


def test_unknown_mask_gives_exit_2(tmp_path, capsys):
    code, _, err = _run(["mask", "fit", "--mask", "nasal-XXL", "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and "unknown mask" in err


def test_mask_fit_writes_the_report(tmp_path, capsys):
    out = tmp_path / "fit"
    code, stdout, err = _run(["mask", "fit", "--force", "8", "--layers", "1", "--crop", "6", "--mask-edge", "5",
                              "--out", str(out)], capsys)
    assert code in (0, None), err
    for name in ("report.html", "result.json", "pressure.png", "face_deformed.ply", "mask_deformed.vtu"):
        assert (out / name).exists(), name
    data = json.loads((out / "result.json").read_text())
    assert data["fit"]["force_balance_error"] < 0.01
    from headsim.mask.fit import STALL_TOL

    assert data["problem"]["contact_model"] == "barrier"   # the default contact model
    assert 0.0 <= data["fit"]["force_residual_n"] <= STALL_TOL * 8.0
    assert ("SEALED" in stdout) == data["fit"]["sealed"]
    assert f"leak {data['leak_flow_lpm']:.2f} L/min" in stdout and data["leak_threshold_lpm"] == 24.0
    check = data["contact_check"]  # the geometric contact check of the nonlinear fit, warned about when failed
    assert check["consistent"] == (check["max_phantom_gap"] <= check["tolerance"]
                                   and check["max_excess_depth"] <= check["tolerance"])
    assert ("warning: contact check" in err) == (not check["consistent"])
    from headsim.cli import mask_cmd
    from headsim.mask.leak import LARGE_LEAK_LPM

    assert mask_cmd.LARGE_LEAK_LPM == LARGE_LEAK_LPM


def test_condensed_mode_fit_writes_the_report(tmp_path, capsys):
    out = tmp_path / "fit"
    code, stdout, err = _run(["mask", "fit", "--mode", "condensed", "--force", "8", "--crop", "6", "--mask-edge", "5",
                              "--leak-threshold", "500", "--out", str(out)], capsys)
    assert code in (0, None), err
    data = json.loads((out / "result.json").read_text())
    assert data["fit"]["solver_mode"] == "condensed" and data["contact_check"] is None
    assert data["leak_threshold_lpm"] == 500.0 and data["leak_acceptable"] == (data["leak_flow_lpm"] <= 500.0)
    assert data["fit"]["force_balance_error"] < 1e-9
    assert "condensed" in (out / "report.html").read_text()


def test_held_rotation_reaches_the_fit(tmp_path, capsys):
    """``--rotation held`` (headgear with a forehead support): the mask only advances along the approach
    axis, so the fit reports no pitch or yaw, the problem records the choice, and the strap force still
    balances; the free default turns the mask (a non-zero pitch on this face)."""
    runs = {}
    for rotation in ("held", "free"):
        out = tmp_path / rotation
        code, _, err = _run(["mask", "fit", "--mode", "condensed", "--force", "8", "--crop", "6", "--mask-edge", "5",
                             "--rotation", rotation, "--out", str(out)], capsys)
        assert code in (0, None), err
        runs[rotation] = json.loads((out / "result.json").read_text())
    held, free = runs["held"], runs["free"]
    assert held["problem"]["mask_rotation"] == "held" and held["fit"]["mask_rotation_deg"] is None
    assert held["fit"]["force_balance_error"] < 1e-9
    assert free["problem"]["mask_rotation"] == "free" and abs(free["fit"]["mask_rotation_deg"]["pitch"]) > 0.1


def test_bad_rotation_gives_exit_2_and_no_output(tmp_path, capsys):
    out = tmp_path / "fit"
    code, _, err = _run(["mask", "fit", "--rotation", "tilted", "--out", str(out)], capsys)
    assert code == 2 and "--rotation must be 'free' or 'held'" in err
    assert not out.exists()


def test_bad_mode_gives_exit_2_and_no_output(tmp_path, capsys):
    out = tmp_path / "fit"
    code, _, err = _run(["mask", "fit", "--mode", "linear", "--out", str(out)], capsys)
    assert code == 2 and "--mode" in err
    assert not out.exists()


@pytest.mark.parametrize("workers", ["0", "two", "-1"])
def test_bad_workers_give_exit_2_and_no_output(tmp_path, capsys, workers):
    out = tmp_path / "search"
    code, _, err = _run(["mask", "seal-force", "--workers", workers, "--out", str(out)], capsys)
    assert code == 2 and "--workers must be 'auto' or an integer >= 1" in err
    assert not out.exists()


def test_auto_workers_use_two_cores_for_the_barrier_search_only(monkeypatch):
    """``--workers auto``: two fits at a time for the barrier contact's nonlinear search on >= 2 cores;
    one for the planes contact (warm-start dependent) and the condensed mode (0.1 s fits)."""
    import os

    from headsim.cli.mask_cmd import search_workers

    monkeypatch.setattr(os, "cpu_count", lambda: 2)
    assert search_workers("auto", "barrier", "nonlinear") == 2
    assert search_workers("auto", "planes", "nonlinear") == 1
    assert search_workers("auto", "barrier", "condensed") == 1
    assert search_workers("3", "planes", "nonlinear") == 3
    monkeypatch.setattr(os, "cpu_count", lambda: 1)
    assert search_workers("auto", "barrier", "nonlinear") == 1
