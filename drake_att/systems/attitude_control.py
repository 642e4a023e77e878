"""Attitude control of the truth: a PD law that keeps the body on a frame that turns with the orbit.

The bench compares estimators on one trajectory, so the controller closes its loop on the
**true** state (the estimates never steer the spacecraft); what it gives the bench is a realistic
mission truth: nadir pointing that follows the real orbit, with jitter from the disturbance
torque, the zero-order hold and a random torque.

Control law (held over each period ``T``, :class:`PdAttitudeLaw`)::

    q_IR = q_IO ⊗ q_OR                     reference: the LVLH frame O turned by a fixed offset
    dtheta = log(q_IR^-1 ⊗ q_IB)            attitude error (body relative to the reference, rad)
    w_ref_B = R_BI w_IO_I,  w_IO_I = r x v / |r|^2      the orbit frame's rate (rad/s)
    tau_B = I (-wn^2 dtheta - 2 zeta wn (w_IB_B - w_ref_B)) + w_IB_B x I w_IB_B + tau_noise

``tau_noise`` is white, ``N(0, sigma^2 I3)`` per period, a pure function of (seed, system name,
period index). ``w_IO_I`` neglects the orbit plane's own slow turn (J2, drag): the PD term takes up
what it misses.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pydrake.systems.framework import BasicVector, EventStatus, LeafSystem

from drake_att import rotations as rot
from drake_att.noise import CounterRandom
from drake_att.systems.randomness import SEED_WORDS, counter_random, declare_seed_port, read_seed_words


def orbit_frame_rate_I(r_I, v_I) -> np.ndarray:
    """The LVLH frame's angular velocity in I (rad/s): ``r x v / |r|^2`` (the orbital rate about
    the orbit normal)."""
    r, v = np.asarray(r_I, dtype=float), np.asarray(v_I, dtype=float)
    return np.cross(r, v) / float(r @ r)


@dataclass(frozen=True)
class PdAttitudeLaw:
    """A PD attitude law on the rotation-vector error with gyroscopic compensation.

    Attributes:
        inertia: (3, 3) kg m^2.
        natural_frequency_rad_per_s: closed-loop ``wn`` of each axis (> 0).
        damping_ratio: ``zeta`` (> 0).
        q_OR: the reference frame R relative to the orbit frame O (wxyz).
    """

    inertia: np.ndarray
    natural_frequency_rad_per_s: float
    damping_ratio: float
    q_OR: np.ndarray

    def reference(self, q_IO, r_I, v_I, q_IB) -> tuple[np.ndarray, np.ndarray]:
        """``(q_IR, w_ref_B)``: the reference attitude and its rate in the body frame."""
        q_IR = rot.quat_multiply(q_IO, self.q_OR)
        w_ref_B = rot.quat_to_rotmat(q_IB).T @ orbit_frame_rate_I(r_I, v_I)
        return q_IR, w_ref_B

    def torque(self, q_IB, w_IB_B, q_IO, r_I, v_I) -> np.ndarray:
        """The commanded torque (N m, body frame) for the true state and the orbit."""
        q_IR, w_ref_B = self.reference(q_IO, r_I, v_I, q_IB)
        dtheta = rot.quat_error_rotvec(q_IR, q_IB)
        wn, zeta = self.natural_frequency_rad_per_s, self.damping_ratio
        w = np.asarray(w_IB_B, dtype=float)
        accel = -wn * wn * dtheta - 2.0 * zeta * wn * (w - w_ref_B)
        return self.inertia @ accel + np.cross(w, self.inertia @ w)


class OrbitPointingController(LeafSystem):
    """The :class:`PdAttitudeLaw` as a sampled controller (see the module).

    Args:
        law: the control law.
        period_s: control period ``T`` (s) > 0; the torque is held between updates.
        torque_noise_N_m: per-axis sigma of the random torque added each period (N m) >= 0.
        name: system name (the noise stream's name).

    Input ports:
        q_IB (4), w_IB_B (3, rad/s): the true state.
        r_I (3, m), v_I (3, m/s), q_IO (4): the orbit (:class:`~drake_att.systems.orbit_source.OrbitSource`).
        seed_uniform (4, random uniform): seed.
    Output ports:
        torque_B (3): the held command (N m).
    Discrete state: ``[seed words (4), torque (3)]``; periodic update every ``T`` from t = 0
    (the torque for ``[kT, (k+1)T)`` is computed at ``kT`` from the state then).
    """

    def __init__(
        self, law: PdAttitudeLaw, period_s: float, torque_noise_N_m: float = 0.0, name: str = "attitude_control"
    ):
        LeafSystem.__init__(self)
        self.set_name(name)
        if not (math.isfinite(period_s) and period_s > 0):
            raise ValueError(f"{name}.period_s: got {period_s}; must be finite and > 0 (s)")
        if not (math.isfinite(torque_noise_N_m) and torque_noise_N_m >= 0):
            raise ValueError(f"{name}.torque_noise_N_m: got {torque_noise_N_m}; must be finite and >= 0")
        self.law, self.period_s, self.torque_noise_N_m = law, float(period_s), float(torque_noise_N_m)
        self._ports = {
            n: self.DeclareVectorInputPort(n, k)
            for n, k in (("q_IB", 4), ("w_IB_B", 3), ("r_I", 3), ("v_I", 3), ("q_IO", 4))
        }
        self._seed_port = declare_seed_port(self)
        self.DeclareDiscreteState(np.zeros(SEED_WORDS + 3))  # type: ignore[arg-type]  # pydrake stub
        self.DeclareInitializationDiscreteUpdateEvent(self._initialize)
        self.DeclarePeriodicDiscreteUpdateEvent(self.period_s, 0.0, self._update)
        self.DeclareVectorOutputPort("torque_B", 3, self._calc_torque, {self.xd_ticket()})

    def _command(self, context, words, t: float) -> np.ndarray:
        u = {n: p.Eval(context) for n, p in self._ports.items()}
        tau = self.law.torque(u["q_IB"], u["w_IB_B"], u["q_IO"], u["r_I"], u["v_I"])
        if self.torque_noise_N_m > 0:
            block, r = divmod(int(round(t / self.period_s)), CounterRandom.BLOCK)
            tau = tau + self.torque_noise_N_m * counter_random(words, self.get_name()).normals_block(block, 3)[r]
        return tau

    def _initialize(self, context, discrete_state):
        words = read_seed_words(self, context, self._seed_port)
        discrete_state.set_value(np.concatenate([words, self._command(context, words, context.get_time())]))
        return EventStatus.Succeeded()

    def _update(self, context, discrete_state):
        x = context.get_discrete_state_vector().value()
        words = x[:SEED_WORDS]
        discrete_state.set_value(np.concatenate([words, self._command(context, words, context.get_time())]))
        return EventStatus.Succeeded()

    def _calc_torque(self, context, output: BasicVector):
        output.SetFromVector(context.get_discrete_state_vector().value()[SEED_WORDS:])
