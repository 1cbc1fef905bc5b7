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


def text_width(text: str) -> float:
    """Advance width of `text` at cap height 1, without laying out its strokes."""
    return sum(_glyph(char).width for char in text)


@dataclass(frozen=True)
class TextBlock:
    """Many strings laid out together at cap height 1, each from x = 0: all vertices, whose string each vertex and
    each stroke is, where strokes start, and each string's width."""

    points: np.ndarray
    owner: np.ndarray
    starts: np.ndarray
    stroke_owner: np.ndarray
    widths: np.ndarray


def layout_block(texts: list[str]) -> TextBlock:
    """Lay out many strings at once (the same glyphs as `layout`, without a Python loop per string's arrays)."""
    glyph_of = {char: _glyph(char) for char in set("".join(texts))}
    glyphs = [glyph_of[char] for text in texts for char in text]
    text_of_char = np.repeat(np.arange(len(texts)), [len(text) for text in texts])
    char_width = np.array([g.width for g in glyphs])
    widths = np.bincount(text_of_char, weights=char_width, minlength=len(texts))
    advance = np.cumsum(char_width) - char_width                       # from the block's start ...
    first_char = np.concatenate([[0], np.cumsum([len(text) for text in texts])[:-1]]).astype(int)
    advance -= np.repeat(advance[first_char] if len(glyphs) else np.zeros(len(texts)), [len(t) for t in texts])
    counts = np.array([len(g.points) for g in glyphs], dtype=int)     # ... made relative to each string's start
    if not counts.sum():
        return TextBlock(np.zeros((0, 2)), np.zeros(0, int), np.zeros(0, int), np.zeros(0, int), widths)
    points = np.concatenate([g.points for g in glyphs if len(g.points)])
    points[:, 0] += np.repeat(advance, counts)
    row = np.cumsum(counts) - counts
    stroke_counts = [len(g.starts) if len(g.points) else 0 for g in glyphs]
    starts = np.concatenate([g.starts for g in glyphs if len(g.points)]) + np.repeat(row, stroke_counts)
    return TextBlock(points, np.repeat(text_of_char, counts), starts, np.repeat(text_of_char, stroke_counts), widths)


def arrow(length: float, height: float) -> list[np.ndarray]:
    """An orientation arrow along +x: a shaft and an open head, as two polylines (origin at the shaft's start)."""
    head = min(height, length / 3.0)
    return [np.array([[0.0, 0.0], [length, 0.0]]),
            np.array([[length - head, head / 2.0], [length, 0.0], [length - head, -head / 2.0]])]
