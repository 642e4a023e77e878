"""The library's estimator plug-ins (:mod:`drake_att.scenarios.registry`): each module holds an
estimator's config dataclass (its YAML tag), validation and build function, registered
with :func:`~drake_att.scenarios.registry.register_estimator`. The filter math lives in
:mod:`drake_att.filters`, the one Drake system in :mod:`drake_att.systems.estimator_system`."""

from drake_att.estimators import (  # noqa: F401, I001  (registers them, in this order: not sorted)
    mekf_plugin,
    estimate_fusion_plugin,
    mrp_ekf_plugin,
    bootstrap_pf_plugin,
    ekpf_plugin,
    gyroless_pf_plugin,
    lie_group_plugin,
    quaternion_ekf_plugin,
    cubature_plugin,
    indoor_star_tracker_plugin,
)
