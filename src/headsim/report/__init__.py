"""Reports: interactive offline HTML pages and PNG pictures of results.

Generic pieces (:mod:`headsim.report.html`, :mod:`headsim.report.images`) and app pages built on them
(:mod:`headsim.report.graft`, :mod:`headsim.report.drape`).
"""

from headsim.report.html import MeshLayer, mesh_figure, numbers_table, write_html_report
from headsim.report.images import render_mesh, render_panels

__all__ = ["MeshLayer", "mesh_figure", "numbers_table", "write_html_report", "render_mesh", "render_panels"]
