"""The library's sensor plug-ins (:mod:`drake_att.scenarios.registry`): each module holds a
sensor's config dataclass (its YAML tag), build, validation and logging, registered with
:func:`~drake_att.scenarios.registry.register_sensor`."""

from drake_att.sensors import (  # noqa: F401, I001  (registers them, in this order: not sorted)
    gyro,
    star_tracker,
    star_tracker_average,
    scale_factor_star_noise,
    screen_camera,
)
from drake_att.sensors import faults  # noqa: F401,E402  (registers !SensorFaultsConfig; after the sensors it corrupts)
