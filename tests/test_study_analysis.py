"""The study's analysis on synthetic answers with known pick ratios, and ``python -m gnsx.study analyse``."""

from __future__ import annotations

import json
import shutil

import imageio.v3 as iio
import numpy as np
import pytest
from scipy.stats import binomtest

from gnsx.study.__main__ import main
from gnsx.study.analysis import analyse, wilson_interval
from gnsx.study.assign import Question
from gnsx.study.store import AnswerStore

ORIGINAL, SIMPLIFIED = "original GNS", "simplified GNS"
#: Share of picks of the first method of each group. The first is a coin flip (the methods cannot be told
#: apart); the others are clear preferences, one each way.
TRUE_SHARES = {("MPM", ORIGINAL): 0.50, ("MPM", SIMPLIFIED): 0.62, (ORIGINAL, SIMPLIFIED): 0.40}


def synthetic_answers(shares=TRUE_SHARES, participants=72, pairs_per_group=8, seed=0) -> list[dict]:
    """The paper's survey size (72 participants x 3 groups x 8 pairs = 576 answers per group), each pick of
    a group's first method a Bernoulli trial of its true share, sides at random."""
    rng = np.random.default_rng(seed)
    rows = []
    for p in range(participants):
        for (a, b), share in shares.items():
            for k in range(pairs_per_group):
                left, right = (a, b) if rng.random() < 0.5 else (b, a)
                chosen = a if rng.random() < share else b
                rows.append(
                    {
                        "participant": f"p{p:02d}",
                        "pair_id": f"{a}-{b}-{k}",
                        "method_a": a,
                        "method_b": b,
                        "left_method": left,
                        "right_method": right,
                        "chosen_method": chosen,
                        "choice": "left" if chosen == left else "right",
                        "time_ms": int(rng.integers(1000, 9000)),
                    }
                )
    return rows


@pytest.mark.parametrize(
    "successes, trials, lo, hi",
    # Newcombe (1998), Statistics in Medicine 17:857, table I, method 3 (Wilson score, no continuity corr.).
    [(81, 263, 0.2553, 0.3662), (15, 148, 0.0624, 0.1605), (0, 20, 0.0, 0.1611), (1, 29, 0.0061, 0.1718)],
)
def test_wilson_interval_matches_published_values(successes, trials, lo, hi):
    assert wilson_interval(successes, trials) == pytest.approx((lo, hi), abs=6e-5)


def test_wilson_interval_covers_the_true_share_95_percent_of_the_time():
    rng = np.random.default_rng(1)
    trials, share = 40, 0.3
    counts = rng.binomial(trials, share, size=2000)
    covered = np.mean([lo <= share <= hi for lo, hi in (wilson_interval(k, trials) for k in counts)])
    assert 0.93 < covered < 0.97  # 2,000 draws: 0.95 +- 3 standard errors (0.005)


def test_synthetic_answers_recover_their_known_ratios():
    result = analyse(synthetic_answers())
    assert [tuple(g["methods"]) for g in result["groups"]] == list(TRUE_SHARES)
    assert result["answers"] == 3 * 576 and result["participants"] == 72
    for group, (methods, true_share) in zip(result["groups"], TRUE_SHARES.items()):
        a, b = methods
        assert group["answers"] == 576 and group["picks"][a] + group["picks"][b] == 576
        lo, hi = group["ci95"][a]
        assert lo < true_share < hi
        assert group["share"][a] == pytest.approx(true_share, abs=0.06)
        assert group["ci95"][b] == pytest.approx([1 - hi, 1 - lo])
        assert group["p_value"] == pytest.approx(binomtest(group["picks"][a], 576).pvalue)
        # A coin flip is not flagged; a 62/38 or 40/60 preference over 576 answers is.
        assert group["significant"] == (true_share != 0.5)
    mpm_original, mpm_simplified, original_simplified = result["groups"]
    assert mpm_original["verdict"].startswith("cannot be told apart from 50/50")
    assert mpm_simplified["verdict"].startswith("MPM picked more often")
    assert original_simplified["verdict"].startswith("simplified GNS picked more often")
    assert not result["left"]["significant"]  # sides were random


def test_a_side_bias_is_flagged():
    rows = synthetic_answers({("MPM", SIMPLIFIED): 0.5}, participants=40)
    for row in rows[: len(rows) * 3 // 4]:  # three quarters always pick the left one
        row["chosen_method"], row["choice"] = row["left_method"], "left"
    assert analyse(rows)["left"]["significant"]


def test_the_papers_own_survey_numbers():
    """Figure 10: 46% picked the original GNS and 43% the simplified GNS over the ground truth (576 each)."""
    rows = []
    for method, picks in ((ORIGINAL, round(0.46 * 576)), (SIMPLIFIED, round(0.43 * 576))):
        for i in range(576):
            chosen = method if i < picks else "MPM"
            rows.append(
                {
                    "participant": f"p{i % 72}",
                    "method_a": "MPM",
                    "method_b": method,
                    "chosen_method": chosen,
                    "choice": "left",
                    "time_ms": 1,
                }
            )
    original, simplified = analyse(rows)["groups"]
    assert not original["significant"] and 0.05 < original["p_value"] < 0.1
    assert simplified["significant"] and simplified["p_value"] < 0.001


def _answers_db(path, rows):
    """An answers database written the way the web app writes it (assign, show, record)."""
    store = AnswerStore(path)
    by_participant: dict[str, list[dict]] = {}
    for row in rows:
        by_participant.setdefault(row["participant"], []).append(row)
    for participant, answers in by_participant.items():
        store.assign(
            participant,
            [
                Question(
                    i,
                    r["pair_id"],
                    f"{r['method_a']} vs {r['method_b']}",
                    r["method_a"],
                    r["method_b"],
                    r["left_method"],
                    r["right_method"],
                )
                for i, r in enumerate(answers)
            ],
        )
        for row in answers:
            store.record(participant, store.show_next(participant)["token"], row["choice"], row["time_ms"])
    return path


def test_cli_analyses_an_exported_database(tmp_path, capsys):
    rows = synthetic_answers(participants=6, pairs_per_group=2)
    exported = shutil.copy(_answers_db(tmp_path / "answers.sqlite", rows), tmp_path / "exported.sqlite")
    assert main(["analyse", str(exported), "--out", str(tmp_path / "report")]) == 0
    printed = capsys.readouterr().out
    assert "| MPM vs simplified GNS | 12 |" in printed
    saved = json.loads((tmp_path / "report" / "analysis.json").read_text())
    assert saved == json.loads(json.dumps(analyse(rows)))
    assert (tmp_path / "report" / "analysis.md").read_text().startswith("# Perceptual study")
    image = iio.imread(tmp_path / "report" / "figure10.png")
    assert image.ndim == 3 and image.shape[1] > 600 and image.std() > 10


@pytest.mark.parametrize(
    "content, message", [(None, "no such answers database"), ("x", "not a study answers")]
)
def test_cli_bad_database_is_one_line_and_exit_2(tmp_path, capsys, content, message):
    path = tmp_path / "answers.sqlite"
    if content is not None:
        path.write_text(content)
    assert main(["analyse", str(path)]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


def test_cli_no_answers_yet_is_exit_2(tmp_path, capsys):
    AnswerStore(tmp_path / "answers.sqlite")
    assert main(["analyse", str(tmp_path / "answers.sqlite")]) == 2
    assert "no answers to analyse" in capsys.readouterr().err
