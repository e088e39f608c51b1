"""argparse types of the command lines: finite numbers in a range, with one-line reasons."""

from __future__ import annotations

import argparse
import math


def number_in(kind: type, least: float, most: float | None = None, *, open_low: bool = False,
              open_high: bool = False, reason: str | None = None):
    """argparse type: a finite ``kind`` in [least, most] (ends open where asked); else the one-line
    "must <reason>, got <text>" (default reason: "be at least / above <least>" or "lie in [least, most]")."""
    if reason is None:
        if most is None:
            reason = f"be {'above' if open_low else 'at least'} {least}"
        else:
            reason = f"lie in {'(' if open_low else '['}{least}, {most}{')' if open_high else ']'}"

    def parse(text: str):
        value = kind(text)
        low_ok = value > least if open_low else value >= least
        high_ok = most is None or (value < most if open_high else value <= most)
        if not (math.isfinite(value) and low_ok and high_ok):
            raise argparse.ArgumentTypeError(f"must {reason}, got {text}")
        return value

    parse.__name__ = kind.__name__  # argparse names the type in "invalid int value: 'x'"
    return parse


positive_int = number_in(int, 1)  # frame counts: 0 or fewer would write or compare nothing
count_int = number_in(int, 0, reason="be 0 (no limit) or more")
seed_int = number_in(int, 0, reason="be 0 or more")  # numpy's seed sequences take no negatives
non_negative_float = number_in(float, 0.0, reason="be a finite number of 0 or more")  # times, timeouts
positive_float = number_in(float, 0.0, open_low=True, reason="be a finite number above 0")  # rates, durations
workers_int = number_in(int, 0, reason="be 0 (in this process) or more")  # worker processes (sweep: Dask; gap: forked)
port_int = number_in(int, 0, 65535, reason="be a TCP port, 0 (any free port) to 65535")
