"""A Drake cache entry for any Python value a system computes from its context.

Several output ports of one sensor often need the same per-sample computation (a tracker's
exclusion causes for its measurement and for its ``exclusion`` port; a coarse sensor's sample for
its observations, its logged measurement and its status): as a cache entry it is computed once
per context change instead of once per port evaluation.
"""

from __future__ import annotations

from collections.abc import Callable

from pydrake.common.value import AbstractValue
from pydrake.systems.framework import ValueProducer


def declare_value_cache(system, name: str, compute: Callable, tickets) -> Callable:
    """Declare cache entry ``name`` on ``system`` holding ``compute(context)``, recomputed when
    one of ``tickets`` (e.g. ``{system.time_ticket(), system.all_input_ports_ticket()}``) changes;
    returns ``context -> value`` (the system's own context)."""

    def calc(context, value):
        value.set_value(compute(context))

    entry = system.DeclareCacheEntry(name, ValueProducer(allocate=lambda: AbstractValue.Make(None), calc=calc), tickets)
    return lambda context: entry.EvalAbstract(context).get_value()
