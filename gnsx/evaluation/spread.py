"""Errors with their spread over trajectories, so that models can be ranked (numpy and scipy only).

A comparison is a result only if it is larger than its spread. Errors of rollouts vary by orders of magnitude
from one trajectory to the next, so two models are compared on the *same* trajectories by the ratio of their
errors, trajectory by trajectory, summarised as a geometric mean with a t interval on the log ratios:

* :func:`mean_se`: mean and standard error (sample std, ``ddof=1``, over ``sqrt(n)``) of finite values;
* :func:`geometric_mean_interval`: geometric mean of positive ratios and its confidence interval;
* :func:`compare`: two models' per-trajectory rows paired by trajectory index, with a verdict ("A better",
  "B better" or "cannot be told apart" when the interval contains 1);
* :func:`baseline_verdict`: whether a model beats the physics-free baseline, from its per-trajectory
  ``baseline_mse / rollout_mse`` ratios;
* :func:`alarm`: a line in red on a terminal (or with ``FORCE_COLOR`` set), plain text in logs.
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Iterable, Sequence
from typing import TextIO

import numpy as np
from scipy import stats

#: Confidence of every interval reported (two-sided).
CONFIDENCE = 0.95
#: Verdicts of :func:`compare`.
A_BETTER, B_BETTER, TIED = "A better", "B better", "cannot be told apart"
#: Verdicts of :func:`baseline_verdict`.
BEATS, DOES_NOT_BEAT = "beats the baseline", "does not beat the baseline"
TIED_WITH_BASELINE = "cannot be told apart from the baseline"
_RED, _RESET = "\033[1;31m", "\033[0m"


def _finite(values: Iterable) -> np.ndarray:
    """The finite floats among ``values`` (None and NaN dropped)."""
    out = [float(v) for v in values if v is not None and not isinstance(v, bool)]
    return np.array([v for v in out if math.isfinite(v)], dtype=np.float64)


def mean_se(values: Iterable) -> tuple[float, float]:
    """``(mean, standard error)`` of the finite values: ``std(ddof=1) / sqrt(n)``.

    NaN mean when there is no finite value, NaN standard error when there are fewer than two.
    """
    x = _finite(values)
    if len(x) == 0:
        return float("nan"), float("nan")
    se = float(np.std(x, ddof=1) / math.sqrt(len(x))) if len(x) >= 2 else float("nan")
    return float(np.mean(x)), se


def geometric_mean_interval(
    ratios: Iterable, confidence: float = CONFIDENCE
) -> tuple[float, float, float, int]:
    """Geometric mean of the finite positive ``ratios`` and its two-sided t interval on the log ratios.

    Returns:
        ``(geometric mean, low, high, n)``, n the number of ratios used; the geometric mean is NaN for n = 0,
        the interval NaN for n < 2.
    """
    x = _finite(ratios)
    logs = np.log(x[x > 0])
    n = len(logs)
    if n == 0:
        return float("nan"), float("nan"), float("nan"), 0
    centre = float(np.mean(logs))
    if n < 2:
        return math.exp(centre), float("nan"), float("nan"), 1
    half = float(stats.t.ppf(0.5 + confidence / 2, n - 1) * np.std(logs, ddof=1) / math.sqrt(n))
    return math.exp(centre), math.exp(centre - half), math.exp(centre + half), n


def _by_trajectory(rows: Sequence[dict], key: str) -> dict[int, float]:
    out = {}
    for i, row in enumerate(rows):
        value = row.get(key)
        if value is not None and math.isfinite(float(value)) and float(value) > 0:
            out[int(row.get("trajectory", i))] = float(value)
    return out


def compare(
    rows_a: Sequence[dict], rows_b: Sequence[dict], key: str = "rollout_mse", confidence: float = CONFIDENCE
) -> dict:
    """Paired comparison of two models on the same trajectories: the geometric mean of ``b / a``.

    Args:
        rows_a, rows_b: per-trajectory rows (:func:`gnsx.evaluation.scoring.score_trajectory`), paired by their
            ``trajectory`` index (their position when absent); a pair counts only when both values are finite
            and positive.
        key: the error compared (lower is better), e.g. ``rollout_mse``, ``emd``, ``mse_at_10``.
    Returns:
        ``{"key", "ratio", "lo", "hi", "trajectories", "wins_a", "verdict"}``: the geometric-mean ratio b/a
        with its ``confidence`` t interval (NaN with fewer than 2 pairs), the number of pairs, the number
        where a's error is lower, and ``"A better"`` (interval above 1), ``"B better"`` (below 1) or
        ``"cannot be told apart"``.
    """
    a, b = _by_trajectory(rows_a, key), _by_trajectory(rows_b, key)
    common = sorted(a.keys() & b.keys())
    ratio, lo, hi, n = geometric_mean_interval([b[t] / a[t] for t in common], confidence)
    if n >= 2 and lo > 1:
        verdict = A_BETTER
    elif n >= 2 and hi < 1:
        verdict = B_BETTER
    else:
        verdict = TIED
    wins_a = sum(a[t] < b[t] for t in common)
    return {"key": key, "ratio": ratio, "lo": lo, "hi": hi, "trajectories": n, "wins_a": wins_a,
            "verdict": verdict}  # fmt: skip


def format_comparison(result: dict, label_a: str = "A", label_b: str = "B") -> str:
    """One line for a :func:`compare` result, naming the models, e.g. ``rollout_mse: simplified / original =
    0.82x [0.70, 0.95] (95% t interval, geometric mean over 10 trajectories; original lower on 2):
    simplified better``."""
    verdict = {A_BETTER: f"{label_a} better", B_BETTER: f"{label_b} better"}.get(result["verdict"], TIED)
    ratio = _interval(result["ratio"], result["lo"], result["hi"])
    return (f"{result['key']}: {label_b} / {label_a} = {ratio}"
            f" (95% t interval, geometric mean over {result['trajectories']} trajectories; {label_a} lower on"
            f" {result['wins_a']}): {verdict}")  # fmt: skip


def _interval(centre: float, lo: float, hi: float) -> str:
    if math.isnan(lo) or math.isnan(hi):
        return f"{centre:.3g}x [interval needs 2+ trajectories]"
    return f"{centre:.3g}x [{lo:.3g}, {hi:.3g}]"


def baseline_verdict(geomean: float | None, lo: float | None = None, hi: float | None = None) -> str | None:
    """Whether a model beats the physics-free baseline, from the geometric mean of ``baseline_mse /
    rollout_mse`` over trajectories and its interval.

    Returns:
        :data:`DOES_NOT_BEAT` when the geometric mean is below 1 (whatever the interval), :data:`BEATS` when
        the interval lies above 1, :data:`TIED_WITH_BASELINE` otherwise (interval contains 1, or unknown), and
        None when the geometric mean is unknown.
    """
    if geomean is None or not math.isfinite(geomean):
        return None
    if geomean < 1:
        return DOES_NOT_BEAT
    if lo is not None and math.isfinite(lo) and lo > 1:
        return BEATS
    return TIED_WITH_BASELINE


def interval_contains_one(lo: float | None, hi: float | None) -> bool:
    """True when ``[lo, hi]`` contains 1, or is unknown (None or NaN)."""
    if lo is None or hi is None or not (math.isfinite(lo) and math.isfinite(hi)):
        return True
    return lo <= 1 <= hi


def use_colour(stream: TextIO | None = None) -> bool:
    """ANSI colours only on a terminal, or when ``FORCE_COLOR`` is set (non-empty), so logs stay plain."""
    if os.environ.get("FORCE_COLOR"):
        return True
    stream = stream if stream is not None else sys.stdout
    isatty = getattr(stream, "isatty", None)
    return bool(isatty and isatty())


def alarm(text: str, colour: bool | None = None) -> str:
    """``text`` in bold red (ANSI) when ``colour`` (default :func:`use_colour` on stdout), else unchanged."""
    return f"{_RED}{text}{_RESET}" if (use_colour() if colour is None else colour) else text
