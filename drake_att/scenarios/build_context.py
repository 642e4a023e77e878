"""What a plug-in's build function gets: the diagram builder, the scenario, the truth and
every system built so far, with helpers to wire an estimator to its sensors.

Plug-ins (:mod:`drake_att.scenarios.registry`) import this module, never the scenario
builder (:mod:`drake_att.scenarios.builder`), which imports them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import cast

import numpy as np
from pydrake.systems.framework import DiagramBuilder

from drake_att import rotations as rot
from drake_att.orbit import CircularOrbit
from drake_att.orbit_propagators import KeplerOrbit, TleOrbit, julian_date_utc, parse_epoch_utc
from drake_att.scenarios import config as cfg
from drake_att.scenarios.registry import PluginError, SensorOutput, plugin_for
from drake_att.systems.estimator_system import EstimatorSystem
from drake_att.units import DEG


def make_orbit(scenario: cfg.Scenario):
    """The scenario's orbit model (None: no orbit)."""
    return None if scenario.orbit is None else orbit_model(scenario.orbit)


def orbit_model(o):
    """The orbit model of an orbit config: :class:`~drake_att.orbit.CircularOrbit`,
    :class:`~drake_att.orbit_propagators.KeplerOrbit` or :class:`~drake_att.orbit_propagators.TleOrbit`
    (each with ``q_IO(t)``; the last two also ``position_velocity_I(t)``)."""
    if isinstance(o, cfg.TleOrbitConfig):
        return TleOrbit(o.line1, o.line2, o.epoch_utc)
    if isinstance(o, cfg.KeplerOrbitConfig):
        parse_epoch_utc(o.epoch_utc)
        return KeplerOrbit(
            o.semi_major_axis_km * 1e3,
            o.eccentricity,
            o.inclination_deg * DEG,
            o.raan_deg * DEG,
            o.arg_perigee_deg * DEG,
            o.mean_anomaly_deg * DEG,
            j2=bool(o.j2),
        )
    return CircularOrbit(o.altitude_km * 1e3, o.inclination_deg * DEG, o.raan_deg * DEG, o.arg_latitude0_deg * DEG)


def attitude_from_rpy_deg(scenario: cfg.Scenario, rpy_deg) -> np.ndarray:
    """``q_IB`` at t = 0 for roll/pitch/yaw (deg) relative to the scenario's reference frame."""
    q = rot.rpy_to_quat(np.asarray(rpy_deg, dtype=float) * DEG)
    orbit = make_orbit(scenario)
    if orbit is not None:
        q = rot.quat_multiply(orbit.q_IO(0.0), q)
    return rot.quat_canonical(q)


@dataclass
class BuildContext:
    """The builder, the scenario, the truth system and the systems built so far.

    Attributes:
        builder: the ``DiagramBuilder``; None once the diagram is built (a plug-in's ``configure``).
        scenario: the validated scenario.
        truth: plant or prescribed motion (output ports ``q_IB``, ``w_IB_B``,
            ``w_IB_B_integral``).
        sensors, sensor_configs, estimators, estimator_configs: name -> system / config.
        measurement_sources: sensor name -> ``(system, output port)`` that consumers read
            instead of the sensor's own output (set by a fault-injection entry,
            :mod:`drake_att.sensors.faults_plugin`); :meth:`sensor_output` still describes the sensor.
        realizations: the runs one diagram carries (a batch on one truth; 1: a single run);
            the plug-ins that support more pass it to their systems
            (:data:`drake_att.scenarios.builder.BATCH_SENSORS`).
    """

    builder: DiagramBuilder | None
    scenario: cfg.Scenario
    truth: object
    sensors: dict = field(default_factory=dict)
    sensor_configs: dict = field(default_factory=dict)
    estimators: dict = field(default_factory=dict)
    estimator_configs: dict = field(default_factory=dict)
    measurement_sources: dict = field(default_factory=dict)
    environment_systems: tuple = ()
    orbit_system: object = None
    magnetic_field_system: object = None
    realizations: int = 1

    def orbit_source(self):
        """The :class:`~drake_att.systems.orbit_source.OrbitSource` of the scenario's orbit (any
        kind), added to the diagram on first use."""
        if self.orbit_system is None:
            from drake_att.systems.orbit_source import OrbitSource

            self.orbit_system = self._diagram_builder().AddSystem(OrbitSource(make_orbit(self.scenario)))
            self.orbit_system.set_name("orbit")
        return self.orbit_system

    def environment(self) -> tuple:
        """``(OrbitSource, SunMoonSource)`` of the scenario's orbit and epoch, added to the
        diagram on first use (a sensor that needs the geometry calls this while it is built)."""
        if not self.environment_systems:
            from drake_att.systems.environment import SunMoonSource

            o = self.scenario.orbit
            jd_epoch = julian_date_utc(parse_epoch_utc(o.epoch_utc))  # type: ignore[union-attr]  # validated
            orbit = self.orbit_source()
            sun_moon = self._diagram_builder().AddSystem(SunMoonSource(jd_epoch, self.scenario.duration_s))
            sun_moon.set_name("sun_moon")
            self.environment_systems = (orbit, sun_moon)
        return self.environment_systems

    def magnetic_field(self):
        """The :class:`~drake_att.systems.environment.MagneticFieldSource` of the scenario's epoch, fed
        by the orbit's ``r_I``; added on first use (output ``B_I``, T, in I)."""
        if self.magnetic_field_system is None:
            from drake_att.systems.environment import MagneticFieldSource

            orbit, _ = self.environment()
            jd_epoch = julian_date_utc(parse_epoch_utc(self.scenario.orbit.epoch_utc))
            source = self._diagram_builder().AddSystem(MagneticFieldSource(jd_epoch))
            source.set_name("geomagnetic_field")
            self._diagram_builder().Connect(orbit.GetOutputPort("r_I"), source.GetInputPort("r_I"))
            self.magnetic_field_system = source
        return self.magnetic_field_system

    def sensor_output(self, name: str) -> SensorOutput:
        """What sensor ``name`` delivers (kind, port, period)."""
        c = self.sensor_configs[name]
        output = plugin_for(c).output
        if output is None:  # only a sensor's plug-in describes its output
            raise PluginError(f"{name}: {type(c).__name__} is not a sensor's config")
        return output(c, self.sensor_configs)

    def quaternion_model(self, name: str):
        """What a filter assumes about quaternion sensor ``name`` (mounting, noise covariance)."""
        c = self.sensor_configs[name]
        model = plugin_for(c).quaternion_model
        if model is None:  # only a quaternion sensor's plug-in has one
            raise PluginError(f"{name}: {type(c).__name__} is not a quaternion sensor")
        return model(self, c)

    def add_estimator(self, name: str, setup):
        """Add the :class:`~drake_att.systems.estimator_system.EstimatorSystem` of ``setup`` (an
        :class:`~drake_att.systems.estimator_system.EstimatorSetup`) and wire its gyro, quaternion
        and vector sensors (with ``setup.monitor``: the sensors that monitor watches through its
        outputs, and its verdicts to ``sensor_verdicts``); the random seed port is wired by the
        builder. Returns the system."""
        est = self._diagram_builder().AddSystem(EstimatorSystem.from_setup(name, setup, self.realizations))
        connect = self.connect_sensor
        if setup.monitor is not None:
            monitor = self.sensors[setup.monitor]
            port = monitor.declare_verdicts(name, setup.gyro, cast(EstimatorSystem, est).input_names)
            self._diagram_builder().Connect(monitor.GetOutputPort(port), est.GetInputPort("sensor_verdicts"))

            def connect(sensor, system, input_port):
                if sensor in monitor.sensor_names:  # read through the monitor
                    source = monitor.GetOutputPort(f"measurement_{sensor}")
                    self._diagram_builder().Connect(source, system.GetInputPort(input_port))
                else:
                    self.connect_sensor(sensor, system, input_port)

        if setup.core.uses_gyro:
            if setup.gyro is None:
                raise ValueError(f"{name}: the core uses a gyro but the setup names none")
            connect(setup.gyro, est, "gyro_measurement")
        for m in setup.quaternion_sensors:
            connect(m.name, est, f"q_meas_{m.name}")
            if m.sample_covariance:  # the sample's own covariance, straight from the sensor
                source = self.sensors[m.name].GetOutputPort("covariance_S")
                self._diagram_builder().Connect(source, est.GetInputPort(f"q_cov_{m.name}"))
        for n in setup.vector_sensors:
            connect(n, est, f"vectors_{n}")
        for n in setup.camera_sensors:
            self.connect_sensor(n, est, f"centroids_{n}")
        return est

    def measurement_source(self, name: str):
        """``(system, output port name)`` consumers of sensor ``name`` read: its own
        measurement output, or what replaces it (``measurement_sources``)."""
        return self.measurement_sources.get(name) or (self.sensors[name], self.sensor_output(name).port)

    def connect_sensor(self, name: str, system, input_port: str) -> None:
        """Wire sensor ``name``'s measurement (:meth:`measurement_source`) to ``system``'s
        ``input_port``."""
        source, port = self.measurement_source(name)
        self._diagram_builder().Connect(source.GetOutputPort(port), system.GetInputPort(input_port))

    def _diagram_builder(self) -> DiagramBuilder:
        """The builder; refused once the diagram is built (nothing can be added or wired then)."""
        if self.builder is None:
            raise ValueError("the diagram is built: no system can be added or wired")
        return self.builder
