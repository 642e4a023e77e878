"""Which signals a run logs and how often: a scenario's ``logging:`` section
(:class:`~drake_att.scenarios.config.LoggingConfig`) resolved against the signals the builder
can log. No Drake here; the builder (:class:`~drake_att.scenarios.builder.ScenarioDiagram`)
wires what :func:`plan_logging` returns.

**Periods.** Every signal has its own period (the truth: the smallest sensor or estimator
period; a sensor's port: its sample period; an estimator's ports: its filter step). A logged
period is ``n`` own periods, ``n >= 1``:

* ``logging.periods_s[key or pattern]``: must be ``n`` own periods (within 1e-9 relative),
  else refused; an exact key wins over patterns, and patterns matching one key must agree;
* else ``logging.period_s``: ``n = max(1, floor(period_s / own period))`` (at most
  ``period_s`` apart; a slower signal keeps its own period);
* else ``n = 1`` (the default: every signal at its own period, as without a policy).

**Sample times of a decimated signal** (``n > 1``, logged period ``P``): its samples are at
``t_k = k P``, ``k = 0, 1, ...`` while ``t_k + P <= duration`` (the builder logs through
holds, see :class:`~drake_att.scenarios.builder.ScenarioDiagram`):

* the truth and a sensor's port: the value the full-rate log holds at ``t_k``;
* an estimator's port: its value just after its update at ``t_k`` (the estimate of ``t_k``;
  the full-rate log holds it at ``t_k`` + one filter step, since Drake publishes before the
  updates of an instant).

So an estimate logged every ``P_e`` is scored against the truth at its own time when ``P_e``
is a multiple of the truth's logged period (and of the true gyro bias's, and of the truth
rate's for a body-rate estimator): :func:`plan_logging` refuses a policy where it is not.

**Exclusion.** ``logging.exclude`` patterns drop signals, except what scoring needs
(``required``: the truth, each estimator's estimate, the true gyro bias).

Its one job: the logging plan, checked, with one-line errors naming the ``logging.`` field.
"""

from __future__ import annotations

import fnmatch
import math
from dataclasses import dataclass

from drake_att.validation import ConfigError

RELATIVE_TOLERANCE = 1e-9  # a period within this of n own periods is n own periods


@dataclass(frozen=True)
class Signal:
    """One logger the builder can add.

    Attributes:
        key: ``"<system>/<port>"`` of the logged port.
        parts: the keys the log holds for it (a packed estimate: its four ports; else ``(key,)``).
        period_s: the signal's own period (s).
        estimator: True for an estimator's port (sampled just after its update when decimated).
    """

    key: str
    parts: tuple
    period_s: float
    estimator: bool = False


@dataclass(frozen=True)
class Alignment:
    """An estimate scored against reference signals at its own times: ``estimate`` (a part
    key) must be logged at a multiple of each ``references`` key's period."""

    estimator: str
    estimate: str
    references: tuple  # ((part key, what it is), ...)


def _short_list(keys, limit: int = 12) -> str:
    keys = list(keys)
    text = ", ".join(keys[:limit])
    return f"[{text}{', ...' if len(keys) > limit else ''}]"


def _multiple(period: float, own: float) -> int | None:
    """``n`` with ``period == n * own`` (relative tolerance), or None."""
    n = round(period / own)
    return n if n >= 1 and abs(period - n * own) <= RELATIVE_TOLERANCE * period else None


def _examples(own: float) -> str:
    return ", ".join(f"{k * own:g}" for k in (1, 2, 10))


def resolve_period(policy, part: str, own_period_s: float) -> tuple[float, int, str]:
    """``(logged period, n own periods, the field that set it)`` of signal ``part`` (a key such as
    ``"st1/star_tracker_measurement"``) whose own period is ``own_period_s``: an exact key of
    ``periods_s``, else its matching pattern, else ``period_s`` rounded down to a multiple (at
    least 1), else its own period.

    Raises:
        ConfigError: two patterns give it different periods, or a ``periods_s`` value is not a
            positive multiple of its own period.
    """
    T = own_period_s
    if part in policy.periods_s:
        matches = {part: policy.periods_s[part]}
    else:
        matches = {k: v for k, v in policy.periods_s.items() if fnmatch.fnmatchcase(part, k)}
    if len(set(matches.values())) > 1:
        (a, pa), (b, pb) = list(matches.items())[:2]
        raise ConfigError(
            f"logging.periods_s: the patterns {a!r} ({pa:g} s) and {b!r} ({pb:g} s) both match {part!r}; "
            "give it one period (an exact key wins over patterns)"
        )
    if matches:
        field, P = next(iter(matches.items()))
        n = _multiple(float(P), T)
        if n is None:
            raise ConfigError(
                f"logging.periods_s[{field!r}]: got {P:g} for {part!r}; must be a positive multiple of its "
                f"own period {T:g} s (e.g. {_examples(T)})"
            )
        return n * T, n, f"logging.periods_s[{field!r}]"
    if policy.period_s is not None:
        n = max(1, math.floor(float(policy.period_s) / T * (1 + RELATIVE_TOLERANCE)))
        return n * T, n, "logging.period_s"
    return T, 1, "its own period"


def is_excluded(policy, part: str) -> bool:
    """Whether a pattern of ``exclude`` matches signal ``part``."""
    return any(fnmatch.fnmatchcase(part, pattern) for pattern in policy.exclude)


def plan_logging(policy, signals, required: dict, alignments=(), duration_s: float | None = None) -> dict:
    """The logged period of every signal the policy keeps.

    Args:
        policy: a :class:`~drake_att.scenarios.config.LoggingConfig` (validated).
        signals: the :class:`Signal` s the builder can log, in its order.
        required: part key -> what it is (e.g. ``"the truth attitude"``), for the signals
            scoring needs.
        alignments: :class:`Alignment` s to check.
        duration_s: the run's duration: a scored estimate must have a sample in it.

    Returns:
        ``{signal key: (logged period, n)}`` for the kept signals (``n`` own periods; ``n == 1``:
        logged as without a policy), in ``signals``' order.

    Raises:
        ConfigError: one line naming the ``logging.`` field, the value and what is allowed.
    """
    parts = [p for s in signals for p in s.parts]
    own = {p: s.period_s for s in signals for p in s.parts}
    for key in policy.periods_s:
        if not any(fnmatch.fnmatchcase(p, key) for p in parts):
            raise ConfigError(
                f"logging.periods_s[{key!r}]: matches no logged signal; signals: {_short_list(parts)} "
                "(keys or fnmatch patterns, e.g. 'st1/*', '*/innovations')"
            )
    excluded = set()
    for i, pattern in enumerate(policy.exclude):
        hits = [p for p in parts if fnmatch.fnmatchcase(p, pattern)]
        if not hits:
            raise ConfigError(
                f"logging.exclude[{i}]: got {pattern!r}, which matches no logged signal; signals: {_short_list(parts)}"
            )
        needed = [p for p in hits if p in required]
        if needed:
            raise ConfigError(
                f"logging.exclude[{i}]: got {pattern!r}, which matches {needed[0]!r} ({required[needed[0]]}); "
                "scoring needs it: the truth, each estimator's estimate and the true gyro bias cannot be excluded"
            )
        excluded.update(hits)

    plan = {}
    for s in signals:
        kept = [p for p in s.parts if p not in excluded]
        if not kept:
            continue
        resolved = {p: resolve_period(policy, p, own[p]) for p in s.parts}
        if len({r[1] for r in resolved.values()}) > 1:
            a, b = s.parts[0], next(p for p in s.parts if resolved[p][1] != resolved[s.parts[0]][1])
            raise ConfigError(
                f"{resolved[b][2]}: {b!r} would be logged every {resolved[b][0]:g} s and {a!r} every "
                f"{resolved[a][0]:g} s; they are one logged port ({s.key}): give them one period"
            )
        if len(kept) != len(s.parts):
            raise ConfigError(
                f"logging.exclude: drops {sorted(set(s.parts) - set(kept))} but not {kept}; they are one logged "
                f"port ({s.key}): exclude all or none"
            )
        period, n, _ = resolved[s.parts[0]]
        plan[s.key] = (period, n)
    logged = {p: plan[s.key] for s in signals if s.key in plan for p in s.parts}
    for a in alignments:
        pe, ne = logged[a.estimate]
        for ref, what in a.references:
            pr, nr = logged[ref]
            if ne == 1 and nr == 1:
                continue  # as without a policy
            if _multiple(pe, pr) is None:
                raise ConfigError(
                    f"logging: the estimate of {a.estimator!r} would be logged every {pe:g} s and {ref!r} ({what}) "
                    f"every {pr:g} s; an estimate is scored against it at the estimate's time, so its period must be "
                    f"a multiple of {pr:g} s (set logging.periods_s for '{a.estimate.split('/')[0]}/*' or {ref!r})"
                )
        if ne > 1 and duration_s is not None and 2 * pe > duration_s * (1 + RELATIVE_TOLERANCE):
            raise ConfigError(
                f"logging: the estimate of {a.estimator!r} would be logged every {pe:g} s, and a run of "
                f"{duration_s:g} s would hold at most one sample of it; its period must be at most half the "
                f"duration (a shorter run: --set logging.period_s={max(duration_s / 2, 0.0):g} or less)"
            )
    return plan


def describe_plan(signals, plan: dict) -> dict:
    """What a run's metadata records: ``{"periods_s": {part key: logged period}, "excluded": [...]}``."""
    periods, excluded = {}, []
    for s in signals:
        for p in s.parts:
            if s.key in plan:
                periods[p] = float(plan[s.key][0])
            else:
                excluded.append(p)
    return {"periods_s": periods, "excluded": excluded}
