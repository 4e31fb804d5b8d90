"""Numba path tracer for fibre assemblies with the Marschner far-field BSDF (render subpackage).

``near`` selects the near-field lobes (Sobottka 6.20) at the hit's offset h across the fibre width
instead of the far field. Per camera sample: up to ``max_scatter`` fibre scattering events (order 1 = single scattering); at every
event next-event estimation toward each light with a shadow ray, then a new direction importance-sampled
from the lobes' longitudinal Gaussians (defensive mixture, φ uniform); rays escaping after ≥ 1 event see
the constant environment. Russian roulette from path segment ``rr_depth`` on (Mitsuba's rule,
q = min(max throughput, 0.95); unbiased). Lights: ``lights`` (L, 7) rows [kind, x, y, z, r, g, b] with kind 0 =
directional (x,y,z toward the light, rgb irradiance W/m²) and kind 1 = point (position m, rgb intensity W/sr).

Opaque diffuse surfaces: analytic rows ``surfaces`` (:func:`surface_hit`) and one triangle ``mesh``, a tuple
(tri_coords, order, node_child, node_start, node_count, node_lo, node_hi: the arrays of
:func:`headsim.collide._kernels_ray.first_hit_ray`; corner_normals (m, 3, 3) unit vertex normals of every triangle's
corners, geometric (m, 3) unit face normals and albedo (m, 3), by triangle id; stack_size (1,) int64); no
triangles: no mesh. A hit is (t, k, u, v) (:func:`scene_hit`): k ≥ 0 an analytic row, k ≤ −2 triangle −2 − k at
barycentric weights u, v of its vertices 1 and 2, −1 none.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from headsim.collide._kernels_ray import first_hit_ray
from headsim.hair.render._kernels_bvh import _STACK, intersect
from headsim.hair.render._kernels_scattering import far_field, gauss, near_field

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)


@njit(cache=True, inline="always")
def _mix64(z):
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@njit(cache=True, inline="always")
def _rand(state):
    state[0] += _GOLDEN
    return float(_mix64(state[0]) >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@njit(cache=True, inline="always")
def _frame(tx, ty, tz):
    """Unit vectors u, v ⊥ tangent t (fixed rule, so φ has an absolute origin for the elliptic TRT)."""
    if abs(tx) < 0.9:
        hx, hy, hz = 1.0, 0.0, 0.0
    else:
        hx, hy, hz = 0.0, 1.0, 0.0
    ux = ty * hz - tz * hy
    uy = tz * hx - tx * hz
    uz = tx * hy - ty * hx
    n = math.sqrt(ux * ux + uy * uy + uz * uz)
    ux /= n
    uy /= n
    uz /= n
    vx = ty * uz - tz * uy
    vy = tz * ux - tx * uz
    vz = tx * uy - ty * ux
    return ux, uy, uz, vx, vy, vz


@njit(cache=True, inline="always")
def _angles(wx, wy, wz, tx, ty, tz, ux, uy, uz, vx, vy, vz):
    s = wx * tx + wy * ty + wz * tz
    s = min(1.0, max(-1.0, s))
    return math.asin(s), math.atan2(wx * vx + wy * vy + wz * vz, wx * ux + wy * uy + wz * uz)


@njit(cache=True)
def _theta_pdf(prm, mixp, theta_r, th):
    p = mixp[0] / math.pi
    for lobe in range(3):
        c = 2.0 * prm[1 + lobe] - theta_r
        w = 2.0 * prm[4 + lobe]
        mass = 0.5 * (math.erf((0.5 * math.pi - c) / (w * math.sqrt(2.0)))
                      - math.erf((-0.5 * math.pi - c) / (w * math.sqrt(2.0))))
        p += mixp[1 + lobe] * gauss(w, th - c) / max(mass, 1e-12)
    return p


@njit(cache=True)
def _sample_theta(prm, mixp, theta_r, state):
    u = _rand(state)
    if u < mixp[0]:
        return (_rand(state) - 0.5) * math.pi
    acc = mixp[0]
    lobe = 2
    for k in range(3):
        acc += mixp[1 + k]
        if u < acc:
            lobe = k
            break
    c = 2.0 * prm[1 + lobe] - theta_r
    w = 2.0 * prm[4 + lobe]
    for _ in range(64):
        u1 = max(_rand(state), 1e-300)
        u2 = _rand(state)
        x = c + w * math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)
        if abs(x) < 0.5 * math.pi:
            return x
    return (_rand(state) - 0.5) * math.pi


@njit(cache=True, inline="always")
def _light_at(lights, q, xx, xy, xz):
    """Light q as seen from x: unit direction towards it, its distance (inf: directional) and its irradiance
    there (RGB; a point light's intensity / distance²)."""
    if lights[q, 0] == 0.0:
        return lights[q, 1], lights[q, 2], lights[q, 3], np.inf, lights[q, 4], lights[q, 5], lights[q, 6]
    wx = lights[q, 1] - xx
    wy = lights[q, 2] - xy
    wz = lights[q, 3] - xz
    dist = math.sqrt(wx * wx + wy * wy + wz * wz)
    inv = 1.0 / (dist * dist)
    return wx / dist, wy / dist, wz / dist, dist, lights[q, 4] * inv, lights[q, 5] * inv, lights[q, 6] * inv


@njit(cache=True)
def surface_hit(ox, oy, oz, dx, dy, dz, tmin, surfaces):
    """Nearest hit t > tmin of the ray o + t d (d unit) with the analytic opaque surfaces, rows of ``surfaces``
    (k, 10): kind (0 sphere: centre, radius; 1 plane: point, unit normal), (x, y, z), (r, 0, 0) or (nx, ny, nz),
    diffuse albedo RGB. Returns (t, row) or (inf, −1)."""
    best_t = np.inf
    best = -1
    for k in range(surfaces.shape[0]):
        px = surfaces[k, 1] - ox
        py = surfaces[k, 2] - oy
        pz = surfaces[k, 3] - oz
        if surfaces[k, 0] == 0.0:  # sphere: |o + t d − c|² = r²
            bb = px * dx + py * dy + pz * dz
            cc = px * px + py * py + pz * pz - surfaces[k, 4] ** 2
            disc = bb * bb - cc
            if disc < 0.0:
                continue
            sq = math.sqrt(disc)
            t = bb - sq
            if t <= tmin:
                t = bb + sq
        else:  # plane: (o + t d − p)·n = 0
            den = dx * surfaces[k, 4] + dy * surfaces[k, 5] + dz * surfaces[k, 6]
            if den == 0.0:
                continue
            t = (px * surfaces[k, 4] + py * surfaces[k, 5] + pz * surfaces[k, 6]) / den
        if tmin < t < best_t:
            best_t = t
            best = k
    return best_t, best


@njit(cache=True)
def scene_hit(ox, oy, oz, dx, dy, dz, tmin, surfaces, mesh, mstack, mstack_t):
    """Nearest opaque-surface hit t > tmin of the ray o + t d (d unit): the analytic rows (:func:`surface_hit`)
    and the mesh's triangles (t ≥ tmin). Returns (t, k, u, v) as the module docstring says; (inf, −1, 0, 0): none."""
    t, k = surface_hit(ox, oy, oz, dx, dy, dz, tmin, surfaces)
    if mesh[1].shape[0] > 0:
        tm, tri, u, v = first_hit_ray(ox, oy, oz, dx, dy, dz, tmin, t, mesh[0], mesh[1], mesh[2], mesh[3], mesh[4],
                                      mesh[5], mesh[6], mstack, mstack_t)
        if tri >= 0 and tm < t:
            return tm, -2 - tri, u, v
    return t, k, 0.0, 0.0


@njit(cache=True)
def _surface_at(k, u, v, xx, xy, xz, dx, dy, dz, surfaces, mesh):
    """Shading normal, geometric normal (both unit, on the side the ray o + t d comes from) and albedo of the hit
    (k, u, v) at x: an analytic row's exact normal, a triangle's vertex normals interpolated at (u, v)."""
    if k >= 0:
        if surfaces[k, 0] == 0.0:
            nx = (xx - surfaces[k, 1]) / surfaces[k, 4]
            ny = (xy - surfaces[k, 2]) / surfaces[k, 4]
            nz = (xz - surfaces[k, 3]) / surfaces[k, 4]
        else:
            nx, ny, nz = surfaces[k, 4], surfaces[k, 5], surfaces[k, 6]
        gx, gy, gz = nx, ny, nz
        r, g, b = surfaces[k, 7], surfaces[k, 8], surfaces[k, 9]
    else:
        tri = -2 - k
        cn = mesh[7]
        w0 = 1.0 - u - v
        nx = w0 * cn[tri, 0, 0] + u * cn[tri, 1, 0] + v * cn[tri, 2, 0]
        ny = w0 * cn[tri, 0, 1] + u * cn[tri, 1, 1] + v * cn[tri, 2, 1]
        nz = w0 * cn[tri, 0, 2] + u * cn[tri, 1, 2] + v * cn[tri, 2, 2]
        ln = math.sqrt(nx * nx + ny * ny + nz * nz)
        gx, gy, gz = mesh[8][tri, 0], mesh[8][tri, 1], mesh[8][tri, 2]
        if ln > 0.0:
            nx, ny, nz = nx / ln, ny / ln, nz / ln
        else:
            nx, ny, nz = gx, gy, gz
        r, g, b = mesh[9][tri, 0], mesh[9][tri, 1], mesh[9][tri, 2]
    if gx * dx + gy * dy + gz * dz > 0.0:  # the side the ray comes from
        gx, gy, gz = -gx, -gy, -gz
    if nx * gx + ny * gy + nz * gz < 0.0:
        nx, ny, nz = -nx, -ny, -nz
    return nx, ny, nz, gx, gy, gz, r, g, b


@njit(cache=True)
def _shade_surface(k, u, v, xx, xy, xz, dx, dy, dz, surfaces, mesh, mstack, mstack_t, lights, env, a, b, radius,
                   left, right, bmin, bmax, start, count, stack, out):
    """Radiance (3,) leaving the diffuse surface hit (k, u, v) at x towards −d: Lambert, ρ/π Σ_lights E cos⁺ with
    shadow rays through the fibres and the surfaces, plus ρ × env (a uniform environment seen from an open
    surface, exact for a lone sphere or plane; the fibres' shading of the environment is not counted)."""
    nx, ny, nz, gx, gy, gz, r0, r1, r2 = _surface_at(k, u, v, xx, xy, xz, dx, dy, dz, surfaces, mesh)
    out[0] = r0 * env[0]
    out[1] = r1 * env[1]
    out[2] = r2 * env[2]
    for q in range(lights.shape[0]):
        wx, wy, wz, dist, e0, e1, e2 = _light_at(lights, q, xx, xy, xz)
        cos = nx * wx + ny * wy + nz * wz
        if cos <= 0.0:
            continue
        # shadow rays start a hair's breadth off the surface (along its geometric normal)
        ox, oy, oz = xx + 1e-9 * gx, xy + 1e-9 * gy, xz + 1e-9 * gz
        ts, _, _, _ = scene_hit(ox, oy, oz, wx, wy, wz, 0.0, surfaces, mesh, mstack, mstack_t)
        if ts < dist:
            continue
        th, ph = intersect(ox, oy, oz, wx, wy, wz, 0.0, dist, -1, True, a, b, radius, left, right, bmin, bmax, start,
                           count, stack)
        if ph >= 0:
            continue
        f = cos / math.pi
        out[0] += r0 * f * e0
        out[1] += r1 * f * e1
        out[2] += r2 * f * e2


@njit(cache=True)
def trace_pixel(i, j, height, width, spp, seed, cam, prm, ztab, gtab, mixp, lights, env, background, max_scatter,
                rr_depth, near, a, b, radius, left, right, bmin, bmax, start, count, surfaces, mesh, out):
    """Accumulate the mean radiance of pixel (i, j) over ``spp`` samples into ``out`` (3,).

    cam (12,): position, forward, right·tan(fov_x/2), up·tan(fov_y/2). surfaces (k, 10), mesh: opaque diffuse
    surfaces (module docstring; none: fibres alone): a path that reaches one ends there with its radiance
    (:func:`_shade_surface`), and they cast shadows on the fibres."""
    state = np.empty(1, np.uint64)
    lobes = np.empty((3, 3))
    stack = np.empty(_STACK, np.int64)
    srad = np.empty(3)
    has_surfaces = surfaces.shape[0] > 0 or mesh[1].shape[0] > 0
    mstack = np.empty(mesh[10][0], np.int64)
    mstack_t = np.empty(mesh[10][0])
    acc0 = 0.0
    acc1 = 0.0
    acc2 = 0.0
    for s in range(spp):
        state[0] = _mix64(np.uint64(seed) * np.uint64(0x100000001B3) + np.uint64((i * width + j) * spp + s))
        px = (j + _rand(state)) / width * 2.0 - 1.0
        py = 1.0 - (i + _rand(state)) / height * 2.0
        dx = cam[3] + px * cam[6] + py * cam[9]
        dy = cam[4] + px * cam[7] + py * cam[10]
        dz = cam[5] + px * cam[8] + py * cam[11]
        n = math.sqrt(dx * dx + dy * dy + dz * dz)
        dx /= n
        dy /= n
        dz /= n
        ox, oy, oz = cam[0], cam[1], cam[2]
        b0 = 1.0
        b1 = 1.0
        b2 = 1.0
        l0 = 0.0
        l1 = 0.0
        l2 = 0.0
        skip = -1
        for depth in range(max_scatter):
            t_s, k_s, u_s, v_s = np.inf, -1, 0.0, 0.0
            if has_surfaces:
                t_s, k_s, u_s, v_s = scene_hit(ox, oy, oz, dx, dy, dz, 1e-9, surfaces, mesh, mstack, mstack_t)
            t, prim = intersect(ox, oy, oz, dx, dy, dz, 1e-9, t_s, skip, False, a, b, radius, left, right,
                                bmin, bmax, start, count, stack)
            if prim < 0 and k_s != -1:  # the path ends on a surface
                _shade_surface(k_s, u_s, v_s, ox + t_s * dx, oy + t_s * dy, oz + t_s * dz, dx, dy, dz, surfaces, mesh,
                               mstack, mstack_t, lights, env, a, b, radius, left, right, bmin, bmax, start, count,
                               stack, srad)
                l0 += b0 * srad[0]
                l1 += b1 * srad[1]
                l2 += b2 * srad[2]
                break
            if prim < 0:
                if depth == 0:
                    l0 += background[0]
                    l1 += background[1]
                    l2 += background[2]
                else:
                    l0 += b0 * env[0]
                    l1 += b1 * env[1]
                    l2 += b2 * env[2]
                break
            xx = ox + t * dx
            xy = oy + t * dy
            xz = oz + t * dz
            tx = b[prim, 0] - a[prim, 0]
            ty = b[prim, 1] - a[prim, 1]
            tz = b[prim, 2] - a[prim, 2]
            tn = math.sqrt(tx * tx + ty * ty + tz * tz)
            tx /= tn
            ty /= tn
            tz /= tn
            ux, uy, uz, vx, vy, vz = _frame(tx, ty, tz)
            theta_r, phi_r = _angles(-dx, -dy, -dz, tx, ty, tz, ux, uy, uz, vx, vy, vz)
            h_r = 0.0
            if near:
                # exit offset across the width: h_r = sin(φ_r − φ_n), φ_n the azimuth of the surface normal
                px_ = xx - a[prim, 0]
                py_ = xy - a[prim, 1]
                pz_ = xz - a[prim, 2]
                s_ax = px_ * tx + py_ * ty + pz_ * tz
                nx_ = px_ - s_ax * tx
                ny_ = py_ - s_ax * ty
                nz_ = pz_ - s_ax * tz
                phi_n = math.atan2(nx_ * vx + ny_ * vy + nz_ * vz, nx_ * ux + ny_ * uy + nz_ * uz)
                h_r = math.sin(phi_r - phi_n)
            # next-event estimation
            for k in range(lights.shape[0]):
                wx, wy, wz, dist, e0, e1, e2 = _light_at(lights, k, xx, xy, xz)
                if has_surfaces:
                    ts, _, _, _ = scene_hit(xx, xy, xz, wx, wy, wz, 1e-9, surfaces, mesh, mstack, mstack_t)
                    if ts < dist:
                        continue
                ts, ps = intersect(xx, xy, xz, wx, wy, wz, 1e-9, dist, prim, True, a, b, radius, left, right,
                                   bmin, bmax, start, count, stack)
                if ps >= 0:
                    continue
                theta_i, phi_i = _angles(wx, wy, wz, tx, ty, tz, ux, uy, uz, vx, vy, vz)
                if near:
                    near_field(prm, ztab, h_r, theta_i, phi_i, theta_r, phi_r, lobes)
                else:
                    far_field(prm, ztab, gtab, theta_i, phi_i, theta_r, phi_r, lobes)
                ci = math.cos(theta_i)
                l0 += b0 * (lobes[0, 0] + lobes[1, 0] + lobes[2, 0]) * ci * e0
                l1 += b1 * (lobes[0, 1] + lobes[1, 1] + lobes[2, 1]) * ci * e1
                l2 += b2 * (lobes[0, 2] + lobes[1, 2] + lobes[2, 2]) * ci * e2
            if depth + 1 >= max_scatter:
                break
            # sample the next (incident) direction
            theta_i = _sample_theta(prm, mixp, theta_r, state)
            phi_i = (2.0 * _rand(state) - 1.0) * math.pi
            if near:
                near_field(prm, ztab, h_r, theta_i, phi_i, theta_r, phi_r, lobes)
            else:
                far_field(prm, ztab, gtab, theta_i, phi_i, theta_r, phi_r, lobes)
            ci = math.cos(theta_i)
            w = ci * ci * 2.0 * math.pi / _theta_pdf(prm, mixp, theta_r, theta_i)
            b0 *= (lobes[0, 0] + lobes[1, 0] + lobes[2, 0]) * w
            b1 *= (lobes[0, 1] + lobes[1, 1] + lobes[2, 1]) * w
            b2 *= (lobes[0, 2] + lobes[1, 2] + lobes[2, 2]) * w
            if b0 + b1 + b2 <= 0.0:
                break
            if depth + 2 >= rr_depth:  # Russian roulette as Mitsuba's path integrator (rr_depth counts segments)
                q = min(max(b0, max(b1, b2)), 0.95)
                if _rand(state) >= q:
                    break
                b0 /= q
                b1 /= q
                b2 /= q
            cp = math.cos(phi_i)
            sp = math.sin(phi_i)
            si = math.sin(theta_i)
            dx = ci * (cp * ux + sp * vx) + si * tx
            dy = ci * (cp * uy + sp * vy) + si * ty
            dz = ci * (cp * uz + sp * vz) + si * tz
            ox, oy, oz = xx, xy, xz
            skip = prim
        acc0 += l0
        acc1 += l1
        acc2 += l2
    out[0] = acc0 / spp
    out[1] = acc1 / spp
    out[2] = acc2 / spp


@njit(cache=True, parallel=True)
def render_rows(row0, row1, height, width, spp, seed, cam, prm, ztab, gtab, mixp, lights, env, background,
                max_scatter, rr_depth, near, a, b, radius, left, right, bmin, bmax, start, count, surfaces, mesh, image):
    """Render rows [row0, row1) into ``image`` (height, width, 3) float64, parallel over pixels (surfaces, mesh:
    see :func:`trace_pixel`)."""
    n = (row1 - row0) * width
    for k in prange(n):
        i = row0 + k // width
        j = k % width
        trace_pixel(i, j, height, width, spp, seed, cam, prm, ztab, gtab, mixp, lights, env, background,
                    max_scatter, rr_depth, near, a, b, radius, left, right, bmin, bmax, start, count, surfaces,
                    mesh, image[i, j])
