"""Estimator plug-in: fusion of several estimators' outputs (paper S3's "decentralized"
scheme, :class:`drake_att.systems.fusion.EstimateFusion`). YAML tag ``!EstimateFusionConfig``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import List

from pydrake.systems.primitives import Demultiplexer

from drake_att.contract import COVARIANCE, Q_IB, SECOND, STATUS
from drake_att.estimators.mekf_plugin import MekfConfig
from drake_att.scenarios import config as cfg
from drake_att.scenarios.registry import register_estimator
from drake_att.systems.fusion import EstimateFusion

COVARIANCE_MODELS = ("tracked", "conservative", "independent")


@dataclass
class EstimateFusionConfig:
    """Fusion of several estimators' outputs (paper S3's "decentralized" scheme):
    quaternion average of the attitudes, linear average of the biases.
    ``covariance_model``: "tracked" (exact cross-covariance of two MEKFs sharing a gyro),
    "conservative" (sum w_i P_i, valid for any correlation) or "independent"
    (sum w_i^2 P_i, ignores the shared gyro)."""

    name: str = "fusion"
    sources: List[str] = field(default_factory=lambda: ["mekf1", "mekf2"])
    weights: List[float] = field(default_factory=lambda: [0.5, 0.5])
    covariance_model: str = "conservative"


def fusion_second_quantity(c: EstimateFusionConfig, checks):
    """The sources' common second quantity (validated to be one)."""
    return checks.second_quantity(c.sources[0])


def validate_estimate_fusion(path: str, c: EstimateFusionConfig, checks) -> None:
    if len(c.sources) < 2:
        cfg.fail(f"{path}.sources", c.sources, "needs at least 2 estimators")
    cfg.check_listed_once(path, "sources", c.sources, "estimator")
    for src in c.sources:
        if src not in checks.estimators:
            cfg.fail(
                f"{path}.sources", src, f"must name an estimator listed before it; have {sorted(checks.estimators)}"
            )
    kinds = {checks.second_quantity(src).port_name for src in c.sources}
    if len(kinds) != 1:
        cfg.fail(f"{path}.sources", c.sources, f"the sources estimate different quantities {sorted(kinds)}")
    cfg.check_weights(f"{path}.weights", c.weights, len(c.sources))
    if c.covariance_model not in COVARIANCE_MODELS:
        cfg.fail(f"{path}.covariance_model", c.covariance_model, "allowed: 'tracked', 'conservative', 'independent'")
    sources = [checks.estimators[n] for n in c.sources]
    if c.covariance_model == "tracked":
        if len(sources) != 2 or not all(isinstance(x, MekfConfig) for x in sources):
            cfg.fail(
                f"{path}.covariance_model",
                c.covariance_model,
                f"'tracked' needs exactly 2 MEKF sources; got {c.sources}",
            )
        a, b = sources
        # The recursion P12+ = A1 (Phi1 P12 Phi2' + Q) A2' models the two filters' common error
        # only if both propagate alike (one gyro, one period, one coning setting - the last two
        # are structural) from identical initial estimates and sigmas (their initial errors are
        # then equal). Their gyro-noise tunings may differ (a context sweep of one branch): the
        # common noise Q is then the first source's (drake_att.systems.fusion).
        fields = (
            "gyro",
            "period_s",
            "initial_attitude_rpy_deg",
            "initial_bias_deg_per_h",
            "initial_attitude_sigma_deg",
            "initial_bias_sigma_deg_per_h",
            "coning_correction",
        )
        differ = [f for f in fields if getattr(a, f) != getattr(b, f)]
        if differ:
            cfg.fail(
                f"{path}.covariance_model",
                c.covariance_model,
                f"'tracked' needs sources {c.sources} that propagate alike (one gyro, one period, one "
                f"coning setting) from identical initial estimates and sigmas; they differ in {differ}",
            )
    elif any(getattr(x, "period_s", None) is None for x in sources):
        cfg.fail(f"{path}.sources", c.sources, "every source needs a period_s (fusions of fusions are not supported)")


@register_estimator(EstimateFusionConfig, second_quantity=fusion_second_quantity, validate=validate_estimate_fusion)
def build_estimate_fusion(ctx, c: EstimateFusionConfig):
    sources = [ctx.estimators[n] for n in c.sources]
    period = min(ctx.estimator_configs[n].period_s for n in c.sources)
    second = sources[0].second_output_name
    fusion = ctx.builder.AddSystem(
        EstimateFusion(c.name, c.sources, c.weights, second, c.covariance_model, period, ctx.realizations)
    )
    contract_ports = [
        ("q_IB_hat", "q_IB_hat", Q_IB),
        (second, "second", SECOND),
        ("covariance", "covariance", COVARIANCE),
        ("status", "status", STATUS),
    ]
    for n, src in zip(c.sources, sources, strict=True):
        if ctx.realizations > 1:  # a batch: each source's packed estimate, N blocks
            ctx.builder.Connect(src.GetOutputPort("estimate_state"), fusion.GetInputPort(f"{n}_estimate_state"))
        elif src.HasOutputPort("estimate_state"):
            # The packed estimate (a C++ state port) split by a C++ Demultiplexer: no Python
            # output call per contract port.
            split = ctx.builder.AddNamedSystem(
                f"{c.name}_{n}_split", Demultiplexer([part.stop - part.start for _, _, part in contract_ports])
            )
            ctx.builder.Connect(src.GetOutputPort("estimate_state"), split.get_input_port())
            for k, (_, dst, _) in enumerate(contract_ports):
                ctx.builder.Connect(split.get_output_port(k), fusion.GetInputPort(f"{n}_{dst}"))
        else:
            for port, dst, _ in contract_ports:
                ctx.builder.Connect(src.GetOutputPort(port), fusion.GetInputPort(f"{n}_{dst}"))
        if c.covariance_model == "tracked":
            ctx.builder.Connect(src.GetOutputPort("step_linearization"), fusion.GetInputPort(f"{n}_linearization"))
    return fusion
