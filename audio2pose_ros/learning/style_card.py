"""The model card's generated sections, kept by card rebuilds: speaking style and population.

The speaking-style section lies between :data:`CARD_BEGIN` and :data:`CARD_END`.
``audio2pose evaluate-style --card`` (``make evaluate-style``) replaces it or appends it; the
default model's card writer (:mod:`audio2pose_ros.learning.model_card`) carries an existing
section over into the rebuilt card (:func:`with_style_section`), marked as measured on the model
it was measured on until ``make evaluate-style`` runs again. The population section
(:data:`POPULATION_BEGIN` to :data:`POPULATION_END`, :mod:`audio2pose_ros.style.population`)
is written and carried over the same way (:func:`put_section`, :func:`carried`).
"""

from __future__ import annotations

from pathlib import Path

CARD_BEGIN = "<!-- begin: evaluate-style (generated; do not edit by hand) -->"
CARD_END = "<!-- end: evaluate-style -->"
STALE = "(Measured on an earlier build of the model: `make evaluate-style` measures this one.)"
POPULATION_BEGIN = "<!-- begin: population (generated; do not edit by hand) -->"
POPULATION_END = "<!-- end: population -->"
POPULATION_STALE = (
    "(Measured on an earlier build of the model: `make default-model` measures this one.)"
)


def section_of(text: str, begin: str, end: str) -> str:
    """The section of ``text`` between ``begin`` and ``end`` with them, or '' when it has none."""
    if begin not in text or end not in text:
        return ""
    return begin + text.split(begin, 1)[1].split(end, 1)[0] + end


def carried(card_path: Path, new_card: str, begin: str, end: str, stale: str) -> str:
    """``new_card`` with the section of the card at ``card_path`` (if any) appended, as stale."""
    old = card_path.read_text(encoding="utf-8") if card_path.is_file() else ""
    section = section_of(old, begin, end)
    if not section or section_of(new_card, begin, end):
        return new_card
    if stale not in section:
        section = section.replace(end, stale + "\n" + end)
    return new_card.rstrip("\n") + "\n\n" + section + "\n"


def put_section(card: Path, begin: str, end: str, lines: list[str]) -> None:
    """Put the section of ``lines`` between ``begin`` and ``end`` into ``card`` (or append it)."""
    section = "\n".join([begin, *lines, end])
    old = card.read_text(encoding="utf-8") if card.exists() else ""
    if section_of(old, begin, end):
        head, rest = old.split(begin, 1)
        new = head + section + rest.split(end, 1)[1]
    else:
        new = old.rstrip("\n") + "\n\n" + section + "\n"
    card.write_text(new, encoding="utf-8")


def style_section(text: str) -> str:
    """The speaking-style section of ``text`` with its markers, or '' when it has none."""
    return section_of(text, CARD_BEGIN, CARD_END)


def with_style_section(card_path: Path, new_card: str) -> str:
    """``new_card`` with the generated sections of the card at ``card_path`` (if any) appended."""
    new_card = carried(card_path, new_card, POPULATION_BEGIN, POPULATION_END, POPULATION_STALE)
    return carried(card_path, new_card, CARD_BEGIN, CARD_END, STALE)


def write_card_section(card: Path, body: str, command: str) -> None:
    """Put the speaking-style section with ``body`` into ``card`` (replaced, or appended)."""
    put_section(
        card,
        CARD_BEGIN,
        CARD_END,
        [
            "## Speaking style: default (subject-independent) vs enrolled (subject-dependent)",
            "",
            "Enrolled on the start of each source (whole clips, at most 60 s and at most half; "
            "also on its first 10 s and 20 s, what the console's Learn my style records) as "
            "`audio2pose enroll` fits it, cross-validated inside the enrolment (part by part the "
            "default where the learned style does not come closer on stretches it did not fit), "
            "and run as `--model` runs the folder (the personal checkpoint with the arms' own "
            "sampling noise when it was fitted, with the fitted style), scored on the rest "
            "against the real motion; the real split half is the floor, the real enrolment part "
            "shows how well the stretch enrolled on predicts the rest at all. Goals: enrolled at "
            "least as close as the default on every measure (or the default kept), within 25 % "
            "on the percentiles, H <= 0.12, std ratio 0.8 to 1.25.",
            "",
            body,
            "",
            f"Rebuild: `{command}`",
        ],
    )
