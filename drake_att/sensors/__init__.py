"""The library's sensor plug-ins (:mod:`drake_att.scenarios.registry`): each module holds a
sensor's config dataclass (its YAML tag), build, validation and logging, registered with
:func:`~drake_att.scenarios.registry.register_sensor`."""

from drake_att.sensors import (  # noqa: F401, I001  (registers them, in this order: not sorted)
    gyro_plugin,
    star_tracker_plugin,
    sky_star_tracker_plugin,
    star_tracker_average_plugin,
    scale_factor_star_noise_plugin,
    screen_camera_plugin,
    sun_sensor_plugin,
    magnetometer_plugin,
)
from drake_att.sensors import faults_plugin  # noqa: F401,E402  (registers !SensorFaultsConfig; after the sensors it corrupts)
from drake_att.sensors import sensor_monitor_plugin  # noqa: F401,E402  (registers !SensorMonitorConfig)
