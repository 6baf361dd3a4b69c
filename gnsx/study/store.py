"""The study's answers in SQLite: what was shown to whom, and what they chose.

Tables:

``questions``
    One row per participant and pair, written when the participant starts (:mod:`gnsx.study.assign`):
    ``participant, position, pair_id, group_id, method_a, method_b, left_method, right_method``, and
    ``token, shown_at``, set when the question is first shown. The token is a random secret that the page
    carries; an answer must bring it back.
``answers``
    One row per answered question: ``participant, pair_id, group_id, method_a, method_b, left_method,
    right_method, choice ('left' | 'right'), chosen_method, time_ms`` (from showing to choosing, as the page
    measured it, or as the server did when the page sent none), ``server_ms`` and ``answered_at`` (UTC, ISO
    8601). Its primary key ``(participant, pair_id)`` and its foreign key to ``questions`` make a second
    answer, or an answer to a pair never assigned, impossible in the database itself.
``meta``
    ``secret`` (signs the web app's session cookies, so sessions survive a restart) and ``study`` (the
    SHA-256 of the manifest the answers belong to).

An answer is only recorded (:meth:`AnswerStore.record`) against a token that was issued to the same
participant when the question was shown, and only once: nobody can record a choice for a pair the server did
not show them, nor answer twice. Every write is one short transaction (``BEGIN IMMEDIATE``), so the threads of
the web server can share the file.
"""

from __future__ import annotations

import secrets
import sqlite3
from collections.abc import Iterator, Sequence
from contextlib import closing, contextmanager
from datetime import datetime, timezone
from pathlib import Path

from gnsx.core.errors import DataError
from gnsx.study.assign import Question

#: What a question shows, stored with it and copied into its answer: the pair, its group and the group's
#: methods in report order, and the method on each side.
SHOWN = ("pair_id", "group_id", "method_a", "method_b", "left_method", "right_method")
_SHOWN_COLUMNS = "".join(f"\n    {column} TEXT NOT NULL," for column in SHOWN)
SCHEMA = f"""
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS questions (
    participant TEXT NOT NULL,
    position INTEGER NOT NULL,{_SHOWN_COLUMNS}
    token TEXT UNIQUE,
    shown_at TEXT,
    PRIMARY KEY (participant, position),
    UNIQUE (participant, pair_id)
);
CREATE TABLE IF NOT EXISTS answers (
    participant TEXT NOT NULL,{_SHOWN_COLUMNS}
    choice TEXT NOT NULL CHECK (choice IN ('left', 'right')),
    chosen_method TEXT NOT NULL,
    time_ms INTEGER NOT NULL CHECK (time_ms >= 0),
    server_ms INTEGER NOT NULL,
    answered_at TEXT NOT NULL,
    PRIMARY KEY (participant, pair_id),
    FOREIGN KEY (participant, pair_id) REFERENCES questions (participant, pair_id)
);
"""
#: The columns of an answer, in order (what :func:`read_answers` returns for each row).
ANSWER_COLUMNS = ("participant", *SHOWN, "choice", "chosen_method", "time_ms", "server_ms", "answered_at")
CHOICES = ("left", "right")
#: The question shown to a participant under a token (none before it is shown).
_SHOWN_UNDER_TOKEN = "SELECT * FROM questions WHERE participant = ? AND token = ? AND shown_at IS NOT NULL"
#: The answers file in a study's folder (the web app's default database).
ANSWERS = "answers.sqlite"


class UnknownQuestion(LookupError):
    """No question with this token was shown to this participant."""


class AlreadyAnswered(Exception):
    """The participant already answered this question."""


def _now() -> datetime:
    return datetime.now(timezone.utc)


class AnswerStore:
    """The answers database of one study (created on first use)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        with closing(self._connect()) as db:
            db.executescript(SCHEMA)  # idempotent; executescript commits by itself

    def _connect(self) -> sqlite3.Connection:
        db = sqlite3.connect(self.path, timeout=10, isolation_level=None)
        db.row_factory = sqlite3.Row
        db.execute("PRAGMA foreign_keys = ON")
        return db

    @contextmanager
    def _write(self) -> Iterator[sqlite3.Connection]:
        """One write transaction (committed when the block succeeds, rolled back otherwise)."""
        with closing(self._connect()) as db:
            db.execute("BEGIN IMMEDIATE")
            try:
                yield db
                db.execute("COMMIT")
            except BaseException:
                db.execute("ROLLBACK")
                raise

    def _read(self, sql: str, params: Sequence = ()) -> list[sqlite3.Row]:
        with closing(self._connect()) as db:
            return db.execute(sql, params).fetchall()

    def meta(self, key: str, make: str) -> str:
        """The value of ``key`` in ``meta``, set to ``make`` first when it has none."""
        with self._write() as db:
            db.execute("INSERT OR IGNORE INTO meta (key, value) VALUES (?, ?)", (key, make))
            return db.execute("SELECT value FROM meta WHERE key = ?", (key,)).fetchone()[0]

    def secret_key(self) -> str:
        """The key that signs session cookies (made once per database)."""
        return self.meta("secret", secrets.token_hex(32))

    def bind_study(self, digest: str) -> None:
        """Tie the answers to one build of the study (its manifest's SHA-256).

        Raises:
            DataError: the database already holds questions of another build.
        """
        with self._write() as db:
            row = db.execute("SELECT value FROM meta WHERE key = 'study'").fetchone()
            if row is not None and row[0] != digest:
                if db.execute("SELECT 1 FROM questions LIMIT 1").fetchone():
                    raise DataError(
                        str(self.path), "holds answers to another build of the study; give a new --db"
                    )
            db.execute("INSERT OR REPLACE INTO meta (key, value) VALUES ('study', ?)", (digest,))

    def assign(self, participant: str, questions: Sequence[Question]) -> None:
        """Store ``participant``'s questions, unless they have some already (a returning participant)."""
        with self._write() as db:
            if db.execute("SELECT 1 FROM questions WHERE participant = ?", (participant,)).fetchone():
                return
            db.executemany(
                "INSERT INTO questions (participant, position, pair_id, group_id, method_a, method_b, "
                "left_method, right_method) VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                [
                    (participant, q.position, q.pair_id, q.group, q.method_a, q.method_b, q.left, q.right)
                    for q in questions
                ],
            )

    def progress(self, participant: str) -> tuple[int, int]:
        """``(answered, assigned)`` questions of ``participant``."""
        (row,) = self._read(
            "SELECT (SELECT COUNT(*) FROM answers WHERE participant = :p), "
            "(SELECT COUNT(*) FROM questions WHERE participant = :p)",
            {"p": participant},
        )
        return row[0], row[1]

    def show_next(self, participant: str) -> sqlite3.Row | None:
        """``participant``'s first unanswered question, its token issued (once: a reload shows the same).

        Returns:
            the ``questions`` row, or None when every question is answered (or none was assigned).
        """
        with self._write() as db:
            row = db.execute(
                "SELECT q.* FROM questions q LEFT JOIN answers a "
                "ON a.participant = q.participant AND a.pair_id = q.pair_id "
                "WHERE q.participant = ? AND a.pair_id IS NULL ORDER BY q.position LIMIT 1",
                (participant,),
            ).fetchone()
            if row is None or row["token"] is not None:
                return row
            db.execute(
                "UPDATE questions SET token = ?, shown_at = ? WHERE participant = ? AND position = ?",
                (secrets.token_urlsafe(24), _now().isoformat(), participant, row["position"]),
            )
            return db.execute(
                "SELECT * FROM questions WHERE participant = ? AND position = ?",
                (participant, row["position"]),
            ).fetchone()

    def shown(self, participant: str, token: str) -> sqlite3.Row:
        """The question shown to ``participant`` under ``token``.

        Raises:
            UnknownQuestion: no such token was issued to this participant.
        """
        rows = self._read(_SHOWN_UNDER_TOKEN, (participant, token))
        if not rows:
            raise UnknownQuestion(token)
        return rows[0]

    def record(self, participant: str, token: str, choice: str, time_ms: int | None = None) -> dict:
        """Record ``participant``'s ``choice`` for the question shown under ``token``.

        Args:
            choice: ``"left"`` or ``"right"``.
            time_ms: time from showing to choosing as the page measured it; None: the server's measure.
        Returns:
            the stored answer (:data:`ANSWER_COLUMNS`).
        Raises:
            ValueError: a choice other than left/right, or a negative time.
            UnknownQuestion: no question was shown to this participant under ``token``.
            AlreadyAnswered: it was answered before (a replay).
        """
        if choice not in CHOICES:
            raise ValueError(f"choice must be one of {CHOICES}, got {choice!r}")
        if time_ms is not None and time_ms < 0:
            raise ValueError(f"time_ms must be >= 0, got {time_ms}")
        now = _now()
        with self._write() as db:
            q = db.execute(_SHOWN_UNDER_TOKEN, (participant, token)).fetchone()
            if q is None:
                raise UnknownQuestion(token)
            done = db.execute(
                "SELECT 1 FROM answers WHERE participant = ? AND pair_id = ?", (participant, q["pair_id"])
            ).fetchone()
            if done:
                raise AlreadyAnswered(q["pair_id"])
            server_ms = max(0, round((now - datetime.fromisoformat(q["shown_at"])).total_seconds() * 1000))
            answer = {
                "participant": participant,
                **{column: q[column] for column in SHOWN},
                "choice": choice,
                "chosen_method": q["left_method"] if choice == "left" else q["right_method"],
                "time_ms": server_ms if time_ms is None else int(time_ms),
                "server_ms": server_ms,
                "answered_at": now.isoformat(),
            }
            db.execute(
                f"INSERT INTO answers ({', '.join(ANSWER_COLUMNS)}) "
                f"VALUES ({', '.join('?' * len(ANSWER_COLUMNS))})",
                [answer[c] for c in ANSWER_COLUMNS],
            )
            return answer


def read_answers(path: str | Path) -> list[dict]:
    """Every answer of a study database (e.g. a copy exported from the machine that ran the study).

    Opened read-only; rows as dicts of :data:`ANSWER_COLUMNS`, in the order they were given.

    Raises:
        DataError: a missing file or one that is not a study's answers database.
    """
    path = Path(path)
    if not path.is_file():
        raise DataError(str(path), "no such answers database")
    try:
        with closing(sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True)) as db:
            db.row_factory = sqlite3.Row
            rows = db.execute(f"SELECT {', '.join(ANSWER_COLUMNS)} FROM answers ORDER BY rowid").fetchall()
    except sqlite3.DatabaseError as e:
        raise DataError(str(path), f"not a study answers database ({e})") from None
    return [dict(row) for row in rows]
