#!/usr/bin/env python3
"""drake_att against plain-numpy peer loops: three cases, CPU time (or instructions) and accuracy.

Cases (``--case``; default ``all``, in this order):

* ``ten_hz``: drake_att's ``cubesat_single_star_tracker`` with the gyro, the tracker and the
  MEKF at 10 Hz (truth by fixed-step RK3 at 0.1 s, as shipped) against
  ``peer_numpy_loop.py``; 5000 s.
* ``default``: the default scenario ``cubesat_dual_star_tracker`` as shipped (two trackers at
  10 Hz, gyro and four MEKFs at 1 Hz, tracker average, decentralized fusion) against
  ``peer_default_loop.py``; 5000 s.
* ``ekpf``: ``s0_particle_filters_small_error`` with only its ``ekpf`` estimator (N = 1000,
  drake_att's compiled kernels as shipped; ``--ekpf-kernel numpy`` builds it with the numpy core
  the peer uses, the tests' oracle ``ReferenceEkpfCore``) against ``peer_ekpf_loop.py`` (that
  numpy EKPF core in a plain loop); 1000 s.

Per case, in one process: the peer's loop and ``ScenarioDiagram.simulate(seed)`` alone (the
diagram's build time is reported separately), CPU time (``time.process_time``), best of
``--repeats``, after one short warm-up run of each side with another seed (imports, first calls,
numba's cached kernels); the ratio drake_att / peer; every estimator's attitude RMSE per axis,
both sides, scored from ``min(500 s, duration / 2)`` (different random streams: they must agree
in class, within a factor 2 per axis, not in digits).

    python benchmarks/bench_peer.py                      # all three cases, best of 2 (~6 min)
    python benchmarks/bench_peer.py --case ten_hz        # the 10 Hz case only
    python benchmarks/bench_peer.py --quick              # 1000 s / 1000 s / 300 s, 1 repeat
    python benchmarks/bench_peer.py --instructions --duration 500 --ekpf-duration 100   # callgrind

``--duration`` sets every selected case's duration, ``--ekpf-duration`` the ekpf case's (it
takes precedence). ``--batch N`` (``ten_hz`` only): drake_att runs seeds ``seed .. seed+N-1`` in
one batch diagram (``ScenarioDiagram(realizations=N).simulate_batch``, what a campaign's worker
does) and its figures are per run, the batch's divided by N; the RMSE is the first seed's. ``--instructions``: each side of each case runs once in its own child under
valgrind's callgrind, counting only the timed part (the peer's loop; ``simulate`` after a short
warm-up with another seed) - the same count for the same code whatever else the machine does
(a shared VM moves CPU times by 2x). ~50x slower. The children import drake_att from the
current directory first: to measure another checkout, run from it, e.g. ``cd /tmp/old &&
PYTHONPATH=/tmp/old python /path/to/bench_peer.py --instructions``.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import peer_default_loop
import peer_ekpf_loop
import peer_numpy_loop

# drake_att's scenario modules (pydrake) are imported inside the functions that need them, so
# an instruction-count child of a peer loads no Drake.

TEN_HZ = ["sensors.gyro.period_s=0.1", "sensors.st1.period_s=0.1", "estimators.single.period_s=0.1"]
CASES = ("ten_hz", "default", "ekpf")
DURATION_S = {"ten_hz": 5000.0, "default": 5000.0, "ekpf": 1000.0}
QUICK_DURATION_S = {"ten_hz": 1000.0, "default": 1000.0, "ekpf": 300.0}
STEP_S = {"ten_hz": 0.1, "default": 0.1, "ekpf": 1.0}  # the truth step ("per step" figures)
ESTIMATORS = {"ten_hz": ("single",), "default": peer_default_loop.ESTIMATORS, "ekpf": ("ekpf",)}
SCORE_FROM_S = 500.0  # the three scenarios' scoring.score_from_s
WARM_UP_S = {"ten_hz": 20.0, "default": 20.0, "ekpf": 5.0}
WARM_UP_SEED_OFFSET = 1000  # warm-up runs use another seed (no noise memo shared with the timed run)
SAME_CLASS = (0.5, 2.0)  # drake_att / peer RMSE per axis


def title(case: str, ekpf_kernel: str = "numba") -> str:
    return {
        "ten_hz": "S3 single tracker, gyro/ST/MEKF at 10 Hz",
        "default": "default scenario (S3 dual tracker: 2 trackers at 10 Hz, gyro + 4 MEKFs at 1 Hz, average, fusion)",
        "ekpf": f"S0 EKPF, N = 1000, all at 1 Hz (drake_att's kernel: {ekpf_kernel}; the peer's: numpy)",
    }[case]


def score_from(duration: float) -> float:
    """The scored window's start: the scenarios' 500 s, or half the run if that is shorter."""
    return min(SCORE_FROM_S, duration / 2.0)


# --- the two sides ----------------------------------------------------------------------------
def run_peer(case: str, duration: float, seed: int) -> dict:
    """One peer run: ``{"cpu_s", "rmse_deg": {estimator: [x, y, z]}, "steps", "note"}``."""
    start = score_from(duration)
    if case == "ten_hz":
        saved, peer_numpy_loop.SCORE_FROM_S = peer_numpy_loop.SCORE_FROM_S, start  # the loop reads the global
        try:
            r = peer_numpy_loop.run(duration, seed, 10.0)
        finally:
            peer_numpy_loop.SCORE_FROM_S = saved
        return {
            "cpu_s": r["cpu_s"],
            "rmse_deg": {"single": r["rmse_deg"]},
            "steps": r["steps"],
            "note": f"{r['steps']} steps, {r['gate_rejections']} gate rejections",
        }
    if case == "default":
        r = peer_default_loop.run(duration, seed, start)
        rejected = sum(r["gate_rejections"].values())
        return {
            "cpu_s": r["cpu_s"],
            "rmse_deg": r["rmse_deg"],
            "steps": r["steps"],
            "note": f"{r['steps']} truth steps, {r['filter_steps']} filter steps, {rejected} gate rejections",
        }
    r = peer_ekpf_loop.run(duration, seed, start)
    return {
        "cpu_s": r["cpu_s"],
        "rmse_deg": r["rmse_deg"],
        "steps": r["steps"],
        "note": f"{r['steps']} steps, {r['resamplings']} resamplings",
    }


def drake_scenario(case: str, duration: float):
    """The drake_att scenario of a case, ``duration`` long, scored from :func:`score_from`."""
    from drake_att.scenarios.config import apply_overrides
    from drake_att.scenarios.library import load
    from drake_att.scenarios.selection import with_estimators

    run = [f"duration_s={duration}", f"scoring.score_from_s={score_from(duration)}"]
    if case == "ten_hz":
        return apply_overrides(load("cubesat_single_star_tracker"), run + TEN_HZ)
    if case == "default":
        return apply_overrides(load("cubesat_dual_star_tracker"), run)
    return with_estimators(apply_overrides(load("s0_particle_filters_small_error"), run), ["ekpf"])


@contextlib.contextmanager
def ekpf_core(ekpf_kernel: str):
    """While building: the EKPF core of the setups, the library's (``"numba"``) or the peer's
    numpy core (``"numpy"``: the tests' oracle, ``ReferenceEkpfCore``)."""
    from drake_att.systems import filter_setups

    library = filter_setups.EkpfCore
    if ekpf_kernel == "numpy":
        sys.path.append(os.path.join(os.path.dirname(os.path.abspath(__file__)), os.pardir, "tests"))
        from particle_reference import ReferenceEkpfCore

        filter_setups.EkpfCore = ReferenceEkpfCore
    try:
        yield
    finally:
        filter_setups.EkpfCore = library


def build_diagram(case: str, duration: float, ekpf_kernel: str = "numba", batch: int = 1):
    """``(ScenarioDiagram, build CPU s)`` (a batch diagram of ``batch`` realizations if > 1)."""
    from drake_att.scenarios.builder import ScenarioDiagram

    scenario = drake_scenario(case, duration)
    c0 = time.process_time()
    with ekpf_core(ekpf_kernel):
        sd = ScenarioDiagram(scenario, realizations=batch)
    return sd, time.process_time() - c0


def simulate(sd, seed: int, overrides=None):
    """The run of ``seed`` (a batch diagram: seeds ``seed ..``, all simulated, the first returned)."""
    if sd.realizations == 1:
        return sd.simulate(seed, overrides=overrides)
    return sd.simulate_batch(list(range(seed, seed + sd.realizations)), overrides=overrides)[0]


def warm_up_drake(case: str, sd, seed: int) -> None:
    w = WARM_UP_S[case]
    simulate(sd, seed + WARM_UP_SEED_OFFSET, overrides=[f"duration_s={w}", f"scoring.score_from_s={w / 2}"])


def drake_results(case: str, run) -> tuple[dict, str]:
    """``({estimator: RMSE [x, y, z]}, note)`` of a drake_att run."""
    from drake_att.analysis.metrics import compute_metrics

    m = compute_metrics(run)["estimators"]
    rmse = {n: m[n]["attitude_rmse_deg"] for n in ESTIMATORS[case]}
    used = sum(m[n]["measurements_used"] for n in ESTIMATORS[case] if n != "decentralized")
    skipped = sum(m[n]["measurements_skipped"] for n in ESTIMATORS[case] if n != "decentralized")
    return rmse, f"{used} used / {skipped} skipped"


# --- instruction counts -------------------------------------------------------------------------
_CHILD = """
import json, os, subprocess, sys
bench_dir, case, side, T, seed, kernel = sys.argv[1], sys.argv[2], sys.argv[3], float(sys.argv[4]), int(sys.argv[5]), sys.argv[6]
batch = int(sys.argv[7])
sys.path.insert(0, bench_dir)
import bench_peer
toggle = lambda state: subprocess.run(["callgrind_control", "-i", state, str(os.getpid())], check=True,
                                      capture_output=True)
print("RESULT " + json.dumps(bench_peer.child_run(case, side, T, seed, kernel, toggle, batch)))
"""


def child_run(case: str, side: str, duration: float, seed: int, ekpf_kernel: str, toggle, batch: int = 1) -> dict:
    """The body of an instruction-count child: warm up, ``toggle("on")``, the timed part,
    ``toggle("off")``; returns ``{"rmse_deg", "note"}`` (computed after the count)."""
    if side == "peer":
        run_peer(case, WARM_UP_S[case], seed + WARM_UP_SEED_OFFSET)
        toggle("on")
        r = run_peer(case, duration, seed)
        toggle("off")
        return {"rmse_deg": r["rmse_deg"], "note": r["note"]}
    sd, _ = build_diagram(case, duration, ekpf_kernel, batch)
    warm_up_drake(case, sd, seed)
    toggle("on")
    run = simulate(sd, seed)
    toggle("off")
    rmse, note = drake_results(case, run)
    return {"rmse_deg": rmse, "note": note}


def count_instructions(
    case: str, side: str, duration: float, seed: int, ekpf_kernel: str = "numba", batch: int = 1
) -> tuple:
    """``(callgrind's instruction count of one side's timed part, its child_run result)``."""
    import subprocess

    out = subprocess.run(
        [
            "valgrind",
            "--tool=callgrind",
            "--instr-atstart=no",
            "--callgrind-out-file=/dev/null",
            sys.executable,
            "-c",
            _CHILD,
            os.path.dirname(os.path.abspath(__file__)),
            case,
            side,
            str(duration),
            str(seed),
            ekpf_kernel,
            str(batch),
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    counts = [line.split(":")[-1] for line in out.stderr.splitlines() if "Collected :" in line]
    results = [line[len("RESULT ") :] for line in out.stdout.splitlines() if line.startswith("RESULT ")]
    if out.returncode != 0 or not counts or not results:
        raise SystemExit(f"{case} {side} under callgrind failed:\n{out.stderr[-2000:]}")
    return float(counts[-1].replace(",", "")), json.loads(results[-1])


# --- reporting -------------------------------------------------------------------------------
def _fmt(v) -> str:
    return " ".join(f"{x:.2e}" for x in v)


def rmse_verdict(case: str, peer_rmse: dict, lib_rmse: dict) -> tuple[bool, list]:
    """``(same class for every estimator, lines)``: per estimator the two RMSEs and their ratio."""
    lo, hi = SAME_CLASS
    lines, all_same = [], True
    for n in ESTIMATORS[case]:
        ratios = [x / y if y > 0 else math.inf for x, y in zip(lib_rmse[n], peer_rmse[n], strict=True)]
        same = all(lo <= r <= hi for r in ratios)
        all_same &= same
        lines.append((n, peer_rmse[n], lib_rmse[n], ratios, same))
    return all_same, lines


def print_rmse_table(case: str, peer_rmse: dict, lib_rmse: dict, start: float) -> bool:
    same, lines = rmse_verdict(case, peer_rmse, lib_rmse)
    print(f"attitude RMSE x/y/z after {start:.0f} s (deg):")
    print(f"  {'estimator':<14} {'peer':<27} {'drake_att':<27} drake_att / peer")
    for n, p, d, ratios, ok in lines:
        print(
            f"  {n:<14} {_fmt(p):<27} {_fmt(d):<27} {' '.join(f'{r:.2f}' for r in ratios)}"
            + ("" if ok else "  <- NOT the same class")
        )
    print(
        "-> "
        + (
            "same class (within a factor 2 per axis; different random streams)"
            if same
            else "NOT the same class (a factor > 2 on some axis): check the models"
        )
    )
    return same


def measure_cpu(case: str, duration: float, seed: int, repeats: int, ekpf_kernel: str, batch: int = 1) -> dict:
    """One case by CPU time; prints its block and returns the summary row."""
    start = score_from(duration)
    print(f"{title(case, ekpf_kernel)}, {duration:.0f} s, seed {seed}, best of {repeats} (CPU s)")
    run_peer(case, WARM_UP_S[case], seed + WARM_UP_SEED_OFFSET)
    peer_runs = [run_peer(case, duration, seed) for _ in range(repeats)]
    peer = min(peer_runs, key=lambda r: r["cpu_s"])

    sd, build = build_diagram(case, duration, ekpf_kernel, batch)
    warm_up_drake(case, sd, seed)
    lib_cpu, run = [], None
    for _ in range(repeats):
        c0 = time.process_time()
        run = simulate(sd, seed)
        lib_cpu.append((time.process_time() - c0) / batch)  # per run
    lib_rmse, lib_note = drake_results(case, run)
    lib = min(lib_cpu)
    ratio = lib / peer["cpu_s"]
    peer_all = ", ".join(f"{r['cpu_s']:.2f}" for r in peer_runs)
    lib_all = ", ".join(f"{c:.2f}" for c in lib_cpu)
    if case == "ten_hz":  # with its per-axis RMSE
        m = lib_rmse["single"]
        print(f"{'':<10} {'CPU (s)':>9}  {'RMSE x/y/z after ' + str(int(start)) + ' s (deg)':>32}")
        print(f"{'peer':<10} {peer['cpu_s']:9.2f}  {_fmt(peer['rmse_deg']['single']):>32}   ({peer['note']})")
        print(f"{'drake_att':<10} {lib:9.2f}  {_fmt(m):>32}   (simulate only; build {build:.2f} s; {lib_note})")
        print(f"ratio drake_att / peer: {ratio:.1f}  (all CPU times: peer {peer_all}; drake_att {lib_all})")
        same, lines = rmse_verdict(case, peer["rmse_deg"], lib_rmse)
        print(
            f"RMSE drake_att / peer per axis: {' '.join(f'{r:.2f}' for r in lines[0][3])} -> "
            + (
                "same class (within a factor 2 per axis; different random streams)"
                if same
                else "NOT the same class (a factor > 2 on some axis): check the models"
            )
        )
    else:
        print(f"{'':<10} {'CPU (s)':>9}")
        print(f"{'peer':<10} {peer['cpu_s']:9.2f}   ({peer['note']})")
        print(f"{'drake_att':<10} {lib:9.2f}   (simulate only; build {build:.2f} s; {lib_note})")
        print(f"ratio drake_att / peer: {ratio:.2f}  (all CPU times: peer {peer_all}; drake_att {lib_all})")
        same = print_rmse_table(case, peer["rmse_deg"], lib_rmse, start)
    return {"case": case, "duration": duration, "peer": peer["cpu_s"], "lib": lib, "ratio": ratio, "same": same}


def measure_instructions(case: str, duration: float, seed: int, ekpf_kernel: str, batch: int = 1) -> dict:
    """One case by callgrind instruction counts; prints its block and returns the summary row."""
    peer_n, peer_r = count_instructions(case, "peer", duration, seed, ekpf_kernel)
    lib_n, lib_r = count_instructions(case, "drake_att", duration, seed, ekpf_kernel, batch)
    lib_n /= batch  # per run
    steps = round(duration / STEP_S[case])
    what = f"{STEP_S[case]:g}-s step"
    per_run = f"; drake_att per run of a batch of {batch}" if batch > 1 else ""
    print(
        f"{title(case, ekpf_kernel)}, {duration:.0f} s ({steps} steps), seed {seed}: instructions (callgrind{per_run})\n"
        f"{'peer':<10} {peer_n / 1e9:8.3f} G  ({peer_n / steps / 1e3:.0f} k per {what}; {peer_r['note']})\n"
        f"{'drake_att':<10} {lib_n / 1e9:8.3f} G  ({lib_n / steps / 1e3:.0f} k per {what}; {lib_r['note']})\n"
        f"ratio drake_att / peer: {lib_n / peer_n:.2f}"
    )
    same = print_rmse_table(case, peer_r["rmse_deg"], lib_r["rmse_deg"], score_from(duration))
    return {
        "case": case,
        "duration": duration,
        "peer": peer_n / 1e9,
        "lib": lib_n / 1e9,
        "ratio": lib_n / peer_n,
        "same": same,
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--case", choices=CASES + ("all",), default="all", help="which case (default: all three)")
    ap.add_argument(
        "--duration",
        type=float,
        default=None,
        help="simulated seconds of every selected case (default: 5000 ten_hz, 5000 default, 1000 ekpf)",
    )
    ap.add_argument("--ekpf-duration", type=float, default=None, help="simulated seconds of the ekpf case")
    ap.add_argument("--repeats", type=int, default=2, help="best of N (default 2)")
    ap.add_argument("--quick", action="store_true", help="1000 s (ten_hz, default), 300 s (ekpf), 1 repeat")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument(
        "--ekpf-kernel",
        choices=("numba", "numpy"),
        default="numba",
        help="drake_att's EKPF core (default numba: the compiled kernels, as shipped; numpy: the "
        "peer's core, the tests' numpy oracle, which leaves the framework's overhead)",
    )
    ap.add_argument(
        "--instructions",
        action="store_true",
        help="count instructions under callgrind instead of timing (deterministic; ~50x slower)",
    )
    ap.add_argument(
        "--batch",
        type=int,
        default=1,
        help="ten_hz only: drake_att runs this many seeds in one batch diagram; figures per run (default 1)",
    )
    a = ap.parse_args(argv)
    cases = CASES if a.case == "all" else (a.case,)
    if a.batch < 1 or (a.batch > 1 and cases != ("ten_hz",)):
        ap.error(f"--batch: got {a.batch}; must be >= 1, and > 1 only with --case ten_hz")
    durations = dict(QUICK_DURATION_S if a.quick else DURATION_S)
    if a.quick:
        a.repeats = 1
    for c in cases:
        if a.duration is not None:
            durations[c] = a.duration
    if a.ekpf_duration is not None:
        durations["ekpf"] = a.ekpf_duration
    rows = []
    for i, case in enumerate(cases):
        if i:
            print()
        if a.instructions:
            rows.append(measure_instructions(case, durations[case], a.seed, a.ekpf_kernel, a.batch))
        else:
            rows.append(measure_cpu(case, durations[case], a.seed, a.repeats, a.ekpf_kernel, a.batch))
        sys.stdout.flush()
    if len(rows) > 1:
        unit = "G instr" if a.instructions else "CPU s"
        print(f"\nsummary, seed {a.seed} ({'callgrind instructions' if a.instructions else f'best of {a.repeats}'}):")
        print(
            f"  {'case':<8} {'duration':>9} {'peer (' + unit + ')':>15} {'drake_att (' + unit + ')':>20} "
            f"{'drake_att / peer':>17}  RMSE in class"
        )
        for r in rows:
            print(
                f"  {r['case']:<8} {r['duration']:>7.0f} s {r['peer']:>15.3f} {r['lib']:>20.3f} {r['ratio']:>17.2f}  "
                + ("yes" if r["same"] else "NO")
            )


if __name__ == "__main__":
    main()
