"""The paper reproductions' interval tables (docs/papers/intervals): the confidence interval,
and the committed fragments against what make_tables.py renders."""

from __future__ import annotations

import importlib.util
import json
import math
import os
import re

import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
INTERVALS = os.path.join(ROOT, "docs", "papers", "intervals")
PAPERS = ("s0", "s1", "s2", "s3", "s4")


def _load(name):
    spec = importlib.util.spec_from_file_location(name, os.path.join(INTERVALS, f"{name}.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


mt = _load("make_tables")
run_all = _load("run_all")


# ----------------------------------------------------------------------------------------
# The interval
# ----------------------------------------------------------------------------------------
def t975_two_dof():
    """Student's t 0.975 quantile at 2 dof from its closed form, (2p-1)/sqrt(2p(1-p))."""
    p = 0.975
    return (2 * p - 1) / math.sqrt(2 * p * (1 - p))


def test_ci_hand_worked_three_values():
    # [1, 2, 3]: mean 2, sample standard deviation 1, n = 3 -> half width t(0.975, 2) / sqrt(3).
    mean, half, n = mt.mean_ci95([1.0, 2.0, 3.0])
    assert (mean, n) == (2.0, 3)
    assert half == pytest.approx(t975_two_dof() / math.sqrt(3.0), rel=1e-12)
    assert half == pytest.approx(2.4841, abs=1e-4)


def test_ci_hand_worked_two_values():
    # [0, 1]: s = sqrt(1/2), n = 2, t(0.975, 1) = tan(0.475 pi) (the Cauchy quantile).
    mean, half, n = mt.mean_ci95([0.0, 1.0])
    assert (mean, n) == (0.5, 2)
    assert half == pytest.approx(math.tan(0.475 * math.pi) * math.sqrt(0.5) / math.sqrt(2.0), rel=1e-12)


def test_ci_thirty_values_uses_the_tabulated_quantile():
    x = np.arange(30.0) ** 1.5
    mean, half, n = mt.mean_ci95(x)
    s = math.sqrt(sum((v - x.mean()) ** 2 for v in x) / 29)
    assert n == 30 and mean == pytest.approx(sum(x) / 30)
    assert half == pytest.approx(2.045229642 * s / math.sqrt(30), rel=1e-8)  # t(0.975, 29), printed tables


def test_ci_covers_the_true_mean_95_percent_of_the_time():
    rng = np.random.default_rng(7)
    trials, covered = 4000, 0
    for _ in range(trials):
        x = rng.exponential(2.0, size=30) + rng.normal(0.0, 1.0, size=30)
        mean, half, _ = mt.mean_ci95(x)
        covered += abs(mean - 2.0) <= half
    # binomial sd at 95% and 4000 trials: 0.0034; a skewed sample loses ~1% coverage at n = 30
    assert 0.925 <= covered / trials <= 0.965


@pytest.mark.parametrize("bad", [[1.0], [], [1.0, float("nan")], [[1.0, 2.0], [3.0, 4.0]]])
def test_ci_refuses_too_few_or_non_finite_values(bad):
    with pytest.raises(ValueError, match="values: got"):
        mt.mean_ci95(bad)


def row_numbers(line):
    """(mean, half width, low, high) printed in a table row."""
    m = re.search(r"\| ([-0-9.e]+) ± ([-0-9.e]+) \| \[([-0-9.e]+), ([-0-9.e]+)\] \|$", line)
    assert m, line
    return [float(g) for g in m.groups()]


def test_row_with_missing_seeds_says_how_many():
    line = mt.format_row(mt.value_row("NEES", [1.0, None, 3.0]), 3)
    s = math.sqrt(2.0)  # sample standard deviation of [1, 3]
    half = math.tan(0.475 * math.pi) * s / math.sqrt(2.0)
    assert line.startswith("| NEES (2 of 3 seeds) | – | ")
    mean, printed_half, lo, hi = row_numbers(line)
    assert (mean, lo, hi) == pytest.approx((2.0, 2.0 - half, 2.0 + half), rel=5e-3)
    assert printed_half == pytest.approx(half, rel=5e-2)  # printed to 2 significant digits


# ----------------------------------------------------------------------------------------
# A tiny synthetic result set in each input's format
# ----------------------------------------------------------------------------------------
SEEDS = [1, 2, 3]


def fake_estimator(rng, second="gyro_bias"):
    m = {
        "attitude_rmse_deg": rng.uniform(1e-3, 2e-3, 3).tolist(),
        "attitude_rmse_total_deg": float(rng.uniform(1e-3, 2e-3)),
        "bias_rmse_deg_per_h": rng.uniform(0.1, 0.2, 3).tolist() if second == "gyro_bias" else None,
        "rate_rmse_deg_per_s": rng.uniform(1e-4, 2e-4, 3).tolist() if second == "body_rate" else None,
        "nees_mean": float(rng.uniform(5.0, 7.0)),
        "convergence_time_s": float(rng.uniform(0, 10)),
        "scored_from_s": 500.0,
    }
    return m


def fake_metrics(rng, names, second="gyro_bias"):
    return {"duration_s": 1000.0, "estimators": {n: fake_estimator(rng, second) for n in names}}


def write_provenance(folder):
    run_all.write_provenance(str(folder), f"synthetic {os.path.basename(folder)}", 60.0, "2000-01-01")


def write_json(folder, obj):
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "results.json").write_text(json.dumps(obj))
    write_provenance(folder)


def write_campaign(folder, names, rng):
    (folder / "runs").mkdir(parents=True)
    for s in SEEDS:
        np.savez(folder / "runs" / f"seed_{s}.npz", metrics_json=np.array(json.dumps(fake_metrics(rng, names))))
    write_provenance(folder)


def per_seed(rng, names):
    return {n: rng.uniform(0.1, 1.0, len(SEEDS)).tolist() for n in names}


def synthetic_inputs(root, rng):
    small = ["ekf", "bootstrap_pf", "bootstrap_pf_true_arw", "bootstrap_pf_roughened", "ekpf"]
    large = ["ekf", "ekpf", "ekpf_iterated", "ekf_iterated"]
    gyroless = ["gyroless_pf", "gyroless_pf_paper"]
    write_json(
        root / "s0",
        {
            "seeds": SEEDS,
            "particles": 1000,
            "duration_s": 1000.0,
            "claims": [
                {
                    "claim": "1. x",
                    "per_seed": {
                        "bias_error_final_deg_per_h": per_seed(rng, small),
                        "bias_sigma_final_deg_per_h": per_seed(rng, small),
                    },
                },
                {"claim": "3. x", "per_seed": {"final_error_deg": per_seed(rng, large)}},
                {"claim": "4. x", "per_seed": {"peak_rate_error_deg_per_s": per_seed(rng, gyroless)}},
            ],
            "metrics": {
                "s0_particle_filters_small_error": [fake_metrics(rng, small) for _ in SEEDS],
                "s0_particle_filters_large_error": [fake_metrics(rng, large) for _ in SEEDS],
                "s0_gyroless_pf": [fake_metrics(rng, gyroless, "body_rate") for _ in SEEDS],
            },
        },
    )
    write_campaign(root / "s1", ["cqe", "cqe_mcns", "mekf"], rng)
    write_campaign(root / "s3", ["single", "centralized", "single_st2", "joint", "decentralized"], rng)
    dyn_case = {
        "rmse_moving_roll_pitch_yaw_deg": [1e-3, 2e-3, 3e-3],
        "fused_rmse_moving_at_frames_roll_pitch_yaw_deg": [1e-3, 2e-3, 3e-3],
        "outage_max_error_deg": {"indoor_star_tracker": 0.5, "indoor_star_tracker_gyro": 0.03},
        "stars_identified_first_frame": 49,
    }
    write_json(
        root / "s2",
        {
            "seeds": SEEDS,
            "table2": {
                "centroid_noise_0.05px": {
                    "per_seed_abs_error_pitch_roll_yaw_deg": rng.uniform(0, 1e-2, (3, 5, 3)).tolist(),
                    "per_seed_stars": rng.integers(3, 8, (3, 5)).tolist(),
                }
            },
            "dynamic_per_seed": [
                {"seed": s, "centroid_noise_0.1px": dyn_case, "least_squares_0.1px": dyn_case} for s in SEEDS
            ],
        },
    )
    filters = ["lie_group", "lie_group_paper_literal", "quaternion_ekf"]
    write_json(
        root / "s4",
        {
            "seeds": SEEDS,
            "duration_s": 600.0,
            "claims": [{"per_seed": rng.uniform(100, 200, 3).tolist()} for _ in range(3)],
            "table": [
                {
                    "case": c,
                    "filter": f,
                    "steady_rmse_deg_seeds": rng.uniform(0, 1, 3).tolist(),
                    "nees_attitude_3dof_seeds": rng.uniform(0, 4, 3).tolist(),
                }
                for c in ("noise_free", "100urad_nav_gyro", "tuning_as_truth")
                for f in filters
            ],
        },
    )
    bench = {}
    for name, (_, labels) in mt.BENCH_LABELS.items():
        runs = []
        for _ in SEEDS:
            m = fake_metrics(rng, list(labels))["estimators"]
            runs.append({"metrics": m, "extra": {e: {"nees3_mean": float(rng.uniform(2, 4))} for e in labels}})
        bench[name] = {"runs": runs}
    write_json(root / "s4_bench", {"seeds": SEEDS, "scenarios": bench})


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    root = tmp_path_factory.mktemp("paper_results")
    synthetic_inputs(root, np.random.default_rng(1))
    out = tmp_path_factory.mktemp("fragments")
    assert mt.main(["--root", str(root), "--out", str(out), "--machine", "test machine"]) == 0
    return root, out


def table_labels(text):
    """Per ``####`` section: its title and the first cell of each table row (the seed-count
    suffix of rows with missing values dropped)."""
    sections, current = [], None
    for line in text.splitlines():
        if line.startswith("#### "):
            current = (line[5:], [])
            sections.append(current)
        elif line.startswith("| ") and current is not None and not line.startswith("| quantity"):
            current[1].append(re.sub(r" \(\d+ of \d+ seeds\)$", "", line.split(" | ")[0][2:]))
    return sections


def without_seed_counts(sections):
    return [(re.sub(r"\d+", "N", title), labels) for title, labels in sections]


@pytest.mark.parametrize("paper", PAPERS)
def test_committed_fragment_has_the_rendered_structure(synthetic, paper):
    _, out = synthetic
    rendered = (out / f"{paper}.md").read_text()
    with open(os.path.join(INTERVALS, f"{paper}.md")) as f:
        committed = f.read()
    assert without_seed_counts(table_labels(committed)) == without_seed_counts(table_labels(rendered))
    for text in (committed, rendered):
        assert text.startswith("### 30-seed intervals\n")
        assert not re.search(r"^# ", text, re.M)
        assert "```bash\n" in text and "Machine time: " in text and "Date: " in text


@pytest.mark.parametrize("paper", PAPERS)
def test_committed_fragment_is_the_render_of_its_committed_data(paper):
    with open(os.path.join(INTERVALS, "data", f"{paper}.json")) as f:
        data = json.load(f)
    with open(os.path.join(INTERVALS, f"{paper}.md")) as f:
        assert f.read() == mt.render(data)
    assert len(data["seeds"]) >= 10
    assert all(r["command"] and r["wall_s"] > 0 for r in data["runs"])


def test_synthetic_row_is_the_interval_of_its_per_seed_values(synthetic):
    root, out = synthetic
    res = json.loads((root / "s4" / "results.json").read_text())
    values = res["table"][0]["steady_rmse_deg_seeds"]
    x = np.array(values)
    half = 4.302652729911275 * x.std(ddof=1) / math.sqrt(3)  # t(0.975, 2) from printed tables
    line = next(row for row in (out / "s4.md").read_text().splitlines() if row.startswith("| lie_group steady RMSE"))
    mean, printed_half, lo, hi = row_numbers(line)
    assert mean == pytest.approx(x.mean(), rel=5e-3) and printed_half == pytest.approx(half, rel=5e-2)
    assert (lo, hi) == pytest.approx((x.mean() - half, x.mean() + half), rel=5e-3)
    assert "synthetic s4" in (out / "s4.md").read_text() and "1.0 min" in (out / "s4.md").read_text()


def test_missing_provenance_is_named(tmp_path):
    synthetic_inputs(tmp_path, np.random.default_rng(2))
    os.remove(tmp_path / "s1" / "provenance.json")
    with pytest.raises(FileNotFoundError, match="provenance.json: missing"):
        mt.main(["--root", str(tmp_path), "--out", str(tmp_path / "o"), "--papers", "s1"])
