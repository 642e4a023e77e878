"""The library's estimator plug-ins (:mod:`drake_att.scenarios.registry`): each module holds an
estimator's config dataclass (its YAML tag), validation and build function, registered
with :func:`~drake_att.scenarios.registry.register_estimator`. The filter math lives in
:mod:`drake_att.filters`, the one Drake system in :mod:`drake_att.systems.estimators`."""

from drake_att.estimators import (  # noqa: F401, I001  (registers them, in this order: not sorted)
    mekf,
    estimate_fusion,
    mrp_ekf,
    bootstrap_pf,
    ekpf,
    gyroless_pf,
    lie_group,
    quaternion_ekf,
    cubature,
    indoor_star_tracker,
)
