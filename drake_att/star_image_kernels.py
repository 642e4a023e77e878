"""The star image's pixel arithmetic, compiled (numba, :func:`drake_att.filters.compiled.jit`):
the windows' expected electrons, the exposure's clipping and ADC, and the centre-of-mass
centroids. :mod:`drake_att.star_image` documents the model and is the API; its functions check
their inputs, draw the noise from the frame's ``numpy.random.Generator`` (Poisson counts and
read-noise normals, passed in here: no random numbers are drawn in this module) and call these
loops, which replace numpy's many small array operations per window (their per-call overhead
was most of a frame's cost).

Arrays are float64 / int64 / bool, windows indexed ``[star, row (v), column (u)]``; the outputs
are written into arrays the caller allocates.
"""

from __future__ import annotations

import math

import numpy as np

from drake_att.filters.compiled import jit
from drake_att.star_attitude import project_pixel

_INV_SQRT2 = 1.0 / math.sqrt(2.0)


@jit
def _erf(x):
    """``math.erf``, with its exact double value +-1 beyond |x| = 6 (erf(6) = 1 - 2e-17)."""
    if x >= 6.0:
        return 1.0
    if x <= -6.0:
        return -1.0
    return math.erf(x)


@jit
def _pixel_fractions(first_edge, centre, scale, out):
    """``out[i]``: the fraction of a unit Gaussian at ``centre`` (``scale`` = 1 / (sqrt(2)
    sigma)) in the pixel ``[first_edge + i, first_edge + i + 1)``; returns the range
    ``(lo, hi)`` of ``i`` where it is not exactly 0 (``(len, 0)`` when none is)."""
    lo, hi = len(out), 0
    lower = _erf((first_edge - centre) * scale)
    for i in range(len(out)):
        upper = _erf((first_edge + i + 1 - centre) * scale)
        out[i] = 0.5 * (upper - lower)
        lower = upper
        if out[i] != 0.0:
            lo = min(lo, i)
            hi = i + 1
    return lo, hi


@jit
def expected_windows_kernel(
    uv, track, electrons, origin, k_steps, sigma, width, height, background_e, hot_index, hot_e, star_e, background, on
):
    """Fill ``star_e``, ``background`` and ``on`` (n, w_v, w_u) of the windows whose first pixel
    is ``origin`` (n, 2 int ``(column, row)``): each star's ``electrons`` (n,) spread by a
    Gaussian PSF of ``sigma`` px integrated over each pixel, averaged over ``k_steps`` positions
    ``uv + track t`` along the smear track, ``t = ((k + 1/2) / K - 1/2) sqrt(K^2 / (K^2 - 1))``
    (evenly spaced, with the track's mean and variance ``L^2 / 12``); the background ``background_e`` per
    pixel plus ``hot_e`` at the sorted linear indices ``hot_index`` (``row * width + column``).
    Pixels off the ``width x height`` detector hold zeros and ``on`` False."""
    n, w_v, w_u = star_e.shape
    scale = _INV_SQRT2 / sigma
    fu = np.empty((k_steps, w_u))
    fv = np.empty((k_steps, w_v))
    # per position, the columns / rows where the PSF is not exactly 0 (beyond ~6.8 sigma erf is
    # exactly +-1): the sum over positions skips only exact zeros
    u_lo, u_hi = np.empty(k_steps, np.int64), np.empty(k_steps, np.int64)
    v_lo, v_hi = np.empty(k_steps, np.int64), np.empty(k_steps, np.int64)
    psf = np.empty((w_v, w_u))
    inv_k = 1.0 / k_steps
    # the K positions' variance is the track's, L^2 / 12 (equal spacing gives (1 - 1/K^2) of it)
    spread = math.sqrt(k_steps * k_steps / (k_steps * k_steps - 1.0)) if k_steps > 1 else 1.0
    n_hot = len(hot_index)
    for s in range(n):
        u0 = origin[s, 0]
        v0 = origin[s, 1]
        for k in range(k_steps):
            t = ((k + 0.5) / k_steps - 0.5) * spread
            pu = uv[s, 0] + track[s, 0] * t
            pv = uv[s, 1] + track[s, 1] * t
            u_lo[k], u_hi[k] = _pixel_fractions(u0, pu, scale, fu[k])
            v_lo[k], v_hi[k] = _pixel_fractions(v0, pv, scale, fv[k])
        psf[:, :] = 0.0
        for k in range(k_steps):
            for j in range(v_lo[k], v_hi[k]):
                a = fv[k, j]
                for i in range(u_lo[k], u_hi[k]):
                    psf[j, i] += a * fu[k, i]
        for j in range(w_v):
            row = v0 + j
            row_on = 0 <= row < height
            for i in range(w_u):
                col = u0 + i
                if not (row_on and 0 <= col < width):
                    star_e[s, j, i] = 0.0
                    background[s, j, i] = 0.0
                    on[s, j, i] = False
                    continue
                star_e[s, j, i] = electrons[s] * (psf[j, i] * inv_k)
                background[s, j, i] = background_e
                on[s, j, i] = True
        if n_hot:  # the hot pixels in the window's rows, then its columns
            first = np.searchsorted(hot_index, max(v0, 0) * width)
            last = np.searchsorted(hot_index, min(v0 + w_v, height) * width)
            for h in range(first, last):
                col = hot_index[h] % width - u0
                if 0 <= col < w_u:
                    background[s, hot_index[h] // width - v0, col] += hot_e[h]


@jit
def adc_code(electrons, gain, black_level, max_code):
    """One pixel's ADC code: ``round(e / gain) + black``, clipped to ``[0, max_code]``."""
    code = math.floor(electrons / gain + black_level + 0.5)
    return min(max(code, 0.0), max_code)


@jit
def digitize_kernel(electrons, gain, black_level, max_code, adu):
    """``adu[i] = adc_code(electrons[i])`` over flat arrays."""
    for i in range(len(electrons)):
        adu[i] = adc_code(electrons[i], gain, black_level, max_code)


#: Poisson draws of a mean below this are made here by inversion; the others by numpy.
POISSON_INVERSION_LIMIT = 30.0


@jit
def poisson_by_inversion(mean, u):
    """The Poisson(``mean``) count whose cumulative probability first reaches the uniform ``u``
    (sequential search from 0, Devroye 1986 sec. X.3.3; ~``mean`` + 1 steps: for small means).
    The search stops where the terms no longer change the sum in double precision."""
    p = math.exp(-mean)
    c = p
    k = 0
    while u > c:
        k += 1
        p *= mean / k
        if p <= 1e-17 * c:
            break
        c += p
    return k


@jit
def poisson_counts_kernel(mean, u, big, big_counts, counts):
    """``counts[i]``: Poisson(``mean[i]``) by inversion of ``u[i]``, except at the indices
    ``big`` (ascending), whose counts ``big_counts`` were drawn elsewhere."""
    b = 0
    for i in range(len(mean)):
        if b < len(big) and big[b] == i:
            counts[i] = big_counts[b]
            b += 1
        else:
            counts[i] = poisson_by_inversion(mean[i], u[i])


@jit
def expose_kernel(counts, read_normals, on, full_well, gain, black_level, max_code, adu, clipped):
    """The exposure after the shot noise, over flat arrays: the Poisson ``counts`` clipped at the
    full well, plus the read noise ``read_normals`` (e-; empty: none), through the ADC; ``clipped``
    where the full well or the ADC's top was reached. Pixels not ``on`` the detector read 0 and
    are never clipped."""
    read = len(read_normals) > 0
    for i in range(len(counts)):
        if not on[i]:
            adu[i] = 0
            clipped[i] = False
            continue
        charge = min(float(counts[i]), full_well)
        full = charge >= full_well
        if read:
            charge += read_normals[i]
        code = adc_code(charge, gain, black_level, max_code)
        adu[i] = code
        clipped[i] = full or code >= max_code


@jit
def centroid_kernel(
    adu,
    background,
    on,
    origin,
    black_level,
    gain,
    read_e,
    threshold_sigma,
    significant_sigma,
    uv,
    cov,
    signal_e,
    snr,
    detected,
    edge,
):
    """Per window (n, w_v, w_u): the star electrons ``(ADU - black) gain - background`` (0 off
    the detector), the pixels' variances ``bg + read^2 + gain^2/12`` (+ the star signal where it
    exceeds ``significant_sigma`` noise sigmas), and writes ``signal_e`` (the window's sum),
    ``snr``, ``edge`` (a pixel off the detector), ``detected`` (the peak pixel's signal reaches
    ``threshold_sigma`` background sigmas, the sum is positive, not an edge) and, for detections,
    the centre of mass ``uv`` (n, 2) and its covariance ``cov`` (n, 2, 2) by first-order
    propagation (:mod:`drake_att.star_image`)."""
    n, w_v, w_u = adu.shape
    fixed = read_e * read_e + gain * gain / 12.0
    signal = np.empty((w_v, w_u))
    var = np.empty((w_v, w_u))
    for s in range(n):
        total = 0.0
        var_total = 0.0
        peak = -np.inf
        off = False
        for j in range(w_v):
            for i in range(w_u):
                noise_var = background[s, j, i] + fixed
                if on[s, j, i]:
                    x = (adu[s, j, i] - black_level) * gain - background[s, j, i]
                    v = noise_var + (x if x > significant_sigma * math.sqrt(noise_var) else 0.0)
                else:
                    off = True
                    x = 0.0
                    v = 0.0
                signal[j, i] = x
                var[j, i] = v
                total += x
                var_total += v
                peak = max(peak, x / math.sqrt(noise_var))
        signal_e[s] = total
        snr[s] = total / math.sqrt(var_total) if var_total > 0.0 else 0.0
        edge[s] = off
        detected[s] = peak >= threshold_sigma and total > 0.0 and not off
        if not detected[s]:
            continue
        su = 0.0
        sv = 0.0
        for j in range(w_v):
            for i in range(w_u):
                su += (origin[s, 0] + i + 0.5) * signal[j, i]
                sv += (origin[s, 1] + j + 0.5) * signal[j, i]
        u_hat = su / total
        v_hat = sv / total
        cuu = 0.0
        cuv = 0.0
        cvv = 0.0
        for j in range(w_v):
            dv = origin[s, 1] + j + 0.5 - v_hat
            for i in range(w_u):
                du = origin[s, 0] + i + 0.5 - u_hat
                cuu += var[j, i] * du * du
                cuv += var[j, i] * du * dv
                cvv += var[j, i] * dv * dv
        inv_s2 = 1.0 / (total * total)
        uv[s, 0] = u_hat
        uv[s, 1] = v_hat
        cov[s, 0, 0] = cuu * inv_s2
        cov[s, 0, 1] = cuv * inv_s2
        cov[s, 1, 0] = cuv * inv_s2
        cov[s, 1, 1] = cvv * inv_s2


@jit
def _project_rotated(camera_params, R, x, y, z):
    """``(in front, u, v)``: the pixel of the inertial direction ``(x, y, z)`` seen at ``R_IS``
    (``d_S = R^T d_I``), or ``(False, 0, 0)`` behind the camera."""
    dx = x * R[0, 0] + y * R[1, 0] + z * R[2, 0]
    dy = x * R[0, 1] + y * R[1, 1] + z * R[2, 1]
    dz = x * R[0, 2] + y * R[1, 2] + z * R[2, 2]
    if not dz > 0.0:
        return False, 0.0, 0.0
    u, v = project_pixel(camera_params, dx, dy, dz)
    return True, u, v


@jit
def tracked_windows_kernel(
    camera_params,
    width,
    height,
    half,
    unit_I,
    magnitude,
    cone,
    R_prior,
    max_stars,
    render_of,
    render_unit_I,
    R_true,
    out_index,
    out_uv,
):
    """A tracking frame's windows: of the catalogue stars ``cone`` (``unit_I``, ``magnitude``),
    the ``max_stars`` brightest (ties in ``cone``'s order) whose window of half size ``half``
    lies whole on the ``width x height`` detector at the prior ``R_prior``, kept where their
    true pixel (``render_unit_I[render_of[j]]`` at ``R_true``) is within ``half - 1`` of the
    prediction on both axes. Writes their render-catalogue indices and true pixels; returns how
    many."""
    m = len(cone)
    pred = np.empty((m, 2))
    inside = np.empty(m, dtype=np.int64)
    n_in = 0
    for k in range(m):
        j = cone[k]
        front, u, v = _project_rotated(camera_params, R_prior, unit_I[j, 0], unit_I[j, 1], unit_I[j, 2])
        if front and half + 1 <= u <= width - half - 1 and half + 1 <= v <= height - half - 1:
            pred[n_in, 0] = u
            pred[n_in, 1] = v
            inside[n_in] = k
            n_in += 1
    mags = np.empty(n_in)
    for t in range(n_in):
        mags[t] = magnitude[cone[inside[t]]]
    order = np.argsort(mags, kind="mergesort")
    count = 0
    for t in range(min(max_stars, n_in)):
        s = order[t]
        r = render_of[cone[inside[s]]]
        front, u, v = _project_rotated(
            camera_params, R_true, render_unit_I[r, 0], render_unit_I[r, 1], render_unit_I[r, 2]
        )
        if front and abs(u - pred[s, 0]) <= half - 1 and abs(v - pred[s, 1]) <= half - 1:
            out_index[count] = r
            out_uv[count, 0] = u
            out_uv[count, 1] = v
            count += 1
    return count


__all__ = [
    "tracked_windows_kernel",
    "POISSON_INVERSION_LIMIT",
    "expected_windows_kernel",
    "adc_code",
    "digitize_kernel",
    "poisson_by_inversion",
    "poisson_counts_kernel",
    "expose_kernel",
    "centroid_kernel",
]
