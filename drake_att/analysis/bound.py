"""The posterior Cramér–Rao bound (PCRB) of gyro + star-tracker attitude determination.

What it bounds
--------------
The covariance of any estimator of ``x_k = [dtheta_B, dbias_B]`` (attitude error in the body
frame, rad; gyro-bias error, rad/s) at the gyro's sample instants, given **the data the
sensors actually delivered** in one run: the gyro's interval-mean rates and every valid
star-tracker sample. Per axis, ``E[dtheta_i^2] >= P_bound[i, i]``.

The model (the data's, with the TRUE noise, on the TRUE trajectory)
-------------------------------------------------------------------
Gyro-driven attitude determination: the body rate is unknown a priori (no dynamics model is
used as information) and is supplied by the gyro. On the gyro's grid ``t_k = k T`` the
error obeys, exactly as drake_att's gyro generates its data
(:class:`drake_att.noise.FarrenkopfGyroNoise`, :class:`drake_att.systems.gyro.Gyro`):
the sample of ``t_k`` is ``mean(w over (t_{k-1}, t_k]) + b(t_{k-1}) + e_k`` and
``b(t_k) = b(t_{k-1}) + db_k``, with ``(e_k, db_k)`` zero-mean Gaussian, per axis
``var(e) = sigma_v^2 / T + sigma_u^2 T / 3``, ``cov(e, db) = sigma_u^2 T / 2``,
``var(db) = sigma_u^2 T``. Hence

``x_k = Phi_k x_{k-1} + G_k [e_k; db_k]``, ``Phi_k = [[exp(-[phi_k x]), -J_k], [0, I]]``,
``G_k = [[-J_k, 0], [0, I]]``,

with ``phi_k = log(q_IB(t_{k-1})^-1 q_IB(t_k))`` the TRUE rotation of the interval (from the
logged truth), ``Phi_k`` the closed form of :func:`drake_att.filters.mekf.transition_matrix`
at the true mean rate ``phi_k / T`` and ``J_k`` its bias block. ``Q_k = G_k C G_k'`` with the
TRUE gyro noise (the gyro's sensor config, not any filter's tuning). The MEKF's
:func:`~drake_att.filters.mekf.process_noise` is the same ``Q`` with ``J = T I`` (it neglects
the rotation of the error frame within one step, a relative O((|w| T)^2) difference).

Measurements at ``t_k``: each valid sample of a quaternion star tracker mounted by ``q_BS``
(``z = R_SB dtheta + delta_S``, ``delta_S ~ N(0, diag(s_c^2, s_c^2, s_b^2))``, the tracker's
TRUE config) gives ``H = [R_SB, 0]``, ``R = diag(s_c^2, s_c^2, s_b^2)``; a vector tracker's
``m`` directions give ``H_i = [R_SB [b_B x], 0]`` at the TRUE attitude, ``R = s^2 I3`` each.
An averaged tracker (``!StarTrackerAverageConfig``) is replaced by the raw trackers it
averages (the information the sensors delivered: a filter that reads the average loses some
of it, and its RMSE / bound ratio shows that). A fusion of estimators reads the union of its
sources' sensors.

The linear-Gaussian recursion along the true trajectory (Riccati in covariance form,
:func:`covariance_recursion`) is then the PCRB recursion (Tichavsky, Muravchik & Nehorai
1998) with the Jacobians evaluated on the truth: exact for this error model, which is the
MEKF's own linearization with the true rate instead of the measured one. An efficient
estimator (the MEKF in its linear regime) sits on it.

Which tracker samples count
---------------------------
Only samples at the gyro's instants. Between two gyro samples the gyro says nothing about
the rotation (it delivers the interval's mean rate only, and the rate has no prior), so a
tracker sample at ``t_{k-1} < t < t_k`` carries no information on the attitude at the gyro
instants in this model. (A model that also knows the rate to be constant within the
interval would extract information from them; drake_att's truth is not constant-rate
within 1 s under its disturbance torque and gyroscopic coupling, so such a "bound" would not
bound anything.) They are counted and reported (``samples_between_gyro_samples``). For scale:
in paper S3 (gyro means over 1 s, 10 Hz tracker) the steady-state bound on roll/pitch is 25.6"
(yaw 4.95"); a gyro delivering 0.1 s means with the same noise would put every tracker sample
to use and lower it to 16.0" (yaw 4.6") - the data rate, not the estimator, sets that gap.
Validity: a quaternion tracker's samples and flags are read from its log; a vector tracker's
are not logged: its outage windows are honoured, its random drop-outs are not known and are
reported as an assumption.

The prior (``t = 0``)
---------------------
The estimator's own initial 1-sigmas (``initial_attitude_sigma_deg``,
``initial_bias_sigma_deg_per_h`` of its config, or its first source's for a fusion) — the
Bayesian reading: the initial error is drawn from the filter's prior. In the shipped S3
scenarios the initial error is deterministic (truth ``[2, -2, 2]`` deg and 12 deg/h, the
estimate zero), so there is no "true" initial-error distribution; the prior is forgotten
within seconds and does not move the bound over a scoring window that starts at 500 s: each
result carries ``prior_sensitivity``, the relative change of the window's bound when the
prior covariance is 100 times larger. A config without those fields gets 1 rad and
``max(|b0|, sigma_b0, 1 deg/h)``.

No bound (``None`` with a reason): estimators without a gyro (gyroless particle filters:
the rate comes from Euler's equations), a camera input (the indoor star tracker), fault
injection on any sensor the estimator reads (outliers, stuck samples: not Gaussian), the
paper-S1 multiplicative gyro noise correlated with the star noise. Gyro scale-factor and
misalignment errors are deterministic and not in the bound (a note is added: estimators
that do not model them sit above it).

One concern at full length: reading a scenario into the linear model and the bound's recursion over it.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field

import numpy as np

from drake_att import rotations as rot
from drake_att.contract import TIME_TOLERANCE_S
from drake_att.filters.mekf import transition_matrix
from drake_att.noise import FarrenkopfGyroNoise
from drake_att.scenarios.selection import measurement_sensor_names
from drake_att.units import ARCSEC, ARW_DEG_PER_RT_H, DEG, DEG_PER_H, RRW_DEG_PER_H_15

PRIOR_SENSITIVITY_FACTOR = 100.0


class NoBound(ValueError):
    """No bound is defined for this estimator on this scenario (the message says why)."""


@dataclass
class BoundResult:
    """The bound of one run for one data set.

    Attributes:
        t: (K,) the gyro's sample instants (s), from 0.
        P: (K, 6, 6) the bound on the covariance of ``[dtheta_B (rad), dbias_B (rad/s)]``
            after the measurements of each instant.
        info: JSON-able facts: sensors, prior, counts of tracker samples used and not used,
            assumptions and notes.
    """

    t: np.ndarray
    P: np.ndarray
    info: dict = field(default_factory=dict)

    def sigma(self) -> np.ndarray:
        """(K, 6) the bound's 1-sigmas (sqrt of the diagonal)."""
        return np.sqrt(np.maximum(np.einsum("kii->ki", self.P), 0.0))

    def at(self, times) -> np.ndarray:
        """(n, 6, 6) the bound at ``times`` (each must be one of :attr:`t`, within 1 us)."""
        times = np.asarray(times, dtype=float)
        idx = np.clip(np.searchsorted(self.t, times - TIME_TOLERANCE_S), 0, len(self.t) - 1)
        bad = np.abs(self.t[idx] - times) > TIME_TOLERANCE_S
        if np.any(bad):
            raise ValueError(f"the bound is defined at the gyro's sample instants only; not at {times[bad][:3]} s")
        return self.P[idx]


# ---------------------------------------------------------------------------------------------
# The recursions (plain linear algebra)
# ---------------------------------------------------------------------------------------------
def farrenkopf_step_noise(arw: float, rrw: float, dt: float, J=None) -> np.ndarray:
    """Covariance (6x6) of ``G [e; db]`` for one gyro interval of length ``dt``.

    ``(e, db)``: the interval-mean rate noise and the bias increment of
    :class:`~drake_att.noise.FarrenkopfGyroNoise` (per axis, independent axes);
    ``G = [[-J, 0], [0, I]]`` with ``J`` the transition's bias block (default ``dt I``, which
    gives exactly :func:`drake_att.filters.mekf.process_noise`)."""
    c = FarrenkopfGyroNoise(arw, rrw, dt).interval_covariance()
    return _step_noise(c, dt * np.eye(3) if J is None else np.asarray(J, dtype=float))


def _step_noise(c, J):
    """``G C G'`` for the per-axis (e, db) covariance ``c`` (2x2) and ``G = [[-J, 0], [0, I]]``."""
    Q = np.zeros((6, 6))
    Q[:3, :3] = c[0, 0] * (J @ J.T)
    Q[:3, 3:] = -c[0, 1] * J
    Q[3:, :3] = Q[:3, 3:].T
    Q[3:, 3:] = c[1, 1] * np.eye(3)
    return Q


def _joseph_update(P, H, R):
    S = H @ P @ H.T + R
    K = np.linalg.solve(S, H @ P).T
    I_KH = np.eye(P.shape[0]) - K @ H
    P = I_KH @ P @ I_KH.T + K @ R @ K.T
    return 0.5 * (P + P.T)


def covariance_recursion(P0, transitions, noises, measurements) -> np.ndarray:
    """The Riccati recursion in covariance form: the posterior covariances ``(K, n, n)``.

    Args:
        P0: (n, n) prior covariance at step 0.
        transitions, noises: sequences of length K; entry ``k >= 1`` is the step from ``k-1``
            to ``k`` (``P <- Phi P Phi' + Q``); entry 0 is ignored.
        measurements: sequence of length K; entry ``k``: a list of ``(H, R)`` applied at step
            ``k`` (Joseph form), possibly empty.
    """
    P = np.array(P0, dtype=float)
    out = np.empty((len(measurements),) + P.shape)
    for k, meas in enumerate(measurements):
        if k > 0:
            Phi = transitions[k]
            P = Phi @ P @ Phi.T + noises[k]
            P = 0.5 * (P + P.T)
        for H, R in meas:
            P = _joseph_update(P, H, R)
        out[k] = P
    return out


def information_recursion(P0, transitions, noises, measurements) -> np.ndarray:
    """The same recursion in information form (``Y = P^-1``; measurement: ``Y += H' R^-1 H``;
    prediction: ``Y <- M - M (M + Q^-1)^-1 M`` with ``M = Phi^-T Y Phi^-1``, which needs
    invertible ``Q``). Returns the covariances ``Y^-1`` (K, n, n); used by the tests as an
    independent check of :func:`covariance_recursion`."""
    Y = np.linalg.inv(np.asarray(P0, dtype=float))
    out = np.empty((len(measurements),) + Y.shape)
    for k, meas in enumerate(measurements):
        if k > 0:
            Phi_inv = np.linalg.inv(transitions[k])
            M = Phi_inv.T @ Y @ Phi_inv
            Y = M - M @ np.linalg.solve(M + np.linalg.inv(noises[k]), M)
            Y = 0.5 * (Y + Y.T)
        for H, R in meas:
            Y = Y + H.T @ np.linalg.solve(R, H)
        out[k] = np.linalg.inv(Y)
    return out


# ---------------------------------------------------------------------------------------------
# Which data an estimator reads
# ---------------------------------------------------------------------------------------------
def _configs(scenario):
    return {s.name: s for s in scenario.sensors}, {e.name: e for e in scenario.estimators}


def bound_sources(scenario, name: str) -> dict:
    """The raw sensors estimator ``name`` reads and the config that gives its prior:
    ``{"gyro": GyroConfig, "trackers": [StarTrackerConfig, ...], "prior_config": config,
    "notes": [...]}``. Raises :class:`NoBound` (the reason) where no bound is defined."""
    from drake_att.sensors.gyro_plugin import GyroConfig

    sensors, estimators = _configs(scenario)
    if name not in estimators:
        raise ValueError(f"{name}: not an estimator of {scenario.name}; estimators: {list(estimators)}")
    configs = _leaf_estimators(estimators, name)
    gyro_name, tracker_names = _gyro_and_tracker_names(name, configs)
    gyro = sensors.get(gyro_name)
    if not isinstance(gyro, GyroConfig):
        raise NoBound(f"{gyro_name} is not a !GyroConfig gyro")
    read = {gyro_name}
    raw = _raw_trackers(sensors, tracker_names, read)
    _require_unperturbed(scenario, read)
    notes = _model_gap_notes(gyro_name, gyro, raw)
    prior = next((c for c in configs if hasattr(c, "initial_attitude_sigma_deg")), configs[0])
    return {"gyro": gyro, "trackers": raw, "prior_config": prior, "notes": notes}


def _leaf_estimators(estimators, name, seen=()) -> list:
    """The non-fusing estimator configs under ``name`` (itself when it fuses nothing), depth first;
    a fusion cycle has no bound."""
    from drake_att.scenarios.selection import fused_sources

    c = estimators[name]
    if fused_sources(c):
        if name in seen:
            raise NoBound(f"{name}: a fusion cycle")
        out = []
        for s in fused_sources(c):
            out += _leaf_estimators(estimators, s, seen + (name,))
        return out
    return [c]


def _gyro_and_tracker_names(name, configs) -> tuple:
    """The one gyro and the star-tracker names (in reading order, repeats kept) the leaf
    estimators ``configs`` read; :class:`NoBound` for a camera, no gyro, no tracker or several gyros."""
    gyros, tracker_names = set(), []
    for c in configs:
        if getattr(c, "camera", None):
            raise NoBound(f"{c.name} reads a camera ({c.camera}): the camera's measurement model is not in the bound")
        gyro = getattr(c, "gyro", None)
        if not gyro:
            raise NoBound(
                f"{c.name} uses no gyro (its rate comes from a dynamics model); the bound is for gyro-driven estimation"
            )
        gyros.add(gyro)
        names = measurement_sensor_names(c)
        if not names:
            raise NoBound(f"{c.name} reads no star tracker")
        tracker_names += names
    if len(gyros) != 1:
        raise NoBound(f"{name} reads {len(gyros)} gyros {sorted(gyros)}; the bound handles one")
    return gyros.pop(), tracker_names


def _raw_trackers(sensors, tracker_names, read: set) -> list:
    """The distinct raw star-tracker configs behind ``tracker_names`` (an average expands to its
    inputs), first appearance first; adds every sensor name involved to ``read``."""
    from drake_att.sensors.star_tracker_average_plugin import StarTrackerAverageConfig
    from drake_att.sensors.star_tracker_plugin import StarTrackerConfig

    raw = []
    for n in tracker_names:
        s = sensors.get(n)
        read.add(n)
        if isinstance(s, StarTrackerAverageConfig):
            expanded = list(s.star_trackers)
            read.update(expanded)
        elif isinstance(s, StarTrackerConfig):
            expanded = [n]
        else:
            raise NoBound(f"{n} ({type(s).__name__}) has no measurement model in the bound")
        for e in expanded:
            if e not in [t.name for t in raw]:
                raw.append(sensors[e])
    return raw


def _require_unperturbed(scenario, read: set) -> None:
    """:class:`NoBound` when a fault injector or the correlated scale-factor / star-noise model
    acts on a sensor in ``read``: the bound assumes Gaussian, independent noise."""
    from drake_att.sensors.faults_plugin import SensorFaultsConfig
    from drake_att.sensors.scale_factor_star_noise_plugin import ScaleFactorStarNoiseConfig

    for s in scenario.sensors:
        if isinstance(s, SensorFaultsConfig) and s.sensor in read:
            raise NoBound(
                f"fault injection on {s.sensor} ({s.name}): faulted samples are not Gaussian; "
                "the bound is for fault-free data"
            )
        if isinstance(s, ScaleFactorStarNoiseConfig) and (s.gyro in read or s.star_tracker in read):
            raise NoBound(
                f"{s.name}: the gyro's per-step scale-factor error correlated with the star noise "
                "(paper S1) is not in the bound's model"
            )


def _model_gap_notes(gyro_name, gyro, raw) -> list:
    """Notes on effects the bound leaves out but that do not void it (deterministic gyro
    errors, unlogged vector-mode dropouts)."""
    notes = []
    if np.any(np.asarray(gyro.scale_factor_error_ppm) != 0) or np.any(np.asarray(gyro.misalignment_urad) != 0):
        notes.append(
            f"{gyro_name}'s scale-factor / misalignment errors are deterministic and not in the bound "
            "(estimators that do not model them sit above it)"
        )
    for t in raw:
        if t.mode == "vectors" and t.dropout_probability > 0:
            notes.append(
                f"{t.name}: vector-mode samples are not logged; the bound assumes none was dropped "
                f"(dropout_probability {t.dropout_probability}: the bound is slightly optimistic)"
            )
    return notes


def prior_covariance(sources: dict) -> tuple[np.ndarray, str]:
    """The bound's prior covariance (6x6) and a sentence saying where it comes from."""
    c, gyro = sources["prior_config"], sources["gyro"]
    att = getattr(c, "initial_attitude_sigma_deg", None)
    bias = getattr(c, "initial_bias_sigma_deg_per_h", None)
    where = f"{c.name}'s initial sigmas"
    if att is None or bias is None:
        where = f"{c.name} gives no initial sigma for " + ", ".join(
            n
            for n, v in (("the attitude (1 rad used)", att), ("the bias (max(|b0|, sigma_b0, 1 deg/h) used)", bias))
            if v is None
        )
    att_rad = 1.0 if att is None else att * DEG
    bias_rad = (
        max(float(np.max(np.abs(gyro.initial_bias_deg_per_h))), gyro.initial_bias_sigma_deg_per_h, 1.0)
        if bias is None
        else bias
    ) * DEG_PER_H
    return np.diag([att_rad**2] * 3 + [bias_rad**2] * 3), where


# ---------------------------------------------------------------------------------------------
# The bound of one run
# ---------------------------------------------------------------------------------------------
def _sample_index(times, grid):
    """For each grid time, the index of the sample at that time (|dt| < 1 us), or -1."""
    idx = np.clip(np.searchsorted(times, grid - TIME_TOLERANCE_S), 0, max(len(times) - 1, 0))
    if len(times) == 0:
        return np.full(len(grid), -1)
    return np.where(np.abs(times[idx] - grid) <= TIME_TOLERANCE_S, idx, -1)


def run_bound(run, name: str, prior_scale: float = 1.0) -> BoundResult:
    """The bound for estimator ``name`` on ``run`` (a :class:`~drake_att.scenarios.builder.RunLog`),
    with the prior covariance scaled by ``prior_scale``.

    Raises :class:`NoBound` where none is defined (the reason: no gyro, a camera, faults,
    a log without the gyro's or the trackers' samples or the truth at the gyro's instants)."""
    model = bound_model(run, name)
    return BoundResult(
        model["t"],
        covariance_recursion(prior_scale * model["P0"], model["transitions"], model["noises"], model["measurements"]),
        model["info"],
    )


def bound_model(run, name: str) -> dict:
    """The linear model of :func:`run_bound`: ``{"t", "P0", "transitions", "noises",
    "measurements", "info"}`` (the arguments of :func:`covariance_recursion`)."""
    return _linear_model(_model_inputs(run, name))


def _model_inputs(run, name: str) -> dict:
    """What the bound of ``name`` on ``run`` is a function of, read from the log (cheap, no
    per-step loop): the sources, the gyro's grid, the true attitudes on it, each raw tracker's
    grid instants with a usable sample and its sample counts, the prior and the info."""
    src = bound_sources(run.scenario, name)
    gyro = src["gyro"]
    grid = _gyro_grid(run, gyro)
    q_true = _true_attitudes(run, grid)
    used, counts = [], {}
    for st in src["trackers"]:
        if st.mode == "quaternion":
            ks, counts[st.name] = _quaternion_tracker_samples(run, st, grid)
        else:
            ks, counts[st.name] = _vector_tracker_samples(st, grid)
        used.append((st, ks))
    P0, prior_from = prior_covariance(src)
    info = {
        "gyro": gyro.name,
        "trackers": [t.name for t in src["trackers"]],
        "grid_period_s": float(gyro.period_s),
        "prior": prior_from,
        "gyro_arw_deg_per_rt_h": gyro.arw_deg_per_rt_h,
        "gyro_rrw_deg_per_h15": gyro.rrw_deg_per_h15,
        "tracker_samples": counts,
        "notes": list(src["notes"]),
    }
    return {"gyro": gyro, "grid": grid, "q_true": q_true, "used": used, "P0": P0, "info": info}


def _linear_model(inputs: dict) -> dict:
    """:func:`bound_model` from :func:`_model_inputs`: the per-interval transitions and noises
    and the per-instant measurement rows, in the trackers' order."""
    grid, q_true = inputs["grid"], inputs["q_true"]
    transitions, noises = _propagation(inputs["gyro"], grid, q_true)
    measurements: list[list] = [[] for _ in range(len(grid))]
    for st, ks in inputs["used"]:
        if st.mode == "quaternion":
            _quaternion_tracker_rows(st, ks, measurements)
        else:
            _vector_tracker_rows(st, ks, q_true, measurements)
    return {
        "t": grid,
        "P0": inputs["P0"],
        "transitions": transitions,
        "noises": noises,
        "measurements": measurements,
        "info": inputs["info"],
    }


# Recursions already computed in this process, by the digest of their inputs: the runs of a
# campaign whose truth and sensor validity do not depend on the seed (a fixed trajectory, noise
# varying) share one bound. A pure function's cache: a hit returns the very arrays a fresh
# computation gives. Each entry is 2 x K x 36 floats (K gyro steps); the oldest are dropped once
# the entries pass _RECURSIONS_BYTES (the newest is always kept): every estimator's bound of a
# scenario with several sensor sets (S3's five estimators, four sets) stays for the next run.
_RECURSIONS: dict = {}
_RECURSIONS_BYTES = 128 * 2**20


def _inputs_digest(inputs: dict) -> bytes:
    """A digest of everything :func:`_linear_model` and the prior read (configs by ``repr``,
    arrays by their bytes, shape and dtype)."""
    h = hashlib.blake2b(digest_size=32)
    for part in [repr(inputs["gyro"]), inputs["P0"], inputs["grid"], inputs["q_true"]] + [
        x for st, ks in inputs["used"] for x in (repr(st), ks)
    ]:
        if isinstance(part, str):
            h.update(part.encode())
        else:
            a = np.ascontiguousarray(part)
            h.update(f"{a.dtype.str}{a.shape}".encode())
            h.update(a.tobytes())
        h.update(b"|")
    return h.digest()


def _bound_and_loose(inputs: dict) -> tuple[np.ndarray, np.ndarray]:
    """The recursion's covariances with the prior ``P0`` and with ``PRIOR_SENSITIVITY_FACTOR P0``,
    each (K, 6, 6); reused from :data:`_RECURSIONS` when the inputs were seen."""
    key = _inputs_digest(inputs)
    hit = _RECURSIONS.get(key)
    if hit is not None:
        return hit
    model = _linear_model(inputs)
    args = (model["transitions"], model["noises"], model["measurements"])
    out = (
        covariance_recursion(model["P0"], *args),
        covariance_recursion(PRIOR_SENSITIVITY_FACTOR * model["P0"], *args),
    )
    _RECURSIONS[key] = out
    while len(_RECURSIONS) > 1 and sum(a.nbytes + b.nbytes for a, b in _RECURSIONS.values()) > _RECURSIONS_BYTES:
        _RECURSIONS.pop(next(iter(_RECURSIONS)))  # the oldest
    return out


def _gyro_grid(run, gyro) -> np.ndarray:
    """The gyro's sample instants (one per sample, the log may repeat one); NoBound unless every
    interval after the first instant has a usable sample."""
    gkey = f"{gyro.name}/gyro_measurement"
    if gkey not in run.signals:
        raise NoBound(f"the gyro's samples ({gkey}) are not logged")
    g = run.values(gkey)
    grid = np.asarray(run.times(gkey), dtype=float)
    keep = np.r_[True, np.diff(grid) > TIME_TOLERANCE_S]
    grid, g = grid[keep], g[keep]
    gyro_ok = (np.abs(g[:, 0] - grid) <= TIME_TOLERANCE_S) & (g[:, 1] > 0.5) & np.all(np.isfinite(g[:, 2:]), axis=1)
    if not np.all(gyro_ok[1:]):
        raise NoBound(
            f"{gyro.name} delivered {int(np.sum(~gyro_ok[1:]))} unusable samples; the bound assumes "
            "a gyro sample for every interval"
        )
    return grid


def _true_attitudes(run, grid) -> np.ndarray:
    """The logged true attitude quaternions at the grid's instants; NoBound where one is missing."""
    truth_key = run.metadata["truth"]["attitude"]
    tq = run.times(truth_key)
    it = _sample_index(np.asarray(tq, dtype=float), grid)
    if np.any(it < 0):
        raise NoBound(f"the truth is not logged at the gyro's instants (e.g. {grid[it < 0][:2]} s)")
    return run.values(truth_key)[it]


def _propagation(gyro, grid, q_true) -> tuple[list, list]:
    """The transitions and process noises of each gyro interval on the true trajectory (entry 0:
    None), with the gyro's TRUE noise; intervals of equal length share one noise covariance."""
    arw = gyro.arw_deg_per_rt_h * ARW_DEG_PER_RT_H
    rrw = gyro.rrw_deg_per_h15 * RRW_DEG_PER_H_15
    K = len(grid)
    transitions, noises = [None] * K, [None] * K
    phis = rot.quat_error_rotvec(q_true[:-1], q_true[1:])  # rotation of each interval, in B
    interval = {}
    for k in range(1, K):
        dt = grid[k] - grid[k - 1]
        Phi = transition_matrix(phis[k - 1] / dt, dt)
        transitions[k] = Phi
        c = interval.get(dt)
        if c is None:
            c = interval[dt] = FarrenkopfGyroNoise(arw, rrw, dt).interval_covariance()
        noises[k] = _step_noise(c, -Phi[:3, 3:])
    return transitions, noises


def _sample_counts(used: int, between, invalid: int) -> dict:
    """A tracker's entry of the bound's ``tracker_samples``."""
    return {"samples_used": used, "samples_between_gyro_samples": int(between), "samples_invalid": invalid}


def _quaternion_tracker_samples(run, st, grid) -> tuple[np.ndarray, dict]:
    """The grid indices at which quaternion tracker ``st`` has a valid sample, and its sample
    counts. NoBound when its samples are not logged."""
    key = f"{st.name}/star_tracker_measurement"
    if key not in run.signals:
        raise NoBound(f"{st.name}'s samples ({key}) are not logged")
    x = run.values(key)
    t_meas = x[:, 0]
    ok = (x[:, 1] > 0.5) & np.all(np.isfinite(x), axis=1)
    # one row per sample (the log may repeat a sample)
    first = np.r_[True, np.diff(t_meas) > TIME_TOLERANCE_S]
    t_s, ok_s = t_meas[first], ok[first]
    on_grid = _sample_index(t_s, grid)
    ks = np.flatnonzero(on_grid >= 0)
    ks = ks[ok_s[on_grid[ks]]]
    n_valid = int(np.sum(ok_s & (t_s <= grid[-1] + TIME_TOLERANCE_S)))
    n_invalid = int(np.sum(~ok_s & (t_s <= grid[-1] + TIME_TOLERANCE_S)))
    return ks, _sample_counts(len(ks), n_valid - len(ks), n_invalid)


def _quaternion_tracker_rows(st, ks, measurements) -> None:
    """Appends quaternion tracker ``st``'s ``(H, R)`` to ``measurements[k]`` for each ``k`` in ``ks``."""
    R_SB = rot.quat_to_rotmat(_mounting(st)).T
    H = np.hstack([R_SB, np.zeros((3, 3))])
    sig = (
        np.array([st.sigma_cross_boresight_arcsec, st.sigma_cross_boresight_arcsec, st.sigma_boresight_arcsec]) * ARCSEC
    )
    R = np.diag(sig**2)
    for k in ks:
        measurements[k].append((H, R))


def _vector_tracker_samples(st, grid) -> tuple[np.ndarray, dict]:
    """The grid indices at which vector tracker ``st`` samples outside its outage windows (its
    samples are not logged: they follow from its period), and its sample counts."""
    windows = np.reshape(st.outage_windows_s, (-1, 2))
    n_samples = int(np.floor(grid[-1] / st.period_s + 1e-9)) + 1
    t_s = np.arange(n_samples) * st.period_s
    out = np.zeros(n_samples, dtype=bool)
    for a, b in windows:
        out |= (a <= t_s) & (t_s < b)
    on_grid = _sample_index(t_s, grid)
    ks = np.flatnonzero(on_grid >= 0)
    ks = ks[~out[on_grid[ks]]]
    n_invalid = int(np.sum(out))
    return ks, _sample_counts(len(ks), n_samples - n_invalid - len(ks), n_invalid)


def _vector_tracker_rows(st, ks, q_true, measurements) -> None:
    """Appends the ``(H, R)`` of each of vector tracker ``st``'s directions, at the TRUE attitude,
    to ``measurements[k]`` for each ``k`` in ``ks``."""
    R_SB = rot.quat_to_rotmat(_mounting(st)).T
    refs = np.asarray(st.references_I, dtype=float)
    refs = refs / np.linalg.norm(refs, axis=1, keepdims=True)
    sigma = st.sigma_vector_urad * 1e-6
    for k in ks:
        R_BI = rot.quat_to_rotmat(q_true[k]).T
        for r in refs:
            b_B = R_BI @ r
            H = np.hstack([R_SB @ rot.skew(b_B), np.zeros((3, 3))])
            measurements[k].append((H, sigma**2 * np.eye(3)))


def _mounting(st):
    from drake_att.sensors.star_tracker_plugin import star_tracker_mounting

    return star_tracker_mounting(st)


def bound_for_estimator(run, name: str, t_est, score_from_s: float, cache: dict | None = None):
    """The bound of estimator ``name`` on its own estimate times ``t_est``.

    Returns ``(sigma (n, 6) or None, window_variance (6,) or None, info dict)``:
    ``window_variance`` is the mean over ``t_est >= score_from_s`` of the bound's variances
    (its square root is the bound on the RMSE over the window); ``info`` has ``reason``
    (None when defined), ``prior_sensitivity`` (max relative change of the window variances
    with a 100x prior covariance) and :attr:`BoundResult.info`. ``cache`` (a dict, one per
    run) shares the computation between estimators that read the same sensors with the same
    prior covariance (the "prior" sentence in ``info`` names the first of them). Across runs,
    the recursions are reused when their inputs are the same bytes (:data:`_RECURSIONS`)."""
    try:
        src = bound_sources(run.scenario, name)
        key = (src["gyro"].name, tuple(t.name for t in src["trackers"]), prior_covariance(src)[0].tobytes())
        if cache is not None and key in cache:
            result, loose = cache[key]
        else:
            inputs = _model_inputs(run, name)
            P, P_loose = _bound_and_loose(inputs)
            result, loose = BoundResult(inputs["grid"], P, inputs["info"]), BoundResult(inputs["grid"], P_loose)
            if cache is not None:
                cache[key] = (result, loose)
    except NoBound as e:
        return None, None, {"reason": str(e)}
    t_est = np.asarray(t_est, dtype=float)
    try:
        P = result.at(t_est)
    except ValueError as e:
        return None, None, {"reason": f"{name}: {e}"}
    var = np.einsum("kii->ki", P)
    m = t_est >= score_from_s - TIME_TOLERANCE_S
    info = dict(result.info, reason=None, prior_sensitivity=None)
    if not np.any(m):
        return np.sqrt(np.maximum(var, 0.0)), None, info
    window = var[m].mean(axis=0)
    loose_window = np.einsum("kii->ki", loose.at(t_est[m])).mean(axis=0)
    info["prior_sensitivity"] = float(np.max(np.abs(loose_window / window - 1.0)))
    return np.sqrt(np.maximum(var, 0.0)), window, info
