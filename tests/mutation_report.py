"""Summarize a mutation run (``tests/mutation_run.py``): figures per module, and every
surviving mutant not judged equivalent in ``tests/mutation_equivalents.txt``.

Each line of that file is ``<mutant name>  <one-line reason>``; ``#`` starts a comment.
Mutant names are ``<module>.x_<function>__mutmut_<n>`` and change when the function
changes, so the file is re-judged after each run (``cd <work>/<module> && mutmut show
<name>`` prints the diff).

    .venv/bin/python tests/mutation_report.py [--work DIR]

Exit status 0 when every survivor is judged equivalent, 1 otherwise.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
MUTMUT = os.path.join(os.path.dirname(sys.executable), "mutmut")
EQUIVALENTS = os.path.join(HERE, "mutation_equivalents.txt")
sys.path.insert(0, HERE)
from mutation_run import DEFAULT_WORK, MODULES  # noqa: E402
from mutation_run import _statuses as results  # noqa: E402


def judged_equivalent(path: str = EQUIVALENTS) -> dict[str, str]:
    out = {}
    if os.path.exists(path):
        for line in open(path):
            line = line.split("#", 1)[0].strip()
            if line:
                name, _, reason = line.partition(" ")
                out[name] = reason.strip()
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--work", default=DEFAULT_WORK)
    args = ap.parse_args(argv)
    equivalent = judged_equivalent()
    totals: dict[str, int] = {}
    unjudged = []
    for key, (_mutated, _tests) in MODULES.items():
        folder = os.path.join(args.work, key)
        if not os.path.isdir(os.path.join(folder, "mutants")):
            print(f"{key:<20} not run")
            continue
        res = results(folder)
        sample_path = os.path.join(folder, "SAMPLE")
        sampled = None
        if os.path.exists(sample_path):
            lines = open(sample_path).read().splitlines()
            sampled = set(lines[1:])
            res = {n: s for n, s in res.items() if n in sampled}
        counts: dict[str, int] = {}
        for status in res.values():
            counts[status] = counts.get(status, 0) + 1
            totals[status] = totals.get(status, 0) + 1
        survivors = sorted(n for n, s in res.items() if s == "survived")
        judged = [n for n in survivors if n in equivalent]
        unjudged += [n for n in survivors if n not in equivalent]
        commit = (
            open(os.path.join(folder, "COMMIT")).read().strip()[:10]
            if os.path.exists(os.path.join(folder, "COMMIT"))
            else "?"
        )
        killed = counts.get("killed", 0) + counts.get("timeout", 0)
        score = (killed + len(judged)) / max(1, len(res))
        print(
            f"{key:<20} {len(res):5d} mutants{' (sample)' if sampled else ''}  "
            + ", ".join(f"{k} {v}" for k, v in sorted(counts.items()))
            + f"  (equivalent {len(judged)}; score {score:.3f}; commit {commit})"
        )
    totals["survived_judged_equivalent"] = totals.get("survived", 0) - len(unjudged)
    print(json.dumps(totals, indent=1, sort_keys=True))
    for n in unjudged:
        print(f"SURVIVED (not judged equivalent): {n}")
    return 1 if unjudged else 0


if __name__ == "__main__":
    sys.exit(main())
