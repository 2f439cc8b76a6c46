"""The model card's speaking-style section: written by ``evaluate-style``, kept by card rebuilds.

The section lies between :data:`CARD_BEGIN` and :data:`CARD_END`. ``audio2pose evaluate-style
--card`` (``make evaluate-style``) replaces it or appends it; the default model's card writer
(:mod:`audio2pose_ros.learning.model_card`) carries an existing section over into the rebuilt
card (:func:`with_style_section`), marked as measured on the model it was measured on until
``make evaluate-style`` runs again.
"""

from __future__ import annotations

from pathlib import Path

CARD_BEGIN = "<!-- begin: evaluate-style (generated; do not edit by hand) -->"
CARD_END = "<!-- end: evaluate-style -->"
STALE = "(Measured on an earlier build of the model: `make evaluate-style` measures this one.)"


def style_section(text: str) -> str:
    """The section of ``text`` with its markers, or '' when it has none."""
    if CARD_BEGIN not in text or CARD_END not in text:
        return ""
    return CARD_BEGIN + text.split(CARD_BEGIN, 1)[1].split(CARD_END, 1)[0] + CARD_END


def with_style_section(card_path: Path, new_card: str) -> str:
    """``new_card`` with the style section of the card at ``card_path`` (if any) appended."""
    old = card_path.read_text(encoding="utf-8") if card_path.is_file() else ""
    section = style_section(old)
    if not section or style_section(new_card):
        return new_card
    if STALE not in section:
        section = section.replace(CARD_END, STALE + "\n" + CARD_END)
    return new_card.rstrip("\n") + "\n\n" + section + "\n"


def write_card_section(card: Path, body: str, command: str) -> None:
    """Put the speaking-style section with ``body`` into ``card`` (replaced, or appended)."""
    section = "\n".join(
        [
            CARD_BEGIN,
            "## Speaking style: default (subject-independent) vs enrolled (subject-dependent)",
            "",
            "Enrolled on the start of each source (whole clips, at most 60 s and at most half) "
            "as `audio2pose enroll` fits it, and run as `--model` runs the folder (the personal "
            "checkpoint with the arms' own sampling noise when it was fitted, with the fitted "
            "style), scored on the rest against the real motion; the real split half is the "
            "floor, the real enrolment part shows how well the stretch enrolled on predicts the "
            "rest at all. Goals: enrolled within 25 % on the percentiles, H <= 0.12, std ratio "
            "0.8 to 1.25, and better than the default.",
            "",
            body,
            "",
            f"Rebuild: `{command}`",
            CARD_END,
        ]
    )
    old = card.read_text(encoding="utf-8") if card.exists() else ""
    if style_section(old):
        head, rest = old.split(CARD_BEGIN, 1)
        new = head + section + rest.split(CARD_END, 1)[1]
    else:
        new = old.rstrip("\n") + "\n\n" + section + "\n"
    card.write_text(new, encoding="utf-8")
