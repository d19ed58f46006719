"""``python -m arbor``: sweeps and their plots.

python -m arbor sweep SWEEP.toml --out DIR [--jobs N] [--ray ADDRESS|local]
python -m arbor plot DIR/results.parquet --x param.set.m --y result.ms --out fig.svg
"""

from __future__ import annotations

import argparse
import sys
from typing import Sequence

from . import plot, sweep


def main(argv: Sequence[str] | None = None) -> int:
    """Runs ``python -m arbor`` with ``argv`` (default: the process's arguments)."""
    ap = argparse.ArgumentParser(
        prog="python -m arbor", description="Arbor sweeps: run a sweep file, plot its results."
    )
    sub = ap.add_subparsers(dest="command", required=True)
    sweep.add_arguments(
        sub.add_parser(
            "sweep",
            help="run a sweep file on this machine or a Ray cluster",
            description=sweep.__doc__.split("\n\n")[0] if sweep.__doc__ else None,
        )
    )
    plot.add_arguments(
        sub.add_parser("plot", help="plot a metric of a results file against one parameter")
    )
    a = ap.parse_args(argv)
    if a.command == "sweep":
        return sweep.main_args(a)
    return plot.main_args(a)


if __name__ == "__main__":
    sys.exit(main())
