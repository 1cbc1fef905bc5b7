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


def reach_text(summary: dict[str, Any], regions: list[dict[str, Any]] | None, most: int = 4) -> str:
    """Where the verdicts do not reach: `12 not seen of 440 nodes: 9 around (-3.2, 4.1) m within 1.4 m (N004-011,
    N004-012, ...), 3 around ...`; `every node seen` when none is missing. `regions` are a survey record's
    `not_seen_regions` (groups of unmeasured nodes joined along lamellas), at most `most` of them named."""
    missing = int(summary.get("not_seen", 0))
    if not missing:
        return f"every one of the {summary['nodes']} nodes seen"
    if not regions:
        return f"{missing} not seen of {summary['nodes']} nodes"
    parts = []
    for region in regions[:most]:
        x, y = (v / 1000 for v in region["centre_mm"][:2])
        names = ", ".join(region["nodes"][:3]) + (", ..." if len(region["nodes"]) > 3 else "")
        parts.append(f"{len(region['nodes'])} around ({x:.1f}, {y:.1f}) m within {region['radius_mm'] / 1000:.1f} m ({names})")
    rest = sum(len(r["nodes"]) for r in regions[most:])
    return (f"{missing} not seen of {summary['nodes']} nodes: " + "; ".join(parts)
            + (f"; {rest} more in {len(regions) - most} other group(s)" if rest else ""))
