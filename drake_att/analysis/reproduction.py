"""The paper scripts' reference settings (``diagrams/``): their option defaults are the runs
the documentation's tables come from. A quick look with less (fewer seeds, a shorter run,
fewer particles, a skipped study) prints the same verdicts, which then say nothing about the
paper; :func:`reduced_settings_note` says so under the claims.
"""

from __future__ import annotations

import argparse


def reduced_settings(args: argparse.Namespace, parser: argparse.ArgumentParser, options) -> list[str]:
    """``--option value (reference default)`` for each of ``options`` (dest names) that is
    below its default or set where the default is the scenario's own (None), or a
    ``--no-...`` flag that is set (a study skipped)."""
    out = []
    for dest in options:
        value, default = getattr(args, dest), parser.get_default(dest)
        flag = "--" + dest.replace("_", "-")
        if isinstance(default, bool):
            if value and not default:
                out.append(f"{flag} (the reference runs it)")
        elif default is None and value is not None:
            out.append(f"{flag} {value:g} (reference: the scenario's)")
        elif value is not None and default is not None and value < default:
            out.append(f"{flag} {value:g} (reference {default:g})")
    return out


def reduced_settings_note(args: argparse.Namespace, parser: argparse.ArgumentParser, options) -> str:
    """The line printed under a script's claims when it ran with reduced settings ('' when it
    ran at the reference settings)."""
    reduced = reduced_settings(args, parser, options)
    if not reduced:
        return ""
    return (
        "  NOTE: reduced settings ("
        + ", ".join(reduced)
        + "): the verdicts below are not evidence about the paper; they hold or fail at the "
        "script's default settings"
    )
