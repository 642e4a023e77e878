"""Time per filter step (predict + update) of the S0 filter cores.

Usage::

    python benchmarks/bench_particle_filters.py [--steps 300] [--particles 1000] [--kernel numba|numpy]

Runs each filter core on the same synthetic S0 data (constant small body rate, Farrenkopf
gyro, two star vectors at 100 urad, 1 Hz; body-mounted tracker samples built before the
timing) and prints a table of the mean and best wall-clock time per step, measured with
``time.perf_counter`` around each ``predict`` + ``update`` pair of the core (what the
estimator system calls), plus the extrapolated time of the paper's 1000-step run.
``--kernel numba`` (default) times the library's cores (their steps are the compiled kernels);
``--kernel numpy`` the ``Reference*`` cores of the tests' numpy oracle
(``tests/particle_reference.py``: the same filters with numpy steps).
No assertions: timings depend on the machine.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time

import numpy as np

from drake_att import rotations as rot
from drake_att.contract import VectorObservations
from drake_att.filters.mrp_ekf import MrpEkfCore
from drake_att.filters.particle import BootstrapPfCore, EkpfCore, GyrolessPfCore, RandomWalkRoughening

sys.path.append(os.path.join(os.path.dirname(os.path.abspath(__file__)), os.pardir, "tests"))
import particle_reference  # noqa: E402  (the numpy oracle, in tests/)

DEG = np.pi / 180.0
HOUR = 3600.0
SIGMA_V = 0.2 * DEG / HOUR
SIGMA_U = 0.02 * DEG / HOUR / np.sqrt(HOUR)
SIGMA_STAR = 100e-6
REFS = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
BODY = np.array([1.0, 0.0, 0.0, 0.0])  # the tracker's mounting q_BS
INERTIA = np.diag([100.0, 200.0, 200.0])
TORQUE = np.full(3, 1e-5)


def make_data(num_steps: int, seed: int = 0):
    """Synthetic S0 measurements: y (K, 6) and averaged gyro rates w_meas (K, 3)."""
    rng = np.random.default_rng(seed)
    w = np.array([1e-3, -5e-4, 2e-4])
    b = np.full(3, DEG / HOUR)
    q = np.array([1.0, 0.0, 0.0, 0.0])
    ys, wms = [], []
    for _ in range(num_steps):
        ys.append(
            particle_reference.vector_measurement_model(rot.quat_to_mrp(q), REFS) + SIGMA_STAR * rng.standard_normal(6)
        )
        wms.append(w + b + SIGMA_V * rng.standard_normal(3))
        b = b + SIGMA_U * rng.standard_normal(3)
        q = rot.quat_propagate(q, w, 1.0)
    return np.array(ys), np.array(wms)


def cores(kernel: str):
    """The MRP EKF, bootstrap PF, EKPF and gyroless PF core classes: the library's
    (``"numba"``) or the numpy oracle's (``"numpy"``)."""
    if kernel == "numba":
        return MrpEkfCore, BootstrapPfCore, EkpfCore, GyrolessPfCore
    return (
        particle_reference.ReferenceMrpEkfCore,
        particle_reference.ReferenceBootstrapPfCore,
        particle_reference.ReferenceEkpfCore,
        particle_reference.ReferenceGyrolessPfCore,
    )


def time_steps(step, num_steps: int):
    """Return per-step wall-clock times (s) of ``step(k)`` for k = 1..num_steps."""
    times = np.empty(num_steps)
    for k in range(num_steps):
        t0 = time.perf_counter()
        step(k + 1)
        times[k] = time.perf_counter() - t0
    return times


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=300, help="timed steps per filter")
    parser.add_argument("--particles", type=int, default=1000, help="particles per PF")
    parser.add_argument(
        "--kernel",
        choices=("numba", "numpy"),
        default="numba",
        help="numba: the library's cores (compiled kernels); numpy: the tests' numpy oracle",
    )
    args = parser.parse_args(argv)
    ekf_core, bootstrap_core, ekpf_core, gyroless_core = cores(args.kernel)
    n, num_steps = args.particles, args.steps
    ys, wms = make_data(num_steps + 2)
    q0 = rot.rpy_to_quat(np.array([1.0, 1.0, 1.0]) * DEG)
    b0 = np.full(3, 2 * DEG / HOUR)
    P0 = np.diag([DEG**2] * 3 + [(DEG / HOUR) ** 2] * 3)
    P0_gyroless = np.diag([DEG**2] * 3 + [(0.001 * DEG) ** 2] * 3)

    observations = [
        VectorObservations(float(k), True, y.reshape(2, 3), REFS, SIGMA_STAR, BODY) for k, y in enumerate(ys)
    ]
    rows = []

    def bench(name, core, state, rng, particles):
        """Time ``core`` from ``state``: step k predicts with ``wms[k]`` and updates with the
        sample of step k + 1 (k = -1: the update at t_0 only)."""
        held = [state]

        def step(k):
            s = held[0]
            if k >= 0:
                s = core.predict(s, wms[k] if core.uses_gyro else None, 1.0, rng)
            held[0] = core.update(s, observations[k + 1], rng)[0]

        step(-1)  # warm-up: the update at t_0 and one step (numpy's first-call overheads,
        step(0)  # numba's kernels loaded from its cache or compiled)
        t = time_steps(step, num_steps)
        rows.append((name, particles, 1e3 * np.mean(t), 1e3 * np.min(t), 1000 * np.mean(t)))

    ekf = ekf_core(SIGMA_V, SIGMA_U)
    bench("MRP EKF", ekf, ekf.initial_state(q0, b0, P0), None, 1)

    def particle_bench(name, core, seed):
        rng = np.random.default_rng(seed)
        bench(name, core, core.draw_initial_state(rng), rng, n)

    particle_bench(
        "bootstrap PF (gyro)", bootstrap_core(n, q0, b0, P0, 2e-5, bias_roughening=RandomWalkRoughening(3e-7)), 2
    )
    particle_bench("EKPF (gyro)", ekpf_core(n, q0, b0, P0, SIGMA_V, SIGMA_U), 3)
    particle_bench(
        "EKPF, iterated proposal (<=10)", ekpf_core(n, q0, b0, P0, SIGMA_V, SIGMA_U, proposal_iterations=10), 4
    )
    particle_bench(
        "gyroless PF (RK4, 1 substep)",
        gyroless_core(n, q0, np.full(3, 0.001 * DEG), P0_gyroless, INERTIA, TORQUE, 1e-6, attitude_process_sigma=3e-5),
        5,
    )

    what = "the library (compiled kernels)" if args.kernel == "numba" else "the numpy oracle"
    print(
        f"S0 filter cores, {what}, {num_steps} timed steps (predict + update), "
        f"numpy {np.__version__}, Python {platform.python_version()}, {platform.machine()}"
    )
    header = f"{'filter':<32} {'N':>6} {'mean ms/step':>13} {'best ms/step':>13} {'1000 steps s':>13}"
    print(header)
    print("-" * len(header))
    for name, particles, mean_ms, best_ms, total_s in rows:
        print(f"{name:<32} {particles:>6d} {mean_ms:>13.3f} {best_ms:>13.3f} {total_s:>13.2f}")


if __name__ == "__main__":
    main()
