"""Electrostatic charging of hair (Sobottka 2008, ch. 4), SI units inside (C, m, N, V/m).

- :mod:`.units` — eps0, K = 1/(4 pi eps0), the seed's cgs/esu values and their conversion.
- :mod:`.charges` — point charges by arc length at density rho_P, interpolated from the rod nodes,
  and the consistent map of their forces back to the nodes (§4.3.1).
- :mod:`.coulomb` — forces by the exact direct sum (Numba, the reference), fmm3dpy's FMM (precision
  ``eps``) or :mod:`.treecode` (Morton-sorted octree, multipoles to the quadrupole, opening angle,
  refit across charging steps). No distance cut-off (eq. 4.2).
- :mod:`.scalp` — repulsion by the charged scalp along a distance-field gradient, clamped (eq. 4.13).
- :mod:`.charging` — Algorithm 2: logarithmically decreasing increments each followed by a
  self-consistent static equilibrium of all fibres, or one-shot charging.
- :mod:`.field` — field strength at probe points and maps; :mod:`.scenes` — test 1 (bundle),
  a C6-symmetric bundle, a half-head hairstyle; :mod:`.validation` — error tables vs the direct sum.
"""

from headsim.hair.electrostatics.charges import ChargeSampling, sample_charges
from headsim.hair.electrostatics.charging import ChargingOptions, ChargingResult, charge_fibres, charge_schedule
from headsim.hair.electrostatics.coulomb import (
    CoulombOptions,
    coulomb_forces,
    direct_field,
    direct_forces,
    field_at,
    fmm_field,
    fmm_forces,
)
from headsim.hair.electrostatics.field import field_map, field_strength, probe_beside
from headsim.hair.electrostatics.scalp import MeshDistance, scalp_forces
from headsim.hair.electrostatics.scenes import ChargingScene, bundle_scene, head_scene, symmetric_bundle
from headsim.hair.electrostatics.treecode import Treecode, TreecodeOptions
from headsim.hair.electrostatics.validation import accuracy_table, force_errors, format_table

__all__ = [
    "ChargeSampling",
    "sample_charges",
    "ChargingOptions",
    "ChargingResult",
    "charge_fibres",
    "charge_schedule",
    "CoulombOptions",
    "coulomb_forces",
    "direct_field",
    "direct_forces",
    "field_at",
    "fmm_field",
    "fmm_forces",
    "field_map",
    "field_strength",
    "probe_beside",
    "MeshDistance",
    "scalp_forces",
    "ChargingScene",
    "bundle_scene",
    "head_scene",
    "symmetric_bundle",
    "Treecode",
    "TreecodeOptions",
    "accuracy_table",
    "force_errors",
    "format_table",
]
