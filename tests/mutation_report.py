"""Summarize a mutmut run (``make mutation``): figures, and every surviving mutant that is
not judged equivalent in ``tests/mutation_equivalents.txt``.

Each line of that file is ``<mutant name>  <one-line reason>``; ``#`` starts a comment.
Mutant names are ``<module>.x_<function>__mutmut_<n>`` and change when the function
changes, so the file is re-judged after each run (``mutmut show <name>`` prints the diff).

Exit status 0 when every survivor is judged equivalent, 1 otherwise.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
MUTMUT = os.path.join(os.path.dirname(sys.executable), "mutmut")
EQUIVALENTS = os.path.join(HERE, "mutation_equivalents.txt")


def judged_equivalent(path: str = EQUIVALENTS) -> dict[str, str]:
    out = {}
    if os.path.exists(path):
        for line in open(path):
            line = line.split("#", 1)[0].strip()
            if line:
                name, _, reason = line.partition(" ")
                out[name] = reason.strip()
    return out


def results() -> dict[str, str]:
    """mutant name -> status, from ``mutmut results --all true``."""
    text = subprocess.run([MUTMUT, "results", "--all", "true"], cwd=REPO, capture_output=True,
                          text=True, check=True).stdout
    out = {}
    for line in text.splitlines():
        name, sep, status = line.strip().rpartition(": ")
        if sep:
            out[name] = status
    return out


def main() -> int:
    res = results()
    counts: dict[str, int] = {}
    for status in res.values():
        counts[status] = counts.get(status, 0) + 1
    equivalent = judged_equivalent()
    survivors = sorted(n for n, s in res.items() if s == "survived")
    unjudged = [n for n in survivors if n not in equivalent]
    per_module: dict[str, dict[str, int]] = {}
    for n, s in res.items():
        module = n.split(".x_")[0].split(".xǁ")[0]
        per_module.setdefault(module, {}).setdefault(s, 0)
        per_module[module][s] += 1
    print(json.dumps({"total": len(res), **counts, "survived_judged_equivalent": len(survivors) - len(unjudged),
                      "survived_not_judged": len(unjudged)}, indent=1))
    for module in sorted(per_module):
        print(f"  {module:<36} " + ", ".join(f"{k} {v}" for k, v in sorted(per_module[module].items())))
    for n in unjudged:
        print(f"SURVIVED (not judged equivalent): {n}")
    return 1 if unjudged else 0


if __name__ == "__main__":
    sys.exit(main())
