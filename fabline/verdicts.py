"""How every summary words a survey's verdicts: all four counts, pass, fail, uncertain and not seen, which add up to
the design's nodes (a summary that names only the failures hides the nodes the survey could not decide).

Lives below the survey stage and the job report, which both print it; no import of the survey's libraries.
"""

from __future__ import annotations

from typing import Any

VERDICTS = (("passed", "pass"), ("failed", "fail"), ("uncertain", "uncertain"), ("not_seen", "not seen"))
"""The survey summary's count keys and their words, in the order summaries print them."""


def verdict_counts(summary: dict[str, Any]) -> dict[str, int]:
    """The four counts of a survey summary (`fabline.survey.measure`), keyed by their words (they add up to its
    nodes: every measured node is judged pass, fail or uncertain, every other one is not seen)."""
    return {word: int(summary.get(key, 0)) for key, word in VERDICTS}


def verdict_text(summary: dict[str, Any]) -> str:
    """`369 pass, 17 fail, 42 uncertain, 12 not seen of 440 nodes`."""
    counts = verdict_counts(summary)
    return ", ".join(f"{n} {word}" for word, n in counts.items()) + f" of {summary['nodes']} nodes"
