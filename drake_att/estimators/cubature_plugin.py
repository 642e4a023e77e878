"""Estimator plug-in: paper S1's cubature quaternion estimator (CQE) and, with a
multiplicative-noise model, the CQE-MCNS (:mod:`drake_att.filters.cubature`), fed by a gyro
and one vector-mode star tracker. YAML tag ``!CubatureQuaternionConfig``.

``multiplicative_noise`` names a ``!ScaleFactorStarNoiseConfig`` sensor (the per-step gyro
scale-factor error correlated with the star noise, :mod:`drake_att.filters.multiplicative_noise`):
the filter then models it (CQE-MCNS) with that sensor's ``Q_zeta``, ``rho`` and ``kappa``;
``assumed_correlation`` overrides the ``rho`` it assumes (mismatch studies). Empty: the plain
CQE. Defaults follow the paper (SPEC.md S1): ``P0 = diag((40 deg)^2, (0.1 deg/h)^2)``, GRP
``a = 1, f = 4`` (the USQUE convention: ``dp`` ~ the rotation angle for small errors).
``update_iterations`` > 1 iterates the measurement update (ours: from the paper's [-45, 45, 155]
deg error, a 175 deg rotation, a single update leaves the bias wrecked for hours with 2 arcsec
stars; 1 = the paper).
``zeta_gate_sigmas`` > 0 ignores ``M`` on innovations that are implausible under the model
(ours; 0 = never, the patent). ``zeta_state_correlation`` adds the term the patent's
prediction drops, ``Cov(x, zeta | D) = -K S`` (ours; false = the patent).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import List, Optional

from drake_att.contract import SecondQuantity
from drake_att.estimators import common
from drake_att.filters.cubature import CubatureQuaternionEstimator
from drake_att.filters.gating import DEFAULT_GATE_PROBABILITY
from drake_att.filters.multiplicative_noise import MultiplicativeNoiseModel
from drake_att.scenarios import config as cfg
from drake_att.scenarios.registry import register_estimator
from drake_att.sensors.scale_factor_star_noise_plugin import ScaleFactorStarNoiseConfig, noise_model
from drake_att.systems.estimator_system import EstimatorSetup
from drake_att.units import DEG, DEG_PER_H


@dataclass
class CubatureQuaternionConfig:
    """CQE (``multiplicative_noise: ""``) or CQE-MCNS (the name of a noise source).

    ``max_time_tag_lag_s``: a sample tagged up to this much before the step is carried forward
    to it and used (:class:`~drake_att.estimators.mekf_plugin.MekfConfig`); 0: none.
    """

    name: str = "cqe"
    period_s: float = 1.0
    gyro: str = "gyro"
    star_tracker: str = "st"
    vector_sensors: List[str] = field(default_factory=list)
    multiplicative_noise: str = ""
    assumed_correlation: Optional[float] = None
    arw_deg_per_rt_h: Optional[float] = None
    rrw_deg_per_h15: Optional[float] = None
    initial_attitude_rpy_deg: List[float] = field(default_factory=cfg.zeros3)
    initial_bias_deg_per_h: List[float] = field(default_factory=cfg.zeros3)
    initial_attitude_sigma_deg: float = 40.0
    initial_bias_sigma_deg_per_h: float = 0.1
    grp_a: float = 1.0
    grp_f: float = 4.0
    update_iterations: int = 10
    zeta_gate_sigmas: float = 4.0
    zeta_state_correlation: bool = False
    innovation_gate_chi2: Optional[float] = None
    innovation_gate_probability: float = DEFAULT_GATE_PROBABILITY
    max_time_tag_lag_s: float = 0.0


def validate_cubature(path: str, c: CubatureQuaternionConfig, checks) -> None:
    common.validate_vector_filter(path, c, checks, integer_fields=("update_iterations",), filter_gyro_noise=True)
    cfg.check_finite(f"{path}.grp_a", c.grp_a)
    if not 0.0 <= c.grp_a <= 1.0:
        cfg.fail(f"{path}.grp_a", c.grp_a, "must be in [0, 1]")
    cfg.check_positive(f"{path}.grp_f", c.grp_f)
    cfg.check_nonnegative(f"{path}.zeta_gate_sigmas", c.zeta_gate_sigmas)
    common.check_flags(path, c, "zeta_state_correlation")
    common.check_innovation_gate(path, c)
    common.check_step_settings(path, c)
    if c.multiplicative_noise and c.vector_sensors:
        cfg.fail(
            f"{path}.vector_sensors",
            c.vector_sensors,
            "must be empty with multiplicative_noise: the correlated-noise model is the star tracker's only",
        )
    if c.multiplicative_noise:
        source = checks.sensors.get(c.multiplicative_noise)
        if not isinstance(source, ScaleFactorStarNoiseConfig):
            have = sorted(n for n, s in checks.sensors.items() if isinstance(s, ScaleFactorStarNoiseConfig))
            cfg.fail(
                f"{path}.multiplicative_noise",
                c.multiplicative_noise,
                f"must name a !ScaleFactorStarNoiseConfig listed before it (have {have}); empty: the plain CQE",
            )
        if (source.gyro, source.star_tracker) != (c.gyro, c.star_tracker):
            cfg.fail(
                f"{path}.multiplicative_noise",
                c.multiplicative_noise,
                f"drives gyro {source.gyro!r} and tracker {source.star_tracker!r}; this filter reads "
                f"{c.gyro!r} and {c.star_tracker!r}",
            )
        if c.assumed_correlation is not None:
            try:
                _assumed_model(c, source).cross_covariance(1.0, len(checks.sensors[c.star_tracker].references_I))
            except ValueError as e:
                raise cfg.ConfigError(f"{path}.assumed_correlation: {e}") from e
    elif c.assumed_correlation is not None:
        cfg.fail(f"{path}.assumed_correlation", c.assumed_correlation, "needs multiplicative_noise (a noise source)")


def _assumed_model(c: CubatureQuaternionConfig, source: ScaleFactorStarNoiseConfig) -> MultiplicativeNoiseModel:
    model = noise_model(source)
    if c.assumed_correlation is None:
        return model
    return MultiplicativeNoiseModel.make(model.zeta_variance, c.assumed_correlation, model.scale_per_zeta)


@register_estimator(
    CubatureQuaternionConfig,
    second_quantity=SecondQuantity.GYRO_BIAS,
    validate=validate_cubature,
    parameters=(
        "assumed_correlation",
        "arw_deg_per_rt_h",
        "rrw_deg_per_h15",
        "grp_a",
        "grp_f",
        "update_iterations",
        "zeta_gate_sigmas",
        "zeta_state_correlation",
        *common.GATE_FIELDS,
        *common.INITIAL_GYRO_MODE_FIELDS,
        *common.LAG_FIELDS,
    ),
)
def build_cubature(ctx, c: CubatureQuaternionConfig) -> EstimatorSetup:
    arw, rrw = common.filter_gyro_noise(ctx, c)
    model = _assumed_model(c, ctx.sensor_configs[c.multiplicative_noise]) if c.multiplicative_noise else None
    core = CubatureQuaternionEstimator(
        arw,
        rrw,
        c.grp_a,
        c.grp_f,
        common.innovation_gate(c),
        model,
        c.zeta_gate_sigmas if c.zeta_gate_sigmas > 0 else None,
        c.update_iterations,
        zeta_state_correlation=c.zeta_state_correlation,
    )
    q0, b0, _ = common.initial_gyro_mode_estimate(ctx, c)
    init = core.initial_state(q0, b0, c.initial_attitude_sigma_deg * DEG, c.initial_bias_sigma_deg_per_h * DEG_PER_H)
    return EstimatorSetup(
        core, init, c.period_s, gyro=c.gyro, vector_sensors=common.vector_sensor_names(c), **common.step_settings(c)
    )
