"""Errors with their spread: standard errors, geometric means with t intervals, paired comparisons, verdicts
against the baseline, all on hand-made values with known answers."""

from __future__ import annotations

import io
import math

import numpy as np
import pytest

from gnsx.evaluation.spread import (
    A_BETTER,
    B_BETTER,
    BEATS,
    DOES_NOT_BEAT,
    TIED,
    TIED_WITH_BASELINE,
    alarm,
    baseline_verdict,
    compare,
    format_comparison,
    geometric_mean_interval,
    mean_se,
    use_colour,
)

#: Student's t quantiles (two-sided 95%) for 1 and 4 degrees of freedom.
T_975 = {1: 12.706204736, 4: 2.776445105}


def test_mean_and_standard_error_of_known_values():
    mean, se = mean_se([1.0, 2.0, 3.0, 4.0])
    assert mean == 2.5
    assert se == pytest.approx(math.sqrt(5 / 3) / 2)  # sample variance 5/3 (ddof=1), over sqrt(4)
    assert mean_se([2.0, None, float("nan"), 4.0]) == pytest.approx((3.0, 1.0))  # missing values left out
    mean, se = mean_se([5.0])
    assert mean == 5.0 and math.isnan(se)  # one trajectory has no spread
    assert all(math.isnan(v) for v in mean_se([]))


def test_geometric_mean_and_its_t_interval():
    geomean, lo, hi, n = geometric_mean_interval([2.0, 8.0])
    assert geomean == pytest.approx(4.0) and n == 2
    half = T_975[1] * (math.log(8) - math.log(2)) / math.sqrt(2) / math.sqrt(2)  # t * sd / sqrt(n)
    assert lo == pytest.approx(4.0 * math.exp(-half)) and hi == pytest.approx(4.0 * math.exp(half))
    # Identical ratios: no spread, the interval is the point.
    assert geometric_mean_interval([3.0, 3.0, 3.0])[:3] == pytest.approx((3.0, 3.0, 3.0))
    # Non-positive and missing ratios cannot enter a geometric mean.
    geomean, lo, hi, n = geometric_mean_interval([0.0, -1.0, None, float("inf"), 9.0])
    assert (geomean, n) == (pytest.approx(9.0), 1) and math.isnan(lo) and math.isnan(hi)


def _rows(values, trajectories=None, key="rollout_mse"):
    trajectories = range(len(values)) if trajectories is None else trajectories
    return [{"trajectory": t, key: v} for t, v in zip(trajectories, values)]


def test_compare_verdicts_on_paired_rows():
    a = [1e-3, 5e-2, 2e-4, 8e-3, 3e-2]  # errors spread over two decades: only pairing can rank the models
    noise = np.array([1.05, 0.97, 1.02, 0.99, 1.01])
    worse = compare(_rows(a), _rows(np.multiply(a, 2 * noise)))
    assert worse["verdict"] == A_BETTER and worse["trajectories"] == 5 and worse["wins_a"] == 5
    assert worse["lo"] < 2.0 < worse["hi"] and worse["lo"] > 1
    better = compare(_rows(a), _rows(np.multiply(a, 0.5 * noise)))
    assert better["verdict"] == B_BETTER and better["hi"] < 1 and better["wins_a"] == 0
    mixed = np.array([1.5, 0.6, 1.4, 0.7, 1.0])
    tied = compare(_rows(a), _rows(np.multiply(a, mixed)))
    assert tied["verdict"] == TIED and tied["lo"] < 1 < tied["hi"]
    logs = np.log(mixed)
    assert tied["ratio"] == pytest.approx(math.exp(logs.mean()))
    half = T_975[4] * logs.std(ddof=1) / math.sqrt(5)
    assert tied["hi"] == pytest.approx(math.exp(logs.mean() + half))
    # The means alone would favour B (its mean error is 25% lower, set by one trajectory): pairing cannot.
    assert np.mean(np.multiply(a, mixed)) < 0.8 * np.mean(a)


def test_compare_pairs_by_trajectory_index_and_needs_two_pairs():
    a = _rows([1.0, 2.0, 4.0], trajectories=[0, 1, 2])
    b = _rows([8.0, 2.0, 4.0, 0.1], trajectories=[2, 0, 1, 7])  # shuffled, with one trajectory a lacks
    result = compare(a, b)
    assert result["trajectories"] == 3 and result["ratio"] == pytest.approx(2.0)
    assert result["lo"] == pytest.approx(2.0) == result["hi"]  # b doubles a on every trajectory
    assert result["verdict"] == A_BETTER
    one = compare(_rows([1.0]), _rows([100.0]))
    assert one["trajectories"] == 1 and one["verdict"] == TIED  # one trajectory cannot rank two models
    emd = compare(_rows([1.0, 1.0], key="emd"), _rows([3.0, 3.3], key="emd"), key="emd")
    assert emd["key"] == "emd" and emd["verdict"] == A_BETTER
    line = format_comparison(emd, "original", "simplified")
    assert line.startswith("emd: simplified / original = ") and line.endswith("original better")


def test_baseline_verdicts():
    assert baseline_verdict(0.8, 0.5, 1.3) == DOES_NOT_BEAT  # below 1 even if the interval contains 1
    assert baseline_verdict(0.8, 0.7, 0.9) == DOES_NOT_BEAT
    assert baseline_verdict(2.0, 1.5, 2.6) == BEATS
    assert baseline_verdict(1.2, 0.9, 1.6) == TIED_WITH_BASELINE
    assert baseline_verdict(1.2) == TIED_WITH_BASELINE  # no interval: cannot claim a win
    assert baseline_verdict(None) is None and baseline_verdict(float("nan")) is None


def test_alarm_is_red_only_on_terminals_or_when_forced(monkeypatch):
    monkeypatch.delenv("FORCE_COLOR", raising=False)
    assert alarm("x", colour=True) == "\033[1;31mx\033[0m" and alarm("x", colour=False) == "x"

    class Terminal:
        def isatty(self):
            return True

    assert use_colour(Terminal()) and not use_colour(io.StringIO())
    assert alarm("x") == "x"  # pytest captures stdout: not a terminal
    monkeypatch.setenv("FORCE_COLOR", "1")
    assert alarm("x") == "\033[1;31mx\033[0m"
