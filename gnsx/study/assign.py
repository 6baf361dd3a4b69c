"""A participant's questions: every pair of the study once, in an order and with sides of their own.

As in the paper's survey, the pairs are shuffled for each participant and each pair's left/right sides are
drawn at random, so neither the order nor the side tells the methods apart. The draw is seeded by the study's
seed and the participant's id: the same participant always gets the same questions (a reload or a restart of
the server resumes where they were), and different participants get different ones.
"""

from __future__ import annotations

import random
import re
from dataclasses import dataclass

from gnsx.study.manifest import Study

#: Participant ids: 1-64 letters, digits, ``.``, ``_`` or ``-``, starting with a letter or digit.
PARTICIPANT_ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")


def valid_participant(text: str) -> bool:
    """Whether ``text`` is a well-formed participant id (:data:`PARTICIPANT_ID`)."""
    return bool(PARTICIPANT_ID.fullmatch(text))


@dataclass(frozen=True)
class Question:
    """One pair as one participant sees it.

    Attributes:
        position: 0-based place in the participant's order.
        pair_id, group: the pair and its group (:mod:`gnsx.study.manifest`).
        method_a, method_b: the group's methods in report order (the analysis counts picks of ``method_a``).
        left, right: the methods shown on each side.
    """

    position: int
    pair_id: str
    group: str
    method_a: str
    method_b: str
    left: str
    right: str


def questions_for(study: Study, participant: str) -> list[Question]:
    """Every pair of ``study``, shuffled, with random sides, seeded by the study seed and ``participant``."""
    rng = random.Random(f"{study.seed}/{participant}")  # a str seed hashes the same in every process
    pairs = list(study.pairs)
    rng.shuffle(pairs)
    out = []
    for position, pair in enumerate(pairs):
        a, b = pair.methods
        left, right = (b, a) if rng.random() < 0.5 else (a, b)
        out.append(Question(position, pair.id, pair.group, a, b, left, right))
    return out
