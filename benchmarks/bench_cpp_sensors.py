#!/usr/bin/env python3
"""Measured gain of a gyro and a star tracker built from Drake's C++ primitives over the shipped
Python sensors ("sensors evaluated in C++ where Drake's primitives can express them
exactly").

    .venv/bin/python benchmarks/bench_cpp_sensors.py                  # checks + callgrind counts (~3 min)
    .venv/bin/python benchmarks/bench_cpp_sensors.py --no-callgrind   # checks + CPU time instead
    .venv/bin/python benchmarks/bench_cpp_sensors.py --skip-checks --cases baseline,cpp_gyro

Every diagram is the S3 truth plant (``RigidBodyAttitudePlant`` with the
``cubesat_single_star_tracker`` inertia, initial state and constant disturbance torque, fixed
RK3 steps of 0.1 s as that scenario's ``simulation:``) with C++ loggers of ``q_IB`` and
``w_IB_B`` every T = 0.1 s, plus at most the sensors of one case, each logged every T:

* ``py_gyro``: the shipped :class:`drake_att.systems.gyro.Gyro` (S3: ARW 0.56 deg/rt-h, RRW
  123.75 deg/h^1.5, bias 12 deg/h) with its seed port (``AddRandomInputs``); logged:
  ``gyro_measurement`` and ``bias_B``.
* ``cpp_gyro``: the same Farrenkopf model from Drake primitives: ``RandomSource`` (6 Gaussians
  every T) and the plant's ``w_IB_B_integral`` into a ``Multiplexer``, then ONE discrete
  ``AffineSystem`` (period T) whose state is ``[n, integral at the previous sample (3),
  offset = B_(n-1) + e_n (3), B_n (3)]`` and whose output is ``[t_n, 1, w_meas (3), B_n (3)]``
  (``w_meas = (integral_n - integral_(n-1)) / T + offset``), split by a ``Demultiplexer``. The
  noise ``(e_n, db_n)`` per axis is the Cholesky factor of
  ``FarrenkopfGyroNoise.interval_covariance()`` times two standard normals. (The affine system
  holds the integral itself: no separate ``ZeroOrderHold``. Its output has no feedthrough of the
  draws, so a filter updating at t_k reads what the logger records at t_k.)
* ``py_tracker``: the shipped :class:`drake_att.systems.star_tracker.StarTracker` (quaternion
  mode, 5"/5"/50", S3 tracker 1's mounting q_BS); logged: ``star_tracker_measurement``.
* ``cpp_tracker``: ``RandomSource`` (3 Gaussians every T) through a ``ZeroOrderHold`` (so that
  a filter's discrete update at t_k reads the sample the logger records at t_k: the source redraws
  in the unrestricted-update phase, before the discrete updates of the same instant) and ``q_IB``
  into ONE ``SymbolicVectorSystem`` whose output is ``[t_n, 1, canonical((q_IB ⊗ q_BS) ⊗
  exp(diag(sigmas) z / 2))]`` (exact exponential map: sqrt, sin and cos of the half angle, with
  the Python code's small-angle branch; ``t_n`` from the symbolic time with ``ceil``,
  bit-identical to the Python stamp). ``cpp_tracker_split``: the same from three systems:
  ``exp(...)`` of the held draw (a ``SymbolicVectorSystem``), ``q_BS ⊗`` it (a ``MatrixGain``),
  then ``canonical(q_IB ⊗ .)`` and the stamp (a second ``SymbolicVectorSystem``): Drake
  evaluates an expression tree without sharing repeated subexpressions (and squares by
  ``std::pow``), so in one system each output element evaluates the four elements of ``exp(.)``
  twice (once more for the canonical sign), each with its square root and sin or cos. ``cpp_tracker_floor`` (not a sensor): ``cpp_tracker``'s systems with a
  trivial output ``[0, 1, q_IB]``, the least any one-system symbolic tracker costs here.
  None can be stateless or discrete: in pydrake 1.51.1 a ``SymbolicVectorSystem`` without
  continuous state, in a diagram with continuous state, aborts in ``DoCalcTimeDerivatives``
  (``DRAKE_DEMAND(time_period_ == 0.0)`` / ``dynamics_.size() > 0``; the diagram calls it for
  every subsystem). Each has one dummy continuous state with derivative 0 (its cost is in the
  counts: three derivative calls per RK3 step).
* ``py_both`` / ``cpp_both``: gyro and tracker (split) together.
* ``shipped``: bench_ab.py's "S3 single tracker, 10 Hz gyro + ST + MEKF" scenario (for scale);
  ``shipped_cpp_gyro``: the same with the gyro plug-in's build function replaced, in the child
  process only, by the C++ gyro (the MEKF reads it; no file changes): the end-to-end figure.

Part 1 (unless ``--skip-checks``) runs the Python and C++ sensors side by side on one truth
and prints checks with PASS/FAIL: a noise-free run where the C++ and Python outputs must agree to
round-off; at the S3 noise (``--samples`` = 20000 samples), the C++ outputs against the model
evaluated in numpy on the draws they used (logged), what a discrete update at t_k reads (a C++
hold) against what the logger records at t_k, and the statistics of each sensor against its
model and the C++ against the Python ones (tolerance: 4 standard errors); the same statistics
with a large RRW (so that the correlation of the interval noise and the bias increment, 0.003 at
S3's numbers, is 0.6 and its check has power).

Part 2 runs each case in a child process of this script under ``valgrind --tool=callgrind
--instr-atstart=no``; the child builds the diagram, runs a warm-up (seed 1), then counts the
instructions of ``simulator.AdvanceTo(duration)`` alone (fresh context, seed 2; context
creation and ``Initialize`` are outside the count) by ``callgrind_control -i on/off``. The
table gives instructions per 0.1-s step and the sensor's cost per sample = (case - baseline) /
samples. Instruction counts do not depend on machine load (the children run with
``PYTHONHASHSEED=0``; repeated runs agreed to 0.1%); ``--no-callgrind`` times the same call with
``time.process_time`` (best of ``--repeats``) instead.

Reading it: the C++ gyro's own cost includes a cost that grows with the diagram. Its
RandomSource redraws in a per-sample unrestricted update, which Drake applies as a change of the
whole state: every state-dependent cache entry of the diagram is notified and invalidated (in
callgrind_annotate of ``shipped`` against ``shipped_cpp_gyro``, 50 s each,
``DependencyTracker::NotifySubscribers`` grows by ~70k instructions per step). The shipped Python
sensors draw with no per-sample event. So ``shipped_cpp_gyro`` saves less than the gyro line of
the table.

What the C++ versions do not reproduce (by design or because no primitive expresses it): the
noise streams (Drake's ``RandomSource`` draws std::normal_distribution from a seed that
``SetRandomContext`` hands out in subsystem order, not the counter-based (seed, sensor name,
sample index) streams of the shipped sensors); sample 0 (t = 0: the Python gyro gives
``w_IB_B(0) + B_0 + e_0``, the affine system, with no interval before t = 0, ``B_0``; the C++
tracker's hold starts at 0, so its sample 0 has no noise); outputs read between sample instants
(the Python gyro divides by the elapsed time, the C++ one by T); the gyro stamp is ``T n`` (one
rounding) instead of ``(n - 1) T + T`` (<= 1 ulp apart); the per-context noise parameters
(``set_model`` / ``set_noise``: the C++ noise levels are matrices and constants of the diagram),
a random initial bias (``configure_random_state`` of the affine system could), dropouts and
outages (a symbolic comparison with a uniform draw), misalignment and scale-factor errors (a
constant matrix in the affine system) and the gyro's ``scale_error`` input (a division by ``1 +
s_k``: not affine; symbolic). None of these is used by the S3 cases measured here.
"""

from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import time
from types import SimpleNamespace

import numpy as np

T = 0.1  # s: sensor period, logger period and integration step
SCENARIO = "cubesat_single_star_tracker"
S3_ARW_DEG_PER_RT_H, S3_RRW_DEG_PER_H15, S3_BIAS_DEG_PER_H = 0.56, 123.75, 12.0  # paper S3's gyro
SIGMA_CROSS_ARCSEC, SIGMA_BORESIGHT_ARCSEC = 5.0, 50.0  # paper S3's tracker
TOL_SE = 4.0  # a statistical check passes within this many standard errors

CASES = {  # case -> sensors in its diagram
    "baseline": (),
    "py_gyro": ("py_gyro",),
    "cpp_gyro": ("cpp_gyro",),
    "cpp_gyro_flat": ("cpp_gyro_flat",),
    "py_tracker": ("py_tracker",),
    "cpp_tracker": ("cpp_tracker",),
    "cpp_tracker_split": ("cpp_tracker_split",),
    "cpp_tracker_floor": ("cpp_tracker_floor",),  # cpp_tracker's systems with a trivial output
    "py_both": ("py_gyro", "py_tracker"),
    "cpp_both": ("cpp_gyro", "cpp_tracker_split"),
    "shipped": None,  # bench_ab.py's S3 single-tracker 10 Hz scenario
    "shipped_cpp_gyro": None,  # the same with the C++ gyro (the gyro plug-in replaced in the child)
}


# ---------------------------------------------------------------------------------------------
# Diagrams
# ---------------------------------------------------------------------------------------------


def s3_numbers():
    """The S3 scenario and the SI numbers the sensors use."""
    from drake_att.scenarios.library import load
    from drake_att.sensors.star_tracker_plugin import star_tracker_mounting
    from drake_att.units import ARCSEC, ARW_DEG_PER_RT_H, DEG_PER_H, RRW_DEG_PER_H_15

    scenario = load(SCENARIO)
    st1 = next(s for s in scenario.sensors if s.name == "st1")
    return SimpleNamespace(
        scenario=scenario,
        arw=S3_ARW_DEG_PER_RT_H * ARW_DEG_PER_RT_H,
        rrw=S3_RRW_DEG_PER_H15 * RRW_DEG_PER_H_15,
        bias0=np.full(3, S3_BIAS_DEG_PER_H * DEG_PER_H),
        sigmas=np.array([SIGMA_CROSS_ARCSEC, SIGMA_CROSS_ARCSEC, SIGMA_BORESIGHT_ARCSEC]) * ARCSEC,
        q_BS=star_tracker_mounting(st1),
    )


def interval_factor(arw: float, rrw: float) -> np.ndarray:
    """Lower-triangular ``L`` with ``L L' = FarrenkopfGyroNoise(arw, rrw, T).interval_covariance()``
    (per axis: ``(e_n, db_n) = L z``, ``z`` two standard normals); zeros for a noise-free gyro."""
    from drake_att.noise import FarrenkopfGyroNoise

    cov = FarrenkopfGyroNoise(arw, rrw, T).interval_covariance()
    return np.linalg.cholesky(cov) if np.any(cov) else np.zeros((2, 2))


def cpp_gyro_matrices(L: np.ndarray, bias0: np.ndarray):
    """The discrete ``AffineSystem`` of the C++ gyro (period T).

    State x (10): ``[n, I_held (3), offset (3), B (3)]``; input u (9): ``[I (3), z1 (3), z2 (3)]``
    (the plant's rate integral, then the RandomSource's 6 standard normals). Update at
    ``t_k = k T`` (after the source's redraw at ``t_k``, which the update reads):
    ``n' = n + 1``, ``I_held' = I``, ``offset' = B + L11 z1``, ``B' = B + L21 z1 + L22 z2``.
    Output ``[T n, 1, (I - I_held) / T + offset, B]``: read at ``t_n`` (before that instant's
    updates, as loggers and discrete-update readers do) it is sample n, ``[t_n, 1, mean rate over
    (t_(n-1), t_n] + B_(n-1) + e_n, B_n]``. Initial state ``[0, 0, B_0, B_0]``.
    """
    i3 = np.eye(3)
    A = np.zeros((10, 10))
    A[0, 0] = 1.0
    A[4:7, 7:10] = i3
    A[7:10, 7:10] = i3
    B = np.zeros((10, 9))
    B[1:4, 0:3] = i3
    B[4:7, 3:6] = L[0, 0] * i3
    B[7:10, 3:6] = L[1, 0] * i3
    B[7:10, 6:9] = L[1, 1] * i3
    f0 = np.zeros(10)
    f0[0] = 1.0
    C = np.zeros((8, 10))
    C[0, 0] = T
    C[2:5, 1:4] = -i3 / T
    C[2:5, 4:7] = i3
    C[5:8, 7:10] = i3
    D = np.zeros((8, 9))
    D[2:5, 0:3] = i3 / T
    y0 = np.zeros(8)
    y0[1] = 1.0
    x0 = np.concatenate([[0.0], np.zeros(3), bias0, bias0])
    return A, B, f0, C, D, y0, x0


def add_cpp_gyro_systems(builder, prefix: str, arw: float, rrw: float, bias0):
    """Add the C++ gyro's systems (period T) to ``builder``: RandomSource -> Multiplexer (with the
    integral) -> AffineSystem (:func:`cpp_gyro_matrices`) -> Demultiplexer. Returns the ports
    ``(w_IB_B_integral input, gyro_measurement (5), bias_B (3), noise (6, the draws))``."""
    from pydrake.common import RandomDistribution
    from pydrake.systems.primitives import AffineSystem, Demultiplexer, Multiplexer, RandomSource

    A, B, f0, C, D, y0, x0 = cpp_gyro_matrices(interval_factor(arw, rrw), np.asarray(bias0, dtype=float))
    noise = builder.AddNamedSystem(f"{prefix}noise", RandomSource(RandomDistribution.kGaussian, 6, T))
    mux = builder.AddNamedSystem(f"{prefix}inputs", Multiplexer([3, 6]))
    affine = builder.AddNamedSystem(f"{prefix}model", AffineSystem(A, B, f0, C, D, y0, T))
    affine.configure_default_state(x0)  # SetRandomContext keeps it (no random-state covariance)
    split = builder.AddNamedSystem(f"{prefix}split", Demultiplexer([5, 3]))
    builder.Connect(noise.get_output_port(), mux.get_input_port(1))
    builder.Connect(mux.get_output_port(), affine.get_input_port())
    builder.Connect(affine.get_output_port(), split.get_input_port())
    return mux.get_input_port(0), split.get_output_port(0), split.get_output_port(1), noise.get_output_port()


def make_cpp_gyro(name: str, arw: float, rrw: float, bias0):
    """The C++ gyro as one Diagram with the shipped gyro's ports: input ``w_IB_B_integral``;
    outputs ``gyro_measurement``, ``bias_B`` and ``noise`` (the draws, for the checks)."""
    from pydrake.systems.framework import DiagramBuilder

    builder = DiagramBuilder()
    integral, measurement, bias, noise = add_cpp_gyro_systems(builder, "", arw, rrw, bias0)
    builder.ExportInput(integral, "w_IB_B_integral")
    builder.ExportOutput(measurement, "gyro_measurement")
    builder.ExportOutput(bias, "bias_B")
    builder.ExportOutput(noise, "noise")
    diagram = builder.Build()
    diagram.set_name(name)
    return diagram


def use_cpp_gyro_plugin() -> None:
    """In this process, make the scenario builder's gyro plug-in build :func:`make_cpp_gyro`
    (for the ``shipped_cpp_gyro`` case; S3's gyro: no random initial bias, scale factor or
    misalignment, period T)."""
    import dataclasses

    from drake_att.scenarios import registry
    from drake_att.sensors.gyro_plugin import gyro_model_si

    def build(ctx, c):
        arw, rrw, bias0, bias_sigma, scale, misalignment = gyro_model_si(c)
        if c.period_s != T or bias_sigma or np.any(scale) or np.any(misalignment):
            raise ValueError(
                f"{c.name}: the C++ gyro here models period {T} s and no random bias, scale or misalignment"
            )
        gyro = ctx.builder.AddSystem(make_cpp_gyro(c.name, arw, rrw, bias0))
        ctx.builder.Connect(ctx.truth.GetOutputPort("w_IB_B_integral"), gyro.GetInputPort("w_IB_B_integral"))
        return gyro

    plugins = registry._PLUGINS[registry.SENSOR]
    plugins["GyroConfig"] = dataclasses.replace(plugins["GyroConfig"], build=build)


def _quat_product(p, q):
    """Hamilton product ``p ⊗ q`` of two 4-sequences (floats or symbolic expressions)."""
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    return [
        pw * qw - px * qx - py * qy - pz * qz,
        pw * qx + px * qw + py * qz - pz * qy,
        pw * qy - px * qz + py * qw + pz * qx,
        pw * qz + px * qy - py * qx + pz * qw,
    ]


def left_product_matrix(p) -> np.ndarray:
    """``L(p)`` with ``p ⊗ q = L(p) q`` (wxyz)."""
    pw, px, py, pz = (float(c) for c in p)
    return np.array([[pw, -px, -py, -pz], [px, pw, -pz, py], [py, pz, pw, -px], [pz, -py, px, pw]])


def exp_half(sigmas, z):
    """``exp(diag(sigmas) z / 2)`` (quaternion) as symbolic expressions of the 3 normals ``z``:
    ``rotations.rotvec_to_quat``'s formula, with its small-angle branch, as the Python tracker."""
    from pydrake.symbolic import cos, if_then_else, sin, sqrt

    from drake_att.rotations import _SMALL_ANGLE

    if not np.any(sigmas):  # noise-free (checks): exp(0) = 1 (the symbolic 0 / 0 would throw)
        return [1.0, 0.0, 0.0, 0.0]
    x, y, w = (float(sigmas[i]) * z[i] for i in range(3))
    a = sqrt(x * x + y * y + w * w)
    k = if_then_else(a < _SMALL_ANGLE, 0.5 - a * a / 48.0, sin(0.5 * a) / a)
    return [cos(0.5 * a), k * x, k * y, k * w]


def tracker_quaternion(q, q_BS, dq):
    """``canonical((q ⊗ q_BS) ⊗ dq)`` (symbolic ``q``; the Python tracker computes ``q ⊗ (q_BS ⊗ dq)``,
    the same to round-off): associated so that each output holds each ``dq`` element once (Drake
    evaluates an expression tree without sharing its repeated subexpressions)."""
    return canonical(_quat_product(_quat_product(q, [float(c) for c in q_BS]), dq))


def tracker_stamp(t):
    """The Python tracker's stamp of the sample an output at ``t`` carries: ``n = ceil(t / T - 1e-9)``,
    ``(n - 1) T + T`` (0 for ``n = 0``), symbolic."""
    from pydrake.symbolic import ceil, if_then_else

    n = ceil(t / T - 1e-9)
    return if_then_else(n > 0.5, (n - 1.0) * T + T, 0.0)


def canonical(q):
    """``q`` with its scalar part made >= 0 (symbolic)."""
    from pydrake.symbolic import if_then_else

    sign = if_then_else(q[0] < 0.0, -1.0, 1.0)
    return [sign * c for c in q]


def build(sensors, gyro_noise=None, tracker_sigmas=None, check_logs=False):
    """The truth plant, its loggers and ``sensors`` (names of ``CASES``' sensors), each logged.

    ``gyro_noise``: ``(arw, rrw)`` (default S3's); ``tracker_sigmas``: (3,) rad (default S3's).
    Returns a namespace with ``diagram``, ``plant``, ``loggers`` (key -> logger) and ``numbers``.
    """
    from pydrake.common import RandomDistribution
    from pydrake.symbolic import Expression, Variable
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import (
        AddRandomInputs,
        ConstantVectorSource,
        LogVectorOutput,
        MatrixGain,
        Multiplexer,
        RandomSource,
        SymbolicVectorSystem,
        ZeroOrderHold,
    )

    from drake_att.systems.gyro import Gyro
    from drake_att.systems.plant import RigidBodyAttitudePlant
    from drake_att.systems.randomness import RANDOM_SOURCE_SAMPLING_INTERVAL_S
    from drake_att.systems.star_tracker import StarTracker

    num = s3_numbers()
    arw, rrw = (num.arw, num.rrw) if gyro_noise is None else gyro_noise
    sigmas = num.sigmas if tracker_sigmas is None else np.asarray(tracker_sigmas, dtype=float)
    p = num.scenario.plant
    builder = DiagramBuilder()
    inertia = np.asarray(p.inertia_kg_m2, dtype=float)
    plant = builder.AddSystem(RigidBodyAttitudePlant(inertia if inertia.size == 3 else inertia.reshape(3, 3)))
    torque = builder.AddNamedSystem(
        "disturbance_torque", ConstantVectorSource(np.asarray(p.disturbance_torque_N_m, float))
    )
    builder.Connect(torque.get_output_port(), plant.GetInputPort("torque_B"))
    loggers = {}

    def log(key, port):
        loggers[key] = LogVectorOutput(port, builder, T)
        if check_logs and not key.startswith("truth/") and not key.endswith(("/noise", "/bias_B")):
            # What a discrete update at t_k (a filter) reads, logged at t_(k+1): a C++ hold.
            reader = builder.AddNamedSystem(f"{key.replace('/', '_')}_reader", ZeroOrderHold(T, port.size()))
            builder.Connect(port, reader.get_input_port())
            loggers[f"{key}@update"] = LogVectorOutput(reader.get_output_port(), builder, T)

    log("truth/q_IB", plant.GetOutputPort("q_IB"))
    log("truth/w_IB_B", plant.GetOutputPort("w_IB_B"))
    if check_logs:  # checks only (not in the timed cases); the C++ sources' draws below too
        log("truth/w_IB_B_integral", plant.GetOutputPort("w_IB_B_integral"))
    for sensor in sensors:
        if sensor == "py_gyro":
            gyro = builder.AddSystem(Gyro("gyro", T, arw, rrw, num.bias0))
            builder.Connect(plant.GetOutputPort("w_IB_B"), gyro.GetInputPort("w_IB_B"))
            builder.Connect(plant.GetOutputPort("w_IB_B_integral"), gyro.GetInputPort("w_IB_B_integral"))
            log("py_gyro/gyro_measurement", gyro.GetOutputPort("gyro_measurement"))
            log("py_gyro/bias_B", gyro.GetOutputPort("bias_B"))
        elif sensor == "cpp_gyro":  # one Diagram, as a plug-in would build it
            gyro = builder.AddSystem(make_cpp_gyro("gyro_cpp", arw, rrw, num.bias0))
            builder.Connect(plant.GetOutputPort("w_IB_B_integral"), gyro.GetInputPort("w_IB_B_integral"))
            log("cpp_gyro/gyro_measurement", gyro.GetOutputPort("gyro_measurement"))
            log("cpp_gyro/bias_B", gyro.GetOutputPort("bias_B"))
            if check_logs:
                log("cpp_gyro/noise", gyro.GetOutputPort("noise"))
        elif sensor == "cpp_gyro_flat":  # the same systems directly in the top diagram
            integral, measurement, bias, _ = add_cpp_gyro_systems(builder, "gyro_flat_", arw, rrw, num.bias0)
            builder.Connect(plant.GetOutputPort("w_IB_B_integral"), integral)
            log("cpp_gyro_flat/gyro_measurement", measurement)
            log("cpp_gyro_flat/bias_B", bias)
        elif sensor == "py_tracker":
            st = builder.AddSystem(StarTracker("st1", T, num.q_BS, "quaternion", sigmas[0], sigmas[2]))
            builder.Connect(plant.GetOutputPort("q_IB"), st.GetInputPort("q_IB"))
            log("py_tracker/star_tracker_measurement", st.GetOutputPort("star_tracker_measurement"))
        elif sensor in ("cpp_tracker", "cpp_tracker_split", "cpp_tracker_floor"):
            # Each SymbolicVectorSystem has ONE dummy continuous state (derivative 0): in pydrake
            # 1.51.1 a SymbolicVectorSystem without continuous state (stateless, or discrete with
            # time_period > 0) in a diagram with continuous state aborts in its
            # DoCalcTimeDerivatives (DRAKE_DEMAND time_period_ == 0 / dynamics_.size() > 0): the
            # Diagram calls it for every subsystem.
            t = Variable("t")
            q = [Variable(f"q{i}") for i in range(4)]
            z = [Variable(f"z{i}") for i in range(3)]
            noise = builder.AddNamedSystem(f"{sensor}_noise", RandomSource(RandomDistribution.kGaussian, 3, T))
            # The draw through a C++ hold: the RandomSource redraws in the unrestricted-update
            # phase, before the discrete updates of the same instant, so without the hold a filter
            # updating at t_k would read sample k+1's noise while the logger (a publish at t_k)
            # records sample k's. Held, both read the draw of t_(k-1) (as the Python tracker's
            # sample k). Sample 0 then has no noise (the hold starts at 0).
            hold = builder.AddNamedSystem(f"{sensor}_hold", ZeroOrderHold(T, 3))
            builder.Connect(noise.get_output_port(), hold.get_input_port())
            mux = builder.AddNamedSystem(
                f"{sensor}_inputs", Multiplexer([4, 4] if sensor == "cpp_tracker_split" else [4, 3])
            )
            builder.Connect(plant.GetOutputPort("q_IB"), mux.get_input_port(0))
            if sensor != "cpp_tracker_split":  # one system: the whole formula in its output
                # (cpp_tracker_floor, not a sensor: the same systems with a trivial output, the
                # least any one-system symbolic tracker costs here)
                output = (
                    [0.0 * t, 1.0, q[0] + 0.0 * z[0], q[1], q[2], q[3]]
                    if sensor == "cpp_tracker_floor"
                    else [tracker_stamp(t), 1.0] + tracker_quaternion(q, num.q_BS, exp_half(sigmas, z))
                )
                rotation = builder.AddNamedSystem(
                    sensor,
                    SymbolicVectorSystem(
                        time=t, state=[Variable("unused")], input=q + z, dynamics=[Expression(0.0)], output=output
                    ),
                )
                builder.Connect(hold.get_output_port(), mux.get_input_port(1))
            else:  # exp(delta / 2) of the draw, q_BS ⊗ it (a C++ MatrixGain), then the product
                r = [Variable(f"r{i}") for i in range(4)]
                exp_map = builder.AddNamedSystem(
                    f"{sensor}_exp",
                    SymbolicVectorSystem(
                        state=[Variable("unused")], input=z, dynamics=[Expression(0.0)], output=exp_half(sigmas, z)
                    ),
                )
                mounting = builder.AddNamedSystem(f"{sensor}_mounting", MatrixGain(left_product_matrix(num.q_BS)))
                rotation = builder.AddNamedSystem(
                    sensor,
                    SymbolicVectorSystem(
                        time=t,
                        state=[Variable("unused")],
                        input=q + r,
                        dynamics=[Expression(0.0)],
                        output=[tracker_stamp(t), 1.0] + canonical(_quat_product(q, r)),
                    ),
                )
                builder.Connect(hold.get_output_port(), exp_map.get_input_port())
                builder.Connect(exp_map.get_output_port(), mounting.get_input_port())
                builder.Connect(mounting.get_output_port(), mux.get_input_port(1))
            builder.Connect(mux.get_output_port(), rotation.get_input_port())
            log(f"{sensor}/star_tracker_measurement", rotation.get_output_port())
            if check_logs:
                log(f"{sensor}/noise", noise.get_output_port())
        else:
            raise ValueError(f"unknown sensor {sensor!r}")
    AddRandomInputs(RANDOM_SOURCE_SAMPLING_INTERVAL_S, builder)  # the Python sensors' seed ports
    diagram = builder.Build()
    return SimpleNamespace(diagram=diagram, plant=plant, loggers=loggers, numbers=num)


def make_simulator(bench, seed: int):
    """A fresh context (randomized by ``seed``, the S3 initial state) and an initialized simulator
    with the scenario's fixed-step RK3."""
    from pydrake.common import RandomGenerator

    from drake_att.scenarios.build_context import attitude_from_rpy_deg
    from drake_att.units import DEG

    scenario = bench.numbers.scenario
    context = bench.diagram.CreateDefaultContext()
    bench.diagram.SetRandomContext(context, RandomGenerator(seed))  # resets states: set them after it
    plant_context = bench.plant.GetMyMutableContextFromRoot(context)
    bench.plant.SetDefaultParametersAndState(plant_context)
    p = scenario.plant
    bench.plant.SetInitialState(
        plant_context,
        attitude_from_rpy_deg(scenario, p.initial_attitude_rpy_deg),
        np.asarray(p.initial_rate_deg_per_s) * DEG,
    )
    return configured_simulator(bench.diagram, context, scenario.simulation)


def configured_simulator(diagram, context, sc):
    from pydrake.systems.analysis import ApplySimulatorConfig, Simulator, SimulatorConfig

    simulator = Simulator(diagram, context)
    ApplySimulatorConfig(
        SimulatorConfig(
            integration_scheme=sc.integration_scheme,
            max_step_size=sc.max_step_size_s,
            accuracy=sc.accuracy,
            use_error_control=sc.use_error_control,
            target_realtime_rate=0.0,
            publish_every_time_step=False,
        ),
        simulator,
    )
    simulator.Initialize()
    return simulator


def run(bench, seed: int, duration: float) -> dict:
    simulator = make_simulator(bench, seed)
    simulator.AdvanceTo(duration)
    context = simulator.get_context()
    out = {}
    for key, logger in bench.loggers.items():
        log = logger.FindLog(context)
        out[key] = (log.sample_times().copy(), log.data().T.copy())
    return out


# ---------------------------------------------------------------------------------------------
# Part 1: statistical and deterministic checks
# ---------------------------------------------------------------------------------------------


class Checks:
    def __init__(self):
        self.failed = 0
        self.total = 0

    def __call__(self, label: str, ok: bool, detail: str):
        self.total += 1
        self.failed += not ok
        print(f"  [{'PASS' if ok else 'FAIL'}] {label}: {detail}")


def gyro_interval_noise(logs, prefix):
    """Per sample n >= 1: ``e_n = w_n - (I_n - I_(n-1)) / T - B_(n-1)`` and ``db_n = B_n - B_(n-1)``
    (N, 3 each) from the logged measurement and bias and the logged rate integral."""
    _, m = logs[f"{prefix}/gyro_measurement"]
    _, b = logs[f"{prefix}/bias_B"]
    _, integral = logs["truth/w_IB_B_integral"]
    mean_rate = np.diff(integral, axis=0) / T
    return m[1:, 2:5] - mean_rate - b[:-1], np.diff(b, axis=0), m, b


def lag1(x):
    x = x - x.mean()
    return float(x[1:] @ x[:-1] / (x @ x))


def check_gyro_statistics(check: Checks, logs, arw, rrw, title):
    from drake_att.noise import FarrenkopfGyroNoise

    cov = FarrenkopfGyroNoise(arw, rrw, T).interval_covariance()
    ve, c, vd = cov[0, 0], cov[0, 1], cov[1, 1]
    print(
        f"\n{title}: model per axis var(e) = {ve:.4e} (rad/s)^2, var(db) = {vd:.4e}, cov(e, db) = {c:.4e} "
        f"(correlation {c / math.sqrt(ve * vd):.3f})"
    )
    stats = {}
    for prefix in ("py_gyro", "cpp_gyro"):
        e, db, _, _ = gyro_interval_noise(logs, prefix)
        n = len(e)
        k = TOL_SE
        print(f" {prefix} ({n} samples x 3 axes; e_n = w_n - mean rate_n - B_(n-1), db_n = B_n - B_(n-1)):")
        z_e, z_d = e.mean(0) / math.sqrt(ve / n), db.mean(0) / math.sqrt(vd / n)
        check(
            f"{prefix} mean(e), mean(db) / standard error",
            bool(np.all(abs(z_e) <= k) and np.all(abs(z_d) <= k)),
            f"e {np.round(z_e, 2).tolist()}, db {np.round(z_d, 2).tolist()} (|.| <= {k})",
        )
        se_var = k * math.sqrt(2.0 / n)
        r_e, r_d = e.var(0) / ve - 1.0, db.var(0) / vd - 1.0
        check(
            f"{prefix} var(e) / model - 1, var(db) / model - 1",
            bool(np.all(abs(r_e) <= se_var) and np.all(abs(r_d) <= se_var)),
            f"e {np.round(r_e, 4).tolist()}, db {np.round(r_d, 4).tolist()} (|.| <= {se_var:.4f})",
        )
        cov_ed = np.array([np.cov(e[:, i], db[:, i])[0, 1] for i in range(3)])
        se_c = math.sqrt((ve * vd + c * c) / n)
        z_c = (cov_ed - c) / se_c
        check(
            f"{prefix} (cov(e, db) - model) / standard error",
            bool(np.all(abs(z_c) <= k)),
            f"{np.round(z_c, 2).tolist()}; sample {np.array2string(cov_ed, precision=3)} vs {c:.3e}",
        )
        corr = np.corrcoef(np.hstack([e, db]).T)
        off = corr[np.triu_indices(6, 1)]
        off = np.delete(off, [2, 7, 11])  # drop the 3 same-axis (e_i, db_i) pairs checked above
        auto = [lag1(e[:, i]) for i in range(3)] + [lag1(db[:, i]) for i in range(3)]
        lim = k / math.sqrt(n)
        check(
            f"{prefix} independence: cross-axis and lag-1 correlations",
            bool(np.all(abs(off) <= lim) and np.all(np.abs(auto) <= lim)),
            f"max |cross| {np.abs(off).max():.4f}, max |lag-1| {np.abs(auto).max():.4f} (<= {lim:.4f})",
        )
        stats[prefix] = (e, db)
    (e_p, db_p), (e_c, db_c) = stats["py_gyro"], stats["cpp_gyro"]
    n = len(e_p)
    lim = k * math.sqrt(4.0 / n)
    ratio_e, ratio_d = e_c.var(0) / e_p.var(0) - 1.0, db_c.var(0) / db_p.var(0) - 1.0
    check(
        "C++ vs Python: var ratio - 1 of e and db",
        bool(np.all(abs(ratio_e) <= lim) and np.all(abs(ratio_d) <= lim)),
        f"e {np.round(ratio_e, 4).tolist()}, db {np.round(ratio_d, 4).tolist()} (|.| <= {lim:.4f})",
    )
    return stats


def check_tracker_statistics(check: Checks, logs, q_BS, sigmas, prefixes):
    from drake_att import rotations as rot

    _, q_IB = logs["truth/q_IB"]
    q_ref_inv = rot.quat_conjugate(rot.quat_multiply(q_IB, np.broadcast_to(q_BS, q_IB.shape)))
    print(
        f"\nStar tracker: model sigmas {np.round(sigmas / (math.pi / 180 / 3600), 3).tolist()} arcsec "
        "(small-angle error = rotvec((q_IB ⊗ q_BS)^-1 ⊗ q_meas), samples n >= 1)"
    )
    errs = {}
    for prefix in prefixes:
        _, m = logs[f"{prefix}/star_tracker_measurement"]
        q = m[1:, 2:6]
        err = rot.quat_to_rotvec(rot.quat_multiply(q_ref_inv[1:], q))
        n = len(err)
        k = TOL_SE
        z_m = err.mean(0) / (sigmas / math.sqrt(n))
        r_v = err.var(0) / sigmas**2 - 1.0
        lim_v = k * math.sqrt(2.0 / n)
        corr = np.corrcoef(err.T)[np.triu_indices(3, 1)]
        auto = [lag1(err[:, i]) for i in range(3)]
        lim_c = k / math.sqrt(n)
        print(f" {prefix} ({n} samples):")
        check(
            f"{prefix} mean / standard error", bool(np.all(abs(z_m) <= k)), f"{np.round(z_m, 2).tolist()} (|.| <= {k})"
        )
        check(
            f"{prefix} var / sigma^2 - 1",
            bool(np.all(abs(r_v) <= lim_v)),
            f"{np.round(r_v, 4).tolist()} (|.| <= {lim_v:.4f})",
        )
        check(
            f"{prefix} correlations (axes, lag 1)",
            bool(np.all(abs(corr) <= lim_c) and np.all(np.abs(auto) <= lim_c)),
            f"axes {np.round(corr, 4).tolist()}, lag-1 {np.round(auto, 4).tolist()} (|.| <= {lim_c:.4f})",
        )
        norm_err = np.abs(np.linalg.norm(m[:, 2:6], axis=1) - np.linalg.norm(q_IB, axis=1)).max()
        check(
            f"{prefix} |q_meas| = |q_IB|, scalar part >= 0, valid = 1",
            bool(norm_err < 1e-14 and np.all(m[:, 2] >= 0) and np.all(m[:, 1] == 1)),
            f"max | |q_meas| - |q_IB| | = {norm_err:.1e} (|q_IB| - 1 up to {np.abs(np.linalg.norm(q_IB, axis=1) - 1).max():.1e}: "
            "the truth's norm stabilization)",
        )
        errs[prefix] = err
    base = errs["py_tracker"]
    lim = TOL_SE * math.sqrt(4.0 / len(base))
    for prefix in prefixes[1:]:
        r = errs[prefix].var(0) / base.var(0) - 1.0
        check(
            f"{prefix} vs py_tracker: var ratio - 1",
            bool(np.all(abs(r) <= lim)),
            f"{np.round(r, 4).tolist()} (|.| <= {lim:.4f})",
        )


def check_replay(check: Checks, logs, L, num):
    """The C++ sensors' outputs against the model evaluated in numpy on their logged draws
    (a logger at t_n sees the draw the C++ systems used for sample n)."""
    from drake_att import rotations as rot

    print("\nReplay: C++ outputs = the model in numpy on the RandomSource draws they used")
    e, db, _, _ = gyro_interval_noise(logs, "cpp_gyro")
    _, z = logs["cpp_gyro/noise"]
    e_model = L[0, 0] * z[1:, :3]
    db_model = L[1, 0] * z[1:, :3] + L[1, 1] * z[1:, 3:]
    de, dd = np.abs(e - e_model).max() / L[0, 0], np.abs(db - db_model).max() / math.hypot(L[1, 0], L[1, 1])
    check(
        "cpp_gyro (e_n, db_n) = L z_n",
        de < 1e-8 and dd < 1e-8,
        f"max |diff| / sigma: e {de:.1e} (round-off of I_n / T - I_(n-1) / T), db {dd:.1e}",
    )
    _, q_IB = logs["truth/q_IB"]
    for prefix, first in (("cpp_tracker", 1), ("cpp_tracker_split", 1)):
        _, m = logs[f"{prefix}/star_tracker_measurement"]
        _, z = logs[f"{prefix}/noise"]
        dq = rot.quat_multiply(np.broadcast_to(num.q_BS, (len(z), 4)), rot.rotvec_to_quat(num.sigmas * z))
        q_model = rot.quat_canonical(rot.quat_multiply(q_IB, dq))
        diff = np.abs(m[first:, 2:6] - q_model[first:]).max()
        check(
            f"{prefix} q_meas = canonical(q_IB ⊗ q_BS ⊗ exp(sigmas z / 2)) (n >= {first})",
            diff < 1e-14,
            f"max |diff| {diff:.1e}",
        )
    print("Readers: what a discrete update at t_k reads (a C++ hold, logged at t_(k+1)) = the logged sample k")
    for key in sorted(k for k in logs if k.endswith("@update")):
        logged, read = logs[key[: -len("@update")]][1], logs[key][1]
        same = np.array_equal(read[2:], logged[1:-1])
        check(
            f"{key[: -len('@update')]}: read at t_k = logged at t_k (k >= 1)",
            same,
            "bit-identical" if same else f"max |diff| {np.abs(read[2:] - logged[1:-1]).max():.1e}",
        )


def run_checks(samples: int):
    from drake_att.noise import FarrenkopfGyroNoise
    from drake_att.units import RRW_DEG_PER_H_15

    check = Checks()
    all_sensors = ("py_gyro", "cpp_gyro", "py_tracker", "cpp_tracker", "cpp_tracker_split")
    duration = samples * T
    print(
        f"Part 1: checks (Python and C++ sensors side by side on one truth, {samples} samples of T = {T} s each; "
        f"statistical tolerance {TOL_SE:g} standard errors)"
    )

    # (a) noise-free: the C++ sensors must give the Python numbers to round-off.
    t0 = time.perf_counter()
    bench = build(all_sensors, gyro_noise=(0.0, 0.0), tracker_sigmas=np.zeros(3), check_logs=True)
    logs = run(bench, seed=3, duration=100.0)
    print(f"\nNoise-free (100 s, ARW = RRW = 0, sigmas 0; {time.perf_counter() - t0:.0f} s):")
    _, mp = logs["py_gyro/gyro_measurement"]
    _, mc = logs["cpp_gyro/gyro_measurement"]
    _, bp = logs["py_gyro/bias_B"]
    _, bc = logs["cpp_gyro/bias_B"]
    dw = np.abs(mc[1:, 2:5] - mp[1:, 2:5]).max()
    scale = np.abs(mp[1:, 2:5]).max()
    check(
        "C++ gyro w_meas (n >= 1) = Python's to round-off",
        dw <= 1e-11 * max(1.0, scale) and np.array_equal(bp, bc),
        f"max |diff| {dw:.1e} rad/s (|w| up to {scale:.1e}; the C++ affine map computes I_n/T - I_(n-1)/T, "
        f"round-off ~ eps |I| / T); bias_B identical: {np.array_equal(bp, bc)}",
    )
    print(
        f"    sample 0 (by design): Python w(0) + B_0 = {np.round(mp[0, 2:5], 6).tolist()}, C++ B_0 = {np.round(mc[0, 2:5], 6).tolist()}"
    )
    ds = np.abs(mc[:, 0] - mp[:, 0]).max()
    check(
        "C++ gyro stamp T n = Python's (n - 1) T + T",
        ds <= 1e-12 * mp[-1, 0],
        f"max |diff| {ds:.1e} s; valid flags equal: {np.array_equal(mc[:, 1], mp[:, 1])}",
    )
    _, tp = logs["py_tracker/star_tracker_measurement"]
    for prefix in ("cpp_tracker", "cpp_tracker_split"):
        _, tc = logs[f"{prefix}/star_tracker_measurement"]
        dq = np.abs(tc[:, 2:6] - tp[:, 2:6]).max()
        check(
            f"{prefix} q_meas = Python's (q_IB ⊗ q_BS, canonical) to round-off",
            dq <= 1e-15,
            f"max |diff| {dq:.1e}; stamps identical: {np.array_equal(tc[:, 0], tp[:, 0])} "
            f"(max |diff| {np.abs(tc[:, 0] - tp[:, 0]).max():.1e} s)",
        )

    # (b) S3's noise: statistics of each sensor against its model and against each other.
    t0 = time.perf_counter()
    bench = build(all_sensors, check_logs=True)
    num = bench.numbers
    L = interval_factor(num.arw, num.rrw)
    noise = FarrenkopfGyroNoise(num.arw, num.rrw, T)
    print(f"\nS3 noise ({duration:.0f} s simulated)")
    check(
        "C++ gyro factor: L L' = interval_covariance(), L = the Python gyro's factor (FarrenkopfGyroNoise._chol)",
        bool(
            np.allclose(L @ L.T, noise.interval_covariance(), rtol=1e-14, atol=0)
            and np.allclose(L, noise._chol, rtol=1e-14, atol=0)
        ),
        f"L = {np.array2string(L, precision=4, separator=', ').replace(chr(10), '')}",
    )
    logs = run(bench, seed=4, duration=duration)
    print(f"  (built and ran in {time.perf_counter() - t0:.0f} s)")
    check_replay(check, logs, L, num)
    check_gyro_statistics(check, logs, num.arw, num.rrw, "Gyro, S3 noise (ARW 0.56 deg/rt-h, RRW 123.75 deg/h^1.5)")
    check_tracker_statistics(check, logs, num.q_BS, num.sigmas, ("py_tracker", "cpp_tracker", "cpp_tracker_split"))

    # (c) a large RRW, so that the (e, db) correlation is 0.6 and its check has power.
    rrw = math.sqrt(3.0) * num.arw / T
    bench = build(("py_gyro", "cpp_gyro"), gyro_noise=(num.arw, rrw), check_logs=True)
    logs = run(bench, seed=5, duration=duration)
    check_gyro_statistics(
        check,
        logs,
        num.arw,
        rrw,
        f"Gyro, large RRW ({rrw / RRW_DEG_PER_H_15:.3g} deg/h^1.5, var of the bias part of e = the ARW part)",
    )
    print(f"\nChecks: {check.total - check.failed} of {check.total} passed")
    return check.failed


# ---------------------------------------------------------------------------------------------
# Part 2: instruction counts (or CPU time) of AdvanceTo, one child process per case
# ---------------------------------------------------------------------------------------------


def child(case: str, duration: float, warmup: float, clock: str, repeats: int):
    """Build ``case``'s diagram, warm up, then measure ``AdvanceTo(duration)`` (prints the result)."""
    if case in ("shipped", "shipped_cpp_gyro"):
        if case == "shipped_cpp_gyro":
            use_cpp_gyro_plugin()
        sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
        from bench_ab import CASES as AB_CASES

        from drake_att.scenarios.builder import ScenarioDiagram
        from drake_att.scenarios.config import apply_overrides
        from drake_att.scenarios.library import load

        name, overrides = AB_CASES["S3 single tracker, 10 Hz gyro + ST + MEKF"]
        scenario = apply_overrides(
            load(name), [f"duration_s={duration}", f"scoring.score_from_s={duration / 10}"] + overrides
        )
        sd = ScenarioDiagram(scenario)

        def simulator_for(seed):
            return configured_simulator(sd.diagram, sd.create_context(seed), scenario.simulation)
    else:
        bench = build(CASES[case])

        def simulator_for(seed):
            return make_simulator(bench, seed)

    simulator_for(1).AdvanceTo(warmup)
    if clock == "instructions":  # under valgrind --tool=callgrind --instr-atstart=no
        simulator = simulator_for(2)
        subprocess.run(["callgrind_control", "-i", "on", str(os.getpid())], check=True, capture_output=True)
        simulator.AdvanceTo(duration)
        subprocess.run(["callgrind_control", "-i", "off", str(os.getpid())], check=True, capture_output=True)
        print("instrumented")
        return
    best = float("inf")
    for k in range(repeats):
        simulator = simulator_for(2 + k)
        t0 = time.process_time()
        simulator.AdvanceTo(duration)
        best = min(best, time.process_time() - t0)
    print(best)


def launch(case: str, args) -> subprocess.Popen:
    clock = "cpu" if args.no_callgrind else "instructions"
    command = [
        sys.executable,
        os.path.abspath(__file__),
        "--child",
        case,
        "--duration",
        str(args.duration),
        "--warmup",
        str(args.warmup),
        "--repeats",
        str(args.repeats),
        "--clock",
        clock,
    ]
    if clock == "instructions":
        command = ["valgrind", "--tool=callgrind", "--instr-atstart=no", "--callgrind-out-file=/dev/null"] + command
    env = dict(os.environ, MPLBACKEND="Agg", PYTHONHASHSEED="0")  # the same count on every run
    return subprocess.Popen(
        command,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
    )


def result(case: str, process: subprocess.Popen, instructions: bool) -> float:
    out, err = process.communicate()
    if process.returncode != 0:
        raise RuntimeError(f"{case} failed:\n{err[-3000:]}")
    if instructions:
        counts = [line.split(":")[-1] for line in err.splitlines() if "Collected :" in line]
        if not counts:
            raise RuntimeError(f"{case}: no callgrind count in:\n{err[-3000:]}")
        return float(counts[-1].replace(",", ""))
    return float(out.strip().splitlines()[-1])


def run_cases(args, results: dict, progress: list) -> None:
    """Run the cases' children, ``args.jobs`` at a time; fill ``results`` (case -> count or
    seconds) and ``progress`` (lines to print)."""
    pending, running = args.cases.split(","), []
    t0 = time.perf_counter()
    while pending or running:
        while pending and len(running) < args.jobs:
            case = pending.pop(0)
            running.append((case, launch(case, args)))
        case, process = running.pop(0)
        results[case] = result(case, process, not args.no_callgrind)
        progress.append(f"  {case}: done at {time.perf_counter() - t0:.0f} s")


def print_table(results: dict, args):
    instructions = not args.no_callgrind
    steps = round(args.duration / T)
    unit, scale = ("k instr", 1e-3) if instructions else ("us", 1e6)
    what = "callgrind instructions" if instructions else f"CPU time (process_time, best of {args.repeats})"
    print(
        f"\nPart 2: {what} of simulator.AdvanceTo({args.duration:g}) after a {args.warmup:g}-s warm-up; "
        f"{steps} steps of 0.1 s, {steps} sensor samples"
    )
    base = results.get("baseline")
    print(f"{'case':<22} {'total':>14} {unit + ' / step':>16} {'sensor ' + unit + ' / sample':>24}")
    for case in (c for c in CASES if c in results):
        value = results[case]
        total = f"{value / 1e9:.4f} G" if instructions else f"{value:.3f} s"
        per_step = value / steps * scale
        whole = case == "baseline" or case.startswith("shipped")
        sensor = "" if base is None or whole else f"{(value - base) / steps * scale:24.1f}"
        print(f"{case:<22} {total:>14} {per_step:16.1f} {sensor}")
    if base is None:
        return

    def cost(case):
        return (results[case] - base) / steps * scale if case in results else None

    print()
    pairs = [
        ("gyro (one Diagram)", "py_gyro", "cpp_gyro"),
        ("gyro (flat)", "py_gyro", "cpp_gyro_flat"),
        ("star tracker (one system)", "py_tracker", "cpp_tracker"),
        ("star tracker (split)", "py_tracker", "cpp_tracker_split"),
        ("  floor: one system, no math", "py_tracker", "cpp_tracker_floor"),
        ("both (gyro + split)", "py_both", "cpp_both"),
    ]
    shipped = results["shipped"] / steps * scale if "shipped" in results else None
    print(
        f"{'sensor cost per sample':<30} {'Python':>9} {'C++':>9} {'Python/C++':>11} {'saved':>9}"
        + (f" {'saved / shipped step':>21}" if shipped else "")
    )
    for label, py, cpp in pairs:
        a, b = cost(py), cost(cpp)
        if a is None or b is None:
            continue
        line = f"{label:<30} {a:9.1f} {b:9.1f} {a / b:11.2f} {a - b:9.1f}"
        if shipped:
            line += f" {(a - b) / shipped:20.1%}"
        print(line)
    if shipped:
        print(
            f"\nshipped 10 Hz case (bench_ab.py's 'S3 single tracker, 10 Hz gyro + ST + MEKF'): {shipped:.1f} {unit} "
            f"per 0.1-s step (its truth and truth loggers alone, the baseline: {base / steps * scale:.1f})"
        )
        if "shipped_cpp_gyro" in results:
            mixed = results["shipped_cpp_gyro"] / steps * scale
            print(
                f"the same with the C++ gyro (its plug-in replaced):           {mixed:.1f} {unit} per step: "
                f"{shipped - mixed:.1f} saved, {(shipped - mixed) / shipped:.1%} of the step ({shipped / mixed:.3f}x)"
            )
    print(f"(units: {unit}; 'sensor' = (case - baseline) / samples)")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument(
        "--no-callgrind", action="store_true", help="time AdvanceTo with process_time instead of counting instructions"
    )
    ap.add_argument(
        "--duration", type=float, default=200.0, help="simulated seconds of the measured AdvanceTo (default 200)"
    )
    ap.add_argument("--warmup", type=float, default=10.0, help="simulated seconds of the warm-up run (default 10)")
    ap.add_argument("--repeats", type=int, default=3, help="--no-callgrind: timed runs per case, best kept (default 3)")
    ap.add_argument(
        "--jobs",
        type=int,
        default=None,
        help="child processes at once (default 2 under callgrind, 1 with --no-callgrind)",
    )
    ap.add_argument("--cases", default=",".join(CASES), help=f"comma-separated, from {list(CASES)}")
    ap.add_argument("--samples", type=int, default=20000, help="samples per statistical check (default 20000)")
    ap.add_argument("--skip-checks", action="store_true")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    ap.add_argument("--clock", default="instructions", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        child(args.child, args.duration, args.warmup, args.clock, args.repeats)
        return 0
    unknown = [c for c in args.cases.split(",") if c not in CASES]
    if unknown:
        raise SystemExit(f"--cases: unknown {unknown}; choose from {list(CASES)}")
    if args.jobs is None:
        args.jobs = 1 if args.no_callgrind else 2
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    start = time.perf_counter()
    results, progress = {}, []
    # Instruction counts do not depend on load: the valgrind children run while the checks
    # run. CPU times do: then the checks come first and the children after.
    import threading

    worker = threading.Thread(target=run_cases, args=(args, results, progress))
    if not args.no_callgrind:
        print(f"Part 2 started in the background: {args.cases}, {args.jobs} at a time under callgrind\n", flush=True)
        worker.start()
    failed = 0
    if not args.skip_checks:
        failed = run_checks(args.samples)
    if args.no_callgrind:
        worker.start()
    worker.join()
    print("\n" + "\n".join(progress))
    if len(results) < len(args.cases.split(",")):
        raise SystemExit("Part 2 failed (see above)")
    print_table(results, args)
    print(f"\nTotal {time.perf_counter() - start:.0f} s")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
