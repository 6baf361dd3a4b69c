"""Building a study: scenes from rollout files, groups and pairs, animations, the manifest, the CLI."""

from __future__ import annotations

import json
import shutil
from collections import Counter
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
from test_study_support import ORIGINAL, SIMPLIFIED, TINY_RENDER, scene_positions, tiny_study, write_rollouts

from gnsx.core.errors import DataError
from gnsx.data.rollout_io import Rollout, save_rollout
from gnsx.study.__main__ import main
from gnsx.study.build import build_study, choose_pairs
from gnsx.study.manifest import MANIFEST, load_study
from gnsx.study.scenes import TRUTH, collect_scenes


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    """MPM, original and simplified on 4 scenes, 3 pairs per group."""
    return load_study(tiny_study(tmp_path_factory.mktemp("build"), scenes=4, pairs_per_group=3))


def test_groups_are_the_papers_three_method_pairs(study):
    assert study.groups == [(TRUTH, ORIGINAL), (TRUTH, SIMPLIFIED), (ORIGINAL, SIMPLIFIED)]
    per_group = Counter(pair.methods for pair in study.pairs)
    assert per_group == {group: 3 for group in study.groups}
    for group in study.groups:  # a group never shows one scene twice
        scenes = [pair.scene for pair in study.pairs if pair.methods == group]
        assert len(set(scenes)) == 3
    # 9 pairs over 4 scenes: scenes used least so far are drawn first, so each scene is used 2 or 3 times.
    assert sorted(Counter(pair.scene for pair in study.pairs).values()) == [2, 2, 2, 3]


def test_pairs_show_one_initial_state_with_one_colour_scale(study):
    frames = TINY_RENDER.frames // TINY_RENDER.frame_stride
    for pair in study.pairs:
        a, b = (iio.imread(study.media(pair, method)) for method in pair.methods)
        assert a.shape == b.shape == (frames, TINY_RENDER.size, TINY_RENDER.size, 3)
        # Same first frame, discs and colours: only the motion tells the methods apart.
        np.testing.assert_array_equal(a[0], b[0])
        assert not np.array_equal(a[-1], b[-1])


def test_manifest_records_sources_and_render_settings(study):
    data = json.loads((study.folder / MANIFEST).read_text())
    assert data["render"] == {"frames": 8, "frame_stride": 2, "fps": 10, "size": 64, "format": "gif"}
    for pair in study.pairs:
        sources = data["sources"][pair.scene]
        assert set(pair.methods) <= set(sources)
        assert all(Path(path).name == f"{pair.scene}.npz" for path in sources.values())
    assert (study.folder / ".gitignore").read_text() == "*\n"


def test_choose_pairs_is_seeded_and_checks_counts():
    scenes = {f"s{i}": ["A", "B"] for i in range(10)}
    first = choose_pairs(scenes, [("A", "B")], 4, seed=1)
    assert first == choose_pairs(scenes, [("A", "B")], 4, seed=1)
    assert first != choose_pairs(scenes, [("A", "B")], 4, seed=2)
    with pytest.raises(DataError, match="A vs B: 10 scenes have both methods, 11 pairs asked"):
        choose_pairs(scenes, [("A", "B")], 11, seed=1)


def test_named_sources_and_chosen_methods(tmp_path):
    rollouts = write_rollouts(tmp_path / "r", scenes=2)
    out = build_study(
        [f"ours={rollouts / 'simplified'}", str(rollouts / "original")],
        tmp_path / "s",
        pairs_per_group=2,
        methods=["ours", TRUTH],
        settings=TINY_RENDER,
    )
    study = load_study(out.parent)
    assert study.groups == [("ours", TRUTH)]
    assert {pair.methods for pair in study.pairs} == {("ours", TRUTH)}


def test_rollouts_of_evaluate_py(tiny_dataset, tmp_path, one_thread):
    """The study builds from what evaluate.py writes: one scene per trajectory, methods from its labels."""
    from test_evaluate import ORIGINAL_TINY, TINY, save_tiny_checkpoint

    from gnsx.data.store import load_metadata
    from gnsx.evaluation.evaluate import evaluate_checkpoints

    metadata = load_metadata(tiny_dataset)
    checkpoints = [
        save_tiny_checkpoint(tmp_path / f"{n}.ckpt", metadata, m)
        for n, m in (("o", ORIGINAL_TINY), ("s", TINY))
    ]
    evaluate_checkpoints(
        checkpoints,
        tiny_dataset,
        tmp_path / "eval",
        render=False,
        emd_every=0,
        timing_repeats=0,
        onestep_stride=100,
    )
    study = load_study(build_study([tmp_path / "eval"], tmp_path / "study", 1, settings=TINY_RENDER).parent)
    assert study.groups == [
        (TRUTH, "original GNS 8/2"),
        (TRUTH, "simplified GNS 8/2"),
        ("original GNS 8/2", "simplified GNS 8/2"),
    ]
    assert {pair.scene for pair in study.pairs} == {"test_0000"}


def test_rollouts_of_different_initial_states_are_refused(tmp_path):
    rollouts = write_rollouts(tmp_path / "r", scenes=1, methods=(SIMPLIFIED,))
    positions, types = scene_positions(5)  # another block, saved as the same scene
    meta = {
        "bounds": [[0.1, 0.9], [0.1, 0.9]],
        "rollout": {"model": ORIGINAL, "split": "test", "trajectory": 0},
    }
    save_rollout(tmp_path / "other.npz", Rollout(positions, types, 2, positions, meta))
    with pytest.raises(DataError, match="scene test_0000 starts from other particles"):
        collect_scenes([rollouts, tmp_path / "other.npz"])


def test_two_rollouts_of_one_scene_by_one_method_are_refused(tmp_path):
    rollouts = write_rollouts(tmp_path / "r", scenes=1, methods=(SIMPLIFIED,))
    with pytest.raises(DataError, match="a second rollout of scene test_0000 by 'simplified GNS 64/5'"):
        collect_scenes([rollouts, rollouts / "simplified" / "rollouts" / "test_0000.npz"])


def test_a_study_with_answers_is_not_rebuilt(tmp_path):
    rollouts = write_rollouts(tmp_path / "r", scenes=1, methods=(SIMPLIFIED,))
    out = tmp_path / "s"
    build_study([rollouts], out, 1, settings=TINY_RENDER)
    (out / "answers.sqlite").touch()
    with pytest.raises(DataError, match="already has answers"):
        build_study([rollouts], out, 1, settings=TINY_RENDER)
    build_study([rollouts], out, 1, settings=TINY_RENDER, force=True)


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda p: p.update(files={**p["files"], "MPM": "../outside.gif"}), "lies outside the study folder"),
        (lambda p: p.update(files={**p["files"], "MPM": "media/none.gif"}), "missing animation"),
        (lambda p: p.update(group="A vs B"), "is not one of the study's groups"),
    ],
)
def test_tampered_manifests_are_refused(study, tmp_path, change, message):
    data = json.loads((study.folder / MANIFEST).read_text())
    change(data["pairs"][0])
    (tmp_path / "outside.gif").touch()
    copy = tmp_path / "copy"
    shutil.copytree(study.folder / "media", copy / "media")
    (copy / MANIFEST).write_text(json.dumps(data))
    with pytest.raises(DataError, match=message):
        load_study(copy)


def test_cli_builds_a_study(tmp_path, capsys):
    rollouts = write_rollouts(tmp_path / "r", scenes=2)
    args = [
        "build",
        "--rollouts",
        str(rollouts),
        "--out",
        str(tmp_path / "s"),
        "--pairs-per-group",
        "2",
        "--frames",
        "4",
        "--size",
        "48",
        "--format",
        "mp4",
    ]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "6 pairs in 3 groups" in out and f"{ORIGINAL} vs {SIMPLIFIED}: 2 pairs" in out
    study = load_study(tmp_path / "s")
    assert all(study.media(p, m).suffix == ".mp4" for p in study.pairs for m in p.methods)


@pytest.mark.parametrize(
    "args, message",
    [
        (["--rollouts", "missing"], "error: missing: no such file or folder"),
        (["--rollouts", "{r}", "--pairs-per-group", "3"], "2 scenes have both methods, 3 pairs asked"),
        (["--rollouts", "{r}", "--frames", "1"], "error: --frames: at least 2 frames"),
        (["--rollouts", "{r}", "--methods", "MPM", "nope"], "error: --methods: no rollouts of ['nope']"),
        (["--rollouts", "MPM={r}"], "'MPM' names the ground truth"),
    ],
)
def test_cli_bad_input_is_one_line_and_exit_2(tmp_path, capsys, args, message):
    rollouts = write_rollouts(tmp_path / "r", scenes=2, methods=(SIMPLIFIED,))
    args = [a.format(r=rollouts) for a in args]
    assert main(["build", *args, "--out", str(tmp_path / "s")]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert not (tmp_path / "s" / MANIFEST).exists()


def test_cli_usage_errors_exit_2(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["build", "--rollouts", "x", "--out", "y", "--size", "-3"])
    assert exit_info.value.code == 2
    assert "must be >= 1" in capsys.readouterr().err
