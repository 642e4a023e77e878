"""A star tracker's image and centroids: photometry, windowed rendering with smear and detector
noise, windowed centre-of-mass centroids with their predicted covariance (plain numpy/scipy).

One frame, as a sensor system calls it::

    stars at the exposure's mid time: pixel positions uv (n, 2), pixel velocities (n, 2),
    electron rates (n,)  +  PinholeCamera  +  DetectorModel  +  a numpy Generator
        -> render_windows -> StarWindows (n, w_v, w_u ADU)  -> centroid_windows -> StarCentroids

(:func:`simulate_frame` is the two in one call.) Pixel convention: :mod:`drake_att.star_camera`
(``u`` columns along ``+x_S``, ``v`` rows along ``+y_S``, pixel ``(i, j)`` covers
``[i, i + 1) x [j, j + 1)``); window arrays are indexed ``[star, row (v), column (u)]``.

**Photometry.** The catalogue's Hipparcos magnitude ``Hp`` is converted to Johnson ``V`` with
the Hipparcos Input Catalogue's approximate relation (ESA 1992, *The Hipparcos Input
Catalogue*, ESA SP-1136, introduction, the ``Hp`` field; quoted again in ESA SP-1200 vol. 1
sec. 1.3), valid for O–F stars and G–K giants with ``-0.2 < B−V < 1.8``::

    Hp - V = 0.304 (B−V) - 0.202 (B−V)^2 + 0.107 (B−V)^3 - 0.045 (B−V)^4

(``B−V`` is clamped to that interval; the relation is good to a few hundredths of a magnitude
inside it and not meant for M-type stars.) The detector's band is then modelled as ``V`` with a
flat effective bandwidth: a star of magnitude ``V`` delivers
``Phi_0 10^(-0.4 V) A eta`` electrons per second, ``A = pi D^2 / 4`` the aperture, ``eta`` the
optical efficiency (optics throughput times quantum efficiency) and ``Phi_0`` the photon flux of
a ``V = 0`` star in the band (:data:`V0_PHOTON_FLUX_DENSITY_PER_M2_S_NM` times
:data:`DEFAULT_EFFECTIVE_BANDWIDTH_NM`; a :class:`DetectorModel` parameter). The flux density is
Bessell's ``V = 0`` zero point (Bessell 1979, PASP 91, 589: 3640 Jy at 550 nm, i.e.
``F_nu / (h lambda)`` = 1.0e8 photons s^-1 m^-2 nm^-1, the familiar "1000 photons s^-1 cm^-2
A^-1"); the 300-nm effective bandwidth (a silicon detector behind visible optics, ~400–750 nm
weighted by its response) is this module's approximation: the absolute scale is good to a factor
~1.5 (±0.4 mag), and a silicon detector's own colour term (red stars brighter than ``V``) is
not modelled. Such an error moves the magnitude limit, not the noise statistics.

**Rendering** (:func:`render_windows`), only in a window around each star, ``2 h_u + 1``
columns by ``2 h_v + 1`` rows, ``h`` = ``window_half_size_px`` plus half the frame's longest
smear track along that axis (one size per frame, so the stars stack into one array):

* the PSF is a Gaussian of ``psf_sigma_px`` integrated exactly over each pixel (separable erf
  differences);
* smear: the star moves from ``uv - rate T / 2`` to ``uv + rate T / 2`` during the exposure
  ``T`` (a track of length ``L``); the image is the mean of ``K`` pixel-integrated PSFs at
  evenly spaced points along the track, at most ``SMEAR_STEP_SIGMA`` = 0.5 PSF sigma apart
  (a sum of Gaussians that close is smooth to ~1e-30), centred on the mid-exposure position and
  spread so that their variance is the track's, ``L^2 / 12`` (the midpoints of ``K`` equal
  sub-intervals would give ``L^2 / 12 (1 - 1/K^2)``): the image's first and second moments
  are the moving star's exactly;
* each pixel collects ``Poisson(star + (background + dark + hot) T)`` electrons, clipped at the
  full well, plus Gaussian read noise, then the ADC: ``round(e / gain) + black level``, clipped
  to ``[0, 2^bits - 1]``;
* hot pixels are a fixed map per sensor (:func:`draw_hot_pixels`, from a seed): a fraction of the
  pixels with extra dark current, exponentially distributed.

**Centroids** (:func:`centroid_windows`): the window's electrons ``(ADU - black) gain`` minus the
expected background (the tracker's calibrated dark and background level, its hot pixels
included), the centre of mass ``u_hat = sum u_i s_i / S`` over the whole window, and its
covariance by first-order error propagation of the pixels' variances
``var_i = bg_i + read^2 + gain^2 / 12 + s_i`` (``s_i`` the measured star electrons of the pixel
where significant, > 2 sigma; else 0)::

    C_uv = sum (u_i - u_hat)(v_i - v_hat) var_i / S^2

A window is a detection when its brightest pixel's star signal reaches ``detection_threshold_sigma``
times that pixel's background noise ``sqrt(bg_i + read^2 + gain^2 / 12)`` (a threshold detector:
a smeared star's peak, and so its detection, falls as its track lengthens); ``snr`` is the window's
``S / sqrt(sum var_i)``;
windows that leave the detector are not centroided (``edge``), windows with a full-well or
ADC-clipped pixel are flagged ``saturated`` (their covariance is then optimistic). Each window
holds its own star only (a neighbour's light inside it is not rendered).

The pixel loops (expected windows, exposure, centroids) are compiled
(:mod:`drake_att.star_image_kernels`); the noise is drawn here from the frame's generator: one
uniform per pixel for the Poisson inversion (means below 30), numpy's Poisson sampler for the
brighter pixels, numpy's normals for the read noise. Speed (render + centroid,
``benchmarks/bench_star_image.py``): ~0.08–0.15 ms per frame of 5–20 still stars,
~0.12–0.4 ms at 1 deg/s (5-px smear), mostly the PSF's ``erf`` values and the Poisson draws.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from drake_att import star_image_kernels as kernels
from drake_att.star_camera import PinholeCamera
from drake_att.validation import check_finite, check_int, check_seed, fail

#: Photon flux density of a ``V = 0`` star at 550 nm (photons s^-1 m^-2 nm^-1): Bessell (1979)
#: 3640 Jy divided by ``h lambda``.
V0_PHOTON_FLUX_DENSITY_PER_M2_S_NM = 3640e-26 / (6.62607015e-34 * 550e-9) * 1e-9
#: The detector band's effective width (nm) behind :data:`DEFAULT_ZERO_POINT_PHOTONS_PER_M2_S`.
DEFAULT_EFFECTIVE_BANDWIDTH_NM = 300.0
#: Photons per second per m^2 from a ``V = 0`` star in the detector band (~3.0e10).
DEFAULT_ZERO_POINT_PHOTONS_PER_M2_S = V0_PHOTON_FLUX_DENSITY_PER_M2_S_NM * DEFAULT_EFFECTIVE_BANDWIDTH_NM
#: The ``B−V`` interval of the ``Hp -> V`` relation (mag); colours outside are clamped to it.
HP_V_COLOUR_RANGE = (-0.2, 1.8)
#: Smear sub-step spacing, in PSF sigmas.
SMEAR_STEP_SIGMA = 0.5
#: A pixel's star signal enters its predicted variance when it exceeds this many noise sigmas.
SIGNIFICANT_PIXEL_SIGMA = 2.0

_NONE = np.zeros(0)


def v_magnitude_from_hipparcos(hp_mag, b_minus_v) -> np.ndarray:
    """Johnson ``V`` (mag) from the Hipparcos magnitude ``Hp`` and ``B−V`` (mag) by the
    Input Catalogue's relation (module docstring); ``B−V`` is clamped to
    :data:`HP_V_COLOUR_RANGE`, a missing (NaN) colour counts as 0 (``V = Hp``)."""
    hp = np.asarray(hp_mag, dtype=float)
    b = np.nan_to_num(np.asarray(b_minus_v, dtype=float), nan=0.0)
    b = np.clip(b, *HP_V_COLOUR_RANGE)
    return hp - (0.304 * b - 0.202 * b**2 + 0.107 * b**3 - 0.045 * b**4)


@dataclass(frozen=True)
class DetectorModel:
    """A star tracker's optics and detector (SI inside; per-pixel quantities in electrons).

    Defaults: a CubeSat star tracker with a 16-mm f/1.2 lens (13.3-mm aperture) on a 5.5-µm
    global-shutter CMOS sensor of the CMOSIS/ams CMV4000 class (datasheet-order values: full well
    ~13.5 ke-, read noise ~13 e-, 12-bit ADC; dark current ~125 e-/s at 25 °C, here 50 e-/s for
    a sensor near 15 °C, the usual halving every ~7 °C), a 0.1-s exposure (a 10-Hz tracker), a
    slightly defocused PSF (sigma 0.8 px, the usual 3x3–5x5-pixel star image). With the
    default photometry a ``V = 6.5`` star then gives ~520 e- and a 7x7-window SNR of ~5.5: the
    magnitude limit of a 20-deg tracker.
    The background default is a dark sky of ~22 V mag per arcsec^2 (zodiacal light away from
    the ecliptic) seen by 70-arcsec pixels with this photometry (~16 e-/px/s,
    :meth:`background_rate_from_surface_brightness`); stray light near
    the Sun, Earth or Moon raises it. Hot pixels: an illustrative 1e-4 of the pixels with a mean
    of 5000 e-/s extra dark current (radiation damage grows both).

    Attributes:
        aperture_diameter_m: entrance pupil diameter (m).
        exposure_s: integration time (s).
        optical_efficiency: optics throughput times quantum efficiency, in (0, 1].
        read_noise_e: read noise (e- rms per pixel).
        dark_current_e_per_s: dark current (e-/s per pixel).
        full_well_e: full-well capacity (e-).
        gain_e_per_adu: conversion gain (e- per ADU).
        adc_bits: ADC resolution (bits).
        black_level_adu: the ADC's offset (ADU), so that read noise below zero is not clipped.
        psf_sigma_px: the Gaussian PSF's sigma (pixels).
        background_e_per_px_per_s: sky and stray-light background (e-/s per pixel).
        hot_pixel_fraction: fraction of the pixels that are hot.
        hot_pixel_dark_e_per_s: a hot pixel's mean extra dark current (e-/s; exponential).
        window_half_size_px: the centroid window's half size (pixels; the window is
            ``2 h + 1`` wide, grown by the smear).
        detection_threshold_sigma: a window is a detection when its brightest pixel's star signal
            reaches this many background sigmas (module docstring).
        zero_point_photons_per_m2_s: photons per s per m^2 from a ``V = 0`` star in the band.
    """

    aperture_diameter_m: float = 0.0133
    exposure_s: float = 0.1
    optical_efficiency: float = 0.5
    read_noise_e: float = 13.0
    dark_current_e_per_s: float = 50.0
    full_well_e: float = 13500.0
    gain_e_per_adu: float = 3.3
    adc_bits: int = 12
    black_level_adu: float = 64.0
    psf_sigma_px: float = 0.8
    background_e_per_px_per_s: float = 16.0
    hot_pixel_fraction: float = 1e-4
    hot_pixel_dark_e_per_s: float = 5000.0
    window_half_size_px: int = 3
    detection_threshold_sigma: float = 5.0
    zero_point_photons_per_m2_s: float = DEFAULT_ZERO_POINT_PHOTONS_PER_M2_S

    #: field -> (lo, hi, unit, lo inclusive, what it is): the physically plausible values
    #: ``make`` accepts (the sky tracker's config reference prints the same table).
    RANGES = {
        "aperture_diameter_m": (1e-3, 0.5, "m", True, "an entrance pupil"),
        "exposure_s": (1e-5, 10.0, "s", True, "an exposure (also checked: <= the frame period)"),
        "optical_efficiency": (0.0, 1.0, "", False, "throughput x quantum efficiency, > 0"),
        "read_noise_e": (0.0, 1000.0, "e-", True, "read noise per pixel"),
        "dark_current_e_per_s": (0.0, 1e6, "e-/s", True, "dark current per pixel"),
        "full_well_e": (100.0, 1e7, "e-", True, "a pixel's capacity"),
        "gain_e_per_adu": (1e-3, 1e4, "e-/ADU", True, "conversion gain"),
        "black_level_adu": (0.0, 1e6, "ADU", True, "the ADC's offset"),
        "psf_sigma_px": (
            0.3,
            10.0,
            "px",
            True,
            "the defocused PSF's sigma (below 0.3 px the centre of mass locks to pixels)",
        ),
        "background_e_per_px_per_s": (0.0, 1e7, "e-/s", True, "sky and stray-light background per pixel"),
        "hot_pixel_fraction": (0.0, 0.1, "", True, "fraction of hot pixels"),
        "hot_pixel_dark_e_per_s": (0.0, 1e7, "e-/s", True, "a hot pixel's mean extra dark current"),
        "detection_threshold_sigma": (0.0, 100.0, "sigma", False, "a detection's signal-to-noise ratio, > 0"),
        "zero_point_photons_per_m2_s": (1e9, 1e12, "photons/s/m^2", True, "a V = 0 star's flux in the band"),
    }
    #: integer field -> (lo, hi, unit, what it is).
    INT_RANGES = {
        "adc_bits": (8, 24, "bits", "ADC resolution"),
        "window_half_size_px": (1, 32, "px", "the centroid window's half size"),
    }

    @classmethod
    def make(cls, name: str = "st1", **fields) -> DetectorModel:
        """A checked detector: every field in :attr:`RANGES` / :attr:`INT_RANGES` (ValueError
        naming ``<name>.<field>``), unknown fields refused, the black level inside the ADC's
        range."""
        defaults = cls()
        values: dict = {}
        for key, value in fields.items():
            if key not in cls.RANGES and key not in cls.INT_RANGES:
                fail(f"{name}.{key}", value, f"is not a detector field (fields: {', '.join(cls.__annotations__)})")
        for key, (lo, hi, unit, lo_closed, what) in cls.RANGES.items():
            v = check_finite(f"{name}.{key}", fields.get(key, getattr(defaults, key)))
            if not ((v >= lo if lo_closed else v > lo) and v <= hi):
                interval = f"{'[' if lo_closed else '('}{lo:g}, {hi:g}] {unit}".rstrip()
                fail(f"{name}.{key}", v, f"must be in {interval}: {what}")
            values[key] = v
        for key, (lo, hi, _, _) in cls.INT_RANGES.items():
            v = fields.get(key, getattr(defaults, key))
            n = check_int(f"{name}.{key}", v, lo)
            if n > hi:
                fail(f"{name}.{key}", v, f"must be an integer in [{lo}, {hi}]")
            values[key] = n
        if values["black_level_adu"] >= 2 ** values["adc_bits"] - 1:
            fail(
                f"{name}.black_level_adu",
                values["black_level_adu"],
                f"must be below the ADC's maximum code {2 ** values['adc_bits'] - 1}",
            )
        return cls(**values)

    @property
    def aperture_area_m2(self) -> float:
        return math.pi * 0.25 * self.aperture_diameter_m**2

    @property
    def max_code_adu(self) -> int:
        return 2**self.adc_bits - 1

    @property
    def dark_and_background_e_per_px(self) -> float:
        """Expected background + dark electrons per ordinary pixel per exposure."""
        return (self.background_e_per_px_per_s + self.dark_current_e_per_s) * self.exposure_s

    def electron_rate(self, v_mag) -> np.ndarray:
        """Star electrons per second (e-/s) for magnitudes ``V`` in the detector band."""
        v = np.asarray(v_mag, dtype=float)
        return self.zero_point_photons_per_m2_s * self.aperture_area_m2 * self.optical_efficiency * 10.0 ** (-0.4 * v)

    def electron_rate_from_hipparcos(self, hp_mag, b_minus_v) -> np.ndarray:
        """Star electrons per second (e-/s) from the catalogue's ``Hp`` and ``B−V``."""
        return self.electron_rate(v_magnitude_from_hipparcos(hp_mag, b_minus_v))

    def background_rate_from_surface_brightness(self, camera: PinholeCamera, mag_per_arcsec2: float) -> float:
        """Background e-/s per pixel from a sky surface brightness (``V`` mag per arcsec^2) seen by
        the camera's central pixel."""
        pixel_arcsec = math.degrees(camera.pixel_pitch_m / camera.focal_length_m) * 3600.0
        return float(self.electron_rate(mag_per_arcsec2 - 2.5 * math.log10(pixel_arcsec**2)))


@dataclass(frozen=True)
class HotPixelMap:
    """A sensor's hot pixels: sorted linear indices ``row * width + column`` and their extra
    dark current (e-/s)."""

    linear_index: np.ndarray
    rate_e_per_s: np.ndarray
    width_px: int
    height_px: int

    @property
    def columns_rows(self) -> np.ndarray:
        """(k, 2) ``(column, row)`` of each hot pixel."""
        return np.column_stack([self.linear_index % self.width_px, self.linear_index // self.width_px])


def no_hot_pixels(camera: PinholeCamera) -> HotPixelMap:
    return HotPixelMap(np.zeros(0, dtype=np.int64), np.zeros(0), camera.width_px, camera.height_px)


def draw_hot_pixels(detector: DetectorModel, camera: PinholeCamera, seed: int) -> HotPixelMap:
    """A sensor's fixed hot-pixel map drawn once from ``seed``: a binomial number of pixels
    (``hot_pixel_fraction`` each) at distinct uniform positions, exponential rates of mean
    ``hot_pixel_dark_e_per_s``. The same seed gives the same map."""
    rng = np.random.default_rng(check_seed("hot_pixel_seed", seed))
    n_pixels = camera.width_px * camera.height_px
    k = int(rng.binomial(n_pixels, detector.hot_pixel_fraction))
    index = np.sort(rng.choice(n_pixels, size=k, replace=False)).astype(np.int64)
    rates = rng.exponential(detector.hot_pixel_dark_e_per_s, size=k)
    return HotPixelMap(index, rates, camera.width_px, camera.height_px)


def pixel_velocity(camera: PinholeCamera, directions_S, w_IS_S) -> np.ndarray:
    """(n, 2) pixel velocities (px/s) of inertially fixed directions ``d_S`` (n, 3) seen by a
    sensor turning at ``w_IS_S`` (rad/s, in S): ``d_S' = d_S x w = (-w) x d_S``, so
    ``uv' = J(d) (-w)`` with ``J`` = :meth:`PinholeCamera.projection_jacobian`."""
    J = camera.projection_jacobian(directions_S)
    return J @ (-np.asarray(w_IS_S, dtype=float))


@dataclass(frozen=True)
class StarWindows:
    """One frame's windows (``n`` stars, ``w_v x w_u`` pixels each, ``[star, row, column]``).

    Attributes:
        origin_px: (n, 2) int ``(column, row)`` of each window's first pixel.
        adu: (n, w_v, w_u) the digitized pixels (ADU; 0 off the detector).
        star_e: (n, w_v, w_u) the noise-free star electrons (the rendering's expectation).
        background_e: (n, w_v, w_u) expected background + dark (+ hot) electrons (0 off the detector).
        on_detector: (n, w_v, w_u) bool, the pixel lies on the detector.
        saturated: (n,) bool, a pixel reached the full well or the ADC's maximum code.
        uv_px: (n, 2) the stars' true mid-exposure positions (px), for reference.
    """

    origin_px: np.ndarray
    adu: np.ndarray
    star_e: np.ndarray
    background_e: np.ndarray
    on_detector: np.ndarray
    saturated: np.ndarray
    uv_px: np.ndarray

    @property
    def edge(self) -> np.ndarray:
        """(n,) bool: the window leaves the detector."""
        return ~np.all(self.on_detector, axis=(1, 2))

    def electrons(self, detector: DetectorModel) -> np.ndarray:
        """(n, w_v, w_u) the pixels back in electrons: ``(ADU - black) gain``."""
        return (self.adu - detector.black_level_adu) * detector.gain_e_per_adu


@dataclass(frozen=True)
class StarCentroids:
    """One frame's detected stars.

    Attributes:
        uv_px: (m, 2) centroids (px). covariance_px2: (m, 2, 2) their predicted covariance (px^2).
        star_index: (m,) the input star each belongs to (the truth, for tests and scoring).
        signal_e: (m,) background-subtracted window electrons. snr: (m,) signal / its noise.
        saturated: (m,) bool, the window holds a clipped pixel (covariance optimistic).
        detected: (n,) bool per input star; edge: (n,) bool per input star (window leaves the
        detector: not centroided).
    """

    uv_px: np.ndarray
    covariance_px2: np.ndarray
    star_index: np.ndarray
    signal_e: np.ndarray
    snr: np.ndarray
    saturated: np.ndarray
    detected: np.ndarray
    edge: np.ndarray

    def __len__(self) -> int:
        return len(self.star_index)


def _window_half_sizes(detector: DetectorModel, track_px: np.ndarray) -> tuple[int, int]:
    """Half sizes ``(h_u, h_v)`` of a frame's windows: ``window_half_size_px`` plus half the
    longest track along each axis."""
    if len(track_px) == 0:
        return detector.window_half_size_px, detector.window_half_size_px
    extra = np.ceil(0.5 * np.max(np.abs(track_px), axis=0)).astype(int)
    return detector.window_half_size_px + int(extra[0]), detector.window_half_size_px + int(extra[1])


def expected_windows(
    camera: PinholeCamera,
    detector: DetectorModel,
    uv_px,
    uv_rate_px_per_s,
    electron_rate_e_per_s,
    hot_pixels: HotPixelMap | None = None,
):
    """The noise-free windows: ``(origin_px (n, 2), star_e (n, w_v, w_u), background_e (n, w_v, w_u),
    on_detector (n, w_v, w_u))`` (see :class:`StarWindows`)."""
    uv = np.ascontiguousarray(uv_px, dtype=float).reshape(-1, 2)
    rate = np.ascontiguousarray(uv_rate_px_per_s, dtype=float).reshape(-1, 2)
    flux = np.ascontiguousarray(electron_rate_e_per_s, dtype=float).reshape(-1)
    n = len(uv)
    if rate.shape != (n, 2) or flux.shape != (n,):
        fail(
            "uv_rate_px_per_s, electron_rate_e_per_s", (rate.shape, flux.shape), f"must have shapes ({n}, 2) and ({n},)"
        )
    T = detector.exposure_s
    sigma = detector.psf_sigma_px
    track = rate * T
    h_u, h_v = _window_half_sizes(detector, track)
    w_u, w_v = 2 * h_u + 1, 2 * h_v + 1
    origin = np.floor(uv).astype(np.int64) - np.array([h_u, h_v])
    length = np.hypot(track[:, 0], track[:, 1]) if n else np.zeros(0)
    k_steps = max(1, int(math.ceil(float(np.max(length, initial=0.0)) / (SMEAR_STEP_SIGMA * sigma))))
    hot = no_hot_pixels(camera) if hot_pixels is None else hot_pixels
    star_e = np.empty((n, w_v, w_u))
    background = np.empty((n, w_v, w_u))
    on = np.empty((n, w_v, w_u), dtype=bool)
    kernels.expected_windows_kernel(
        uv,
        track,
        flux * T,
        origin,
        k_steps,
        sigma,
        camera.width_px,
        camera.height_px,
        detector.dark_and_background_e_per_px,
        hot.linear_index,
        hot.rate_e_per_s * T,
        star_e,
        background,
        on,
    )
    return origin, star_e, background, on


def digitize(electrons, detector: DetectorModel) -> np.ndarray:
    """ADU of collected electrons (read noise included): ``round(e / gain) + black``, clipped
    to ``[0, 2^bits - 1]`` (int32)."""
    e = np.asarray(electrons, dtype=float)
    adu = np.empty(e.shape, dtype=np.int32)
    kernels.digitize_kernel(
        e.reshape(-1), detector.gain_e_per_adu, detector.black_level_adu, detector.max_code_adu, adu.reshape(-1)
    )
    return adu


def poisson_counts(mean_e, rng: np.random.Generator) -> np.ndarray:
    """Poisson counts (int64, the shape of ``mean_e``) of the means ``mean_e`` (>= 0): by
    inversion of one uniform each below ``POISSON_INVERSION_LIMIT`` (30: the background pixels,
    at a fraction of numpy's per-value cost), by numpy's sampler above. Both from ``rng``: one
    uniform per value, then the large means' draws."""
    mean = np.ascontiguousarray(mean_e, dtype=float)
    flat = mean.reshape(-1)
    u = rng.random(flat.size)
    big = np.flatnonzero(flat >= kernels.POISSON_INVERSION_LIMIT)
    big_counts = rng.poisson(flat[big])
    counts = np.empty(mean.shape, dtype=np.int64)
    kernels.poisson_counts_kernel(flat, u, big, big_counts, counts.reshape(-1))
    return counts


def _expose(mean_e: np.ndarray, on: np.ndarray, detector: DetectorModel, rng: np.random.Generator):
    """Shot noise, full well, read noise, ADC of the pixels ``on`` the detector (0 elsewhere):
    (ADU, clipped-pixel mask). The noise is drawn here, from ``rng``, for every pixel."""
    counts = poisson_counts(mean_e, rng)
    normals = rng.normal(0.0, detector.read_noise_e, size=mean_e.shape) if detector.read_noise_e > 0.0 else _NONE
    adu = np.empty(mean_e.shape, dtype=np.int32)
    clipped = np.empty(mean_e.shape, dtype=bool)
    kernels.expose_kernel(
        counts.reshape(-1),
        normals.reshape(-1),
        on.reshape(-1),
        detector.full_well_e,
        detector.gain_e_per_adu,
        detector.black_level_adu,
        detector.max_code_adu,
        adu.reshape(-1),
        clipped.reshape(-1),
    )
    return adu, clipped


def render_windows(
    camera: PinholeCamera,
    detector: DetectorModel,
    uv_px,
    uv_rate_px_per_s,
    electron_rate_e_per_s,
    rng: np.random.Generator,
    hot_pixels: HotPixelMap | None = None,
) -> StarWindows:
    """One exposure of ``n`` stars, each in its own window (module docstring).

    Args:
        uv_px: (n, 2) true pixel positions at the exposure's mid time (px).
        uv_rate_px_per_s: (n, 2) their pixel velocities (px/s; :func:`pixel_velocity`).
        electron_rate_e_per_s: (n,) star electron rates (e-/s; :meth:`DetectorModel.electron_rate`).
        rng: this frame's noise. hot_pixels: the sensor's map (:func:`draw_hot_pixels`) or None.
    """
    origin, star_e, background, on = expected_windows(
        camera, detector, uv_px, uv_rate_px_per_s, electron_rate_e_per_s, hot_pixels
    )
    adu, clipped = _expose(star_e + background, on, detector, rng)
    saturated = np.any(clipped, axis=(1, 2))
    return StarWindows(origin, adu, star_e, background, on, saturated, np.asarray(uv_px, dtype=float).reshape(-1, 2))


def centroid_windows(windows: StarWindows, detector: DetectorModel) -> StarCentroids:
    """Centre-of-mass centroids, their predicted covariances and the detections of a frame's
    windows (module docstring)."""
    n = len(windows.adu)
    uv = np.zeros((n, 2))
    cov = np.zeros((n, 2, 2))
    signal, snr = np.empty(n), np.empty(n)
    detected, edge = np.empty(n, dtype=bool), np.empty(n, dtype=bool)
    kernels.centroid_kernel(
        np.ascontiguousarray(windows.adu),
        np.ascontiguousarray(windows.background_e, dtype=float),
        np.ascontiguousarray(windows.on_detector),
        np.ascontiguousarray(windows.origin_px, dtype=np.int64),
        detector.black_level_adu,
        detector.gain_e_per_adu,
        detector.read_noise_e,
        detector.detection_threshold_sigma,
        SIGNIFICANT_PIXEL_SIGMA,
        uv,
        cov,
        signal,
        snr,
        detected,
        edge,
    )
    idx = np.flatnonzero(detected)
    return StarCentroids(
        uv_px=uv[idx],
        covariance_px2=cov[idx],
        star_index=idx,
        signal_e=signal[idx],
        snr=snr[idx],
        saturated=windows.saturated[idx],
        detected=detected,
        edge=edge,
    )


def simulate_frame(
    camera: PinholeCamera,
    detector: DetectorModel,
    uv_px,
    uv_rate_px_per_s,
    electron_rate_e_per_s,
    rng: np.random.Generator,
    hot_pixels: HotPixelMap | None = None,
) -> StarCentroids:
    """One frame: :func:`render_windows` then :func:`centroid_windows`."""
    windows = render_windows(camera, detector, uv_px, uv_rate_px_per_s, electron_rate_e_per_s, rng, hot_pixels)
    return centroid_windows(windows, detector)


def render_full_frame(
    camera: PinholeCamera,
    detector: DetectorModel,
    uv_px,
    uv_rate_px_per_s,
    electron_rate_e_per_s,
    rng: np.random.Generator,
    hot_pixels: HotPixelMap | None = None,
) -> np.ndarray:
    """The whole detector (height, width) in ADU with every star's (smeared) image, the
    background, dark current, hot pixels and the same noise and ADC as the windows (for
    figures; ~tens of ms for a 1024^2 detector)."""
    origin, star_e, _, on = expected_windows(camera, detector, uv_px, uv_rate_px_per_s, electron_rate_e_per_s)
    H, W = camera.height_px, camera.width_px
    mean = np.full((H, W), detector.dark_and_background_e_per_px)
    if hot_pixels is not None and len(hot_pixels.linear_index):
        mean.reshape(-1)[hot_pixels.linear_index] += hot_pixels.rate_e_per_s * detector.exposure_s
    w_v, w_u = star_e.shape[1:]
    for k in range(len(star_e)):
        c0, r0 = origin[k]
        rows = slice(max(r0, 0), min(r0 + w_v, H))
        cols = slice(max(c0, 0), min(c0 + w_u, W))
        mean[rows, cols] += star_e[k, rows.start - r0 : rows.stop - r0, cols.start - c0 : cols.stop - c0]
    adu, _ = _expose(mean, np.ones(mean.shape, dtype=bool), detector, rng)
    return adu


__all__ = [
    "DetectorModel",
    "HotPixelMap",
    "StarWindows",
    "StarCentroids",
    "v_magnitude_from_hipparcos",
    "draw_hot_pixels",
    "no_hot_pixels",
    "pixel_velocity",
    "expected_windows",
    "digitize",
    "poisson_counts",
    "render_windows",
    "centroid_windows",
    "simulate_frame",
    "render_full_frame",
    "V0_PHOTON_FLUX_DENSITY_PER_M2_S_NM",
    "DEFAULT_EFFECTIVE_BANDWIDTH_NM",
    "DEFAULT_ZERO_POINT_PHOTONS_PER_M2_S",
    "HP_V_COLOUR_RANGE",
    "SMEAR_STEP_SIGMA",
    "SIGNIFICANT_PIXEL_SIGMA",
]
