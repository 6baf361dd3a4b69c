"""The web app's pages (Jinja templates, served from memory by :mod:`gnsx.study.app`).

Plain HTML and one small script: the question page measures the time from showing the pair to the click and
sends it with the choice (``time_ms``); without scripts the server's own measure is stored. The pages never
name a method: the animations come from ``/media/<token>/<side>``, which hides their file names.
"""

from __future__ import annotations

LAYOUT = """<!doctype html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{{ title }}</title>
<style>
  body { background: #0c0e1c; color: #e6e6e6; font-family: system-ui, sans-serif; margin: 0;
         padding: 1.5rem; }
  main { max-width: 60rem; margin: 0 auto; }
  .pair { display: flex; gap: 1.5rem; justify-content: center; flex-wrap: wrap; }
  figure { margin: 0; display: flex; flex-direction: column; align-items: center; gap: 0.75rem; }
  .pair img, .pair video { width: min(42vw, 65vh, 26rem); height: auto; border: 1px solid #333; }
  button { font-size: 1.1rem; padding: 0.6rem 1.6rem; border-radius: 0.4rem; border: 0; cursor: pointer;
           background: #3c6fd6; color: white; }
  button:hover { background: #5584e6; }
  input { font-size: 1.1rem; padding: 0.4rem; }
  .muted { color: #9aa0b4; }
  .error { color: #ff8a80; }
</style>
</head>
<body><main>{% block body %}{% endblock %}</main></body>
</html>
"""

INTRO = """{% extends "layout.html" %}
{% block body %}
<h1>Which simulation looks more realistic?</h1>
<p>You will see {{ total }} pairs of short animations of water. Both animations of a pair start from the same
state. For each pair, pick the one that looks more realistic; if both look equally realistic, pick the one you
prefer. There is no right answer and no time limit.</p>
{% if error %}<p class="error" id="error">{{ error }}</p>{% endif %}
<form method="post" action="{{ url_for('start') }}">
  <label for="participant">Your participant id</label>
  <input id="participant" name="participant" value="{{ participant }}" required maxlength="64"
         pattern="[A-Za-z0-9][A-Za-z0-9._\\-]{0,63}" autocomplete="off">
  <button id="start" type="submit">Start</button>
  <p class="muted">Letters, digits, dot, underscore or dash (e.g. the id the organiser gave you).
  Entering the same id again resumes where you stopped.</p>
</form>
{% endblock %}
"""

QUESTION = """{% extends "layout.html" %}
{% block body %}
<p class="muted" id="progress">Pair {{ number }} of {{ total }}</p>
<p>Which animation looks more realistic? If both look equally realistic, pick the one you prefer.</p>
<form method="post" action="{{ url_for('answer') }}" id="answer">
  <input type="hidden" name="token" value="{{ token }}">
  <input type="hidden" name="time_ms" id="time_ms" value="">
  <div class="pair">
  {% for side in ("left", "right") %}
    <figure>
      {% set src = url_for('media', token=token, side=side) %}
      {% if video %}<video id="media-{{ side }}" src="{{ src }}" autoplay loop muted playsinline></video>
      {% else %}<img id="media-{{ side }}" src="{{ src }}" alt="{{ side }} animation">{% endif %}
      <button id="choose-{{ side }}" type="submit" name="choice" value="{{ side }}">
        {{ side|capitalize }}</button>
    </figure>
  {% endfor %}
  </div>
</form>
<script>
  const shown = performance.now();
  let sent = false;
  document.getElementById("answer").addEventListener("submit", (event) => {
    if (sent) { event.preventDefault(); return; }
    sent = true;
    document.getElementById("time_ms").value = Math.round(performance.now() - shown);
  });
</script>
{% endblock %}
"""

DONE = """{% extends "layout.html" %}
{% block body %}
<h1 id="done">Thank you!</h1>
<p>You answered {{ answered }} of {{ total }} pairs. You can close this page.</p>
{% endblock %}
"""

ERROR = """{% extends "layout.html" %}
{% block body %}
<h1>{{ code }} {{ name }}</h1>
<p class="error" id="error">{{ description }}</p>
<p><a href="{{ url_for('index') }}" style="color: #8fb3ff">Back to the start</a></p>
{% endblock %}
"""

#: Template name -> source, for a ``jinja2.DictLoader``.
PAGES = {
    "layout.html": LAYOUT,
    "intro.html": INTRO,
    "question.html": QUESTION,
    "done.html": DONE,
    "error.html": ERROR,
}
