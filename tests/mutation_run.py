"""Mutation testing of the math and filter-core modules (``make mutation``; not part of
``make test``).

Each module is mutated against its own fast unit tests (``MODULES``), in a clean snapshot
of the committed code (``git archive HEAD``), one mutmut run per module in its own folder
under ``--work`` (default ``/tmp/drake_att_mutation``): editing the working tree while
mutmut generates its mutants cannot leak into the run, and modules run in sequence.
Hypothesis runs its derandomized ``mutation`` profile (fewer examples).

    .venv/bin/python tests/mutation_run.py [--modules rotations noise ...] [--sample N] [--work DIR]
    .venv/bin/python tests/mutation_report.py [--work DIR]     # figures, unjudged survivors

``--sample N`` runs a seeded random sample of N mutants per module (all are generated;
the report then estimates each module's mutation score from the sample): a full run takes
about 1.3 s per mutant per core here (mutmut's per-mutant pytest start-up dominates), i.e.
about two hours for the ~5000 mutants of these modules on 2 cores.

The shared mutmut settings (what is never mutated, timeouts) are ``[tool.mutmut]`` in
pyproject.toml; this script sets ``only_mutate`` and the test selection per module.
"""

from __future__ import annotations

import argparse
import os
import random
import re
import shutil
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
MUTMUT = os.path.join(os.path.dirname(sys.executable), "mutmut")
DEFAULT_WORK = "/tmp/drake_att_mutation"

_CAMPAIGN_TESTS = [
    "tests/test_campaign_bookkeeping.py",
    "tests/test_campaign_edges.py",
    "tests/test_montecarlo.py",
    "-k",  # the timing probes and the browser are not what a mutant of the campaign changes
    # (the documented snippet is read from README.md, which mutmut's folder does not hold)
    "not deadline and not http_server and not silent and not probe and not chromium and not ctrl_c and not snippet",
    "--timeout=60",
]  # a hung mutant is killed in a minute

# module key -> (file mutated, the unit tests that exercise it)
MODULES = {
    "rotations": (
        "drake_att/rotations.py",
        ["tests/test_rotations.py", "tests/test_quaternion_average.py", "tests/test_mrp_ekf.py"],
    ),
    "noise": ("drake_att/noise.py", ["tests/test_sensors.py", "tests/test_noise.py"]),
    "metrics": (
        "drake_att/analysis/metrics.py",
        ["tests/test_metrics.py", "tests/test_tracker_exclusion.py", "-k", "not every_vector"],
    ),
    "quaternion_average": ("drake_att/filters/quaternion_average.py", ["tests/test_quaternion_average.py"]),
    "mekf": ("drake_att/filters/mekf.py", ["tests/test_mekf.py"]),
    "mrp_ekf": (
        "drake_att/filters/mrp_ekf.py",
        ["tests/test_mrp_ekf.py", "tests/test_particle_filters.py", "tests/test_particle_weights.py"],
    ),
    "contract": ("drake_att/contract.py", ["tests/test_contract.py", "tests/test_plugins.py", "-k", "contract"]),
    "particle": (
        "drake_att/filters/particle.py",
        ["tests/test_particle_filters.py", "tests/test_particle_weights.py", "tests/test_particle_systems.py"],
    ),
    # Added with papers S4 and S1 and the validation family (not yet run: see tests/README.md).
    "validation": (
        "drake_att/validation.py",
        [
            "tests/test_mrp_ekf.py",
            "tests/test_particle_filters.py",
            "tests/test_quaternion_average.py",
            "tests/test_scenarios.py",
        ],
    ),
    "lie_group": ("drake_att/filters/lie_group.py", ["tests/test_lie_group.py"]),
    "quaternion_ekf": ("drake_att/filters/quaternion_ekf.py", ["tests/test_quaternion_ekf.py"]),
    "cubature": ("drake_att/filters/cubature.py", ["tests/test_cubature.py"]),
    "multiplicative_noise": (
        "drake_att/filters/multiplicative_noise.py",
        ["tests/test_cubature.py", "tests/test_correlated_noise.py"],
    ),
    # Added with paper S2 and the gate.
    "gating": ("drake_att/filters/gating.py", ["tests/test_gating.py"]),
    # The estimator loop's rules, shared by the Python loop and the compiled step (so the two
    # loops' equivalence test cannot see a change to a rule: the rules' own semantics must).
    "estimator_step": (
        "drake_att/systems/estimator_step.py",
        [
            "tests/test_estimator_step.py",
            "tests/test_contract.py",
            "tests/test_plugins.py",
            "tests/test_gating.py",
            "tests/test_faults.py",
            "tests/test_fusion.py",
            "-m",
            "not slow",
            "-k",
            "not tutorial",
            "--timeout=120",
            "tests/test_sample_handling.py",
        ],
    ),  # the tutorial runs the CLI in a temporary folder
    # (test_compiled_step.py is left out: under mutmut the rules cannot be compiled, see conftest.py)
    "screen_geometry": ("drake_att/screen_geometry.py", ["tests/test_indoor_star_tracker.py", "-k", "not swarm"]),
    "indoor_star_tracker": (
        "drake_att/filters/indoor_star_tracker.py",
        ["tests/test_indoor_star_tracker.py", "-k", "not swarm and not diagram"],
    ),
    # The edges: output folders and physical ranges.
    "outputs": ("drake_att/outputs.py", ["tests/test_outputs.py"]),
    "interrupts": ("drake_att/interrupts.py", ["tests/test_interrupts.py"]),
    "reproduction": ("drake_att/analysis/reproduction.py", ["tests/test_reproduction.py"]),
    # The mission environment: orbits, exclusion geometry.
    "orbit_propagators": ("drake_att/orbit_propagators.py", ["tests/test_orbit_propagators.py"]),
    "exclusion": ("drake_att/exclusion.py", ["tests/test_exclusion.py", "tests/test_tracker_exclusion.py"]),
    "attitude_control": ("drake_att/systems/attitude_control.py", ["tests/test_attitude_control.py"]),
    "mission": ("drake_att/analysis/mission.py", ["tests/test_mission.py"]),
    "coarse_sensors": ("drake_att/systems/coarse_sensors.py", ["tests/test_coarse_sensors.py"]),
    "logging_policy": ("drake_att/scenarios/logging_policy.py", ["tests/test_logging_policy.py"]),
    "fdir": ("drake_att/fdir.py", ["tests/test_fdir.py", "tests/test_fdir_scenario.py"]),
    "sensor_monitor": ("drake_att/systems/sensor_monitor.py", ["tests/test_fdir.py", "tests/test_fdir_scenario.py"]),
    "screen_calibration": ("drake_att/filters/screen_calibration.py", ["tests/test_s2_calibration.py"]),
    "star_camera": ("drake_att/star_camera.py", ["tests/test_star_camera.py", "tests/test_star_image.py"]),
    "sky_tracker": ("drake_att/sky_tracker.py", ["tests/test_sky_star_tracker.py"]),
    # (its compiled loops, star_image_kernels.py, cannot run as mutmut's trampolines)
    "star_image": ("drake_att/star_image.py", ["tests/test_star_image.py"]),
    # The sensors and the builder. (tests/test_batch_runs.py is left out: a batch runs the
    # compiled MEKF step, which mutmut's trampolines cannot compile; its hand mutants are in
    # tests/README.md.)
    "gyro": ("drake_att/systems/gyro.py", ["tests/test_sensors.py", "tests/test_sensor_output_equivalence.py"]),
    "star_tracker": (
        "drake_att/systems/star_tracker.py",
        ["tests/test_sensors.py", "tests/test_sensor_output_equivalence.py"],
    ),
    "builder": (
        "drake_att/scenarios/builder.py",
        ["tests/test_scenarios.py", "tests/test_logging_policy.py", "--timeout=120"],
    ),
    "estimator_system": (
        "drake_att/systems/estimator_system.py",
        [
            "tests/test_sample_handling.py",
            "tests/test_estimator_step.py",
            "tests/test_contract.py",
            "tests/test_plugins.py",
            "-m",
            "not slow",
            "-k",
            "not tutorial",
            "--timeout=120",
        ],
    ),
    "campaign_records": (
        "drake_att/analysis/campaign_records.py",
        ["tests/test_campaign_edges.py", "-k", "record or resume or run_file or layout or counts"],
    ),
    "config": (
        "drake_att/scenarios/config.py",
        ["tests/test_config_loading.py", "-k", "not sigterm and not downloaded_folder"],
    ),
    # The outer layers users read their conclusions from (statistics, campaigns, faults, frames, CLI).
    "ensemble": (
        "drake_att/analysis/ensemble.py",
        ["tests/test_ensemble.py", "tests/test_ensemble_definitions.py", "tests/test_bound.py"],
    ),
    "bound": ("drake_att/analysis/bound.py", ["tests/test_bound.py", "tests/test_ensemble_definitions.py"]),
    "report": (
        "drake_att/analysis/report.py",
        ["tests/test_report.py", "tests/test_campaign_bookkeeping.py", "tests/test_ensemble.py"],
    ),
    "plot_lines": ("drake_att/analysis/plot_lines.py", ["tests/test_plot_lines.py"]),
    "analysis_faults": (
        "drake_att/analysis/fault_scores.py",
        ["tests/test_fault_joint.py", "tests/test_faults.py", "tests/test_fdir_scenario.py"],
    ),
    "systems_faults": ("drake_att/systems/fault_injector.py", ["tests/test_faults.py", "tests/test_fault_joint.py"]),
    "fusion": ("drake_att/systems/fusion.py", ["tests/test_fusion.py", "tests/test_fusion_speed_equivalence.py"]),
    "build_context": (
        "drake_att/scenarios/build_context.py",
        ["tests/test_initial_frames.py", "tests/test_faults.py", "tests/test_fusion.py"],
    ),
    # The Monte Carlo modules (analysis/montecarlo.py only re-exports them), one selection.
    **{
        key: (f"drake_att/analysis/{key}.py", _CAMPAIGN_TESTS)
        for key in ("executor", "run_records", "campaign", "campaign_folder", "comparison")
    },
    "selection": (
        "drake_att/scenarios/selection.py",
        [
            "tests/test_campaign_outputs.py",
            "tests/test_sweeps.py",
            "tests/test_bound.py",
            "tests/test_preflight.py",
            "tests/test_selection.py",
            "-m",
            "not slow",
            "--timeout=60",
        ],
    ),
    "cli": (
        "drake_att/cli.py",
        [
            "tests/test_cli_errors.py",
            "tests/test_campaign_bookkeeping.py",
            "tests/test_hostile_inputs.py",
            "tests/test_config_loading.py",
            "tests/test_score.py",
            "-k",
            "not sigterm and not downloaded_folder",
            "--timeout=60",
        ],
    ),  # a mutant that hangs a run is killed in a minute, not pytest.ini's ten
    "ranges": (
        "drake_att/scenarios/ranges.py",
        [
            "tests/test_ranges.py",
            "-k",  # docs/ is not copied; the peak is measured in a child process
            "not config_reference_is_the_rendered_table and not measured_peak",
        ],
    ),
}


def snapshot(dest: str) -> str:
    """The committed tree (HEAD) unpacked into ``dest``; returns the commit."""
    os.makedirs(dest, exist_ok=True)
    archive = subprocess.run(["git", "archive", "HEAD"], cwd=REPO, capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", dest], input=archive, check=True)
    return subprocess.run(
        ["git", "rev-parse", "HEAD"], cwd=REPO, capture_output=True, text=True, check=True
    ).stdout.strip()


def configure(folder: str, mutated: str, tests: list[str]) -> None:
    """Set only_mutate and the test selection of ``folder``'s [tool.mutmut]."""
    path = os.path.join(folder, "pyproject.toml")
    text = open(path).read()
    text = re.sub(r"only_mutate = \[[^\]]*\]", f'only_mutate = ["{mutated}"]', text)
    selection = ",\n".join(f'    "{t}"' for t in tests)
    text = re.sub(
        r"pytest_add_cli_args_test_selection = \[[^\]]*\]",
        f"pytest_add_cli_args_test_selection = [\n{selection},\n]",
        text,
    )
    open(path, "w").write(text)


def _statuses(folder: str) -> dict[str, str]:
    """mutant name -> status, from ``mutmut results --all true`` in ``folder``."""
    text = subprocess.run([MUTMUT, "results", "--all", "true"], cwd=folder, capture_output=True, text=True).stdout
    out = {}
    for line in text.splitlines():
        name, sep, status = line.strip().rpartition(": ")
        if sep:
            out[name] = status
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--modules", nargs="*", default=list(MODULES), choices=list(MODULES))
    ap.add_argument("--work", default=DEFAULT_WORK)
    ap.add_argument("--sample", type=int, default=0, help="mutants per module (0: all)")
    ap.add_argument("--seed", type=int, default=1, help="seed of the sample")
    args = ap.parse_args(argv)
    env = dict(os.environ, MPLBACKEND="Agg", HYPOTHESIS_PROFILE="mutation", OPENBLAS_NUM_THREADS="1")
    for key in args.modules:
        mutated, tests = MODULES[key]
        folder = os.path.join(args.work, key)
        shutil.rmtree(folder, ignore_errors=True)
        commit = snapshot(folder)
        configure(folder, mutated, tests)
        start = time.perf_counter()
        print(f"[{key}] {mutated} against {', '.join(tests)} (commit {commit[:10]})", flush=True)
        run = [MUTMUT, "run", "--max-children", str(os.cpu_count() or 2)]
        with open(os.path.join(folder, "mutmut.log"), "w") as log:
            if args.sample:
                # Generate the mutants and the test statistics (no mutant matches), then sample.
                subprocess.run(run + ["no-such-mutant"], cwd=folder, env=env, stdout=log, stderr=subprocess.STDOUT)
                names = sorted(_statuses(folder))
                chosen = sorted(random.Random(args.seed).sample(names, min(args.sample, len(names))))
                with open(os.path.join(folder, "SAMPLE"), "w") as f:
                    f.write(f"{len(chosen)} of {len(names)} mutants, seed {args.seed}\n" + "\n".join(chosen) + "\n")
                run += chosen
            rc = subprocess.run(run, cwd=folder, env=env, stdout=log, stderr=subprocess.STDOUT).returncode
        with open(os.path.join(folder, "COMMIT"), "w") as f:
            f.write(commit + "\n")
        print(f"[{key}] mutmut exit {rc}, {time.perf_counter() - start:.0f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
