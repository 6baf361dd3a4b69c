"""The answers database: issuing tokens, recording once, its own constraints, reading an exported copy."""

from __future__ import annotations

import shutil
import sqlite3
import threading

import pytest

from gnsx.core.errors import DataError
from gnsx.study.assign import Question
from gnsx.study.store import AlreadyAnswered, AnswerStore, UnknownQuestion, read_answers

QUESTIONS = [
    Question(0, "g1-s0", "A vs B", "A", "B", "B", "A"),
    Question(1, "g1-s1", "A vs B", "A", "B", "A", "B"),
]


@pytest.fixture
def store(tmp_path):
    store = AnswerStore(tmp_path / "answers.sqlite")
    store.assign("p1", QUESTIONS)
    return store


def test_tokens_are_issued_when_shown_once_and_answers_recorded_once(store):
    assert store.progress("p1") == (0, 2)
    first = store.show_next("p1")
    assert first["pair_id"] == "g1-s0" and first["token"]
    assert store.show_next("p1")["token"] == first["token"]  # shown again, same token
    answer = store.record("p1", first["token"], "left", time_ms=1500)
    assert answer["chosen_method"] == "B" and answer["time_ms"] == 1500  # B was on the left
    with pytest.raises(AlreadyAnswered):
        store.record("p1", first["token"], "right")
    second = store.show_next("p1")
    assert second["pair_id"] == "g1-s1" and second["token"] != first["token"]
    answer = store.record("p1", second["token"], "right")  # no page time: the server's
    assert answer["chosen_method"] == "B" and answer["time_ms"] == answer["server_ms"] >= 0
    assert store.show_next("p1") is None and store.progress("p1") == (2, 2)


def test_answers_need_a_token_shown_to_the_same_participant(store):
    store.assign("p2", QUESTIONS)
    token = store.show_next("p1")["token"]
    with pytest.raises(UnknownQuestion):
        store.record("p2", token, "left")
    with pytest.raises(UnknownQuestion):
        store.record("p1", "never-issued-token-0000", "left")
    with pytest.raises(ValueError, match="choice must be one of"):
        store.record("p1", token, "both")
    with pytest.raises(ValueError, match="time_ms must be >= 0"):
        store.record("p1", token, "left", time_ms=-1)
    assert read_answers(store.path) == []


def test_assigning_again_keeps_the_first_questions(store):
    store.assign("p1", [Question(0, "other", "C vs D", "C", "D", "C", "D")])
    assert store.show_next("p1")["pair_id"] == "g1-s0"


def test_the_database_itself_refuses_replays_and_unassigned_pairs(store):
    store.record("p1", store.show_next("p1")["token"], "left")
    with sqlite3.connect(store.path) as db:
        db.execute("PRAGMA foreign_keys = ON")
        row = db.execute("SELECT * FROM answers").fetchone()
        with pytest.raises(sqlite3.IntegrityError, match="UNIQUE|PRIMARY KEY"):
            db.execute(f"INSERT INTO answers VALUES ({', '.join('?' * len(row))})", row)
        unassigned = ("p1", "g9-nowhere", *row[2:])
        with pytest.raises(sqlite3.IntegrityError, match="FOREIGN KEY"):
            db.execute(f"INSERT INTO answers VALUES ({', '.join('?' * len(row))})", unassigned)


def test_two_simultaneous_answers_to_one_question_record_one(store):
    token = store.show_next("p1")["token"]
    outcomes, barrier = [], threading.Barrier(4)

    def submit(choice):
        barrier.wait()
        try:
            store.record("p1", token, choice)
            outcomes.append("recorded")
        except AlreadyAnswered:
            outcomes.append("refused")

    threads = [threading.Thread(target=submit, args=(c,)) for c in ("left", "right", "left", "right")]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert sorted(outcomes) == ["recorded", "refused", "refused", "refused"]
    assert len(read_answers(store.path)) == 1


def test_an_exported_copy_reads_back(store, tmp_path):
    store.record("p1", store.show_next("p1")["token"], "right", time_ms=900)
    copy = shutil.copy(store.path, tmp_path / "export.sqlite")
    (row,) = read_answers(copy)
    assert (
        row["participant"],
        row["pair_id"],
        row["left_method"],
        row["right_method"],
        row["choice"],
        row["chosen_method"],
        row["time_ms"],
    ) == ("p1", "g1-s0", "B", "A", "right", "A", 900)


def test_reading_something_else_is_one_clear_error(tmp_path):
    with pytest.raises(DataError, match="no such answers database"):
        read_answers(tmp_path / "none.sqlite")
    (tmp_path / "text.sqlite").write_text("not a database")
    with pytest.raises(DataError, match="not a study answers database"):
        read_answers(tmp_path / "text.sqlite")
    sqlite3.connect(tmp_path / "empty.sqlite").execute("CREATE TABLE t (x)").connection.close()
    with pytest.raises(DataError, match="not a study answers database"):
        read_answers(tmp_path / "empty.sqlite")
