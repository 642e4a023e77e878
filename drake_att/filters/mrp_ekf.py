"""Additive extended Kalman filter on modified Rodrigues parameters (paper S0, gyro mode),
no Drake.

State ``x = [rho; b]``: ``rho`` (3, dimensionless) is the MRP of ``q_IB`` (body to inertial,
``v_I = R(q_IB) v_B``; ``|rho| <= 1`` between calls, the shadow set taken when it grows
past 1) and ``b`` (3, rad/s) the gyro bias; ``P`` (6x6) the covariance of ``x`` in the MRP
chart. Gyro: the mean body rate over the step (Farrenkopf model, ARW ``sigma_v``
rad/s^0.5, RRW ``sigma_u`` rad/s^1.5); measurements: star vectors
``y = [R_BI u_1; ...; R_BI u_m] + v``, ``v ~ N(0, sigma^2 I_3m)`` (rad).

* :class:`MrpEkfCore` on :class:`MrpEkfState`: the :class:`drake_att.contract.FilterCore`. Its
  time and measurement updates are the compiled kernels
  :func:`~drake_att.filters.particle_kernels.ekf_predict` and
  :func:`~drake_att.filters.particle_kernels.ekf_update` (a batch of one; the EKPF of
  :mod:`drake_att.filters.particle` runs one EKF per particle with the same kernels), their one
  implementation; the readable numpy form of the model, its Jacobians and both updates is the
  tests' oracle (``tests/particle_reference.py``).
* :func:`attitude_to_mrp_covariance`, :func:`mrp_to_attitude_covariance`: the covariance of
  ``[dtheta_B; b]`` mapped to the MRP chart and back.
* :func:`body_frame_vectors`, :func:`gyro_rate`: the checks of a vector-fed core's inputs.

Derivation (mean, transition matrix, process noise, update, shadow switch) and measured
behaviour: docs/derivations/mrp_ekf.md
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drake_att.contract import SecondQuantity, UpdateInfo
from drake_att.filters import particle_kernels as _kernels
from drake_att.filters.gating import GatedCore, InnovationGate, inflated, reacquire_factor
from drake_att.rotations import mrp_kinematics_matrix, mrp_to_quat, quat_to_mrp, quat_to_rotmat
from drake_att.validation import (
    check_array,
    check_covariance,
    check_int,
    check_positive,
    check_quaternion,
    check_reference_vectors,
    measurement_or_none,
)

__all__ = [
    "MrpEkfCore",
    "MrpEkfState",
    "mrp_kinematics_inverse",
    "body_frame_vectors",
    "gyro_rate",
    "attitude_to_mrp_covariance",
    "mrp_to_attitude_covariance",
]


def body_frame_vectors(observations) -> tuple[np.ndarray | None, np.ndarray, float]:
    """The vectors of a :class:`~drake_att.contract.VectorObservations` sample in the body frame.

    Returns ``(y_B (3m,) or None, references_I (m, 3), sigma (rad))``: ``y_B = R_BS y_S``
    stacked (exact for the isotropic vector noise of the vector-mode tracker); None when
    a direction is missing or not finite (the caller declines the update). A wrong shape,
    bad references or a sigma <= 0 raise ValueError naming the field.
    """
    U = check_reference_vectors("ref_vectors_I", observations.references_I)
    sigma = check_positive("sigma", observations.sigma_rad)
    y_S = measurement_or_none(
        "directions_S", observations.directions_S, (U.shape[0], 3), " (one direction per reference vector)"
    )
    if y_S is None:
        return None, U, sigma
    q_BS = np.asarray(observations.q_BS, dtype=float)
    if q_BS.tolist() == _IDENTITY:  # a body-mounted sensor: R_BS = I (the product is exact)
        return y_S.ravel(), U, sigma
    return (y_S @ quat_to_rotmat(q_BS).T).ravel(), U, sigma


_IDENTITY = [1.0, 0.0, 0.0, 0.0]


# ----------------------------------------------------------------------------------
# The covariance in the MRP chart (batched over leading dimensions)
# ----------------------------------------------------------------------------------
def mrp_kinematics_inverse(rho) -> np.ndarray:
    """``B(rho)^-1 = 16 / (1 + rho'rho)^2 B(rho)'`` (maps ``drho`` to body angle, rad).

    ``B`` is ``(1 + rho'rho)/4`` times an orthogonal matrix, so the inverse is exact.
    """
    rho = np.asarray(rho, dtype=float)
    n2 = np.sum(rho * rho, axis=-1)[..., None, None]
    return 16.0 / (1.0 + n2) ** 2 * np.swapaxes(mrp_kinematics_matrix(rho), -1, -2)


def _sym(P):
    return 0.5 * (P + np.swapaxes(P, -1, -2))


def attitude_to_mrp_covariance(rho, P_att) -> np.ndarray:
    """Map a covariance of ``[dtheta_B (rad); b (rad/s)]`` to ``[rho; b]`` at ``rho``.

    ``drho = B(rho) dtheta`` (first order), ``dtheta`` the body-frame error
    ``q_IB = q_IB_hat ⊗ exp(dtheta / 2)``.
    """
    T = np.zeros(np.shape(rho)[:-1] + (6, 6))
    T[..., :3, :3] = mrp_kinematics_matrix(rho)
    T[..., 3:, 3:] = np.eye(3)
    return _sym(T @ P_att @ np.swapaxes(T, -1, -2))


def mrp_to_attitude_covariance(rho, P) -> np.ndarray:
    """Inverse of :func:`attitude_to_mrp_covariance`: ``[rho; b]`` -> ``[dtheta; b]``."""
    T = np.zeros(np.shape(rho)[:-1] + (6, 6))
    T[..., :3, :3] = mrp_kinematics_inverse(rho)
    T[..., 3:, 3:] = np.eye(3)
    return _sym(T @ P @ np.swapaxes(T, -1, -2))


# ----------------------------------------------------------------------------------
# The filter core
# ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class MrpEkfState:
    """MRP EKF state: ``x = [rho; b]`` (6, ``|rho| <= 1``) and its covariance ``P`` (6x6, MRP chart)."""

    x: np.ndarray
    P: np.ndarray


class MrpEkfCore(GatedCore):
    """Paper S0's additive EKF on ``x = [rho; b]`` (gyro mode) as a
    :class:`drake_att.contract.FilterCore`: the kernels
    :func:`~drake_att.filters.particle_kernels.ekf_predict` and
    :func:`~drake_att.filters.particle_kernels.ekf_update` on an immutable :class:`MrpEkfState`.

    ``predict`` takes the step's mean gyro rate (rad/s, held over the step); ``update`` a
    :class:`~drake_att.contract.VectorObservations` sample, rotated into the body frame
    (:func:`body_frame_vectors`); a sample with a missing or non-finite direction, or one
    the innovation gate rejects, is declined (``UpdateInfo.accepted`` false, state
    unchanged). State vector: ``[x (6), P (36, MRP chart, row-major)]``.

    Args:
        arw_rad_per_rt_s: gyro ARW ``sigma_v`` (rad/s^0.5) > 0 (a white-noise std ``s`` per
            sample of period ``T`` is ``s sqrt(T)``).
        rrw_rad_per_s15: gyro RRW ``sigma_u`` (rad/s^1.5) >= 0.
        update_iterations: linearizations per update, >= 1: 1 is the paper's EKF, > 1 the
            iterated EKF, which converges from large initial errors.
        innovation_gate_chi2: a chi-square threshold or an
            :class:`~drake_att.filters.gating.InnovationGate`; None: no gate (the paper).
    """

    second_quantity = SecondQuantity.GYRO_BIAS
    uses_gyro = True
    is_random = False
    state_size = 42

    def __init__(
        self,
        arw_rad_per_rt_s: float,
        rrw_rad_per_s15: float = 0.0,
        update_iterations: int = 1,
        innovation_gate_chi2=None,
    ):
        self.gate = InnovationGate.of(innovation_gate_chi2)
        self.arw_rad_per_rt_s = check_positive("arw_rad_per_rt_s", arw_rad_per_rt_s)
        self.rrw_rad_per_s15 = check_positive("rrw_rad_per_s15", rrw_rad_per_s15, allow_zero=True)
        self.update_iterations = check_int("update_iterations", update_iterations, 1)

    @staticmethod
    def initial_state(q_IB_hat0, bias_hat0, covariance0) -> MrpEkfState:
        """The state of an attitude ``q_IB_hat0`` (wxyz, normalized), a bias (3, rad/s) and
        the (6, 6) covariance of ``[dtheta_B (rad); b (rad/s)]`` (``q_IB = q_IB_hat ⊗
        exp(dtheta_B / 2)``), mapped to the MRP chart with ``B(rho0)``
        (:func:`attitude_to_mrp_covariance`)."""
        q0 = check_quaternion("q_IB_hat0", q_IB_hat0)
        b0 = check_array("bias_hat0", bias_hat0, (3,), " (rad/s)")
        P_att = check_covariance("covariance0", covariance0, 6)
        rho0 = quat_to_mrp(q0)
        return MrpEkfState(np.concatenate([rho0, b0]), attitude_to_mrp_covariance(rho0, P_att))

    def predict(self, state: MrpEkfState, w_meas_B, dt: float, rng=None) -> MrpEkfState:
        """The state propagated over ``dt`` (s) > 0 with the mean measured rate ``w_meas_B``."""
        dt = check_positive("dt", dt)
        x, P = _kernels.ekf_predict(
            state.x[None], state.P[None], gyro_rate(w_meas_B), dt, self.arw_rad_per_rt_s, self.rrw_rad_per_s15
        )
        return MrpEkfState(x[0], P[0])

    def update(self, state: MrpEkfState, observations, rng=None) -> tuple[MrpEkfState, UpdateInfo]:
        """Update with a :class:`~drake_att.contract.VectorObservations` sample; the
        ``UpdateInfo`` carries the innovation ``y - h(x^-)``, its covariance and the NIS."""
        y_B, U, sigma = body_frame_vectors(observations)
        if y_B is None:
            return state, UpdateInfo(None, None, float("nan"), False)
        x, P, innovations, covariances = _kernels.ekf_update(
            state.x[None], state.P[None], y_B, U, sigma, iterations=self.update_iterations
        )
        innov, S = innovations[0], covariances[0]
        nis = float(innov @ np.linalg.solve(S, innov))
        if self.gate.rejects(nis, len(innov)):
            return state, UpdateInfo(innov, S, nis, False)
        return MrpEkfState(x[0], P[0]), UpdateInfo(innov, S, nis, True)

    def reacquire(self, state, info):
        """The state with its covariance inflated after repeated gate rejections (the rule of
        :mod:`drake_att.filters.gating`, applied by the estimator system)."""
        return inflated(state, reacquire_factor(self.gate, info))

    @staticmethod
    def estimate(state: MrpEkfState):
        """``(q_IB_hat (scalar part >= 0), bias_hat (rad/s), covariance of [dtheta_B; b])``."""
        return mrp_to_quat(state.x[:3]), state.x[3:].copy(), mrp_to_attitude_covariance(state.x[:3], state.P)

    @staticmethod
    def to_vector(state: MrpEkfState) -> np.ndarray:
        return np.concatenate([state.x, np.asarray(state.P).ravel()])

    @staticmethod
    def from_vector(vector) -> MrpEkfState:
        v = np.array(vector, dtype=float)
        return MrpEkfState(v[:6], v[6:42].reshape(6, 6))


def gyro_rate(w_meas_B) -> np.ndarray:
    """The step's mean gyro rate as a finite ``(3,)`` float array (rad/s).

    A core never sees a missing sample (the estimator system holds the last valid rate);
    anything else raises ValueError naming ``w_meas_B``."""
    return check_array("w_meas_B", w_meas_B, (3,), " (rad/s)")
