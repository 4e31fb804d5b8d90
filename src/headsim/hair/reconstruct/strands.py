"""Strand interpolation around a guide and the obstacle clean-up of the fibres (Sobottka 2008 §5.3.5).

Interpolated fibres ride on the guide inside a generalised cylinder of variable radius: a fibre rooted at q
keeps its root offset o = R_G(0)^T (q - r_G(0)) in the guide's material frame, scaled by the taper
T(s) = 1 - (1 - tip_ratio) s / L_G and optionally rotated about the guide by the winding angle omega s
(the interpolants may wind around the guide). Fibre i follows the guide over min(L_i, L_cut) of arc length.
Lengths in m.
"""

from __future__ import annotations

import numpy as np

from headsim.hair.reconstruct import _kernels as _k

__all__ = ["interpolate_strand", "push_out_of_head", "cut_fibres"]


def interpolate_strand(guide: np.ndarray, frames: np.ndarray, kept: int, roots: np.ndarray, lengths: np.ndarray,
                       guide_length: float, n_segments: int, tip_ratio: float = 0.6, winding: float = 0.0) -> np.ndarray:
    """(M, N+1, 3) fibres of one strand. guide (N+1, 3) and frames (N+1, 3, 3) of the uncut guide; kept: last
    node index after the cut; roots (M, 3); lengths (M,) m; guide_length L_G m."""
    N = n_segments
    ds = guide_length / N
    lmax = kept * ds
    ell = np.minimum(lengths, lmax)  # (M,)
    sig = ell[:, None] * (np.arange(N + 1) / N)[None, :]  # (M, N+1)
    x = np.clip(sig / ds, 0.0, N)
    i0 = np.minimum(np.floor(x).astype(np.int64), N - 1)
    t = (x - i0)[..., None]
    pos = (1 - t) * guide[i0] + t * guide[i0 + 1]
    fr = (1 - t[..., None]) * frames[i0] + t[..., None] * frames[i0 + 1]
    o = (roots - guide[0]) @ frames[0]  # (M, 3) local offsets (rows: o_k = d_k . (q - r0))
    ang = winding * sig
    c, s = np.cos(ang), np.sin(ang)
    taper = 1.0 - (1.0 - tip_ratio) * sig / guide_length
    o1 = (o[:, None, 0] * c - o[:, None, 1] * s) * taper
    o2 = (o[:, None, 0] * s + o[:, None, 1] * c) * taper
    o3 = np.broadcast_to(o[:, None, 2], o1.shape) * taper
    return pos + fr[..., 0] * o1[..., None] + fr[..., 1] * o2[..., None] + fr[..., 2] * o3[..., None]


def push_out_of_head(points: np.ndarray, head_field, clearance: float, passes: int = 3, head_bvh=None,
                     band: float = 0.0015) -> np.ndarray:
    """Move every point with Phi_head < clearance along the field's normal to Phi_head = clearance (m). With
    ``head_bvh`` (a :class:`~headsim.collide.bvh.TriangleBVH` of the head), the points the grid puts within
    clearance + ``band`` are then checked with the exact signed distance and moved to clearance along the
    direction from their closest surface point (two passes)."""
    p = points.reshape(-1, 3).copy()
    for _ in range(passes):
        phi = _k.field_distance(head_field, p)
        bad = np.flatnonzero(phi < clearance)
        if bad.size == 0:
            break
        nrm = head_field.normal(p[bad], scheme="central")
        p[bad] += (clearance - phi[bad])[:, None] * nrm
    if head_bvh is not None:
        cand = np.flatnonzero(_k.field_distance(head_field, p) < clearance + band)
        for _ in range(2):
            if cand.size == 0:
                break
            sd = head_bvh.signed_distance(p[cand])
            low = sd < clearance
            cand = cand[low]
            if cand.size == 0:
                break
            cp = head_bvh.closest_points(p[cand])
            v = p[cand] - cp.point
            dist = np.linalg.norm(v, axis=1, keepdims=True)
            tn = head_bvh.triangle_normals(cp.triangle)
            out = np.where(dist > 1e-9, v / np.maximum(dist, 1e-300) * np.sign(sd[low])[:, None], tn)
            p[cand] = cp.point + clearance * out
    return p.reshape(points.shape)


def cut_fibres(points: np.ndarray, head_field, hair_field, cut_distance: float, cut_length: float) -> np.ndarray:
    """(F,) index of the last node kept by the final cut of each fibre (points (F, n, 3) m)."""
    F, n, _ = points.shape
    flat = points.reshape(-1, 3)
    hd = _k.field_distance(hair_field, flat).reshape(F, n)
    sd = _k.field_distance(head_field, flat).reshape(F, n)
    out = np.empty(F, np.int64)
    _k.first_exit_batch(hd, sd, np.ascontiguousarray(points), cut_distance, cut_length, out)
    return out
