"""The standard sweep picture: a metric against one parameter, one line per scene.

:func:`plot` reads a sweep's ``results.parquet`` (or ``.csv``), keeps the points that ran,
and draws one panel per metric (rows) and per value of a facet column (columns), with one
line per value of ``by`` (the scene by default), as SVG or PNG (from the file name).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path
from typing import Any, Sequence


class PlotError(ValueError):
    """A plot that cannot be drawn: a missing file or column, nothing to draw."""


def read_results(path: str | os.PathLike[str]) -> list[dict[str, Any]]:
    """The rows of a results file (Parquet or CSV), or of a sweep directory's
    ``results.parquet``."""
    p = Path(path)
    if p.is_dir():
        p = p / "results.parquet"
    if not p.exists():
        raise PlotError(f"{p}: no such results file")
    if p.suffix == ".csv":
        import pyarrow.csv as pacsv

        tbl = pacsv.read_csv(p)
    else:
        import pyarrow.parquet as pq

        try:
            tbl = pq.read_table(p)
        except Exception as e:  # pyarrow raises several kinds for a bad file
            raise PlotError(f"{p}: not a Parquet results file: {e}") from None
    rows: list[dict[str, Any]] = tbl.to_pylist()
    return rows


def _number(v: Any) -> bool:
    """Whether `v` can be drawn: a number that is not NaN (booleans are not numbers here)."""
    return isinstance(v, (int, float)) and not isinstance(v, bool) and not math.isnan(v)


def _label(v: Any) -> str:
    if isinstance(v, str):
        name = v.rsplit("/", 1)[-1]
        return name if len(name) <= 40 else name[:37] + "..."
    return str(v)


def plot(
    results: str | os.PathLike[str] | Sequence[dict[str, Any]],
    x: str,
    y: str | Sequence[str],
    out: str | os.PathLike[str],
    *,
    by: str = "scene",
    facet: str | None = None,
    where: dict[str, Any] | None = None,
    logx: bool | None = None,
    logy: bool = False,
    title: str | None = None,
) -> Path:
    """Draws metric(s) ``y`` against column ``x`` (e.g. ``param.set.m``), one line per
    value of ``by``, one panel column per value of ``facet``, into ``out`` (``.svg`` or
    ``.png``); ``where`` keeps the rows whose columns equal the given values. ``logx``
    defaults to a log scale when ``x`` spans a factor of 8 or more. Returns ``out``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = list(results) if not isinstance(results, (str, os.PathLike)) else read_results(results)
    ys = [y] if isinstance(y, str) else list(y)
    if not ys:
        raise PlotError("no metric to plot")
    rows = [r for r in rows if r.get("status", "ok") == "ok"]
    for k, v in (where or {}).items():
        rows = [r for r in rows if r.get(k) == v]
    if not rows:
        raise PlotError("no successful points to plot")
    for col in [x, by, *ys] + ([facet] if facet else []):
        if col not in rows[0]:
            known = ", ".join(k for k in rows[0] if k.startswith(("param.", "result.")))
            raise PlotError(f"no column '{col}' (columns: scene, {known})")
    for metric in ys:
        if not any(_number(r[metric]) for r in rows):
            raise PlotError(f"column '{metric}' has no numeric values to plot")
    out_path = Path(out)
    if out_path.suffix.lower() not in (".svg", ".png"):
        raise PlotError(f"{out_path}: the picture's name must end in .svg or .png")
    facets: list[Any] = sorted({r[facet] for r in rows}, key=str) if facet else [None]
    lines = sorted({r[by] for r in rows}, key=str)
    xs = [r[x] for r in rows if isinstance(r[x], (int, float))]
    if logx is None:
        logx = bool(xs) and min(xs) > 0 and max(xs) / min(xs) >= 8
    fig, axes = plt.subplots(
        len(ys),
        len(facets),
        figsize=(4.2 * len(facets), 3.2 * len(ys)),
        squeeze=False,
        sharex=True,
    )
    for i, metric in enumerate(ys):
        for j, fv in enumerate(facets):
            ax = axes[i][j]
            for lv in lines:
                pts = sorted(
                    (r[x], r[metric])
                    for r in rows
                    if r[by] == lv
                    and (facet is None or r[facet] == fv)
                    and r[x] is not None
                    and _number(r[metric])
                )
                if pts:
                    ax.plot([p[0] for p in pts], [p[1] for p in pts], marker="o", label=_label(lv))
            if logx:
                ax.set_xscale("log", base=2)
            if logy:
                ax.set_yscale("log")
            if i == len(ys) - 1:
                ax.set_xlabel(x.removeprefix("param."))
            if j == 0:
                ax.set_ylabel(metric.removeprefix("result."))
            if facet is not None and i == 0:
                ax.set_title(_label(fv), fontsize=9)
            ax.grid(True, alpha=0.3)
    axes[0][0].legend(fontsize=8)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    out_path.parent.mkdir(parents=True, exist_ok=True)
    tmp = out_path.with_name(out_path.name + ".tmp" + out_path.suffix)
    fig.savefig(tmp, format=out_path.suffix[1:].lower())
    plt.close(fig)
    os.replace(tmp, out_path)
    return out_path


def _where(items: Sequence[str]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for it in items:
        k, sep, v = it.partition("=")
        if not sep:
            raise PlotError(f"--where '{it}' is not COLUMN=VALUE")
        val: Any = v
        for conv in (int, float):
            try:
                val = conv(v)
                break
            except ValueError:
                pass
        out[k] = val
    return out


def add_arguments(ap: argparse.ArgumentParser) -> None:
    """The options of ``python -m arbor plot``."""
    ap.add_argument("results", help="results.parquet or .csv (or the sweep's --out directory)")
    ap.add_argument("--x", required=True, help="the parameter column, e.g. param.set.m")
    ap.add_argument(
        "--y", required=True, action="append", help="a metric column, e.g. result.ms (repeatable)"
    )
    ap.add_argument("--out", required=True, help="the picture, .svg or .png")
    ap.add_argument(
        "--by", default="scene", help="one line per value of this column (default scene)"
    )
    ap.add_argument("--facet", help="one panel per value of this column")
    ap.add_argument(
        "--where", action="append", default=[], metavar="COLUMN=VALUE", help="keep matching rows"
    )
    ap.add_argument("--logy", action="store_true", help="log scale for the metric")
    ap.add_argument("--title")


def main_args(a: argparse.Namespace) -> int:
    """Runs ``python -m arbor plot`` with parsed arguments; returns the exit status."""
    try:
        p = plot(
            a.results,
            a.x,
            a.y,
            a.out,
            by=a.by,
            facet=a.facet,
            where=_where(a.where),
            logy=a.logy,
            title=a.title,
        )
    except PlotError as e:
        print(f"arbor: error: {e}", file=sys.stderr)
        return 2
    print(p)
    return 0
