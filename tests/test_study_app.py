"""The study's web app through Flask's test client: the flow, what is stored, and what is refused."""

from __future__ import annotations

import re
import socket
import sqlite3
from collections import Counter

import pytest
from test_study_support import tiny_study

from gnsx.core.errors import DataError
from gnsx.study.__main__ import main
from gnsx.study.app import create_app
from gnsx.study.assign import questions_for
from gnsx.study.manifest import load_study
from gnsx.study.store import read_answers

TOKEN_FIELD = re.compile(r'name="token" value="([^"]+)"')


@pytest.fixture(scope="module")
def study_dir(tmp_path_factory):
    """MPM, original and simplified: 6 pairs (2 per group) over 3 scenes."""
    return tiny_study(tmp_path_factory.mktemp("app"))


@pytest.fixture
def db(tmp_path):
    return tmp_path / "answers.sqlite"


@pytest.fixture
def app(study_dir, db):
    return create_app(study_dir, db)


def start(client, participant: str):
    response = client.post("/start", data={"participant": participant})
    assert response.status_code == 303 and response.location.endswith("/question")
    return response


def show(client) -> tuple[str, str]:
    """The current question page and its token."""
    response = client.get("/question")
    assert response.status_code == 200, response.status_code
    html = response.get_data(as_text=True)
    return html, TOKEN_FIELD.search(html).group(1)


def answer(client, token: str, choice: str, **extra):
    return client.post("/answer", data={"token": token, "choice": choice, **extra})


def test_a_participant_answers_every_pair_and_each_choice_is_stored(app, study_dir, db):
    client = app.test_client()
    assert "Which simulation looks more realistic?" in client.get("/").get_data(as_text=True)
    start(client, "p-01")
    choices = ["left", "right", "right", "left", "left", "right"]
    for i, choice in enumerate(choices):
        html, token = show(client)
        assert f"Pair {i + 1} of 6" in html
        response = answer(client, token, choice, time_ms=str(1000 + i))
        assert response.status_code == 303 and response.location.endswith("/question")
    assert client.get("/question").location.endswith("/done")
    assert "You answered 6 of 6 pairs" in client.get("/done").get_data(as_text=True)

    rows = read_answers(db)
    expected = questions_for(load_study(study_dir), "p-01")
    assert [row["pair_id"] for row in rows] == [q.pair_id for q in expected]
    for row, question, choice, i in zip(rows, expected, choices, range(6)):
        assert row["participant"] == "p-01"
        assert (row["left_method"], row["right_method"]) == (question.left, question.right)
        assert (row["method_a"], row["method_b"], row["group_id"]) == (
            question.method_a,
            question.method_b,
            question.group,
        )
        assert row["choice"] == choice
        assert row["chosen_method"] == (question.left if choice == "left" else question.right)
        assert row["time_ms"] == 1000 + i and row["server_ms"] >= 0
        assert row["answered_at"].endswith("+00:00")


def test_orders_and_sides_are_seeded_per_participant(study_dir):
    study = load_study(study_dir)
    alice = questions_for(study, "alice")
    assert alice == questions_for(study, "alice")
    assert sorted(q.pair_id for q in alice) == sorted(p.id for p in study.pairs)
    assert alice != questions_for(study, "bob")
    people = [questions_for(study, f"p{i}") for i in range(300)]
    first = Counter(qs[0].pair_id for qs in people)
    assert set(first) == {p.id for p in study.pairs}  # every pair comes first for someone
    swapped = [q.left == q.method_b for qs in people for q in qs]
    assert 0.45 < sum(swapped) / len(swapped) < 0.55  # 1,800 sides; 0.5 +- 3.5 standard errors


def test_pages_never_name_a_method_or_scene(app, study_dir):
    client = app.test_client()
    start(client, "p1")
    html, token = show(client)
    study = load_study(study_dir)
    for hidden in ["MPM", "GNS", ".gif", "test_000", *(pair.id for pair in study.pairs)]:
        assert hidden not in html
    row = app.extensions["gnsx_study"]["store"].shown("p1", token)
    pair = study.pair(row["pair_id"])
    for side, method in (("left", row["left_method"]), ("right", row["right_method"])):
        response = client.get(f"/media/{token}/{side}")
        assert response.status_code == 200 and response.mimetype == "image/gif"
        assert response.data == study.media(pair, method).read_bytes()
        assert response.headers["Content-Disposition"] == f"inline; filename={side}.gif"
        assert "ETag" not in response.headers


def test_media_of_a_study_given_by_a_relative_path(study_dir, db, monkeypatch):
    monkeypatch.chdir(study_dir.parent)
    client = create_app(study_dir.name, db).test_client()
    start(client, "p1")
    _, token = show(client)
    assert client.get(f"/media/{token}/right").data.startswith(b"GIF89a")


def test_a_replayed_answer_is_refused(app, db):
    client = app.test_client()
    start(client, "p1")
    _, token = show(client)
    assert answer(client, token, "left").status_code == 303
    response = answer(client, token, "right")
    assert response.status_code == 409 and "answered already" in response.get_data(as_text=True)
    assert [row["choice"] for row in read_answers(db)] == ["left"]


def test_no_choice_is_recorded_for_a_pair_not_shown_to_the_participant(app, db):
    alice, bob = app.test_client(), app.test_client()
    start(alice, "alice")
    start(bob, "bob")
    _, token = show(alice)
    # Bob cannot answer, nor see, the question shown to Alice.
    assert answer(bob, token, "left").status_code == 404
    assert bob.get(f"/media/{token}/left").status_code == 404
    # Nor can anyone answer a token never issued (well-formed or not).
    assert answer(alice, "A" * 32, "left").status_code == 404
    assert answer(alice, "not a token", "left").status_code == 400
    # Questions after the one shown have no token yet: nothing to answer them with.
    store = app.extensions["gnsx_study"]["store"]
    assert store.progress("alice") == (0, 6)
    assert show(alice)[1] == token  # a reload shows the same question
    assert read_answers(db) == []
    assert answer(alice, token, "right").status_code == 303
    assert [(row["participant"], row["choice"]) for row in read_answers(db)] == [("alice", "right")]


@pytest.mark.parametrize("participant", ["", " ", "a b", "x" * 65, "../etc", "<script>", "-lead", "é"])
def test_bad_participant_ids_are_refused(app, db, participant):
    client = app.test_client()
    response = client.post("/start", data={"participant": participant})
    assert response.status_code == 400 and "participant id is 1-64 letters" in response.get_data(as_text=True)
    assert client.get("/question").location.endswith("/")  # no session
    assert app.extensions["gnsx_study"]["store"].progress(participant) == (0, 0)


@pytest.mark.parametrize(
    "fields, status",
    [
        ({"choice": "middle"}, 400),
        ({"choice": ""}, 400),
        ({"time_ms": "-5"}, 400),
        ({"time_ms": "abc"}, 400),
        ({"time_ms": "1e3"}, 400),
        ({"time_ms": "99999999999"}, 400),
        ({"token": ""}, 400),
    ],
)
def test_bad_answers_are_refused(app, db, fields, status):
    client = app.test_client()
    start(client, "p1")
    _, token = show(client)
    response = client.post("/answer", data={"token": token, "choice": "left", **fields})
    assert response.status_code == status
    assert read_answers(db) == []


def test_answers_need_a_participant(app):
    client = app.test_client()
    assert client.post("/answer", data={"token": "A" * 32, "choice": "left"}).status_code == 403
    assert client.get("/question").location.endswith("/")
    assert client.get(f"/media/{'A' * 32}/left").status_code == 404


def test_a_returning_participant_resumes(app, study_dir, db):
    client = app.test_client()
    start(client, "p1")
    for _ in range(2):
        answer(client, show(client)[1], "left")
    again = app.test_client()  # another browser, same id
    start(again, "p1")
    html, _ = show(again)
    assert "Pair 3 of 6" in html
    assert len(read_answers(db)) == 2


def test_a_database_of_another_build_is_refused(study_dir, db):
    start(create_app(study_dir, db).test_client(), "p1")
    with sqlite3.connect(db) as connection:  # as if the study had been rebuilt since
        connection.execute("UPDATE meta SET value = 'another build' WHERE key = 'study'")
    with pytest.raises(DataError, match="holds answers to another build of the study"):
        create_app(study_dir, db)


@pytest.mark.parametrize(
    "args, message",
    [
        (["{tmp}"], "not a study: no study.json"),
        (["{study}", "--host", "example.com"], "--host: an IP address to listen on"),
        (["{study}", "--port", "70000"], "--port: must be in [0, 65535]"),
        (["{study}", "--port", "{busy}"], "cannot listen"),
    ],
)
def test_serve_bad_input_is_one_line_and_exit_2(study_dir, tmp_path, capsys, args, message):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        args = [a.format(tmp=tmp_path, study=study_dir, busy=port) for a in args]
        assert main(["serve", *args, "--db", str(tmp_path / "answers.sqlite")]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
