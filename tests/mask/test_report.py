"""Mask report: result.json, PNGs, meshes, and report.html rendering in headless Chromium."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from _fit_case import coarse_fit, coarse_problem

sys.path.insert(0, str(Path(__file__).parents[1]))
from headless_chromium import render_page
from headsim.mask.report import write_fit_report
from headsim.mask.search import CurvePoint, SearchOptions, SearchResult


def _search_like(fits):
    """A SearchResult built from real fits (the search itself is tested in test_search.py)."""
    curve = [CurvePoint(f.force, f.summary.contact_area_cm2, f.summary.peak_pressure / 1e3,
                        f.summary.mean_pressure / 1e3, f.summary.area_above_threshold_cm2, f.sealed, f.seconds)
             for f in fits]
    last = fits[-1]
    return SearchResult(None, last.force, None, last, curve, len(fits), 0.0, "no-seal",
                        SearchOptions(start=fits[0].force, maximum=max(f.force for f in fits)))


@pytest.fixture(scope="module")
def report_dir(tmp_path_factory):
    p = coarse_problem()
    fits = [coarse_fit(8.0)]
    out = tmp_path_factory.mktemp("mask-report")
    write_fit_report(out, p, fits[-1], _search_like(fits))
    return out


def test_report_files(report_dir):
    for name in ("report.html", "result.json", "pressure.png", "curves.png", "face_deformed.ply",
                 "mask_deformed.vtu", "pressure_kpa.txt"):
        assert (report_dir / name).stat().st_size > 0, name
    data = json.loads((report_dir / "result.json").read_text())
    fit = coarse_fit(8.0)
    assert data["fit"]["strap_force_n"] == 8.0
    assert data["fit"]["contact_force_n"] == pytest.approx(fit.contact_force)
    assert data["fit"]["peak_pressure_kpa"] == pytest.approx(fit.summary.peak_pressure / 1e3)
    assert "search" in data and data["search"]["n_solves"] == 1
    assert data["leak_flow_lpm"] == pytest.approx(fit.leak_flow_lpm) and data["leak_flow_lpm"] > 0
    assert data["leak_acceptable"] == fit.leak_acceptable and data["leak_threshold_lpm"] == 24.0
    assert len(data["fit"]["leak"]["channels"]) == len(fit.leak.channels)
    p = np.loadtxt(report_dir / "pressure_kpa.txt")
    assert p.shape == fit.pressure.shape and np.allclose(p, fit.pressure / 1e3, rtol=1e-5)
    html = (report_dir / "report.html").read_text()
    assert "<script" in html and "plotly" in html.lower()
    assert "https://cdn" not in html.split("<body>")[0]  # plotly.js embedded: works offline
    assert "9.3-15.0 kPa" in html  # the published sanity figures are quoted
    assert "leak flow at the therapy pressure" in html and "leak channels" in html


def test_report_states_an_acceptable_leak_window(tmp_path):
    """A search whose leak is acceptable only between two forces (the barrier's leak rises with the strap
    force) reports both ends, in the table and in result.json."""
    from dataclasses import replace

    p = coarse_problem()
    fit = coarse_fit(8.0)
    search = replace(_search_like([fit]), leak_force=8.0, leak_lower_bound=None, leak_status="window",
                     leak_fit=fit, leak_upper_force=13.75, leak_upper_bound=14.5)
    write_fit_report(tmp_path, p, fit, search)
    html = (tmp_path / "report.html").read_text()
    assert "13.75 N: too much leak again from 14.50 N" in html
    data = json.loads((tmp_path / "result.json").read_text())["search"]
    assert data["acceptable_leak_up_to_n"] == 13.75 and data["unacceptable_leak_again_from_n"] == 14.5
    assert data["leak_search_status"] == "window"


def test_report_renders_in_headless_chromium(report_dir, tmp_path):
    """report.html opens offline in headless Chromium, plotly draws the 3-D face (WebGL through
    SwiftShader): the DOM has the plotly scene and no 'WebGL is not supported' message, and the
    screenshot of the 3-D area is not uniform."""
    rendered, img = render_page(report_dir / "report.html", tmp_path)
    assert "WebGL is not supported" not in rendered
    assert "gl-container" in rendered  # plotly created the WebGL 3-D scene
    assert "main-svg" in rendered  # and drew the figures
    # the numbers table sits on top; the 3-D scene fills the lower part of the first screen
    lower = img[img.shape[0] // 2:, :, :]
    assert lower.std() > 0.02, "the 3-D area is uniform: plotly/WebGL did not draw"
    colours = np.unique((lower.reshape(-1, 3) * 255).astype(np.uint8), axis=0)
    assert len(colours) > 50
