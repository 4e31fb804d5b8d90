"""Report of a fat-grafting plan: interactive offline HTML and PNG pictures (before / after / difference)."""

from __future__ import annotations

from pathlib import Path


from headsim.graft.plan import GraftResult
from headsim.report.html import MeshLayer, mesh_figure, write_html_report
from headsim.report.images import render_panels

__all__ = ["graft_numbers", "write_graft_report", "write_graft_pictures"]


def graft_numbers(result: GraftResult) -> list[tuple[str, str]]:
    """(label, value) rows for people: cm³, cm², mm."""
    s = result.summary()
    return [
        ("region", f"{s['region']} ({s['region_vertices']} vertices, {s['region_triangles']} triangles)"),
        ("closure (seed §5.3)", s["closure"]),
        ("volume injected (target)", f"{result.volume_injected * 1e6:.3f} cm³"),
        ("closed-model volume before → after", f"{result.volume_before * 1e6:.3f} → {result.volume_after * 1e6:.3f} cm³"),
        ("volume change (measured)", f"{s['volume_change_cm3']:.3f} cm³"),
        ("region area before → after", f"{result.area_before * 1e4:.3f} → {result.area_after * 1e4:.3f} cm²"),
        ("largest displacement", f"{s['max_displacement_mm']:.2f} mm"),
        ("PBD steps (stop rule met)", f"{s['steps']} ({'yes' if s['converged'] else 'no'})"),
    ]


def write_graft_report(result: GraftResult, path: str | Path, *, title: str = "Fat-grafting plan") -> Path:
    """Self-contained HTML: before, after and the signed difference map (mm) in 3-D, plus the numbers."""
    before = result.setup.face
    after = result.face_after
    diff_mm = result.displacement * 1e3
    mm = 1e3
    figs = [
        ("Before and after (after shifted to the right)", mesh_figure(
            [MeshLayer(before.vertices * mm, before.triangles, name="before"),
             MeshLayer(after.vertices * mm, after.triangles, name="after", color="#c99a6b",
                       offset=(float(before.extent[0] * mm * 1.1), 0.0, 0.0))],
            title="before | after (mm)")),
        ("Signed difference after − before along the normal (mm)", mesh_figure(
            MeshLayer(after.vertices * mm, after.triangles, scalar=diff_mm, name="after"),
            colorbar_title="mm", title="after, coloured by displacement")),
    ]
    notes = ["Units: mm in the pictures; volumes in cm³. Monkin 2016 (seed 001): PBD with edge springs and a "
             "closed-model volume constraint whose target is raised by the injected volume."]
    return write_html_report(path, title=title, figures=figs, numbers=graft_numbers(result), notes=notes)


def write_graft_pictures(result: GraftResult, folder: str | Path) -> list[Path]:
    """PNG pictures: before / after / difference (front view) and the difference map alone."""
    folder = Path(folder)
    before, after = result.setup.face, result.face_after
    diff_mm = result.displacement * 1e3
    p1 = render_panels(folder / "before_after.png", [
        dict(vertices=before.vertices, triangles=before.triangles, title="before"),
        dict(vertices=after.vertices, triangles=after.triangles, title="after"),
        dict(vertices=after.vertices, triangles=after.triangles, scalar=diff_mm, title="after − before"),
    ], colorbar_label="displacement along the normal, mm")
    p2 = render_panels(folder / "difference.png", [
        dict(vertices=after.vertices, triangles=after.triangles, scalar=diff_mm, title="after − before (mm)")],
        colorbar_label="mm", panel_size=6.0)
    return [p1, p2]
