"""Geometric check of a fitted contact: does the penalty pressure sit where the bodies touch?

The nonlinear fit (:mod:`headsim.mask.fit`) computes contact pressure on lagged planes (a skin
vertex keeps the plane of its first contact). This module checks the fitted state against the
true geometry of the deformed bodies, independent of those planes:

- **inside**: skin vertices inside the closed cushion body (generalised winding number of the
  cushion's boundary, :meth:`headsim.collide.TriangleBVH.contains`), their depth (closest-point
  distance to that boundary, m) and the force a penalty on the true depth would carry,
  ``sum kappa a_i depth_i`` (N; kappa the fit's penalty, a_i the vertex area) -- against the strap
  force it measures how far the planes under-state the interpenetration;
- **phantom**: skin vertices with contact pressure > 0 that lie *outside* the cushion, their true
  gap (m) and the contact force they carry (N): load that the model puts where the surfaces do
  not touch;
- **cushion in skin**: vertices of the cushion's skin-side surface inside the closed tissue layer
  (the contact is one-sided, :mod:`headsim.mask.fit` "Contact"), their depth (m).

What counts as "touching" follows the contact model that made the pressure. The lagged planes
(``FitOptions.contact="planes"``) put pressure kappa x depth on a skin *vertex*, so a vertex with
pressure must itself be inside the cushion (or within the tolerance of it). The barrier
(``contact="barrier"``, :mod:`headsim.solvers.barrier`) acts between *primitives*: a cushion vertex
pressing the middle of a skin triangle loads that triangle's three vertices, each up to a skin edge
away. There a skin vertex with pressure is phantom when no point, edge or triangle it belongs to
comes within the tolerance of the cushion (:meth:`BarrierContact.vertices_within`), and since the
barrier's pressure stands for a positive gap, any depth inside the cushion is excess.

Measured on the demo configuration (issue 6 follow-up, nasal-M at 4 mm, bundled face, default
options): at 15 N 102 skin vertices inside (median 0.11 mm, max 0.56 mm deep; a penalty on the
true depth would carry 208 N), 64 phantom contacts (true gap median 0.38 mm, max 8.3 mm) carrying
7.5 of the 15 N; at 30 N 114 inside (max 1.47 mm, 412 N) and 84 phantom (median 0.13 mm, max 3.1 mm)
carrying 15.6 of the 30 N; 62-86 cushion vertices inside the skin, up to 0.6-0.8 mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from headsim.mesh import TetMesh

#: allowed beyond a consistent penalty contact, times the median skin edge (the facet scale; the
#: seal is decided by gaps of 0.1-1 mm, :mod:`headsim.mask.fit`)
CONSISTENCY_EDGE_FRACTION = 0.1


@dataclass(frozen=True)
class ContactConsistency:
    """Outcome of :func:`contact_consistency` (SI units: m, N).

    n_inside, max_inside_depth, true_depth_force : skin vertices inside the cushion, their largest
        depth and the penalty force on their true depths
    n_phantom, phantom_force, max_phantom_gap : skin vertices with pressure > 0 outside the cushion,
        the contact force they carry, their largest true gap
    n_cushion_in_skin, max_cushion_in_skin_depth : skin-side cushion vertices inside the tissue
    skin_edge : the fit's median skin edge (the mesh scale to compare the depths with)
    max_excess_depth : largest depth of a skin vertex inside the cushion beyond the depth its own
        pressure stands for (``depth - p / kappa``; 0 for a consistent penalty contact)
    """

    n_inside: int
    max_inside_depth: float
    true_depth_force: float
    n_phantom: int
    phantom_force: float
    max_phantom_gap: float
    n_cushion_in_skin: int
    max_cushion_in_skin_depth: float
    skin_edge: float
    max_excess_depth: float = 0.0

    @property
    def tolerance(self) -> float:
        """m: what the check allows beyond a consistent penalty contact, the polyhedral facet scale
        ``CONSISTENCY_EDGE_FRACTION`` x the median skin edge."""
        return CONSISTENCY_EDGE_FRACTION * self.skin_edge

    @property
    def consistent(self) -> bool:
        """No pressure on skin farther than :attr:`tolerance` outside the cushion, and no skin deeper
        inside than its pressure / kappa + :attr:`tolerance`."""
        return self.max_phantom_gap <= self.tolerance and self.max_excess_depth <= self.tolerance

    def as_dict(self) -> dict:
        out = {k: (float(v) if isinstance(v, float) else int(v)) for k, v in self.__dict__.items()}
        out.update(tolerance=self.tolerance, consistent=self.consistent)
        return out

    def warning(self, strap_force: float) -> str | None:
        """One line for a person reading the result, or None when the contact is consistent."""
        if self.consistent:
            return None
        return (f"contact check: {self.phantom_force:.1f} of {strap_force:g} N sits on skin up to "
                f"{self.max_phantom_gap * 1e3:.2f} mm outside the cushion and skin lies up to "
                f"{self.max_excess_depth * 1e3:.2f} mm inside it unresisted (tolerance "
                f"{self.tolerance * 1e3:.2f} mm): the nonlinear contact planes are stale (known defect, "
                "headsim.mask.fit 'Contact consistency'; --contact barrier avoids it); treat the seal and leak "
                "answers as unreliable")


def contact_consistency(problem, result) -> ContactConsistency:
    """Check a nonlinear fit (:class:`headsim.mask.fit.FitResult` of ``problem``) against the
    geometry of its deformed bodies (module doc)."""
    from headsim.collide import TriangleBVH

    p = problem
    x = result.state.positions
    skin = x[p.skin_vertices]
    pressure = result.pressure[p.crop_face_ids]
    cushion = TriangleBVH(x, p.mask_surface)
    inside = cushion.contains(skin)
    dist = cushion.closest_points(skin).distance
    depth = np.where(inside, dist, 0.0)
    if p.options.contact == "barrier":
        tolerance = CONSISTENCY_EDGE_FRACTION * p.skin_edge
        touching = p.barrier_probe(tolerance).vertices_within(x, tolerance)[p.skin_vertices]
        excess = depth  # the barrier's pressure stands for a gap > 0, never for a depth
        phantom = (~inside) & (pressure > 0) & ~touching
    else:
        excess = np.where(inside, dist - pressure / p.penalty, 0.0)
        phantom = (~inside) & (pressure > 0)
    contact_force = pressure * p.skin_areas
    tissue_tets = p.model.tets[np.all(p.model.tets < p.n_tissue, axis=1)]
    # the boundary's topology from the rest mesh (a deformed state may hold inverted tets)
    tissue = TriangleBVH(x, TetMesh(p.model.rest_positions[:p.n_tissue], tissue_tets).boundary_triangles)
    cv = x[np.unique(p.mask_contact)]
    in_skin = tissue.contains(cv)
    cdepth = tissue.closest_points(cv[in_skin]).distance if in_skin.any() else np.zeros(0)
    return ContactConsistency(
        n_inside=int(inside.sum()), max_inside_depth=float(depth.max(initial=0.0)),
        true_depth_force=float(np.sum(p.penalty * p.skin_areas * depth)),
        n_phantom=int(phantom.sum()), phantom_force=float(contact_force[phantom].sum()),
        max_phantom_gap=float(dist[phantom].max(initial=0.0)),
        n_cushion_in_skin=int(in_skin.sum()), max_cushion_in_skin_depth=float(cdepth.max(initial=0.0)),
        skin_edge=float(p.skin_edge), max_excess_depth=float(excess.max(initial=0.0)))
