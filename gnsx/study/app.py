"""The study's web app (Flask): participants pick the more realistic animation of each pair.

Routes:

==========================  ==================================================================================
``GET /``                   instructions and the participant id form (``?participant=ID`` fills it in)
``POST /start``             ``participant``: checks the id, assigns the participant's questions (seeded order
                            and sides, :mod:`gnsx.study.assign`) and keeps the id in a signed session cookie
``GET /question``           the participant's next unanswered pair, side by side, with a fresh token
``GET /media/<token>/<s>``  the animation on side ``s`` (left/right) of the question shown under ``token``
``POST /answer``            ``token``, ``choice`` (left/right), ``time_ms`` (optional): records the choice
``GET /done``               the end
==========================  ==================================================================================

Answers are only accepted for a question that was shown to the session's participant, once (the token,
:class:`~gnsx.study.store.AnswerStore`): a token never issued or issued to someone else gets 404, a second
answer 409, a malformed field 400, no participant 403. Every error is one line on a small page.
"""

from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path

from flask import Flask, abort, redirect, render_template, request, send_file, session, url_for
from jinja2 import DictLoader
from werkzeug.exceptions import HTTPException

from gnsx.study.assign import questions_for, valid_participant
from gnsx.study.manifest import load_study
from gnsx.study.pages import PAGES
from gnsx.study.store import ANSWERS, CHOICES, AlreadyAnswered, AnswerStore, UnknownQuestion

#: Tokens as :meth:`AnswerStore.show_next` makes them (``secrets.token_urlsafe``).
TOKEN = re.compile(r"[A-Za-z0-9_-]{16,64}")
#: The longest time a choice may take, in ms (a day): longer values are malformed.
MAX_TIME_MS = 86_400_000


def _time_ms(text: str | None) -> int | None:
    """The page's ``time_ms``: None when absent, else an int in [0, MAX_TIME_MS] (400 otherwise)."""
    if text is None or text == "":
        return None
    if not text.isdigit() or int(text) > MAX_TIME_MS:
        abort(400, f"time_ms must be a whole number of milliseconds in [0, {MAX_TIME_MS}]")
    return int(text)


def create_app(study_dir: str | Path, db_path: str | Path | None = None) -> Flask:
    """The web app of the study in ``study_dir``, recording into ``db_path`` (default its ``answers.sqlite``).

    Raises:
        DataError: a bad manifest, or a database that holds answers to another build of the study.
    """
    study = load_study(study_dir)
    store = AnswerStore(db_path or study.folder / ANSWERS)
    store.bind_study(study.digest)
    app = Flask(__name__)
    app.config.update(SECRET_KEY=store.secret_key(), SESSION_COOKIE_SAMESITE="Lax", MAX_CONTENT_LENGTH=16_384)
    app.jinja_loader = DictLoader(PAGES)
    app.extensions["gnsx_study"] = {"study": study, "store": store}
    total = len(study.pairs)

    def participant() -> str | None:
        pid = session.get("participant")
        return pid if isinstance(pid, str) and valid_participant(pid) else None

    @app.after_request
    def headers(response):
        response.headers["X-Content-Type-Options"] = "nosniff"
        response.headers.setdefault("Cache-Control", "no-store")
        return response

    @app.errorhandler(HTTPException)
    def error(e: HTTPException):
        return render_template(
            "error.html", title=e.name, code=e.code, name=e.name, description=e.description
        ), e.code

    @app.get("/")
    def index():
        return render_template(
            "intro.html",
            title=study.name,
            total=total,
            error=None,
            participant=request.args.get("participant", ""),
        )

    @app.post("/start")
    def start():
        pid = request.form.get("participant", "").strip()
        if not valid_participant(pid):
            error = (
                "A participant id is 1-64 letters, digits, '.', '_' or '-', starting with a letter or digit."
            )
            return render_template(
                "intro.html", title=study.name, total=total, error=error, participant=""
            ), 400
        session.clear()
        session["participant"] = pid
        store.assign(pid, questions_for(study, pid))
        return redirect(url_for("question"), 303)

    @app.get("/question")
    def question():
        pid = participant()
        if pid is None:
            return redirect(url_for("index"), 303)
        row = store.show_next(pid)
        if row is None:
            return redirect(url_for("done"), 303)
        video = study.render.get("format") == "mp4"
        return render_template(
            "question.html",
            title=study.name,
            token=row["token"],
            number=row["position"] + 1,
            total=total,
            video=video,
        )

    @app.get("/media/<token>/<side>")
    def media(token: str, side: str):
        pid = participant()
        if pid is None or side not in CHOICES or not TOKEN.fullmatch(token):
            abort(404)
        try:
            row = store.shown(pid, token)
            pair = study.pair(row["pair_id"])
        except (UnknownQuestion, KeyError):
            abort(404)
        method = row["left_method"] if side == "left" else row["right_method"]
        path = study.media(pair, method).resolve()  # Flask reads a relative path from the package's folder
        # Named by its side and without an ETag, so no header tells the method or the file.
        return send_file(path, download_name=f"{side}{path.suffix}", etag=False, max_age=0)

    @app.post("/answer")
    def answer():
        pid = participant()
        if pid is None:
            abort(403, "No participant: start the study from its first page.")
        token = request.form.get("token", "")
        choice = request.form.get("choice", "")
        if not TOKEN.fullmatch(token):
            abort(400, "Malformed or missing token.")
        if choice not in CHOICES:
            abort(400, f"choice must be one of {list(CHOICES)}.")
        try:
            store.record(pid, token, choice, _time_ms(request.form.get("time_ms")))
        except UnknownQuestion:
            abort(404, "No such pair was shown to this participant.")
        except AlreadyAnswered:
            abort(409, "This pair was answered already.")
        return redirect(url_for("question"), 303)

    @app.get("/done")
    def done():
        pid = participant()
        if pid is None:
            return redirect(url_for("index"), 303)
        answered, assigned = store.progress(pid)
        return render_template("done.html", title=study.name, answered=answered, total=assigned)

    return app


def make_server(app: Flask, host: str = "127.0.0.1", port: int = 8000):
    """werkzeug's threaded HTTP server for ``app``, bound but not started (``serve_forever``, ``shutdown``,
    ``server_port``); enough for a few participants at a time.

    Raises:
        OSError: the address cannot be bound (in use, not this machine's), with werkzeug's one-line reason.
    """
    from werkzeug.serving import make_server as werkzeug_server

    reason = io.StringIO()
    try:
        with contextlib.redirect_stderr(reason):
            return werkzeug_server(host, port, app, threaded=True)
    except SystemExit:  # werkzeug prints why it cannot bind, then exits
        lines = reason.getvalue().strip().splitlines()
        raise OSError(lines[0] if lines else "cannot bind") from None
