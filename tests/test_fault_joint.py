"""Fault injection, joint behaviour: what ``tests/test_faults.py`` (one kind
at a time, marginal rates) does not pin down.

* **Independence of the random decisions.** The per-sample yes/no decisions (outlier, NaN,
  inf, drop-out) are drawn through the real :class:`~drake_att.systems.fault_injector.FaultInjector`
  (inputs FixValue'd, the decision events stepped with ``EvalUniquePeriodicDiscreteUpdate``,
  the decisions read back from ``fault_truth``'s mask), 20000 samples per injector. For
  every pair of streams — two kinds on one sensor, one kind on a sample and any kind on the
  next sample, any two kinds on two trackers of the same kind given the *same* seed words
  (only the system name may separate their streams) — the joint rate ``P(A and B)`` must
  equal ``P(A) P(B)`` within 4 binomial standard errors of the joint count, and the 2x2
  contingency table must pass scipy's chi-square test of independence at the two-sided
  4-sigma level (p > 6.3e-5). The number the NaN / inf lands on must be uniform over the
  sample's numbers whatever decided the fault (chi-square goodness of fit, same level).
  The seed words are fixed, so the outcome is a fixed function of the code.
* **Timing to the sample.** One gyro injector (period 0.1 s, a period that is not a binary
  fraction) with every kind that has a time, a window or an onset, on and off the sample
  grid, 1 us either side of a sample, and windows holding no sample or exactly one. The
  expected samples are computed here in exact rational arithmetic from the config numbers
  (a fault "at t" hits sample ``ceil(t / T)``; a window ``[s, e)`` covers samples
  ``ceil(s / T) .. ceil(e / T) - 1``; a bias jump applies from ``ceil(t / T)`` on and marks
  only that sample; a stuck window holds sample ``ceil(s / T) - 1``). Checked on a
  standalone injector run by a Simulator (values: held, clipped, jumped, re-tagged,
  invalid) and through a scenario (the logged ``fault_truth`` and
  :func:`~drake_att.analysis.fault_scores.fault_events`' first and last sample of each event).
* **Detection thresholds.** :data:`drake_att.analysis.fault_scores.DETECTION_NIS` is the 99.9%
  point of chi-square with 3 dof (a quaternion update's innovation), derived here from
  ``scipy.stats.chi2.ppf`` (to the constant's two decimals); ``score_fault_events`` counts an
  accepted step as detected exactly when its NIS is above that quantile (an NIS 0.01 either
  side of it, written into a real run's log); the fault campaign's fixed gates
  (``innovation_gate_chi2``) are the 99.9% point for the innovation dimension of every
  input they gate (3 for a quaternion tracker or the tracker average; a vector tracker's
  model is 3-D additive noise, 3 per vector). A dof off by one moves the quantile by more
  than 2 (13.82 / 18.47 for 2 / 4 dof).
"""

from __future__ import annotations

import inspect
import math
from fractions import Fraction

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from scipy import stats

from drake_att.analysis import fault_scores as afl
from drake_att.scenarios.builder import ScenarioDiagram
from drake_att.scenarios.config import load_scenario
from drake_att.sensors.faults_plugin import SensorFaultsConfig, fault_model
from drake_att.systems import fault_injector as flt
from drake_att.systems.fault_injector import FaultInjector, FaultModel

DEG = math.pi / 180.0  # written out here
Z_BAND = 4.0
P_VALUE_FLOOR = 2.0 * stats.norm.sf(Z_BAND)  # two-sided 4 sigma: 6.3e-5


def _bits(masks, code):
    return (masks & (1 << (code - 1))) > 0


# ======================================================================================
# 1. Independence of the random decisions
# ======================================================================================
N_DRAWS = 20000
PERIOD_RANDOM_S = 0.1
PROBABILITY = {flt.FAULT_OUTLIER: 0.3, flt.FAULT_NAN: 0.2, flt.FAULT_INF: 0.25, flt.FAULT_DROPOUT: 0.15}
RANDOM_KINDS = tuple(PROBABILITY)
SEED_WORDS_UNIFORM = np.array([0.37, 0.81, 0.05, 0.66])  # both trackers: the same seed
Q_SAMPLE = np.r_[0.0, 1.0, np.array([0.9, 0.1, -0.3, 0.2]) / np.linalg.norm([0.9, 0.1, -0.3, 0.2])]


def _decision_stream(name: str) -> dict:
    """Samples 0..N_DRAWS-1 of a quaternion tracker's injector named ``name``: the truth's
    mask, primary code and magnitude per sample."""
    model = FaultModel.make(
        name,
        "quaternion",
        outlier_size=0.01,
        outlier_probability=PROBABILITY[flt.FAULT_OUTLIER],
        nan_probability=PROBABILITY[flt.FAULT_NAN],
        inf_probability=PROBABILITY[flt.FAULT_INF],
        dropout_probability=PROBABILITY[flt.FAULT_DROPOUT],
    )
    inj = FaultInjector(name, "quaternion", PERIOD_RANDOM_S, model)
    ctx = inj.CreateDefaultContext()
    inj.GetInputPort("seed_uniform").FixValue(ctx, SEED_WORDS_UNIFORM)
    inj.GetInputPort("sensor_measurement").FixValue(ctx, Q_SAMPLE)
    ctx.SetTime(0.0)
    inj.ExecuteInitializationEvents(ctx)
    port = inj.GetOutputPort("fault_truth")
    truth = np.empty((N_DRAWS, flt.FAULT_TRUTH_SIZE))
    for k in range(N_DRAWS):
        ctx.SetTime(k * PERIOD_RANDOM_S)
        truth[k] = port.Eval(ctx)
        ctx.get_mutable_discrete_state().SetFrom(inj.EvalUniquePeriodicDiscreteUpdate(ctx))
    # the stepping itself: one row per sample, in order
    np.testing.assert_allclose(truth[:, flt.TRUTH_T_SAMPLE], np.arange(N_DRAWS) * PERIOD_RANDOM_S, rtol=0, atol=1e-9)
    return {
        "mask": truth[:, flt.TRUTH_MASK].astype(np.int64),
        "code": truth[:, flt.TRUTH_CODE].astype(int),
        "magnitude": truth[:, flt.TRUTH_MAGNITUDE],
    }


@pytest.fixture(scope="module")
def streams():
    return {name: _decision_stream(name) for name in ("st1_faults", "st2_faults")}


def _check_independent(a: np.ndarray, b: np.ndarray, what: str) -> None:
    """``a``, ``b``: boolean decisions of the same samples. Joint rate against the product of
    the marginal rates (4 binomial SE of the joint count) and scipy's chi-square test of the
    2x2 table."""
    n = len(a)
    assert len(b) == n
    ra, rb, rab = float(np.mean(a)), float(np.mean(b)), float(np.mean(a & b))
    assert 0.05 < ra < 0.95 and 0.05 < rb < 0.95, (what, ra, rb)  # both streams do vary
    p0 = ra * rb
    band = Z_BAND * math.sqrt(p0 * (1.0 - p0) / n)
    assert abs(rab - p0) <= band, f"{what}: P(A and B) = {rab:.4f}, P(A) P(B) = {p0:.4f}, band {band:.4f}"
    table = np.array([[np.sum(a & b), np.sum(a & ~b)], [np.sum(~a & b), np.sum(~a & ~b)]])
    _, p_value, _, _ = stats.chi2_contingency(table, correction=False)
    assert p_value > P_VALUE_FLOOR, f"{what}: chi-square test of independence p = {p_value:.3g}, table {table.tolist()}"


def test_marginal_rates_of_the_decision_streams_are_the_configured_ones(streams):
    """(So that the joint tests below test the streams the config asks for.)"""
    for name, s in streams.items():
        for code, p in PROBABILITY.items():
            rate = float(np.mean(_bits(s["mask"], code)))
            assert abs(rate - p) <= Z_BAND * math.sqrt(p * (1 - p) / N_DRAWS), (name, flt.FAULT_NAMES[code], rate)


def test_different_fault_kinds_on_one_sensor_decide_independently(streams):
    m = streams["st1_faults"]["mask"]
    for i, c1 in enumerate(RANDOM_KINDS):
        for c2 in RANDOM_KINDS[i + 1 :]:
            _check_independent(_bits(m, c1), _bits(m, c2), f"{flt.FAULT_NAMES[c1]} x {flt.FAULT_NAMES[c2]}")


def test_decisions_of_consecutive_samples_are_independent(streams):
    """Kind c1 on sample k against kind c2 on sample k + 1 (every pair, c1 = c2 included)."""
    m = streams["st1_faults"]["mask"]
    for c1 in RANDOM_KINDS:
        for c2 in RANDOM_KINDS:
            _check_independent(
                _bits(m[:-1], c1), _bits(m[1:], c2), f"{flt.FAULT_NAMES[c1]}[k] x {flt.FAULT_NAMES[c2]}[k+1]"
            )


def test_two_sensors_given_the_same_seed_decide_independently(streams):
    """Two trackers of one kind, one seed: only the system name separates their streams
    (``drake_att.systems.randomness``: two systems never share a stream)."""
    m1, m2 = streams["st1_faults"]["mask"], streams["st2_faults"]["mask"]
    assert np.mean(m1 != m2) > 0.3
    for c1 in RANDOM_KINDS:
        for c2 in RANDOM_KINDS:
            _check_independent(_bits(m1, c1), _bits(m2, c2), f"st1 {flt.FAULT_NAMES[c1]} x st2 {flt.FAULT_NAMES[c2]}")


def test_the_number_hit_by_a_nan_or_inf_is_uniform_whatever_decided_the_fault(streams):
    """The truth's magnitude of a sample whose primary code is NaN (inf) is the index of the
    number set, uniform over the quaternion's 4 numbers (chi-square goodness of fit)."""
    for name, s in streams.items():
        for code in (flt.FAULT_NAN, flt.FAULT_INF):
            idx = s["magnitude"][s["code"] == code].astype(int)
            counts = np.bincount(idx, minlength=4)
            assert len(counts) == 4 and len(idx) > 1000, (name, counts)
            p_value = stats.chisquare(counts).pvalue
            assert p_value > P_VALUE_FLOOR, (name, flt.FAULT_NAMES[code], counts.tolist(), p_value)


# ======================================================================================
# 2. Timing to the sample
# ======================================================================================
T_S = "0.1"  # the period, as written in the config
N_SAMPLES = 60
TIMING_FIELDS = {
    "outlier_times_s": [0.0, 0.35, 0.7],
    "outlier_rate_deg_per_s": 2.0,
    "nan_times_s": [1.0, 1.05],
    "inf_times_s": [1.299999, 1.500001],  # 1 us before sample 13, 1 us after sample 15
    "dropout_times_s": [2.0],
    "time_tag_offset_s": 0.03,
    "time_tag_times_s": [2.15],
    "time_tag_windows_s": [[2.5, 2.8]],
    "outage_windows_s": [[3.0, 3.3], [3.45, 3.5], [3.55, 3.61]],  # 3 samples, none, one
    "stuck_windows_s": [[4.0, 4.3]],
    "saturation_deg_per_s": 1.0,
    "saturation_windows_s": [[4.6, 4.85]],
    "bias_jump_times_s": [5.05, 5.5],
    "bias_jumps_deg_per_h": [[360.0, 0.0, 0.0], [0.0, -720.0, 0.0]],
}


def _first_sample(t: float) -> int:
    """The first sample at or after ``t`` (exact: the config's decimal numbers as rationals)."""
    return math.ceil(Fraction(repr(t)) / Fraction(T_S))


def _window(w) -> list:
    return list(range(_first_sample(w[0]), _first_sample(w[1])))


def _expected_samples() -> dict:
    """Code -> the samples whose mask carries it, from the config numbers."""
    f = TIMING_FIELDS
    points = lambda key: [_first_sample(t) for t in f[key]]  # noqa: E731
    windows = lambda key: sorted(k for w in f[key] for k in _window(w))  # noqa: E731
    return {
        flt.FAULT_OUTLIER: points("outlier_times_s"),
        flt.FAULT_NAN: points("nan_times_s"),
        flt.FAULT_INF: points("inf_times_s"),
        flt.FAULT_DROPOUT: sorted(points("dropout_times_s") + windows("outage_windows_s")),
        flt.FAULT_TIME_TAG: sorted(points("time_tag_times_s") + windows("time_tag_windows_s")),
        flt.FAULT_STUCK: windows("stuck_windows_s"),
        flt.FAULT_SATURATED: windows("saturation_windows_s"),
        flt.FAULT_BIAS_JUMP: points("bias_jump_times_s"),
    }


def test_the_expected_samples_written_out():
    """The rational-arithmetic expectations, spelled out once (T = 0.1 s)."""
    e = _expected_samples()
    assert e[flt.FAULT_OUTLIER] == [0, 4, 7] and e[flt.FAULT_NAN] == [10, 11] and e[flt.FAULT_INF] == [13, 16]
    assert e[flt.FAULT_DROPOUT] == [20, 30, 31, 32, 36] and e[flt.FAULT_TIME_TAG] == [22, 25, 26, 27]
    assert e[flt.FAULT_STUCK] == [40, 41, 42] and e[flt.FAULT_SATURATED] == [46, 47, 48]
    assert e[flt.FAULT_BIAS_JUMP] == [51, 55]


def _jump_total(k: int) -> np.ndarray:
    """The bias jump total (rad/s) at sample k, from the config numbers."""
    total = np.zeros(3)
    for t, j in zip(TIMING_FIELDS["bias_jump_times_s"], TIMING_FIELDS["bias_jumps_deg_per_h"], strict=True):
        if k >= _first_sample(t):
            total += np.asarray(j) * DEG / 3600.0
    return total


def _rate_input(k: int) -> np.ndarray:
    """The gyro reading at sample k (rad/s): x and y above the 1 deg/s range, all moving."""
    return np.array([0.05 + 1e-4 * k, -0.04 - 2e-4 * k, 0.001 + 3e-5 * k])


def _simulate_standalone():
    """Outputs of samples 0..N-1 of the timing injector run by a Simulator (its events at the
    real sample times; after ``AdvanceTo(t_k)`` the state is the one sample k is read with)."""
    T = float(T_S)
    inj = FaultInjector("gyro_faults", "gyro", T, fault_model(SensorFaultsConfig(**TIMING_FIELDS), "gyro"))
    ctx = inj.CreateDefaultContext()
    inj.GetInputPort("seed_uniform").FixValue(ctx, SEED_WORDS_UNIFORM)
    port = inj.GetInputPort("sensor_measurement")
    port.FixValue(ctx, np.r_[0.0, 1.0, _rate_input(0)])
    sim = Simulator(inj, ctx)
    sim.Initialize()
    out, truth = [], []
    for k in range(N_SAMPLES):
        t = k * T
        if k:
            sim.AdvanceTo(t)
        c = sim.get_mutable_context()
        port.FixValue(c, np.r_[c.get_time(), 1.0, _rate_input(k)])
        out.append(inj.GetOutputPort("measurement").Eval(c).copy())
        truth.append(inj.GetOutputPort("fault_truth").Eval(c).copy())
    return np.array(out), np.array(truth)


def _check_mask_bits(truth, where: str) -> None:
    masks = truth[:, flt.TRUTH_MASK].astype(np.int64)
    for code, expected in _expected_samples().items():
        got = np.flatnonzero(_bits(masks, code)).tolist()
        assert got == expected, f"{where}: {flt.FAULT_NAMES[code]} on samples {got}, config says {expected}"


def test_every_fault_hits_exactly_the_samples_its_config_names_standalone():
    out, truth = _simulate_standalone()
    T = float(T_S)
    t = np.arange(N_SAMPLES) * T
    np.testing.assert_allclose(truth[:, flt.TRUTH_T_SAMPLE], t, rtol=0, atol=1e-9)
    _check_mask_bits(truth, "standalone")
    e = _expected_samples()
    # time tags: + offset exactly on the time-tag samples
    tag = np.isin(np.arange(N_SAMPLES), e[flt.FAULT_TIME_TAG])
    np.testing.assert_allclose(out[:, 0], t + np.where(tag, TIMING_FIELDS["time_tag_offset_s"], 0.0), rtol=0, atol=1e-9)
    np.testing.assert_array_equal(truth[:, flt.TRUTH_T_OUT], out[:, 0])
    # validity: 0 exactly on the drop-out and outage samples
    invalid = np.isin(np.arange(N_SAMPLES), e[flt.FAULT_DROPOUT])
    np.testing.assert_array_equal(out[:, 1], np.where(invalid, 0.0, 1.0))
    # the numbers, sample by sample
    r = TIMING_FIELDS["saturation_deg_per_s"] * DEG
    stuck, held = e[flt.FAULT_STUCK], e[flt.FAULT_STUCK][0] - 1
    for k in range(N_SAMPLES):
        live = _rate_input(k) + _jump_total(k)
        got = out[k, 2:]
        if k in e[flt.FAULT_OUTLIER]:
            assert np.linalg.norm(got - live) == pytest.approx(TIMING_FIELDS["outlier_rate_deg_per_s"] * DEG), k
        elif k in e[flt.FAULT_NAN] or k in e[flt.FAULT_INF]:
            assert np.sum(~np.isfinite(got)) == 1, k
        elif k in stuck:
            np.testing.assert_allclose(got, _rate_input(held) + _jump_total(held), rtol=0, atol=1e-15, err_msg=str(k))
        elif k in e[flt.FAULT_SATURATED]:
            np.testing.assert_allclose(got, np.clip(live, -r, r), rtol=0, atol=1e-15, err_msg=str(k))
            assert truth[k, flt.TRUTH_CODE] == flt.FAULT_SATURATED
        else:
            np.testing.assert_allclose(got, live, rtol=0, atol=1e-15, err_msg=str(k))
    # the bias jump total in the truth follows the onsets
    for k in range(N_SAMPLES):
        np.testing.assert_allclose(truth[k, flt.TRUTH_BIAS_JUMP], _jump_total(k), rtol=0, atol=1e-18)
    # the stuck samples say how old the held sample is
    for k in stuck:
        assert truth[k, flt.TRUTH_MAGNITUDE] == pytest.approx((k - held) * T, abs=1e-9)


TIMING_SCENARIO = """
name: fault_timing
duration_s: {duration}
simulation: {{integration_scheme: runge_kutta3, use_error_control: false, max_step_size_s: 0.1}}
plant: !RigidBodyConfig {{inertia_kg_m2: [1.0, 1.0, 1.0], initial_rate_deg_per_s: [3.0, -2.0, 0.5],
                          disturbance_torque_N_m: [0.0, 0.0, 0.0]}}
sensors:
- !GyroConfig {{name: gyro, period_s: {period}, arw_deg_per_rt_h: 0.1, rrw_deg_per_h15: 0.1}}
- !SensorFaultsConfig {{name: gyro_faults, sensor: gyro, {fields}}}
estimators: []
"""


def _yaml_fields(fields: dict) -> str:
    return ", ".join(f"{k}: {v!r}" for k, v in fields.items())


def _event_runs(samples, point: bool):
    """(first, last) sample of each event: every sample its own for point kinds, else runs
    of consecutive samples."""
    if point:
        return [(k, k) for k in samples]
    runs = []
    for k in samples:
        if runs and k == runs[-1][1] + 1:
            runs[-1] = (runs[-1][0], k)
        else:
            runs.append((k, k))
    return runs


def test_every_fault_hits_exactly_the_samples_its_config_names_through_a_scenario():
    """The logged truth of a real run (the gyro's 3 and -2 deg/s exceed the 1 deg/s range
    on two axes) and the events the analysis reads from it: first and last sample each."""
    T = float(T_S)
    text = TIMING_SCENARIO.format(duration=(N_SAMPLES - 1) * T + 0.05, period=T_S, fields=_yaml_fields(TIMING_FIELDS))
    run = ScenarioDiagram(load_scenario(text=text)).simulate(3)
    x = run.values("gyro_faults/fault_truth")
    keep = np.r_[True, np.diff(x[:, flt.TRUTH_T_SAMPLE]) > 1e-6]  # sample 0 is logged twice
    x = x[keep]
    assert len(x) == N_SAMPLES
    np.testing.assert_allclose(x[:, flt.TRUTH_T_SAMPLE], np.arange(N_SAMPLES) * T, rtol=0, atol=1e-9)
    _check_mask_bits(x, "scenario")
    e = _expected_samples()
    np.testing.assert_array_equal(x[:, flt.TRUTH_VALID_OUT] == 0.0, np.isin(np.arange(N_SAMPLES), e[flt.FAULT_DROPOUT]))
    # the analysis' events: kind, first and last sample
    outage = {k for w in TIMING_FIELDS["outage_windows_s"] for k in _window(w)}
    expected = []
    for code, samples in e.items():
        for first, last in _event_runs(samples, code in afl.POINT_CODES):
            kind = flt.FAULT_NAMES[code]
            if code == flt.FAULT_DROPOUT and first in outage:
                kind = "outage"
            expected.append((first, kind, last))
    got = [(round(ev.t_start / T), ev.kind, round(ev.t_end / T)) for ev in afl.fault_events(run)]
    assert got == sorted(expected)
    for ev in afl.fault_events(run):
        assert ev.t_start == pytest.approx(round(ev.t_start / T) * T, abs=1e-9)
        assert ev.t_end == pytest.approx(round(ev.t_end / T) * T, abs=1e-9)


# ======================================================================================
# 3. Detection thresholds
# ======================================================================================
DETECTION_PROBABILITY = 0.999
QUATERNION_DOF = 3  # a quaternion measurement's innovation: a 3-D rotation vector


def test_detection_nis_is_the_chi_square_quantile_of_a_quaternion_update():
    want = stats.chi2.ppf(DETECTION_PROBABILITY, QUATERNION_DOF)
    assert afl.DETECTION_NIS == pytest.approx(want, abs=0.005)  # the constant carries two decimals
    for wrong in (QUATERNION_DOF - 1, QUATERNION_DOF + 1):  # the check tells a dof off by one
        assert abs(stats.chi2.ppf(DETECTION_PROBABILITY, wrong) - want) > 2.0
    default = inspect.signature(afl.score_fault_events).parameters["detection_nis"].default
    assert default == pytest.approx(want, abs=0.005)


DETECTION_SCENARIO = """
name: fault_detection
duration_s: 20.0
simulation: {integration_scheme: runge_kutta3, use_error_control: false, max_step_size_s: 0.1}
plant: !RigidBodyConfig {inertia_kg_m2: [0.042, 0.042, 0.0067], initial_rate_deg_per_s: [-0.5, 0.5, 0.5],
                         disturbance_torque_N_m: [0.0, 0.0, 0.0]}
sensors:
- !GyroConfig {name: gyro, period_s: 1.0, arw_deg_per_rt_h: 0.56, rrw_deg_per_h15: 10.0}
- !StarTrackerConfig {name: st1, period_s: 1.0, sigma_cross_boresight_arcsec: 5.0, sigma_boresight_arcsec: 50.0}
- !SensorFaultsConfig {name: st1_faults, sensor: st1, outlier_times_s: [10.0], outlier_angle_deg: 0.002}
estimators:
- !MekfConfig {name: ungated, star_trackers: [st1], initial_attitude_sigma_deg: 0.1, innovation_gate_probability: 0.0}
"""


def test_an_accepted_fault_counts_as_detected_exactly_above_the_chi_square_quantile():
    """A real run (an ungated MEKF accepts a small outlier of its quaternion tracker at
    t = 10 s) with the logged NIS of that step set 0.01 above / below chi2.ppf(0.999, 3)."""
    run = ScenarioDiagram(load_scenario(text=DETECTION_SCENARIO)).simulate(1)
    status = run.values(run.metadata["estimators"]["ungated"]["signals"]["status"])
    at = np.abs(status[:, 0] - 10.0) < 1e-6
    assert np.any(at)
    quantile = stats.chi2.ppf(DETECTION_PROBABILITY, QUATERNION_DOF)
    for nis, detected in ((quantile + 0.01, 1), (quantile - 0.01, 0)):
        status[at, 3] = nis
        [row] = [r for r in afl.score_fault_events(run) if r["kind"] == "outlier"]
        assert (row["steps"], row["accepted"], row["rejected"]) == (1, 1, 0), row
        assert row["detected"] == detected, (nis, row)


def _innovation_dofs(scenario, estimator) -> set:
    """The innovation dimension of each measurement input of ``estimator`` (from the sensor
    configs): 3 for a quaternion (a tracker or the tracker average), 3 per reference for a
    vector tracker (additive 3-D noise, not re-normalized: the model is 3-D)."""
    sensors = {s.name: s for s in scenario.sensors}
    dofs = set()
    for name in estimator.star_trackers:
        s = sensors[name]
        mode = getattr(s, "mode", "quaternion")
        if mode == "vectors":
            dofs.add(3 * len(s.references_I))
        else:
            dofs.add(QUATERNION_DOF)
    return dofs


def test_the_fault_campaign_gates_are_the_chi_square_quantile_of_their_inputs_dimension():
    from drake_att.scenarios.library import load

    scenario = load("fault_campaign")
    gated = [e for e in scenario.estimators if getattr(e, "innovation_gate_chi2", None) is not None]
    assert len(gated) >= 3
    for e in gated:
        [dof] = _innovation_dofs(scenario, e)  # one fixed threshold fits one dimension only
        assert e.innovation_gate_chi2 == pytest.approx(stats.chi2.ppf(DETECTION_PROBABILITY, dof), abs=0.005), e.name
