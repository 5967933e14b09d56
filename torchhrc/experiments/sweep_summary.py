"""A sweep's summary: mean and 95% CI over seeds of every metric per cell
(:func:`cell_statistics`), ``summary.md`` and a plot per metric (:func:`write_summary`).

Example:
    >>> _mean_ci([1.0, 2.0, 3.0])[0]
    2.0
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from torchhrc.experiments.sweep_grid import _columns, is_timing_column
from torchhrc.experiments.sweep_tasks import SweepSpec


def _is_summary_metric(name: str) -> bool:
    """Headline columns: not a list element (``a.3``, its ``a.mean`` is kept), not a CI, not
    a per-type breakdown (``a.by_type.<type>``)."""
    last = name.rsplit(".", 1)[-1]
    return not last.isdigit() and "ci95" not in name and ".by_type" not in name


def _metric_columns(rows: Sequence[Mapping[str, Any]], spec: SweepSpec) -> list[str]:
    skip = {*spec.parameter_names, "seed"}
    columns = [
        c for c in _columns(rows, [])
        if c not in skip and not is_timing_column(c) and _is_summary_metric(c)
    ]  # fmt: skip
    varying = []
    for c in columns:
        values = {row.get(c) for row in rows}
        if len(values) > 1 or len(spec.grid) == 0:
            varying.append(c)
    return varying


def _mean_ci(values: Sequence[float]) -> tuple[float, float]:
    import torch

    from torchhrc.experiments.robustness import mean_ci95

    mean, half = mean_ci95(torch.tensor(values, dtype=torch.float64), over="subjects")
    return float(mean), float(half)


def cell_statistics(
    rows: Sequence[Mapping[str, Any]], spec: SweepSpec, metric: str
) -> list[tuple[tuple[tuple[str, Any], ...], float, float, int]]:
    """``[(cell params, mean, 95% CI half-width, n seeds), ...]`` of ``metric`` per cell.

    The half-width uses Student's t with ``n - 1`` degrees of freedom (0 for one seed).
    """
    names = spec.parameter_names
    groups: dict[tuple[tuple[str, Any], ...], list[float]] = {}
    for row in rows:
        if row.get(metric) is None:
            continue
        cell = tuple((n, row[n]) for n in names)
        groups.setdefault(cell, []).append(float(row[metric]))
    return [(cell, *_mean_ci(v), len(v)) for cell, v in groups.items()]


def _safe_name(metric: str) -> str:
    return "".join(c if c.isalnum() or c in "._-" else "_" for c in metric)


def write_summary(
    out_dir: str | os.PathLike[str],
    spec: SweepSpec,
    rows: Sequence[Mapping[str, Any]],
    *,
    failed: Mapping[str, str] | None = None,
    plots: bool = True,
) -> Path:
    """Write ``summary.md`` (mean +/- 95% CI per cell) and a PNG per metric; return the md path.

    Each PNG has one panel per swept parameter: the metric's mean and 95% CI over seeds
    against that parameter, one line per combination of the other parameters. The headline
    metrics are summarised: scalars and the mean of each list (``reward.learned.mean``); list
    elements, CI columns and per-type breakdowns (``.by_type.``) stay in ``results.csv``.
    Metrics that do not vary over the sweep are listed once, not plotted.
    """
    from torchhrc.experiments.report import write_text_atomic

    path = Path(out_dir)
    metrics = _metric_columns(rows, spec)
    names = spec.parameter_names
    lines = [
        f"# Sweep: {spec.task}",
        "",
        f"Grid: {', '.join(f'{n} = {list(v)}' for n, v in spec.grid) or '(defaults)'}; "
        f"seeds {list(spec.seeds)}; quick = {spec.quick}; {len(rows)} finished jobs"
        + (f", {len(failed)} failed" if failed else "")
        + ".",
        "",
        "Each entry: mean +/- 95% CI half-width over seeds (Student t).",
        "",
    ]
    constant = [
        c for c in _columns(rows, []) if c not in {*names, "seed"} and c not in metrics
        and not is_timing_column(c) and _is_summary_metric(c)
    ]  # fmt: skip
    for metric in metrics:
        stats = cell_statistics(rows, spec, metric)
        lines += [f"## {metric}", "", "| " + " | ".join([*names, "mean", "ci95", "seeds"]) + " |"]
        lines.append("|" + "---|" * (len(names) + 3))
        for cell, mean, half, n in stats:
            values = [str(v) for _, v in cell]
            lines.append("| " + " | ".join([*values, f"{mean:.4g}", f"{half:.3g}", str(n)]) + " |")
        if plots and names:
            lines += ["", f"![{metric}]({_safe_name(metric)}.png)"]
        lines.append("")
    if constant:
        lines += ["## Constant over the sweep", ""]
        lines += [f"- {c} = {rows[0].get(c)}" for c in constant]
        lines.append("")
    if failed:
        lines += ["## Failed jobs", ""] + [f"- `{k}`: {v}" for k, v in failed.items()] + [""]
    if plots and names:
        for metric in metrics:
            _plot(path / f"{_safe_name(metric)}.png", spec, rows, metric)
    target = path / "summary.md"
    write_text_atomic(target, "\n".join(lines))
    return target


def _plot(target: Path, spec: SweepSpec, rows: Sequence[Mapping[str, Any]], metric: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from torchhrc._atomic import atomic_write

    names = spec.parameter_names
    stats = cell_statistics(rows, spec, metric)
    fig, axes = plt.subplots(1, len(names), figsize=(4.2 * len(names), 3.2), squeeze=False)
    for ax, name in zip(axes[0], names, strict=True):
        grid = dict(spec.grid)[name]
        # numbers on a numeric axis; text (criterion=bic,icl) and bools at their grid positions
        numeric = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in grid)
        lines: dict[tuple[tuple[str, Any], ...], list[tuple[float, float, float]]] = {}
        for cell, mean, half, _ in stats:
            values = dict(cell)
            others = tuple((n, values[n]) for n in names if n != name)
            x_value = float(values[name]) if numeric else float(grid.index(values[name]))
            lines.setdefault(others, []).append((x_value, mean, half))
        if not numeric:
            ax.set_xticks(range(len(grid)), [str(v) for v in grid])
        for others, points in lines.items():
            points.sort()
            x = [p[0] for p in points]
            label = ", ".join(f"{n}={v}" for n, v in others) or None
            ax.errorbar(x, [p[1] for p in points], yerr=[p[2] for p in points], marker="o",
                        capsize=3, label=label)  # fmt: skip
        ax.set_xlabel(name)
        ax.set_ylabel(metric)
        if any(others for others in lines):
            ax.legend(fontsize=7)
    fig.suptitle(f"{spec.task}: {metric} (mean, 95% CI over {len(spec.seeds)} seeds)", fontsize=9)
    fig.tight_layout()

    def write(tmp: str) -> None:
        fig.savefig(tmp, format="png", dpi=90)

    try:
        atomic_write(target, write)
    finally:
        plt.close(fig)
