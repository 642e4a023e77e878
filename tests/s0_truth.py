"""Paper-S0 parameters, the small numpy truth simulation and the star-sensor sample shared by
the MRP-EKF and particle-filter core tests (independent of the Drake plant and sensors)."""

import numpy as np
from particle_reference import vector_measurement_model

from drake_att import rotations as rot
from drake_att.contract import VectorObservations

DEG = np.pi / 180.0
HOUR = 3600.0
SIGMA_V = 0.2 * DEG / HOUR  # ARW, rad/s^0.5 (0.2 deg/h per 1 s sample)
SIGMA_U = 0.02 * DEG / HOUR / np.sqrt(HOUR)  # RRW, rad/s^1.5
SIGMA_STAR = 100e-6  # star-sensor noise per component, rad
REFS = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
P0_ATT = np.diag([DEG**2] * 3 + [(DEG / HOUR) ** 2] * 3)
BODY = np.array([1.0, 0.0, 0.0, 0.0])  # a star sensor mounted with the body axes (q_BS)


def observation(y, refs=REFS, sigma=SIGMA_STAR, t=0.0):
    """The sample of stacked body-frame vectors ``y`` (3m,) of ``refs`` from a body-mounted
    sensor (None entries: missing components)."""
    return VectorObservations(t, True, np.reshape(y, (-1, 3)), refs, sigma, BODY)


def simulate_gyro_truth(
    num_steps,
    rng,
    q0=(1.0, 0.0, 0.0, 0.0),
    w=(1e-3, -5e-4, 2e-4),
    bias0=(DEG / HOUR,) * 3,
    dt=1.0,
    refs=REFS,
    sigma=SIGMA_STAR,
):
    """Constant-rate truth, Farrenkopf gyro and vector measurements.

    Returns q_true (K, 4) and b_true (K, 3) at t_k = k dt, the measurements y (K, 3m) of
    t_k, and w_meas (K - 1, 3): the gyro output averaged over [t_k, t_k+1] (paper S3's
    discrete model with the bias averaged over the sample).
    """
    w = np.asarray(w, dtype=float)
    q = np.asarray(q0, dtype=float)
    b = np.asarray(bias0, dtype=float)
    qs, bs, ys, wms = [], [], [], []
    for _ in range(num_steps):
        qs.append(q)
        bs.append(b)
        ys.append(vector_measurement_model(rot.quat_to_mrp(q), refs) + sigma * rng.standard_normal(3 * len(refs)))
        b_next = b + SIGMA_U * np.sqrt(dt) * rng.standard_normal(3)
        noise_std = np.sqrt(SIGMA_V**2 / dt + SIGMA_U**2 * dt / 12.0)
        wms.append(w + 0.5 * (b + b_next) + noise_std * rng.standard_normal(3))
        q = rot.quat_propagate(q, w, dt)
        b = b_next
    return np.array(qs), np.array(bs), np.array(ys), np.array(wms[:-1])
