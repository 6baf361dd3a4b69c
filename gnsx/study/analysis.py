"""The study's results: pick ratios per method pair, 95% Wilson intervals, binomial tests, figure 10.

For each group (method pair A vs B) the share of answers that picked A, with its 95% Wilson score interval,
and a two-sided exact binomial test of "A and B are picked equally often" (``scipy.stats.binomtest``,
p = 0.5). 50/50 means participants could not tell the methods apart; the paper reports MPM 54% vs original
GNS 46%, MPM 57% vs simplified GNS 43% (576 answers each). Answers are counted as independent trials, as the
paper does; a participant's answers are not quite independent, so with few participants the intervals are
optimistic.
The share of "left" picks over all answers is tested the same way: a side bias would show there.

:func:`analyse` works on answer rows (:data:`gnsx.study.store.ANSWER_COLUMNS`; only ``participant``,
``method_a``, ``method_b``, ``chosen_method``, ``choice`` and ``time_ms`` are read); :func:`write_report`
writes ``analysis.json``, ``analysis.md`` and ``figure10.png``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from scipy.stats import binomtest, norm

from gnsx.core.atomic import write_json
from gnsx.core.errors import DataError
from gnsx.study.manifest import group_id
from gnsx.study.scenes import TRUTH

CONFIDENCE = 0.95
ALPHA = 0.05


def wilson_interval(successes: int, trials: int, confidence: float = CONFIDENCE) -> tuple[float, float]:
    """The Wilson score interval of a proportion (NaNs for no trials).

    ``(p + z^2/2n -+ z sqrt(p(1-p)/n + z^2/4n^2)) / (1 + z^2/n)`` with ``p = successes / trials`` and
    ``z`` the normal quantile of ``(1 + confidence) / 2``: unlike ``p -+ z sqrt(p(1-p)/n)`` it stays inside
    [0, 1] and keeps its coverage near 0 and 1.
    """
    if trials <= 0:
        return math.nan, math.nan
    z = float(norm.ppf(0.5 + confidence / 2))
    p = successes / trials
    denominator = 1 + z * z / trials
    centre = (p + z * z / (2 * trials)) / denominator
    half = z * math.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials)) / denominator
    return max(0.0, centre - half), min(1.0, centre + half)


def proportion(successes: int, trials: int, alpha: float = ALPHA) -> dict:
    """``{"share", "ci95": [lo, hi], "p_value", "significant"}`` of ``successes`` in ``trials`` vs 1/2."""
    p_value = float(binomtest(successes, trials, 0.5).pvalue) if trials else math.nan
    return {
        "share": successes / trials if trials else math.nan,
        "ci95": list(wilson_interval(successes, trials)),
        "p_value": p_value,
        "significant": bool(p_value < alpha),
    }


def _method_order(method: str) -> tuple[bool, str]:
    """Sort key: the ground truth first, then by name (the build's default group order)."""
    return method != TRUTH, method


def analyse(rows: Sequence[dict], alpha: float = ALPHA) -> dict:
    """Pick ratios per method pair with 95% Wilson intervals and binomial tests (see the module docstring).

    Returns:
        ``{"answers", "participants", "alpha", "groups": [{"group", "methods": [a, b], "answers",
        "participants", "picks": {a: k, b: n - k}, "share": {a, b}, "ci95": {a: [lo, hi], b: [lo, hi]},
        "p_value", "significant", "verdict"}], "left": {"picks", "share", "ci95", "p_value", "significant"},
        "time_ms": {"median", "p10", "p90"}}``; groups in report order (MPM first).
    Raises:
        DataError: no answers, or an answer whose chosen method is neither of its group's.
    """
    if not rows:
        raise DataError("answers", "no answers to analyse")
    by_group: dict[tuple[str, str], list[dict]] = {}
    for row in rows:
        a, b = row["method_a"], row["method_b"]
        if row["chosen_method"] not in (a, b):
            raise DataError(
                "answers", f"{row['participant']}: chose {row['chosen_method']!r} in {group_id(a, b)}"
            )
        by_group.setdefault((a, b), []).append(row)
    groups = []
    for (a, b), answers in sorted(by_group.items(), key=lambda item: [_method_order(m) for m in item[0]]):
        n = len(answers)
        k = sum(row["chosen_method"] == a for row in answers)
        stats = proportion(k, n, alpha)
        lo, hi = stats["ci95"]
        groups.append(
            {
                "group": group_id(a, b),
                "methods": [a, b],
                "answers": n,
                "participants": len({row["participant"] for row in answers}),
                "picks": {a: k, b: n - k},
                "share": {a: stats["share"], b: 1 - stats["share"]},
                "ci95": {a: [lo, hi], b: [1 - hi, 1 - lo]},
                "p_value": stats["p_value"],
                "significant": stats["significant"],
                "verdict": verdict(a, b, stats["share"], stats["p_value"], alpha),
            }
        )
    left = sum(row["choice"] == "left" for row in rows)
    times = np.array([row["time_ms"] for row in rows], np.float64)
    return {
        "answers": len(rows),
        "participants": len({row["participant"] for row in rows}),
        "alpha": alpha,
        "groups": groups,
        "left": {"picks": left, **proportion(left, len(rows), alpha)},
        "time_ms": {q: float(np.percentile(times, p)) for q, p in (("median", 50), ("p10", 10), ("p90", 90))},
    }


def verdict(method_a: str, method_b: str, share_a: float, p_value: float, alpha: float = ALPHA) -> str:
    """One line: which method was picked more often, or that the two cannot be told apart from 50/50."""
    if not p_value < alpha:
        return f"cannot be told apart from 50/50 (p = {p_value:.3g})"
    more, share = (method_a, share_a) if share_a > 0.5 else (method_b, 1 - share_a)
    return f"{more} picked more often ({share:.0%}, p = {p_value:.3g})"


def _percent(share: float, ci: Sequence[float]) -> str:
    return f"{share:.1%} [{ci[0]:.1%}, {ci[1]:.1%}]"


def format_markdown(result: dict) -> str:
    """The analysis as a markdown report (a table per group and the side bias)."""
    lines = [
        "# Perceptual study: pick ratios per method pair",
        "",
        f"{result['answers']} answers from {result['participants']} participants. Share of picks with its "
        f"95% Wilson interval; p: two-sided binomial test against 50/50 (alpha {result['alpha']}).",
        "",
        "| method pair | answers | picks A | share A [95%] | share B [95%] | p | verdict |",
        "|---|---|---|---|---|---|---|",
    ]
    for g in result["groups"]:
        a, b = g["methods"]
        share_a, share_b = (f"{m}: {_percent(g['share'][m], g['ci95'][m])}" for m in (a, b))
        lines.append(
            f"| {g['group']} | {g['answers']} | {g['picks'][a]} | {share_a} | {share_b} | "
            f"{g['p_value']:.3g} | {g['verdict']} |"
        )
    left = result["left"]
    side = "a side bias" if left["significant"] else "no side bias"
    times = result["time_ms"]
    lines += [
        "",
        f"Left picks: {left['picks']} of {result['answers']}, {_percent(left['share'], left['ci95'])}, "
        f"p = {left['p_value']:.3g} ({side}).",
        f"Time per choice: median {times['median'] / 1000:.1f} s (10-90%: {times['p10'] / 1000:.1f}-"
        f"{times['p90'] / 1000:.1f} s).",
        "",
    ]
    return "\n".join(lines)


def plot_figure10(result: dict, path: str | Path) -> Path:
    """The paper's figure 10: per method pair, the share of picks of each method, with 95% Wilson intervals.

    One pair of bars per group, one colour per method, a dashed line at 50% (indistinguishable), each bar
    labelled with its method and share, each group with its answer count and p-value.
    """
    from matplotlib.figure import Figure

    groups = result["groups"]
    fig = Figure(figsize=(2.2 + 2.6 * len(groups), 4.4))
    ax = fig.add_subplot()
    methods = list(dict.fromkeys(m for g in groups for m in g["methods"]))
    palette = ("#3c6fd6", "#e0913c", "#4caf6a", "#b45cc8", "#d65c5c", "#8c8c8c")
    colour = {m: palette[i % len(palette)] for i, m in enumerate(methods)}  # one colour per method
    for i, g in enumerate(groups):
        for j, method in enumerate(g["methods"]):
            x = i + (j - 0.5) * 0.38
            share = g["share"][method]
            lo, hi = g["ci95"][method]
            ax.bar(x, share, width=0.36, color=colour[method], edgecolor="black", linewidth=0.5)
            ax.errorbar(x, share, yerr=[[share - lo], [hi - share]], color="black", capsize=4, linewidth=1)
            ax.text(
                x,
                0.02,
                f"{method}\n{share:.0%}",
                ha="center",
                va="bottom",
                fontsize=8,
                color="white",
                rotation=90 if len(method) > 12 else 0,
            )
    ax.axhline(0.5, color="grey", linestyle="--", linewidth=1)
    ax.set_xticks(range(len(groups)))
    ax.set_xticklabels(
        [f"{g['group']}\nn = {g['answers']}, p = {g['p_value']:.2g}" for g in groups], fontsize=8
    )
    ax.set_ylim(0, 1)
    ax.set_ylabel("share of picks (95% Wilson interval)")
    ax.set_title(
        f"Which looks more realistic? {result['answers']} answers, {result['participants']} participants",
        fontsize=10,
    )
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    return path


def write_report(result: dict, out: str | Path) -> dict[str, Path]:
    """``analysis.json``, ``analysis.md`` and ``figure10.png`` of :func:`analyse`'s result into ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    markdown = out / "analysis.md"
    markdown.write_text(format_markdown(result))
    return {
        "json": write_json(out / "analysis.json", result),
        "markdown": markdown,
        "figure": plot_figure10(result, out / "figure10.png"),
    }
