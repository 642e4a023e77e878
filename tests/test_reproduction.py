"""The paper scripts' reduced-settings note: which options count as less than the reference."""

import argparse

from drake_att.analysis.reproduction import reduced_settings, reduced_settings_note


def _parser():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--duration", type=float, default=600.0)
    ap.add_argument("--limit", type=float, default=None)
    ap.add_argument("--no-sweep", action="store_true")
    ap.add_argument("--out", default="out/x")
    return ap


OPTIONS = ("seeds", "duration", "limit", "no_sweep")


def test_the_reference_settings_and_more_print_no_note():
    ap = _parser()
    for argv in ([], ["--seeds", "30"], ["--duration", "600"], ["--seeds", "5", "--out", "elsewhere"]):
        args = ap.parse_args(argv)
        assert reduced_settings(args, ap, OPTIONS) == [] and reduced_settings_note(args, ap, OPTIONS) == "", argv


def test_each_reduction_is_named_with_the_reference():
    ap = _parser()
    args = ap.parse_args(["--seeds", "4", "--duration", "599.5", "--limit", "100", "--no-sweep"])
    assert reduced_settings(args, ap, OPTIONS) == [
        "--seeds 4 (reference 5)",
        "--duration 599.5 (reference 600)",
        "--limit 100 (reference: the scenario's)",
        "--no-sweep (the reference runs it)",
    ]
    note = reduced_settings_note(args, ap, ("seeds", "no_sweep"))
    assert note == (
        "  NOTE: reduced settings (--seeds 4 (reference 5), --no-sweep (the reference runs it)): the verdicts "
        "below are not evidence about the paper; they hold or fail at the script's default settings"
    )
