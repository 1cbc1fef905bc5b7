"""Single-stroke text for engraving: strings to polylines that a laser or pen draws in one pass each.

Glyphs come from the Hershey "futural" stroke font (the HersheyFonts package), scaled so that capital
letters are `height` high, baseline at y = 0, text starting at x = 0.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from HersheyFonts import HersheyFonts

FONT = "futural"


@dataclass(frozen=True)
class StrokeText:
    """A laid-out string at cap height 1: all stroke vertices (N, 2), where each stroke starts, and its width."""

    points: np.ndarray
    starts: np.ndarray
    width: float


def split_rows(points: np.ndarray, starts: np.ndarray) -> list[np.ndarray]:
    """Split an (N, 2) array into the polylines that begin at row indices `starts` (faster than np.split)."""
    ends = list(starts[1:]) + [len(points)]
    return [points[a:b] for a, b in zip(starts, ends)]


@lru_cache(maxsize=1)
def _font() -> tuple[HersheyFonts, float, float]:
    font = HersheyFonts()
    font.load_default_font(FONT)
    glyph = next(iter(font.glyphs_for_text("H")))
    return font, float(glyph.base_line), float(glyph.base_line - glyph.cap_line)


@lru_cache(maxsize=None)
def _glyph(char: str) -> StrokeText:
    """One character at cap height 1, left edge at x = 0: its stroke vertices, stroke starts and advance width."""
    font, base, cap = _font()
    glyphs = list(font.glyphs_for_text(char))
    if not glyphs:
        glyphs = list(font.glyphs_for_text("?"))
    glyph = glyphs[0]
    strokes = [np.array([((x - glyph.left_offset) / cap, (base - y) / cap) for x, y in stroke])
               for stroke in glyph.strokes if len(stroke) >= 2]
    if not strokes:
        return StrokeText(np.zeros((0, 2)), np.zeros(0, dtype=int), glyph.char_width / cap)
    starts = np.cumsum([0] + [len(stroke) for stroke in strokes[:-1]])
    return StrokeText(np.concatenate(strokes), starts, glyph.char_width / cap)


@lru_cache(maxsize=65536)
def layout(text: str) -> StrokeText:
    """Lay out `text` on one line at cap height 1 (multiply by the wanted height)."""
    glyphs = [_glyph(char) for char in text]
    widths = [glyph.width for glyph in glyphs]
    advance = sum(widths)
    counts = [len(glyph.points) for glyph in glyphs]
    if not sum(counts):
        return StrokeText(np.zeros((0, 2)), np.zeros(1, dtype=int), advance)
    points = np.concatenate([glyph.points for glyph in glyphs])
    points[:, 0] += np.repeat(np.cumsum([0.0] + widths[:-1]), counts)
    first_row = np.cumsum([0] + counts[:-1])
    starts = np.concatenate([glyph.starts for glyph in glyphs])
    starts += np.repeat(first_row, [len(glyph.starts) for glyph in glyphs])
    return StrokeText(points, starts, advance)


def arrow(length: float, height: float) -> list[np.ndarray]:
    """An orientation arrow along +x: a shaft and an open head, as two polylines (origin at the shaft's start)."""
    head = min(height, length / 3.0)
    return [np.array([[0.0, 0.0], [length, 0.0]]),
            np.array([[length - head, head / 2.0], [length, 0.0], [length - head, -head / 2.0]])]
