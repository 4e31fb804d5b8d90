"""Write a mask fit (and a least-seal-force search) to a folder a person can open.

``DIR/report.html`` -- self-contained interactive page (plotly.js embedded, works offline): the face
coloured by contact pressure (kPa) with the mask, the inner edge of the seal loop and the leak
points marked; force -> contact area and force -> peak pressure curves; the numbers, and a sanity
statement against published figures. ``DIR/pressure.png`` and ``DIR/curves.png`` beside it;
``DIR/result.json`` with the numbers; deformed meshes ``DIR/face_deformed.ply`` (surface) and
``DIR/mask_deformed.vtu`` (tets, cushion + shell).

Published figures quoted (sanity check, not a tuning target): FE face-respirator and face-mask
studies predict mean contact pressures of about 10 kPa (Kwon, Kim & Lee, PLOS ONE 17(7) e0270092,
2022: estimated 9.7-11.6 kPa, measured 9.3-15.0 kPa; Lei, Yang & Zhuang, J Occup Environ Hyg 9(1)
46-58, 2012: N95 headform FE validated against pressure mapping); NIV mask FE studies report
nasal-bridge peaks of tens of kPa at usual strap tensions.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from headsim.mask.contact_check import ContactConsistency, contact_consistency
from headsim.mask.fit import FitProblem, FitResult
from headsim.mask.search import SearchResult

SANITY_NOTE = (
    "Sanity check against published figures (not a tuning target): FE face-mask studies predict mean "
    "contact pressures around 10 kPa (Kwon et al., PLOS ONE 2022: estimated 9.7-11.6 kPa, measured 9.3-15.0 kPa; "
    "Lei et al., J Occup Environ Hyg 2012, N95 headforms); NIV mask FE studies report nasal-bridge peaks of "
    "tens of kPa at usual strap tensions. The capillary closing pressure (32 mmHg = 4.27 kPa) is the usual "
    "pressure-injury threshold."
)


def _seal_edge(problem: FitProblem, fit: FitResult) -> np.ndarray:
    """(k,) face vertices of the seal loop's inner edge: sealing vertices next to the airway region."""
    seal = fit.seal
    if len(seal.sealing_vertices) == 0:
        return np.zeros(0, np.int64)
    n = problem.face.n_vertices
    region = np.zeros(n, bool)
    region[seal.leak_region] = True
    sealing = np.zeros(n, bool)
    sealing[seal.sealing_vertices] = True
    e = problem.face.edges
    edge = np.zeros(n, bool)
    m = sealing[e[:, 0]] & region[e[:, 1]]
    edge[e[m, 0]] = True
    m = sealing[e[:, 1]] & region[e[:, 0]]
    edge[e[m, 1]] = True
    return np.flatnonzero(edge)


def fit_contact_check(problem: FitProblem, fit: FitResult) -> ContactConsistency | None:
    """The geometric contact check of a nonlinear fit (:mod:`headsim.mask.contact_check`); None for
    the condensed mode, whose linear complementarity contact has no lagged planes."""
    return contact_consistency(problem, fit) if fit.mode == "nonlinear" else None


def result_dict(problem: FitProblem, fit: FitResult, search: SearchResult | None = None,
                contact_check: ContactConsistency | None = None) -> dict:
    """Everything for ``result.json`` (report units: N, cm^2, kPa, mm; ``contact_check`` in m, N)."""
    out = {
        "headsim_result": "mask-fit" if search is None else "mask-seal-force",
        "problem": problem.describe(),
        "landmarks_m": problem.landmarks.as_dict(),
        "therapy_pressure_pa": problem.options.therapy_pressure,
        "pressure_threshold_kpa": problem.options.pressure_threshold / 1e3,
        "leak_flow_lpm": fit.leak_flow_lpm,
        "leak_acceptable": fit.leak_acceptable,
        "leak_threshold_lpm": problem.options.leak_threshold_lpm,
        "fit": fit.as_dict(),
        "contact_check": None if contact_check is None else contact_check.as_dict(),
        "sanity_note": SANITY_NOTE,
    }
    if search is not None:
        out["search"] = search.as_dict()
    return out


def _numbers(problem: FitProblem, fit: FitResult, search: SearchResult | None) -> list[tuple[str, str]]:
    s = fit.summary
    rows = [("face", str(problem.face.name)), ("mask", problem.mask.name)]
    if search is not None:
        if search.seal_force is None:
            rows.append(("least sealing force", f"does not seal up to {search.options.maximum:g} N"))
        else:
            rows.append(("least sealing force", f"{search.seal_force:.2f} N (largest leaking force: "
                         f"{'-' if search.lower_bound is None else f'{search.lower_bound:.2f} N'}; "
                         f"tolerance max({search.options.abs_tol:g} N, {100 * search.options.rel_tol:g} %))"))
        thr = problem.options.leak_threshold_lpm
        if search.leak_status is None:
            pass
        elif search.leak_force is None:
            rows.append((f"least force with leak <= {thr:g} L/min",
                         f"none up to {search.leak_lower_bound:g} N (leak above the threshold at every force solved)"))
        else:
            lo = "-" if search.leak_lower_bound is None else f"{search.leak_lower_bound:.2f} N"
            rows.append((f"least force with leak <= {thr:g} L/min",
                         f"{search.leak_force:.2f} N (largest with more leak: {lo}; leak at that force "
                         f"{search.leak_fit.leak_flow_lpm:.2f} L/min; {search.leak_solves} extra fit(s))"))
            if search.leak_upper_force is not None:
                rows.append((f"leak <= {thr:g} L/min up to", search.leak_window_text()))
        rows.append(("fits in the search", f"{search.n_solves} ({search.seconds:.1f} s)"))
    rows += [
        ("strap force", f"{fit.force:.2f} N"),
        ("total contact force (along the strap)", f"{fit.contact_force:.3f} N (balance error {100 * fit.balance_error:.3g} %)"),
        ("bone support force", f"{fit.support_force:.3f} N"),
        ("sealed", "yes" if fit.sealed else f"no ({len(fit.seal.leak_paths)} leak path(s))"),
        *_leak_rows(fit),
        ("therapy pressure", f"{problem.options.therapy_pressure:.1f} Pa"),
        ("contact area", f"{s.contact_area_cm2:.2f} cm²"),
        ("peak contact pressure", f"{s.peak_pressure / 1e3:.2f} kPa"),
        ("mean contact pressure", f"{s.mean_pressure / 1e3:.2f} kPa"),
        (f"area above {s.threshold / 1e3:.2f} kPa (32 mmHg)", f"{s.area_above_threshold_cm2:.2f} cm²"),
        ("mask travel along the strap", f"{fit.mask_displacement * 1e3:.2f} mm"),
    ]
    for i, lp in enumerate(fit.seal.leak_paths):
        gap = "-" if lp.gap_width is None or not np.isfinite(lp.gap_width) else f"{lp.gap_width * 1e3:.2f} mm"
        ch = "-" if not np.isfinite(lp.channel_width) else f"{lp.channel_width * 1e3:.1f} mm"
        pt = ", ".join(f"{c * 1e3:.1f}" for c in lp.crossing_point)
        rows.append((f"leak {i + 1}", f"at ({pt}) mm, gap {gap}, channel width {ch}"))
    d = problem.describe()
    rows += [
        ("tissue model", f"{d['cropped_skin_vertices']} skin vertices (cropped), {d['tissue_layers']} layer(s), "
         f"{d['tissue_thickness_mm']:.0f} mm to fixed bone, E = {d['tissue_modulus_kpa']:.0f} kPa, nu = {d['tissue_poisson']}"),
        ("cushion", f"E = {d['cushion_modulus_kpa']:.0f} kPa, nu = {d['cushion_poisson']} ({d['cushion_material_source']})"),
        ("model", f"{d['model_vertices']} vertices, {d['model_tets']} tets"),
        ("solver", "condensed linear face + cushion, contact LCP (small-strain model, issue 6 interactive mode)"
         if getattr(fit, "mode", "nonlinear") == "condensed" else
         "nonlinear FEM contact (finite strain, IPC barrier on the current surfaces, "
         f"contact layer {problem.options.contact_layer * 1e6:.0f} um)" if problem.options.contact == "barrier" else
         "nonlinear FEM contact (finite strain, penalty on lagged cushion planes)"),
    ]
    if getattr(fit, "mode", "nonlinear") != "condensed":
        friction = problem.options.friction
        rows.append(("skin-cushion contact",
                     (f"Coulomb friction mu = {friction:g} (lagged, regularised)" if friction > 0 else "frictionless")
                     + "; mask " + ("free to turn on its strap (pitch, yaw)" if problem.options.rotate
                                    else "orientation held by the headgear")))
    return rows


def _leak_rows(fit: FitResult, max_channels: int = 8) -> list[tuple[str, str]]:
    leak = fit.leak
    if leak is None:
        return []
    verdict = "acceptable" if leak.acceptable else "too large"
    rows = [("leak flow at the therapy pressure (estimate)",
             f"{leak.flow_lpm:.3g} L/min, {verdict} (threshold {leak.threshold_lpm:g} L/min; viscous film flow "
             f"{leak.viscous_lpm:.3g} L/min, orifice bound {leak.orifice_lpm:.3g} L/min)")]
    for i, c in enumerate(leak.channels[:max_channels]):
        pt = ", ".join(f"{x * 1e3:.1f}" for x in c.position)
        rows.append((f"leak channel {i + 1}",
                     f"at ({pt}) mm: {c.flow_lpm:.3g} L/min, flow area {c.area * 1e6:.3g} mm², widest gap "
                     f"{c.max_aperture * 1e6:.0f} µm, Re {c.max_reynolds:.3g}"
                     + ("" if c.viscous_valid else " (inertial: orifice-limited estimate)")))
    return rows


def pressure_figure(problem: FitProblem, fit: FitResult):
    """Plotly 3-D figure: deformed face coloured by contact pressure (kPa), mask, seal edge, leaks."""
    import plotly.graph_objects as go

    from headsim.report.html import MeshLayer, mesh_figure

    face = fit.deformed_face
    mm = 1e3
    p = fit.pressure / 1e3
    cmax = max(float(p.max()), problem.options.pressure_threshold / 1e3)
    mask = fit.deformed_mask
    layers = [
        MeshLayer(face.vertices * mm, face.triangles, scalar=p, name="face: contact pressure (kPa)"),
        MeshLayer(mask.tetmesh.vertices * mm, mask.tetmesh.boundary_triangles, name=mask.name, color="#7fa7d9",
                  opacity=0.35),
    ]
    fig = mesh_figure(layers, colorbar_title="kPa", colorscale="Viridis", symmetric=False, cmin=0.0, cmax=cmax)
    edge = _seal_edge(problem, fit)
    if len(edge):
        v = face.vertices[edge] * mm
        fig.add_trace(go.Scatter3d(x=v[:, 0], y=v[:, 1], z=v[:, 2], mode="markers", name="seal loop (inner edge)",
                                   marker=dict(size=2, color="#00d0ff")))
    for i, lp in enumerate(fit.seal.leak_paths):
        path = lp.positions * mm
        fig.add_trace(go.Scatter3d(x=path[:, 0], y=path[:, 1], z=path[:, 2], mode="lines",
                                   name=f"leak path {i + 1}", line=dict(color="red", width=4)))
        c = lp.crossing_point * mm
        fig.add_trace(go.Scatter3d(x=[c[0]], y=[c[1]], z=[c[2]], mode="markers", name=f"leak {i + 1}",
                                   marker=dict(size=7, color="red", symbol="x")))
    if fit.leak is not None and fit.leak.channels:
        ch = fit.leak.channels
        v = np.array([c.position for c in ch]) * mm
        q = np.array([c.flow_lpm for c in ch])
        size = 5 + 15 * np.sqrt(q / max(q.max(), 1e-12))
        fig.add_trace(go.Scatter3d(x=v[:, 0], y=v[:, 1], z=v[:, 2], mode="markers",
                                   name="leak channels (size ~ flow)", text=[f"{x:.3g} L/min" for x in q],
                                   marker=dict(size=size, color="orange", symbol="diamond")))
    return fig


def curves_figure(search: SearchResult):
    """Plotly figure: force -> contact area and force -> peak pressure, sealed points marked."""
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    f = [c.force for c in search.curve]
    fig = make_subplots(rows=1, cols=3, subplot_titles=("contact area", "peak contact pressure", "leak flow"))
    sym = ["circle" if c.sealed else "x" for c in search.curve]
    fig.add_trace(go.Scatter(x=f, y=[c.contact_area_cm2 for c in search.curve], mode="lines+markers",
                             marker=dict(symbol=sym, size=9), name="contact area (cm²)"), row=1, col=1)
    fig.add_trace(go.Scatter(x=f, y=[c.peak_pressure_kpa for c in search.curve], mode="lines+markers",
                             marker=dict(symbol=sym, size=9), name="peak pressure (kPa)"), row=1, col=2)
    leak = [c.leak_flow_lpm for c in search.curve]
    if all(q is not None for q in leak):
        fig.add_trace(go.Scatter(x=f, y=leak, mode="lines+markers", marker=dict(symbol=sym, size=9),
                                 name="leak flow (L/min)"), row=1, col=3)
        thr = getattr(search.fit.leak, "threshold_lpm", None) if getattr(search.fit, "leak", None) else None
        if thr is not None:
            fig.add_hline(y=thr, line_dash="dot", line_color="red", row=1, col=3)
    if search.seal_force is not None:
        for col in (1, 2, 3):
            fig.add_vline(x=search.seal_force, line_dash="dash", line_color="green", row=1, col=col)
    if search.leak_force is not None:
        fig.add_vline(x=search.leak_force, line_dash="dot", line_color="orange", row=1, col=3)
    if search.leak_upper_force is not None:
        fig.add_vline(x=search.leak_upper_force, line_dash="dot", line_color="orange", row=1, col=3)
    fig.update_xaxes(title_text="strap force (N)")
    fig.update_yaxes(title_text="cm²", row=1, col=1)
    fig.update_yaxes(title_text="kPa", row=1, col=2)
    fig.update_yaxes(title_text="L/min", row=1, col=3)
    fig.update_layout(height=380, margin=dict(l=40, r=10, t=40, b=40))
    return fig


def _png(out: Path, problem: FitProblem, fit: FitResult, search: SearchResult | None) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    from headsim.report.images import render_panels

    face = fit.deformed_face
    files = [render_panels(out / "pressure.png", [
        dict(vertices=face.vertices * 1e3, triangles=face.triangles, scalar=fit.pressure / 1e3,
             title=f"{problem.mask.name}, {fit.force:.1f} N: contact pressure"),
    ], colorbar_label="kPa", cmap="viridis", symmetric=False)]
    if search is not None and search.curve:
        fig, ax = plt.subplots(1, 3, figsize=(13, 3.5))
        f = [c.force for c in search.curve]
        ax[0].plot(f, [c.contact_area_cm2 for c in search.curve], "o-")
        ax[0].set_ylabel("contact area (cm²)")
        ax[1].plot(f, [c.peak_pressure_kpa for c in search.curve], "o-")
        ax[1].set_ylabel("peak pressure (kPa)")
        if all(c.leak_flow_lpm is not None for c in search.curve):
            ax[2].plot(f, [c.leak_flow_lpm for c in search.curve], "o-")
            ax[2].axhline(problem.options.leak_threshold_lpm, ls=":", color="r")
        ax[2].set_ylabel("leak flow (L/min)")
        for a in ax:
            a.set_xlabel("strap force (N)")
            if search.seal_force is not None:
                a.axvline(search.seal_force, ls="--", color="g")
        fig.tight_layout()
        fig.savefig(out / "curves.png", dpi=110)
        plt.close(fig)
        files.append(out / "curves.png")
    return files


def write_fit_report(out_dir: str | Path, problem: FitProblem, fit: FitResult,
                     search: SearchResult | None = None, contact_check: ContactConsistency | None = None) -> Path:
    """Write report.html, result.json, PNGs and the deformed meshes into ``out_dir`` (module doc).

    ``out_dir`` should be a fresh folder (the CLI passes the temporary folder of
    :func:`headsim.cli._common.atomic_output_dir`, so a failure leaves no partial output).
    ``contact_check``: :func:`fit_contact_check` of ``fit`` (computed here when not given).
    """
    if contact_check is None:
        contact_check = fit_contact_check(problem, fit)
    from headsim.mesh.io import save_surface, save_tetmesh
    from headsim.report.html import write_html_report

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "result.json").write_text(json.dumps(result_dict(problem, fit, search, contact_check), indent=2, default=float))
    save_surface(fit.deformed_face, out / "face_deformed.ply")
    save_tetmesh(fit.deformed_mask.tetmesh, out / "mask_deformed.vtu")
    np.savetxt(out / "pressure_kpa.txt", fit.pressure / 1e3, fmt="%.6g",
               header="contact pressure (kPa) per face vertex, face vertex order")
    _png(out, problem, fit, search)
    figures = [("Contact pressure on the face (kPa), seal loop and leaks", pressure_figure(problem, fit))]
    if search is not None and search.curve:
        figures.append(("Strap force vs contact area, peak pressure and leak flow (o sealed, x leaks)",
                        curves_figure(search)))
    title = f"headsim mask fit: {problem.mask.name}"
    notes = [SANITY_NOTE,
             "Model: quasi-static FEM contact (stable neo-Hookean tissue over fixed bone, FEM cushion, rigid shell on "
             "the strap force, penalty contact); seal = contact pressure above the therapy pressure closing a loop "
             "around the airway.",
             "Leak flow: an estimate -- steady viscous (lubrication) air flow at the therapy pressure in the gap between "
             "skin and cushion (closest-point gap; closed where the contact pressure exceeds the therapy pressure, a "
             "skin-roughness gap where the skin touches more lightly), limited per channel by the Bernoulli orifice flow "
             "of its narrowest cross-section; judged against the large-leak threshold of CPAP devices (ResMed: 24 L/min "
             "unintentional leak). Orange diamonds mark the channels of that narrowest cross-section."]
    warning = None if contact_check is None else contact_check.warning(fit.force)
    if warning:
        notes.insert(0, "WARNING, " + warning + ".")
    write_html_report(out / "report.html", title=title, figures=figures, numbers=_numbers(problem, fit, search),
                      notes=notes)
    return out
