"""The star tracker's image and centroids (drake_att.star_image) against definitions computed
here: the cited zero point by hand, Poisson + read-noise statistics of a window, the centre of
mass's bias and the consistency of its predicted covariance (NEES), smear's moments, the pixel
velocity against finite differences of the camera's projection, saturation, the hot-pixel map,
the ADC's step, and one-line refusals."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats
from scipy.spatial.transform import Rotation

from drake_att.star_camera import PinholeCamera
from drake_att.star_image import (
    DetectorModel,
    centroid_windows,
    digitize,
    draw_hot_pixels,
    expected_windows,
    pixel_velocity,
    render_full_frame,
    render_windows,
    simulate_frame,
    v_magnitude_from_hipparcos,
)

CAMERA = PinholeCamera.make(0.016, 5.5e-6, 1024, 1024)
DETECTOR = DetectorModel.make()


def _still(n):
    return np.zeros((n, 2))


def _pixel_fraction(lo: float, hi: float, centre: float, sigma: float) -> float:
    """Fraction of a 1-D Gaussian inside [lo, hi) (the definition, with math.erf)."""
    s = math.sqrt(2.0) * sigma
    return 0.5 * (math.erf((hi - centre) / s) - math.erf((lo - centre) / s))


# --- photometry ---------------------------------------------------------------------------


def test_a_stars_electron_rate_is_the_cited_zero_point_worked_by_hand():
    # Bessell (1979): V = 0 is 3640 Jy at 550 nm; photons per unit wavelength = F_nu / (h lambda).
    photons_per_m2_s_nm = 3640e-26 / (6.62607015e-34 * 550e-9) * 1e-9
    assert photons_per_m2_s_nm == pytest.approx(1.0e8, rel=0.01)  # the textbook 1000 /s/cm^2/A
    hp, bv = 4.2, 0.65
    v = hp - (0.304 * bv - 0.202 * bv**2 + 0.107 * bv**3 - 0.045 * bv**4)  # Hipparcos Input Catalogue
    area = math.pi * (0.0133 / 2.0) ** 2
    expected = photons_per_m2_s_nm * 300.0 * area * 0.5 * 10.0 ** (-0.4 * v)
    assert DETECTOR.electron_rate_from_hipparcos(hp, bv) == pytest.approx(expected, rel=1e-12)
    # five magnitudes are a factor 100; an A0 star (B-V = 0) has V = Hp
    assert DETECTOR.electron_rate(1.0) / DETECTOR.electron_rate(6.0) == pytest.approx(100.0, rel=1e-12)
    assert v_magnitude_from_hipparcos(5.0, 0.0) == 5.0
    # colours outside the relation's range are clamped; a missing colour is V = Hp
    assert v_magnitude_from_hipparcos(5.0, 3.0) == v_magnitude_from_hipparcos(5.0, 1.8)
    assert v_magnitude_from_hipparcos(5.0, float("nan")) == 5.0


def test_the_dark_sky_background_follows_the_same_zero_point():
    # 22 mag/arcsec^2 over a pixel of (5.5 um / 16 mm) rad: by hand
    pixel_arcsec = 5.5e-6 / 0.016 * 180.0 / math.pi * 3600.0
    v_pixel = 22.0 - 2.5 * math.log10(pixel_arcsec**2)
    rate = DETECTOR.background_rate_from_surface_brightness(CAMERA, 22.0)
    assert rate == pytest.approx(float(DETECTOR.electron_rate(v_pixel)), rel=1e-12)
    assert 5.0 < rate < 50.0  # the default background_e_per_px_per_s (16) is this order


# --- photon statistics ------------------------------------------------------------------------


def test_a_windows_summed_electrons_have_poisson_plus_read_noise_statistics():
    """Over 4000 independent exposures of one star: the window's summed electrons have mean
    star-in-window + (background + dark) npix T and variance mean + npix (read^2 + gain^2/12)
    (the ADC's uniform rounding, dithered by the read noise). z-test |z| < 4, chi-square test of
    the variance at two-sided 1e-4."""
    rng = np.random.default_rng(11)
    n = 4000
    uv = np.array([400.37, 611.81])
    rate = float(DETECTOR.electron_rate(3.0))  # ~13 ke-: shot noise over half the variance
    windows = render_windows(CAMERA, DETECTOR, np.tile(uv, (n, 1)), _still(n), np.full(n, rate), rng)
    assert not windows.saturated.any()
    total = windows.electrons(DETECTOR).sum(axis=(1, 2))
    w = windows.adu.shape[-1]
    c0, r0 = windows.origin_px[0]
    T, sigma = DETECTOR.exposure_s, DETECTOR.psf_sigma_px
    inside = _pixel_fraction(c0, c0 + w, uv[0], sigma) * _pixel_fraction(r0, r0 + w, uv[1], sigma)
    npix = w * w
    mean = rate * T * inside + (DETECTOR.background_e_per_px_per_s + DETECTOR.dark_current_e_per_s) * T * npix
    var = mean + npix * (DETECTOR.read_noise_e**2 + DETECTOR.gain_e_per_adu**2 / 12.0)
    z = (total.mean() - mean) / math.sqrt(var / n)
    assert abs(z) < 4.0, (total.mean(), mean)
    chi2 = (n - 1) * total.var(ddof=1) / var
    lo, hi = stats.chi2.ppf([1e-4, 1 - 1e-4], n - 1)
    assert lo < chi2 < hi, (total.var(ddof=1), var)


# --- centroids ----------------------------------------------------------------------------


def test_an_unsmeared_centroid_is_unbiased_and_its_predicted_covariance_is_consistent():
    """A star at a random sub-pixel position, 4000 noise draws: the mean error is under 0.1 of
    the empirical sigma (its standard error is 0.016 sigma), the empirical covariance matches the
    mean predicted one within 10 %, and the mean NEES of the 2-D error is inside the two-sided
    99.8 % band of chi-square(2 n) / n."""
    rng = np.random.default_rng(3)
    uv = rng.uniform(100.0, 900.0, size=2)
    n = 4000
    rate = float(DETECTOR.electron_rate(4.5))
    c = simulate_frame(CAMERA, DETECTOR, np.tile(uv, (n, 1)), _still(n), np.full(n, rate), rng)
    assert len(c) == n and not np.any(c.saturated)
    err = c.uv_px - uv
    empirical = np.cov(err.T)
    predicted = c.covariance_px2.mean(axis=0)
    sd = np.sqrt(np.diag(empirical))
    assert np.all(np.abs(err.mean(axis=0)) < 0.1 * sd), (err.mean(axis=0), sd)
    assert np.allclose(np.diag(empirical), np.diag(predicted), rtol=0.10), (empirical, predicted)
    nees = np.einsum("ni,nij,nj->n", err, np.linalg.inv(c.covariance_px2), err)
    lo, hi = stats.chi2.ppf([0.001, 0.999], 2 * n) / n
    assert lo < nees.mean() < hi, (nees.mean(), lo, hi)


def test_smear_keeps_the_centroid_at_mid_exposure_and_adds_L2_over_12_along_the_track():
    det = DetectorModel.make(window_half_size_px=8)  # tails beyond 9 sigma: moments exact
    uv = np.array([[300.3, 420.6]])
    rate = np.array([[40.0, -25.0]])  # px/s: a (4, -2.5) px track in 0.1 s
    track = rate[0] * det.exposure_s
    L = float(np.hypot(*track))
    along = track / L
    across = np.array([-along[1], along[0]])

    def moments(rate_px):
        origin, star_e, _, _ = expected_windows(CAMERA, det, uv, rate_px, [1e5])
        w = star_e.shape[-1]
        u = origin[0, 0] + np.arange(w) + 0.5
        v = origin[0, 1] + np.arange(w) + 0.5
        U, V = np.meshgrid(u, v)  # [row, column]
        s = star_e[0] / star_e[0].sum()
        mean = np.array([(U * s).sum(), (V * s).sum()])
        d = np.stack([U - mean[0], V - mean[1]])
        second = np.einsum("iab,jab,ab->ij", d, d, s)
        return mean, second

    mean0, second0 = moments(_still(1))
    mean1, second1 = moments(rate)
    assert np.allclose(mean1, uv[0], atol=1e-4) and np.allclose(mean0, uv[0], atol=1e-4)
    grown_along = along @ (second1 - second0) @ along
    grown_across = across @ (second1 - second0) @ across
    assert grown_along == pytest.approx(L**2 / 12.0, rel=2e-4), (grown_along, L**2 / 12)
    assert abs(grown_across) < 1e-3

    # with noise: the mean centroid of 2000 smeared frames is the mid-exposure position
    rng = np.random.default_rng(8)
    n = 2000
    c = simulate_frame(
        CAMERA,
        DETECTOR,
        np.tile(uv, (n, 1)),
        np.tile(rate, (n, 1)),
        np.full(n, float(DETECTOR.electron_rate(4.0))),
        rng,
    )
    assert len(c) == n
    err = c.uv_px - uv[0]
    assert np.all(np.abs(err.mean(axis=0)) < 4.0 * err.std(axis=0) / math.sqrt(n))
    # and its predicted covariance is still the noise's (mean NEES within the 99.8 % band)
    nees = np.einsum("ni,nij,nj->n", err, np.linalg.inv(c.covariance_px2), err)
    lo, hi = stats.chi2.ppf([0.001, 0.999], 2 * n) / n
    assert lo < nees.mean() < hi, nees.mean()


def test_the_pixel_velocity_matches_finite_differences_of_a_turning_sensor():
    camera = PinholeCamera.make(0.016, 5.5e-6, 1024, 1024, k1=0.05)
    rng = np.random.default_rng(4)
    d0 = camera.unproject(rng.uniform(50.0, 970.0, size=(6, 2)))
    w = np.array([0.02, -0.03, 0.05])  # rad/s, w_IS_S
    h = 1e-4

    def d_at(t):  # an inertially fixed direction seen from S turning at w: d_S(t) = exp(-[w] t) d_S(0)
        return Rotation.from_rotvec(-w * t).apply(d0)

    fd = (camera.project(d_at(h))[0] - camera.project(d_at(-h))[0]) / (2.0 * h)
    assert np.allclose(pixel_velocity(camera, d0, w), fd, rtol=1e-6, atol=1e-5)
    # size and sign by hand: the boresight under a pitch rate w_y moves by -f_px w_y in u
    f_px = 0.016 / 5.5e-6
    uv_dot = pixel_velocity(CAMERA, [[0.0, 0.0, 1.0]], [0.0, 0.01, 0.0])[0]
    assert np.allclose(uv_dot, [-f_px * 0.01, 0.0], atol=1e-9)


# --- detector effects -----------------------------------------------------------------------


def test_a_bright_star_saturates_and_is_flagged_a_faint_one_is_not():
    rng = np.random.default_rng(5)
    windows = render_windows(
        CAMERA, DETECTOR, [[200.5, 300.5], [600.2, 600.7]], _still(2), DETECTOR.electron_rate([-1.0, 4.0]), rng
    )
    assert windows.saturated.tolist() == [True, False]
    assert windows.adu[0].max() == DETECTOR.max_code_adu  # 13.5 ke- / 3.3 + 64 exceeds 4095
    c = centroid_windows(windows, DETECTOR)
    assert c.saturated.tolist() == [True, False]
    # with a 16-bit ADC and no read noise, the full well itself clips: no pixel above it
    det = DetectorModel.make(adc_bits=16, read_noise_e=0.0)
    windows = render_windows(CAMERA, det, [[200.5, 300.5]], _still(1), det.electron_rate([-1.0]), rng)
    top = windows.electrons(det).max()
    assert windows.saturated[0] and top == pytest.approx(round(13500.0 / 3.3) * 3.3)


def test_the_hot_pixel_map_is_fixed_by_its_seed_and_shows_in_the_windows():
    a = draw_hot_pixels(DETECTOR, CAMERA, seed=42)
    b = draw_hot_pixels(DETECTOR, CAMERA, seed=42)
    c = draw_hot_pixels(DETECTOR, CAMERA, seed=43)
    assert np.array_equal(a.linear_index, b.linear_index) and np.array_equal(a.rate_e_per_s, b.rate_e_per_s)
    assert not np.array_equal(a.linear_index, c.linear_index)
    n_pix = 1024 * 1024
    k = len(a.linear_index)
    mean_k = 1e-4 * n_pix
    assert abs(k - mean_k) < 5.0 * math.sqrt(mean_k)
    assert len(np.unique(a.linear_index)) == k
    # a hot pixel inside a star's window: its mean electrons are background + its rate T
    col, row = a.columns_rows[np.argmax(a.rate_e_per_s)]
    rate = a.rate_e_per_s.max()
    rng = np.random.default_rng(6)
    n = 2000
    uv = np.tile([col + 2.3, row + 1.6], (n, 1))  # the hot pixel 2 columns / 1 row off the star's pixel
    windows = render_windows(CAMERA, DETECTOR, uv, _still(n), np.full(n, 1e-3), rng, a)
    i, j = col - windows.origin_px[0, 0], row - windows.origin_px[0, 1]
    at = windows.electrons(DETECTOR)[:, j, i]
    expected = DETECTOR.dark_and_background_e_per_px + rate * DETECTOR.exposure_s
    sd = math.sqrt(expected + DETECTOR.read_noise_e**2 + DETECTOR.gain_e_per_adu**2 / 12.0)
    assert abs(at.mean() - expected) < 4.0 * sd / math.sqrt(n)
    # the tracker's calibrated background knows it: a near-empty window is not a detection
    assert centroid_windows(windows, DETECTOR).detected.mean() < 0.01


def test_the_adc_rounds_to_the_gain_step_and_clips_to_its_range():
    g, black = DETECTOR.gain_e_per_adu, DETECTOR.black_level_adu
    k = np.arange(0, 200)
    for frac in (-0.49, 0.0, 0.49):
        assert np.array_equal(digitize((k + frac) * g, DETECTOR), k + int(black))
    assert digitize([-1e6], DETECTOR)[0] == 0
    assert digitize([1e9], DETECTOR)[0] == 4095
    # rendered windows come back in whole gain steps
    rng = np.random.default_rng(9)
    e = render_windows(CAMERA, DETECTOR, [[512.5, 512.5]], _still(1), [1e5], rng).electrons(DETECTOR)
    assert np.allclose(e / g, np.round(e / g), atol=1e-9)


def test_detection_follows_the_threshold_and_edge_windows_are_not_centroided():
    rng = np.random.default_rng(10)
    n = 500
    uv = np.tile([300.4, 700.8], (n, 1))
    faint = simulate_frame(CAMERA, DETECTOR, uv, _still(n), np.full(n, float(DETECTOR.electron_rate(9.0))), rng)
    bright = simulate_frame(CAMERA, DETECTOR, uv, _still(n), np.full(n, float(DETECTOR.electron_rate(4.0))), rng)
    assert faint.detected.mean() < 0.02 and bright.detected.all()
    # the threshold is on the brightest pixel: the star's mean peak pixel (pixel-integrated PSF,
    # written here with erf) against the background noise, at the threshold's edge
    sigma_bg = math.sqrt(DETECTOR.dark_and_background_e_per_px + 13.0**2 + 3.3**2 / 12)
    for v_mag, expected_rate in ((6.0, 0.95), (7.5, 0.05)):
        S_v = float(DETECTOR.electron_rate(v_mag)) * DETECTOR.exposure_s
        s = DETECTOR.psf_sigma_px * math.sqrt(2)
        peak = S_v * np.prod(
            [0.5 * (math.erf((k + 1 - x) / s) - math.erf((k - x) / s)) for k, x in ((300, 300.4), (700, 700.8))]
        )
        frames = simulate_frame(CAMERA, DETECTOR, uv, _still(n), np.full(n, S_v / DETECTOR.exposure_s), rng)
        if expected_rate > 0.5:
            assert peak / sigma_bg > 5 and frames.detected.mean() > expected_rate
        else:
            assert peak / sigma_bg < 5 and frames.detected.mean() < 0.5
    # SNR from its definition: the background-subtracted window sum over its predicted sigma is
    # near S / sqrt(S + npix (bg + read^2 + g^2/12)) for the expected S
    S = float(DETECTOR.electron_rate(4.0)) * DETECTOR.exposure_s
    npix = 49
    snr = S / math.sqrt(S + npix * (DETECTOR.dark_and_background_e_per_px + 13.0**2 + 3.3**2 / 12))
    assert np.median(bright.snr) == pytest.approx(snr, rel=0.05)
    edge = simulate_frame(
        CAMERA, DETECTOR, [[1.2, 500.0], [500.0, 500.0]], _still(2), DETECTOR.electron_rate([3.0, 3.0]), rng
    )
    assert edge.edge.tolist() == [True, False] and edge.star_index.tolist() == [1]


def test_the_full_frame_holds_the_stars_over_the_background():
    rng = np.random.default_rng(12)
    uv = np.array([[100.3, 200.7], [700.5, 800.2]])
    image = render_full_frame(CAMERA, DETECTOR, uv, [[0.0, 0.0], [30.0, 0.0]], DETECTOR.electron_rate([3.0, 3.0]), rng)
    assert image.shape == (1024, 1024)
    background = DETECTOR.black_level_adu + DETECTOR.dark_and_background_e_per_px / DETECTOR.gain_e_per_adu
    assert abs(np.median(image) - background) < 1.0
    for u, v in uv:
        patch = image[int(v) - 4 : int(v) + 5, int(u) - 4 : int(u) + 5]
        assert patch.max() > background + 20 * DETECTOR.read_noise_e / DETECTOR.gain_e_per_adu
    # the sensor's hot pixels glow where the map puts them, by their rate
    hot = draw_hot_pixels(DETECTOR, CAMERA, seed=3)
    image = render_full_frame(CAMERA, DETECTOR, uv, np.zeros((2, 2)), np.zeros(2), rng, hot)
    cols, rows = hot.columns_rows.T
    excess = (image[rows, cols] - background) * DETECTOR.gain_e_per_adu
    expected = hot.rate_e_per_s * DETECTOR.exposure_s
    noise = np.sqrt(expected + DETECTOR.dark_and_background_e_per_px + DETECTOR.read_noise_e**2 + 1.0)
    bright = expected < DETECTOR.full_well_e * 0.9
    assert np.all(np.abs(excess - expected)[bright] < 5.0 * noise[bright])


# --- refusals -----------------------------------------------------------------------------


@pytest.mark.parametrize(
    "field, value",
    [
        ("exposure_s", -0.1),
        ("optical_efficiency", 0.0),
        ("optical_efficiency", 1.5),
        ("read_noise_e", float("nan")),
        ("adc_bits", 12.5),
        ("adc_bits", 30),
        ("psf_sigma_px", 0.1),
        ("window_half_size_px", 0),
        ("hot_pixel_fraction", 0.5),
        ("black_level_adu", 5000.0),
        ("aperture_diameter_m", "13 mm"),
        ("exposure", 0.1),
    ],
)
def test_bad_detector_values_are_refused_in_one_line_naming_the_field(field, value):
    with pytest.raises(ValueError) as info:
        DetectorModel.make(name="st1", **{field: value})
    message = str(info.value)
    assert message.startswith(f"st1.{field}: got ") and "\n" not in message


# --- the compiled pixel loops against their definitions ----------------------------------------


def test_poisson_inversion_returns_the_first_count_whose_cdf_reaches_the_uniform():
    """The definition of inversion: k with CDF(k - 1) < u <= CDF(k), the CDF from scipy."""
    from drake_att.star_image_kernels import POISSON_INVERSION_LIMIT, poisson_by_inversion

    rng = np.random.default_rng(21)
    for mean in (0.0, 1e-6, 0.4, 6.6, 17.0, POISSON_INVERSION_LIMIT - 0.01):
        for u in rng.random(300):
            k = poisson_by_inversion(mean, u)
            assert stats.poisson.cdf(k, mean) >= u * (1 - 1e-12), (mean, u, k)
            if k > 0:
                assert stats.poisson.cdf(k - 1, mean) < u * (1 + 1e-12), (mean, u, k)


@pytest.mark.parametrize("mean", [0.05, 2.0, 6.6, 29.9, 30.0, 140.0])
def test_poisson_counts_follow_the_poisson_law(mean):
    """200,000 draws at one mean (either side of the inversion limit): chi-square goodness of fit
    against the pmf (bins of expected count >= 20, the tails pooled) at 1e-4, and the mean and
    variance z-tests at 4 sigma."""
    from drake_att.star_image import poisson_counts

    n = 200_000
    counts = poisson_counts(np.full((400, 500), mean), np.random.default_rng(int(mean * 100) + 7))
    assert counts.shape == (400, 500) and counts.dtype == np.int64
    x = counts.ravel()
    assert abs(x.mean() - mean) < 4.0 * math.sqrt(mean / n)
    var_sd = math.sqrt((mean + 2 * mean * mean) / n)  # the sample variance's sd (mu4 - sigma^4 = m + 2 m^2)
    assert abs(x.var() - mean) < 4.0 * var_sd
    k = np.arange(0, int(mean + 12 * math.sqrt(mean) + 12))
    expected = n * stats.poisson.pmf(k, mean)
    ok = np.flatnonzero(expected >= 20.0)
    lo, hi = ok.min(), ok.max()
    observed = np.bincount(x, minlength=len(k) + 1)
    obs = np.r_[observed[:lo].sum() + observed[lo], observed[lo + 1 : hi], observed[hi:].sum()]
    exp = np.r_[n * stats.poisson.cdf(lo, mean), expected[lo + 1 : hi], n * stats.poisson.sf(hi - 1, mean)]
    if len(obs) > 1:
        chi2 = float(np.sum((obs - exp) ** 2 / exp))
        assert chi2 < stats.chi2.isf(1e-4, len(obs) - 1), (chi2, len(obs))


def test_poisson_counts_are_the_generators():
    from drake_att.star_image import poisson_counts

    m = np.abs(np.random.default_rng(0).normal(10.0, 12.0, size=(7, 9)))
    a = poisson_counts(m, np.random.default_rng(5))
    assert np.array_equal(a, poisson_counts(m, np.random.default_rng(5)))
    assert not np.array_equal(a, poisson_counts(m, np.random.default_rng(6)))
    assert np.array_equal(poisson_counts(np.zeros((3, 4)), np.random.default_rng(1)), np.zeros((3, 4)))


def test_window_backgrounds_hold_the_hot_pixels_inside_them_also_at_the_detectors_edges():
    """Windows all over the detector, edges and corners included, against the map read pixel
    by pixel here: background + hot rate x T on the detector, 0 off it."""
    det = DetectorModel.make(hot_pixel_fraction=0.02)  # ~21,000 hot pixels: several per window
    hot = draw_hot_pixels(det, CAMERA, seed=9)
    rates = dict(zip(hot.linear_index.tolist(), hot.rate_e_per_s.tolist(), strict=True))
    rng = np.random.default_rng(10)
    uv = np.vstack([rng.uniform(-2.0, 1026.0, size=(60, 2)), [[0.2, 0.3], [1023.9, 1023.8], [0.5, 1023.5]]])
    rate = rng.normal(0.0, 30.0, size=uv.shape)  # smeared: larger windows
    origin, _, background, on = expected_windows(CAMERA, det, uv, rate, np.full(len(uv), 1e4), hot)
    T = det.exposure_s
    base = det.dark_and_background_e_per_px
    for s in range(len(uv)):
        for j in range(background.shape[1]):
            for i in range(background.shape[2]):
                row, col = origin[s, 1] + j, origin[s, 0] + i
                inside = 0 <= row < 1024 and 0 <= col < 1024
                assert on[s, j, i] == inside
                want = base + rates.get(row * 1024 + col, 0.0) * T if inside else 0.0
                assert background[s, j, i] == pytest.approx(want, rel=1e-12, abs=1e-12), (s, j, i)


def test_a_detector_range_includes_its_closed_bounds_and_excludes_its_open_ones():
    for key, (lo, hi, _, lo_closed, _) in DetectorModel.RANGES.items():
        if key == "black_level_adu":
            continue  # its top is the ADC's own limit
        assert getattr(DetectorModel.make(**{key: hi}), key) == hi
        if lo_closed:
            assert getattr(DetectorModel.make(**{key: lo}), key) == lo
        else:
            with pytest.raises(ValueError, match=rf"^st1\.{key}: got "):
                DetectorModel.make(**{key: lo})
        with pytest.raises(ValueError, match=rf"^st1\.{key}: got .*must be in "):
            DetectorModel.make(**{key: hi * 1.001 + 1e-9})
    for key, (lo, hi, _, _) in DetectorModel.INT_RANGES.items():
        assert getattr(DetectorModel.make(**{key: lo}), key) == lo
        assert getattr(DetectorModel.make(**{key: hi}), key) == hi
