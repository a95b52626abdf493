"""Lit opaque surfaces (level sets): the hit (surface_hit: albedo, depth), its Blinn-Phong shading
(shade_hit), the reference mode's signed-distance crossing and normal (voxel bricks), and the field
mode's crossing between samples (field_crossing, mixture_hit) and normal from the Gaussians around
the hit (mixture_normal).

Field mode, Gaussians with signed distances d_i (GaussianSet.distances, Objects.sdf): the surface
is the zero of the normalised signed mixture S(x) = sum_i w_i(x) d_i / sum_i w_i(x), trusted where
the occupancy sum_i w_i(x) >= SDF_OCCUPANCY (inside the shell); where the band kept one layer of
voxels S stays just above 0 through it, and such a passage is the hit (field_crossing). The
normal is the gradient of the linear fit d ~ a + g.(x - mu) to the Gaussians' distances weighted
by w_i(x) at the hit (moving least squares: grad S itself follows the jagged shell of voxels, up
to 20 degrees off on a sphere; the fit is within 0.6). Without distances (older files): the 0.5
occupancy, normal from the blurred occupancy's gradient."""
from __future__ import annotations

import math

import numpy as np

from ...jit import njit
from ..inputs.layout import (
    BG_DEPTH,
    BRICK_HI,
    DEPTH,
    HIT,
    HIT_C,
    HIT_FOUND,
    HIT_G,
    HIT_NORMAL,
    HIT_OB,
    HIT_T,
    LEAF,
    LIGHT_KIND,
    LIGHT_RGB,
    LIGHT_VEC,
    LS_COLOR,
    LS_CONST,
    LS_PLANE,
    LS_RANGE,
    NODE_LEAVES,
    NORMAL_BLUR,
    NORMAL_REACH,
    RAD,
    REC_INV,
    REC_MU,
    REC_W,
    SDF_OCCUPANCY,
    SET_SHADING,
    TR,
    LightKind,
)
from .vecmath import INF, _hot, composite, lut_pos

POINT, SUN = float(LightKind.POINT), float(LightKind.SUN)  # as the float lights rows hold them


@njit(**_hot)
def surface_hit(st, ob, t, gx, gy, gz, obj_ls, lut, x, y, z):
    """The ray ends on object ob's surface at t (index point x, y, z; gx, gy, gz: the outward
    normal's direction in index space): its albedo (the constant colour or the colormap over a
    world coordinate, as for shells) and the depth, for render_pixels to shade."""
    st[HIT] = HIT_FOUND
    st[HIT_T] = t
    st[HIT_G] = gx
    st[HIT_G + 1] = gy
    st[HIT_G + 2] = gz
    st[HIT_OB] = ob
    ls = obj_ls[ob]
    if ls[LS_CONST] > 0.5:
        st[HIT_C], st[HIT_C + 1], st[HIT_C + 2] = ls[LS_COLOR], ls[LS_COLOR + 1], ls[LS_COLOR + 2]
    else:
        c = ls[LS_PLANE] * x + ls[LS_PLANE + 1] * y + ls[LS_PLANE + 2] * z + ls[LS_PLANE + 3]
        lo, hi = ls[LS_RANGE], ls[LS_RANGE + 1]
        u = (c - lo) / (hi - lo) if hi > lo else 0.5
        i, w = lut_pos(lut, min(max(u, 0.0), 1.0))
        for k in range(3):
            st[HIT_C + k] = lut[i, k] * (1.0 - w) + lut[i + 1, k] * w
    if st[DEPTH] == BG_DEPTH:
        st[DEPTH] = t


@njit(**_hot, inline="always")
def light_at(lights, k, px, py, pz, dx, dy, dz):
    """Light k seen from world point p on a ray of direction d: (ok, unit direction towards it,
    irradiance rgb, distance). Point lights fall off as 1 / r^2; the headlight shines along d."""
    er, eg, eb = lights[k, LIGHT_RGB], lights[k, LIGHT_RGB + 1], lights[k, LIGHT_RGB + 2]
    kind = lights[k, LIGHT_KIND]
    if kind == POINT:
        lx, ly, lz = lights[k, LIGHT_VEC] - px, lights[k, LIGHT_VEC + 1] - py, lights[k, LIGHT_VEC + 2] - pz
        d2 = lx * lx + ly * ly + lz * lz
        if not d2 > 0.0:
            return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        dl = math.sqrt(d2)
        return True, lx / dl, ly / dl, lz / dl, er / d2, eg / d2, eb / d2, dl
    if kind == SUN:
        return True, -lights[k, LIGHT_VEC], -lights[k, LIGHT_VEC + 1], -lights[k, LIGHT_VEC + 2], er, eg, eb, INF
    return True, -dx, -dy, -dz, er, eg, eb, INF


@njit(**_hot)
def shade_hit(st, M, lights, par, ox, oy, oz, dx, dy, dz):
    """Blinn-Phong at the hit in st (see surface_hit) for the world ray o + t d: the normal is
    the index-space gradient through M (world -> index) transposed, turned to face the viewer;
    par[SET_SHADING:] = (ambient, diffuse, specular, shininess) (packing.pack_settings). Adds
    T x colour and makes the ray opaque."""
    gx, gy, gz = st[HIT_G], st[HIT_G + 1], st[HIT_G + 2]
    nx = M[0, 0] * gx + M[1, 0] * gy + M[2, 0] * gz
    ny = M[0, 1] * gx + M[1, 1] * gy + M[2, 1] * gz
    nz = M[0, 2] * gx + M[1, 2] * gy + M[2, 2] * gz
    nn = math.sqrt(nx * nx + ny * ny + nz * nz)
    if nn > 0.0:
        nx, ny, nz = nx / nn, ny / nn, nz / nn
    else:
        nx, ny, nz = -dx, -dy, -dz
    if nx * dx + ny * dy + nz * dz > 0.0:
        nx, ny, nz = -nx, -ny, -nz
    t = st[HIT_T]
    px, py, pz = ox + t * dx, oy + t * dy, oz + t * dz
    ka, kd, ks, sh = par[SET_SHADING], par[SET_SHADING + 1], par[SET_SHADING + 2], par[SET_SHADING + 3]
    r = ka * st[HIT_C]
    g = ka * st[HIT_C + 1]
    b = ka * st[HIT_C + 2]
    for k in range(lights.shape[0]):
        ok, lx, ly, lz, er, eg, eb, _ = light_at(lights, k, px, py, pz, dx, dy, dz)
        if not ok:
            continue
        ndl = nx * lx + ny * ly + nz * lz
        if ndl <= 0.0:
            continue
        hx, hy, hz = lx - dx, ly - dy, lz - dz
        hn = math.sqrt(hx * hx + hy * hy + hz * hz)
        spec = 0.0
        if hn > 0.0 and ks > 0.0:
            ndh = max(nx * hx + ny * hy + nz * hz, 0.0) / hn
            spec = ks * ndh ** sh
        r += er * (kd * ndl * st[HIT_C] + spec)
        g += eg * (kd * ndl * st[HIT_C + 1] + spec)
        b += eb * (kd * ndl * st[HIT_C + 2] + spec)
    T = st[TR]
    st[RAD] += T * r
    st[RAD + 1] += T * g
    st[RAD + 2] += T * b
    st[TR] = 0.0


@njit(**_hot, inline="always")
def brick_xyz(cxyz, x, y, z):
    """Index point -> coordinates in its leaf's 10^3 brick (apron of one voxel), clamped."""
    fx = min(max(x - (cxyz[0] * LEAF - 1), 0.0), BRICK_HI)
    fy = min(max(y - (cxyz[1] * LEAF - 1), 0.0), BRICK_HI)
    fz = min(max(z - (cxyz[2] * LEAF - 1), 0.0), BRICK_HI)
    return fx, fy, fz


@njit(**_hot, inline="always")
def trilinear(B, fx, fy, fz):
    i0, j0, k0 = int(fx), int(fy), int(fz)
    ax, ay, az = fx - i0, fy - j0, fz - k0
    c00 = B[i0, j0, k0] * (1 - ax) + B[i0 + 1, j0, k0] * ax
    c10 = B[i0, j0 + 1, k0] * (1 - ax) + B[i0 + 1, j0 + 1, k0] * ax
    c01 = B[i0, j0, k0 + 1] * (1 - ax) + B[i0 + 1, j0, k0 + 1] * ax
    c11 = B[i0, j0 + 1, k0 + 1] * (1 - ax) + B[i0 + 1, j0 + 1, k0 + 1] * ax
    return (c00 * (1 - ay) + c10 * ay) * (1 - az) + (c01 * (1 - ay) + c11 * ay) * az


@njit(**_hot)
def trilinear_grad(B, fx, fy, fz):
    """The gradient (per index unit) of the brick's values at a point: the voxels' central
    differences (one-sided at the brick's edge), interpolated trilinearly; smoother than the
    interpolant's own, piecewise, gradient."""
    i0, j0, k0 = int(fx), int(fy), int(fz)
    ax, ay, az = fx - i0, fy - j0, fz - k0
    n = B.shape[0] - 1
    gx = gy = gz = 0.0
    for di in range(2):
        i = i0 + di
        wx = ax if di else 1.0 - ax
        for dj in range(2):
            j = j0 + dj
            wy = ay if dj else 1.0 - ay
            for dk in range(2):
                k = k0 + dk
                w = wx * wy * (az if dk else 1.0 - az)
                ia, ib = max(i - 1, 0), min(i + 1, n)
                ja, jb = max(j - 1, 0), min(j + 1, n)
                ka, kb = max(k - 1, 0), min(k + 1, n)
                gx += w * (B[ib, j, k] - B[ia, j, k]) / (ib - ia)
                gy += w * (B[i, jb, k] - B[i, ja, k]) / (jb - ja)
                gz += w * (B[i, j, kb] - B[i, j, ka]) / (kb - ka)
    return gx, gy, gz


@njit(**_hot)
def sdf_crossing(sprev, ob, phi, t, p0, h, ro, rd, B, cxyz):
    """Object ob's signed distance phi at sample t: the hit t where it first turns <= 0 after a
    positive sample (bisection in this leaf's brick over [max(previous t, p0 - h), t]); t = p0
    when its first sample is already inside; else INF. Records the sample in sprev."""
    tp = sprev[ob, 1]
    pp = sprev[ob, 0]
    sprev[ob, 0] = phi
    sprev[ob, 1] = t
    if phi > 0.0:
        return INF
    if tp != tp:
        return p0
    if not pp > 0.0:
        return INF  # already inside (behind a hit that was ignored): no new crossing
    lo = max(tp, p0 - h)
    hi = t
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        fx, fy, fz = brick_xyz(cxyz, ro[ob, 0] + mid * rd[ob, 0], ro[ob, 1] + mid * rd[ob, 1],
                               ro[ob, 2] + mid * rd[ob, 2])
        if trilinear(B, fx, fy, fz) > 0.0:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


@njit(**_hot, inline="always")
def field_crossing(sprev, ob, isamp, ti, hstep, sv, nv, sdf, level):
    """Object ob's surface between samples isamp - 1 and isamp (at ti, hstep apart), or INF.
    sdf: where S = nv / sv (nv = sum_i w_i d_i) falls through 0 while the occupancy sv >=
    SDF_OCCUPANCY (placed by the secant; a first such sample already <= 0: there); a passage
    through the shell that ends without it, its mean S (occupancy-weighted) below level (a single
    layer of voxels, see levelset.SURFACE_LEVEL): the passage's occupancy-weighted centre. Else
    where sv rises through 0.5 (by the secant). sprev[ob]: the last sample's level and index; the
    passage's sums of sv, sv t and nv."""
    adjacent = sprev[ob, 1] == isamp - 1
    if sdf == 0:
        prev = sprev[ob, 0] if adjacent else 0.0  # none active: 0
        sprev[ob, 0], sprev[ob, 1] = sv, isamp
        if sv >= 0.5 and prev < 0.5:
            return ti - hstep + (0.5 - prev) / (sv - prev) * hstep
        return INF
    prev = sprev[ob, 0] if adjacent else np.nan  # NaN: not in a passage
    if sv < SDF_OCCUPANCY:
        sprev[ob, 0], sprev[ob, 1] = np.nan, isamp
        return sprev[ob, 3] / sprev[ob, 2] if prev == prev and sprev[ob, 4] < level * sprev[ob, 2] else INF
    f = nv / sv
    sprev[ob, 0], sprev[ob, 1] = f, isamp
    if f <= 0.0:
        return ti - hstep + prev / (prev - f) * hstep if prev > 0.0 else ti
    if prev != prev:  # a passage begins
        sprev[ob, 2], sprev[ob, 3], sprev[ob, 4] = 0.0, 0.0, 0.0
    sprev[ob, 2], sprev[ob, 3], sprev[ob, 4] = sprev[ob, 2] + sv, sprev[ob, 3] + sv * ti, sprev[ob, 4] + nv
    return INF


@njit(**_hot)
def mixture_hit(st, ob, th, ti, hstep, ro, rd, obj_ls, lut, acc):
    """Object ob's surface at th, inside the sample at ti: the volumes of that sample composite
    over [ti - hstep / 2, th], then the hit; its normal is left for render_pixels to take from
    the Gaussians around the hit (mixture_normal): the ray's active set is only a tube around it."""
    if acc[0] > 0.0 and th > ti - 0.5 * hstep:
        sig = acc[0]
        composite(st, sig * (th - (ti - 0.5 * hstep)), acc[1] / sig, acc[2] / sig, acc[3] / sig,
                  acc[4] / acc[5] if acc[5] > 0 else np.nan, ti - 0.5 * hstep, th)
    x = ro[ob, 0] + th * rd[ob, 0]
    y = ro[ob, 1] + th * rd[ob, 1]
    z = ro[ob, 2] + th * rd[ob, 2]
    surface_hit(st, ob, th, 0.0, 0.0, 0.0, obj_ls, lut, x, y, z)
    st[HIT] = HIT_NORMAL  # the normal is still to be found


@njit(**_hot, inline="always")
def fit_gradient(s0, s1, s2, s3, sxx, sxy, sxz, syy, syz, szz, d0, d1, d2, d3, slope):
    """The slope g of the weighted least-squares fit d ~ a + g.u from the sums of w (s0), w u
    (s1..s3), w u u^T (sxx..szz), w d (d0) and w d u (d1..d3). Where the fit's |g| falls short of
    half a signed distance's slope (the voxel's size): the points lie in one layer, which leaves
    g across it undetermined; the layer's normal then (the adjugate's longest column: the
    covariance's least axis; any sign, shade_hit turns it to the viewer)."""
    mx, my, mz, dm = s1 / s0, s2 / s0, s3 / s0, d0 / s0
    cxx, cxy, cxz = sxx / s0 - mx * mx, sxy / s0 - mx * my, sxz / s0 - mx * mz
    cyy, cyz, czz = syy / s0 - my * my, syz / s0 - my * mz, szz / s0 - mz * mz
    bx, by, bz = d1 / s0 - mx * dm, d2 / s0 - my * dm, d3 / s0 - mz * dm
    a00, a01, a02 = cyy * czz - cyz * cyz, cxz * cyz - cxy * czz, cxy * cyz - cxz * cyy
    a11, a12, a22 = cxx * czz - cxz * cxz, cxy * cxz - cxx * cyz, cxx * cyy - cxy * cxy
    det = cxx * a00 + cxy * a01 + cxz * a02
    tr = cxx + cyy + czz
    if det > 1e-9 * tr * tr * tr:
        gx = (a00 * bx + a01 * by + a02 * bz) / det
        gy = (a01 * bx + a11 * by + a12 * bz) / det
        gz = (a02 * bx + a12 * by + a22 * bz) / det
        if gx * gx + gy * gy + gz * gz >= 0.25 * slope * slope:
            return gx, gy, gz
    n0, n1, n2 = a00 * a00 + a01 * a01 + a02 * a02, a01 * a01 + a11 * a11 + a12 * a12, a02 * a02 + a12 * a12 + a22 * a22
    if n0 >= n1 and n0 >= n2:
        return a00, a01, a02
    return (a01, a11, a12) if n1 >= n2 else (a02, a12, a22)


@njit(**_hot)
def mixture_normal(st, ro, rd, nmin, ndims, noff, node_table, node_cells, cell_start, cell_items,
                   g_rec, g_cw, sdf, slope):
    """The outward normal at a field-mode surface hit (st, see surface_hit) from the Gaussians
    centred in the leaf cells within NORMAL_REACH of the hit (each is listed in the cell of its
    centre, among others). sdf (the Gaussians' signed distance x weight in g_cw): the fit's
    gradient (fit_gradient; slope: a distance's change per voxel, the voxel's size; see the
    module doc); else -grad of the mixture blurred by a Gaussian
    of variance NORMAL_BLUR (each sigma^2 grows by it), which evens out the lattice of
    voxel-sized Gaussians the shell is made of."""
    ob = int(st[HIT_OB])
    t = st[HIT_T]
    x = ro[ob, 0] + t * rd[ob, 0]
    y = ro[ob, 1] + t * rd[ob, 1]
    z = ro[ob, 2] + t * rd[ob, 2]
    lo0 = int(math.floor((x + 0.5 - NORMAL_REACH) / LEAF))
    lo1 = int(math.floor((y + 0.5 - NORMAL_REACH) / LEAF))
    lo2 = int(math.floor((z + 0.5 - NORMAL_REACH) / LEAF))
    hi0 = int(math.floor((x + 0.5 + NORMAL_REACH) / LEAF))
    hi1 = int(math.floor((y + 0.5 + NORMAL_REACH) / LEAF))
    hi2 = int(math.floor((z + 0.5 + NORMAL_REACH) / LEAF))
    nm = nmin[ob]
    nd = ndims[ob]
    gx = gy = gz = 0.0
    s0 = s1 = s2 = s3 = sxx = sxy = sxz = syy = syz = szz = d0 = d1 = d2 = d3 = 0.0
    for cx in range(lo0, hi0 + 1):
        for cy in range(lo1, hi1 + 1):
            for cz in range(lo2, hi2 + 1):
                nx, ny, nz = cx // NODE_LEAVES, cy // NODE_LEAVES, cz // NODE_LEAVES
                if (nx < nm[0] or ny < nm[1] or nz < nm[2] or nx >= nm[0] + nd[0]
                        or ny >= nm[1] + nd[1] or nz >= nm[2] + nd[2]):
                    continue
                nid = node_table[noff[ob] + ((nx - nm[0]) * nd[1] + (ny - nm[1])) * nd[2] + (nz - nm[2])]
                if nid < 0:
                    continue
                cid = node_cells[nid, ((cx - nx * NODE_LEAVES) * NODE_LEAVES + (cy - ny * NODE_LEAVES)) * NODE_LEAVES
                                 + (cz - nz * NODE_LEAVES)]
                if cid < 0:
                    continue
                for j in range(cell_start[cid], cell_start[cid + 1]):
                    g = cell_items[j]
                    if (math.floor((g_rec[g, REC_MU] + 0.5) / LEAF) != cx
                            or math.floor((g_rec[g, REC_MU + 1] + 0.5) / LEAF) != cy
                            or math.floor((g_rec[g, REC_MU + 2] + 0.5) / LEAF) != cz):
                        continue  # counted in the cell of its centre
                    w = g_rec[g, REC_W]
                    if w == 0.0:
                        continue
                    if sdf:  # the fit's sums, about the hit
                        ux, uy, uz = g_rec[g, REC_MU] - x, g_rec[g, REC_MU + 1] - y, g_rec[g, REC_MU + 2] - z
                        q = ((ux * g_rec[g, REC_INV]) ** 2 + (uy * g_rec[g, REC_INV + 1]) ** 2
                             + (uz * g_rec[g, REC_INV + 2]) ** 2)
                        if q > 16.0:
                            continue
                        e = math.exp(-0.5 * q)
                        ew, ed = w * e, g_cw[g] * e
                        s0, s1, s2, s3 = s0 + ew, s1 + ew * ux, s2 + ew * uy, s3 + ew * uz
                        sxx, sxy, sxz = sxx + ew * ux * ux, sxy + ew * ux * uy, sxz + ew * ux * uz
                        syy, syz, szz = syy + ew * uy * uy, syz + ew * uy * uz, szz + ew * uz * uz
                        d0, d1, d2, d3 = d0 + ed, d1 + ed * ux, d2 + ed * uy, d3 + ed * uz
                        continue
                    ix = 1.0 / math.sqrt(1.0 / g_rec[g, REC_INV] ** 2 + NORMAL_BLUR)
                    iy = 1.0 / math.sqrt(1.0 / g_rec[g, REC_INV + 1] ** 2 + NORMAL_BLUR)
                    iz = 1.0 / math.sqrt(1.0 / g_rec[g, REC_INV + 2] ** 2 + NORMAL_BLUR)
                    ux = (x - g_rec[g, REC_MU]) * ix
                    uy = (y - g_rec[g, REC_MU + 1]) * iy
                    uz = (z - g_rec[g, REC_MU + 2]) * iz
                    q = ux * ux + uy * uy + uz * uz
                    if q > 16.0:
                        continue
                    e = (w * ix * iy * iz / (g_rec[g, REC_INV] * g_rec[g, REC_INV + 1] * g_rec[g, REC_INV + 2])
                         * math.exp(-0.5 * q))
                    gx += e * ux * ix
                    gy += e * uy * iy
                    gz += e * uz * iz
    if sdf and s0 > 0.0:
        gx, gy, gz = fit_gradient(s0, s1, s2, s3, sxx, sxy, sxz, syy, syz, szz, d0, d1, d2, d3, slope)
    st[HIT_G] = gx
    st[HIT_G + 1] = gy
    st[HIT_G + 2] = gz
    st[HIT] = HIT_FOUND
