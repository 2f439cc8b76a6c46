"""``audio2pose faults``: the fault campaign against the live graph (see ``fault_campaign``)."""

from __future__ import annotations

import argparse
from pathlib import Path

from audio2pose_ros.cli.options import Verbs


def command_faults(args: argparse.Namespace) -> int:
    """Run the campaign and print its table; exit status 1 if a case failed."""
    from audio2pose_ros.ros.tools.fault_campaign import cases, run_campaign, table

    chosen = cases()
    if args.case:
        chosen = [c for c in chosen if any(k.lower() in c.name.lower() for k in args.case)]
    rows = run_campaign(chosen, Path(args.log_dir) if args.log_dir else None)
    print(table(rows))
    failed = sum(not outcome.passed for _, outcome in rows)
    print(f"{len(rows) - failed} of {len(rows)} cases passed")
    return 1 if failed else 0


def register(verbs: Verbs) -> None:
    """Add ``audio2pose faults``."""
    faults = verbs.add_parser(
        "faults", help="attack the live node graph with bad inputs and faults; print a table"
    )
    faults.add_argument(
        "--case", action="append", help="run only cases whose name contains this (repeatable)"
    )
    faults.add_argument("--log-dir", help="keep the node logs here")
    faults.set_defaults(func=command_faults)
