"""Paper S1's multiplicative, correlated noise in the diagram
(drake_att.systems.correlated_noise + the gyro's scale_error and the tracker's vector_noise
inputs): the statistics of the drawn (zeta_k, v_k) over 2e4 steps, the timing (zeta_k pairs
with the star sample at t_k and scales the interval [t_k, t_k + T]), and the exact effect on
the gyro and star-tracker outputs in a built scenario."""

from __future__ import annotations

import numpy as np
import pytest

from drake_att import rotations as rot
from drake_att.filters.multiplicative_noise import MultiplicativeNoiseModel
from drake_att.scenarios.builder import ScenarioDiagram
from drake_att.scenarios.config import ConfigError, load_scenario
from drake_att.systems.correlated_noise import ScaleFactorStarNoiseSource

SIGMA_V = 10e-6
SEED = np.array([0.31, 0.72, 0.13, 0.54])


def _draws(model, m, n, sigma_v=SIGMA_V):
    """Per step k: (zeta output at t_k = zeta_{k-1}, scale output, vector_noise = v_k)."""
    src = ScaleFactorStarNoiseSource("mn", 1.0, model, sigma_v, m)
    ctx = src.CreateDefaultContext()
    src.GetInputPort("seed_uniform").FixValue(ctx, SEED)
    src.ExecuteInitializationEvents(ctx)
    zeta, scale, v = np.empty(n), np.empty(n), np.empty((n, 3 * m))
    for k in range(n):
        zeta[k] = src.GetOutputPort("zeta").Eval(ctx)[0]
        scale[k] = src.GetOutputPort("scale_error").Eval(ctx)[0]
        v[k] = src.GetOutputPort("vector_noise").Eval(ctx)
        ctx.SetDiscreteState(src.EvalUniquePeriodicDiscreteUpdate(ctx))
    return zeta, scale, v


def test_drawn_noise_has_the_models_variances_and_same_step_cross_covariance():
    """2e4 steps, m = 2 stars: var(zeta)/Q_zeta and var(v_j)/sigma_v^2 within 4 standard
    errors (sqrt(2/n)) of 1; corr(zeta_k, v_k,j) within 4/sqrt(n) of rho for every component;
    zeta of another step uncorrelated with v_k; scale output = kappa zeta."""
    model = MultiplicativeNoiseModel.paper()
    n, m = 20000, 2
    zeta_out, scale, v = _draws(model, m, n + 1)
    assert zeta_out[0] == 0.0 and scale[0] == 0.0  # no interval ends at t_0
    np.testing.assert_allclose(scale, model.scale_per_zeta * zeta_out, rtol=1e-15, atol=0)
    zeta = zeta_out[1:]  # zeta_k, k = 0..n-1 (reported at t_{k+1})
    vk = v[:n]  # v_k at t_k
    tol = 4 * np.sqrt(2.0 / n)
    assert abs(zeta.var() / model.zeta_variance - 1) < tol
    assert np.all(np.abs(vk.var(axis=0) / SIGMA_V**2 - 1) < tol)
    corr = np.array([np.corrcoef(zeta, vk[:, j])[0, 1] for j in range(3 * m)])
    assert np.all(np.abs(corr - model.correlation) < 4 / np.sqrt(n)), corr
    # Components of v_k are uncorrelated with each other (the c_m term), and v_k with zeta_{k-1}.
    C = np.corrcoef(vk.T)
    assert np.max(np.abs(C - np.eye(3 * m))) < 4 / np.sqrt(n)
    lag = np.array([np.corrcoef(zeta[:-1], vk[1:, j])[0, 1] for j in range(3 * m)])
    assert np.all(np.abs(lag) < 4 / np.sqrt(n))


def test_zero_correlation_and_variance_give_independent_and_zero_noise():
    zeta_out, scale, v = _draws(MultiplicativeNoiseModel.make(0.0, 0.0, 0.01), 2, 50)
    assert np.all(zeta_out == 0.0) and np.all(scale == 0.0) and np.all(np.isfinite(v)) and v.std() > 0


def test_indefinite_joint_covariance_is_refused():
    with pytest.raises(ValueError, match="num_stars"):
        ScaleFactorStarNoiseSource("mn", 1.0, MultiplicativeNoiseModel.make(0.1, 0.5, 0.01), SIGMA_V, 2)


SCENARIO = """
name: s1_noise_probe
duration_s: 30.0
plant: !PrescribedRateConfig
  constant_deg_per_s: [0.0, -0.06, 0.02]
sensors:
- !GyroConfig {name: gyro, period_s: 1.0}
- !StarTrackerConfig {name: st, period_s: 2.0, mode: vectors, references_I: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
                      sigma_vector_urad: 10.0}
- !ScaleFactorStarNoiseConfig {name: mn, gyro: gyro, star_tracker: st, scale_per_zeta: 0.02}
estimators: []
"""


def test_in_a_scenario_the_gyro_reads_the_rate_over_one_plus_kappa_zeta_and_the_tracker_adds_v():
    """Noise-free gyro and a constant body rate w: the gyro output at t_{k+1} is exactly
    w / (1 + kappa zeta_k); the tracker's sample at t_k is exactly R_SB R_BI(q_k) r + v_k with
    the source's v_k (the source's own outputs read in the same context)."""
    from pydrake.systems.analysis import Simulator

    sd = ScenarioDiagram(load_scenario(text=SCENARIO))
    ctx = sd.create_context(3)
    sim = Simulator(sd.diagram, ctx)
    sim.Initialize()
    gyro, st, src = sd.sensors["gyro"], sd.sensors["st"], sd.sensors["mn"]
    w = np.radians([0.0, -0.06, 0.02])
    kappa = 0.02
    checked_gyro = checked_st = 0
    for k in range(1, 12):
        sim.AdvanceTo(float(k))  # events of t_k not yet applied: the outputs of t_k
        g = gyro.GetOutputPort("gyro_measurement").Eval(gyro.GetMyContextFromRoot(ctx))
        zeta = src.GetOutputPort("zeta").Eval(src.GetMyContextFromRoot(ctx))[0]
        np.testing.assert_allclose(g[2:], w / (1.0 + kappa * zeta), rtol=1e-9)
        assert abs(zeta) > 0
        checked_gyro += 1
        if k % 2 == 0:
            obs = st.GetOutputPort("vector_observations").Eval(st.GetMyContextFromRoot(ctx))
            v = src.GetOutputPort("vector_noise").Eval(src.GetMyContextFromRoot(ctx)).reshape(2, 3)
            q = sd.truth.GetOutputPort("q_IB").Eval(sd.truth.GetMyContextFromRoot(ctx))
            expected = (rot.quat_to_rotmat(q).T @ obs.references_I.T).T + v
            assert obs.time_s == pytest.approx(k) and obs.valid
            np.testing.assert_allclose(obs.directions_S, expected, rtol=0, atol=1e-15)
            checked_st += 1
    assert checked_gyro == 11 and checked_st == 5


@pytest.mark.parametrize(
    "over, field",
    [
        ("sensors.2.star_tracker=gyro", "star_tracker"),
        ("sensors.2.correlation=0.5", "num_stars"),
        ("sensors.1.period_s=1.5", "star_tracker"),
    ],
)
def test_scenario_validation_names_the_field(over, field):
    from drake_att.scenarios.config import apply_overrides

    with pytest.raises(ConfigError, match=field):
        apply_overrides(load_scenario(text=SCENARIO), [over])


def test_each_step_draws_its_own_documented_row_of_normals():
    """(zeta_k, v_k) = model.from_normals(normals(k, 1 + 3m), sigma_v) of the counter stream
    (seed words, system name): recomputed here for k = 0..5 from the documented rule, so a
    shifted or repeated counter index (two steps sharing a draw) fails."""
    from drake_att.systems.randomness import SEED_WORDS, counter_random

    model, m = MultiplicativeNoiseModel.paper(), 2
    src = ScaleFactorStarNoiseSource("mn", 1.0, model, SIGMA_V, m)
    ctx = src.CreateDefaultContext()
    src.GetInputPort("seed_uniform").FixValue(ctx, SEED)
    src.ExecuteInitializationEvents(ctx)
    words = ctx.get_discrete_state_vector().value()[:SEED_WORDS].copy()
    zetas = []
    for k in range(6):
        zeta_k, v_k = model.from_normals(counter_random(words, "mn").normals(k, 1 + 3 * m), SIGMA_V)
        np.testing.assert_array_equal(src.GetOutputPort("vector_noise").Eval(ctx), v_k.ravel())
        if k > 0:
            assert src.GetOutputPort("zeta").Eval(ctx)[0] == zetas[-1]  # zeta_{k-1} reported at t_k
        zetas.append(float(zeta_k))
        ctx.SetDiscreteState(src.EvalUniquePeriodicDiscreteUpdate(ctx))
    assert len(set(zetas)) == len(zetas)
