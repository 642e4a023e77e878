"""The shared chi-square innovation gate (drake_att.filters.gating): its quantiles, its
rejection rate on nominal data, outlier rejection and the re-acquisition inflation.

The system-level rule (N consecutive rejections -> re-acquire and retry ungated) is tested
in tests/test_plugins.py (test_contract_a_gate_never_rejects_forever)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import binom, chi2

from drake_att import rotations as rot
from drake_att.contract import UpdateInfo
from drake_att.filters.gating import (
    DEFAULT_GATE_PROBABILITY,
    InnovationGate,
    chi2_cdf,
    chi2_quantile,
    inflate_attitude_block,
    reacquire_factor,
)
from drake_att.filters.mekf import MultiplicativeEKF


@pytest.mark.parametrize("dof", [1, 2, 3, 4, 6, 9, 12, 30, 100])
def test_chi2_quantile_and_cdf_agree_with_scipy(dof):
    for p in (1e-4, 0.05, 0.5, 0.9, 0.99, 0.999, 0.99999):
        assert chi2_quantile(p, dof) == pytest.approx(chi2.ppf(p, dof), rel=1e-11)
    for x in (1e-3, 0.5, dof, 3.0 * dof, 10.0 * dof + 50.0):
        assert chi2_cdf(x, dof) == pytest.approx(chi2.cdf(x, dof), rel=1e-12, abs=1e-15)


def test_gate_thresholds_and_bad_settings():
    assert DEFAULT_GATE_PROBABILITY == 0.99999
    assert InnovationGate(probability=DEFAULT_GATE_PROBABILITY).threshold(3) == pytest.approx(25.90, abs=0.01)
    g = InnovationGate(probability=0.999)
    assert g.threshold(3) == pytest.approx(16.266, abs=1e-3) and g.threshold(6) == pytest.approx(22.458, abs=1e-3)
    assert g.rejects(16.3, 3) and not g.rejects(16.2, 3) and g.rejects(float("nan"), 3)
    assert InnovationGate.of(9.0).threshold(6) == 9.0 and not InnovationGate.of(None).enabled
    assert not InnovationGate().rejects(1e300, 3) and InnovationGate().rejects(float("inf"), 3)
    for kwargs, field in (
        ({"probability": 1.0}, "innovation_gate_probability"),
        ({"probability": -0.1}, "innovation_gate_probability"),
        ({"chi2": 0.0}, "innovation_gate_chi2"),
        ({"chi2": 9.0, "probability": 0.9}, "innovation gate"),
    ):
        with pytest.raises(ValueError, match=field):
            InnovationGate(**kwargs)


def _nominal_run(gate, steps, seed, outlier_every=None, outlier_deg=1.0):
    """An MEKF whose model is the truth: static attitude, gyro white noise (ARW) as the only
    rate signal, quaternion measurements with noise R. Returns (accepted flags, NIS)."""
    rng = np.random.default_rng(seed)
    arw, dt = 1e-5, 1.0
    sigmas = np.array([5.0, 5.0, 50.0]) * math.pi / 648000.0
    R = np.diag(sigmas**2)
    core = MultiplicativeEKF(arw, 0.0, gate)
    q_true = np.array([1.0, 0.0, 0.0, 0.0])
    state = core.initial_state(q_true, np.zeros(3), 1e-5, 1e-12)
    accepted, nis = [], []
    for k in range(steps):
        # truth static; the gyro reads its ARW noise: the filter's error random-walks as modelled
        state = core.predict(state, arw / math.sqrt(dt) * rng.standard_normal(3), dt)
        delta = sigmas * rng.standard_normal(3)
        if outlier_every and k % outlier_every == outlier_every - 1:
            delta = delta + np.radians(outlier_deg) * rng.standard_normal(3) / math.sqrt(3)
        q_meas = rot.quat_multiply(q_true, rot.rotvec_to_quat(delta))
        state, info = core.update_quaternion(state, q_meas, np.array([1.0, 0.0, 0.0, 0.0]), R)
        accepted.append(info.accepted)
        nis.append(info.nis)
    return np.array(accepted), np.array(nis)


@pytest.mark.parametrize("probability", [0.999, 0.99])
def test_gate_rejects_nominal_measurements_at_its_stated_rate(probability):
    """20000 nominal updates of a consistent MEKF (3-dof quaternion innovations): the NIS is
    chi-square(3) (mean within 3 standard errors of 3) and a gate at probability p rejects a
    fraction 1 - p of them (count inside the two-sided 99.9% binomial interval). (The default,
    1 - 1e-5, is too rare to measure here; its threshold is the same quantile.)"""
    n = 20000
    accepted, nis = _nominal_run(InnovationGate(probability=probability), n, seed=3)
    steady = nis[200:]
    assert abs(steady.mean() - 3.0) < 3.0 * math.sqrt(6.0 / len(steady)), steady.mean()
    rejected = int(np.sum(~accepted[200:]))
    lo, hi = binom.ppf([0.0005, 0.9995], n - 200, 1.0 - probability)
    assert lo <= rejected <= hi, (rejected, lo, hi)


def test_default_gate_rejects_injected_outliers_an_ungated_filter_takes():
    """Every 50th sample carries a 0.05 deg error (a 5"/50" tracker): the MEKF with the
    default gate rejects all of them; the ungated one takes them."""
    gated, _ = _nominal_run(
        InnovationGate(probability=DEFAULT_GATE_PROBABILITY), 2000, seed=5, outlier_every=50, outlier_deg=0.05
    )
    ungated, _ = _nominal_run(InnovationGate(), 2000, seed=5, outlier_every=50, outlier_deg=0.05)
    outliers = np.arange(49, 2000, 50)
    assert not np.any(gated[outliers]) and np.all(ungated[outliers])


def test_reacquire_inflation_touches_the_attitude_block_only_keeps_psd_and_is_capped():
    rng = np.random.default_rng(0)
    A = rng.standard_normal((6, 6))
    P = A @ A.T * 1e-6
    Q = inflate_attitude_block(P, 50.0)
    np.testing.assert_array_equal(Q[3:, :], P[3:, :])
    np.testing.assert_array_equal(Q[:3, 3:], P[:3, 3:])
    np.testing.assert_allclose(Q[:3, :3], 50.0 * P[:3, :3], rtol=1e-14)
    assert np.min(np.linalg.eigvalsh(Q)) > 0.0
    capped = inflate_attitude_block(np.diag([1.0, 1.0, 1.0, 1e-6, 1e-6, 1e-6]), 1e6)
    assert np.max(np.diag(capped)[:3]) == pytest.approx(math.pi**2)
    gate = InnovationGate(probability=0.999)
    info = UpdateInfo(np.zeros(3), None, 1000.0, False)
    assert reacquire_factor(gate, info) == pytest.approx(2.0 * 1000.0 / gate.threshold(3))
    assert reacquire_factor(gate, UpdateInfo(np.zeros(3), None, 10.0, False)) == 2.0


def test_quantile_and_gate_errors_name_the_field_and_what_is_allowed():
    with pytest.raises(ValueError, match=r"^probability: got 1\.0; must be in \(0, 1\)"):
        chi2_quantile(1.0, 3)
    with pytest.raises(ValueError, match=r"^dof: got 0; must be an integer >= 1"):
        chi2_quantile(0.5, 0)
    with pytest.raises(ValueError, match=r"give a chi2 threshold or a probability, not both"):
        InnovationGate(chi2=9.0, probability=0.9)
    with pytest.raises(ValueError, match=r"must be in \(0, 1\) \(0 in a config: no gate\)"):
        InnovationGate(probability=1.5)
    # With the gate off there is no threshold to scale to: the fixed factor 2.
    assert reacquire_factor(InnovationGate(), UpdateInfo(np.zeros(3), None, 1e6, False)) == 2.0
