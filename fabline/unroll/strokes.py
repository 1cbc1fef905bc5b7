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
GATHER_CHUNK = 8192  # strings per pass of `gather`: their vertices stay in the CPU cache through all the arithmetic


@dataclass(frozen=True)
class StrokeText:
    """A laid-out string at cap height 1: all stroke vertices (N, 2), where each stroke starts, and its width."""

    points: np.ndarray
    starts: np.ndarray
    width: float


def split_rows(points: np.ndarray, starts: np.ndarray) -> list[np.ndarray]:
    """Split an (N, 2) array into the polylines that begin at row indices `starts` (faster than np.split)."""
    bounds = np.asarray(starts, dtype=int).tolist() + [len(points)]  # plain ints slice fastest
    return [points[a:b] for a, b in zip(bounds[:-1], bounds[1:])]


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


@dataclass(frozen=True)
class TextBlock:
    """Many strings laid out together at cap height 1, each from x = 0: all vertices (string by string), each
    string's vertex count, where strokes start, whose string each stroke is, and each string's width."""

    points: np.ndarray
    point_counts: np.ndarray
    starts: np.ndarray
    stroke_owner: np.ndarray
    widths: np.ndarray


def _codes(texts: list[str]) -> np.ndarray:
    """The characters of all strings, one after another, as code points."""
    return np.frombuffer("".join(texts).encode("utf-32-le"), dtype="<u4")


@lru_cache(maxsize=256)
def _glyph_table(alphabet: str) -> TextBlock:
    """The glyphs of the characters of `alphabet` as a block, one 'string' per character."""
    glyphs = [_glyph(char) for char in alphabet]
    counts = np.array([len(g.points) for g in glyphs], dtype=int)
    stroke_counts = np.array([len(g.starts) if len(g.points) else 0 for g in glyphs], dtype=int)
    drawn = [g for g in glyphs if len(g.points)]
    points = np.concatenate([g.points for g in drawn]) if drawn else np.zeros((0, 2))
    first = np.cumsum(counts) - counts
    starts = (np.concatenate([g.starts for g in drawn]) if drawn else np.zeros(0, int)) + np.repeat(first, stroke_counts)
    index = np.arange(len(glyphs))
    return TextBlock(points, counts, starts, np.repeat(index, stroke_counts),
                     np.array([g.width for g in glyphs]))


def gather(block: TextBlock, which: np.ndarray, scale: np.ndarray | float = 1.0, shift: np.ndarray | None = None,
           advance: np.ndarray | None = None) -> TextBlock:
    """The strings block[which[i]] one after another (owner i): each moved along x by advance[i], then scaled by
    scale[i] (or one scale for all), then moved by shift[i] (an (N, 2) array); widths per instance, unscaled.

    Millions of vertices are made a few thousand strings at a time: each pass then works in the CPU cache
    instead of streaming several arrays of the whole size through memory (a fifth faster for 11 million)."""
    strings = len(block.widths)
    point_count = block.point_counts
    stroke_count = np.bincount(block.stroke_owner, minlength=strings)
    point_first, stroke_first = np.cumsum(point_count) - point_count, np.cumsum(stroke_count) - stroke_count
    counts, strokes = point_count[which], stroke_count[which]
    row = np.cumsum(counts) - counts
    source = point_first[which] - row
    points = np.empty((int(counts.sum()), 2))
    xs, ys = np.ascontiguousarray(block.points[:, 0]), np.ascontiguousarray(block.points[:, 1])
    for lo in range(0, len(which), GATHER_CHUNK):
        hi = lo + GATHER_CHUNK
        count = counts[lo:hi]
        first_row = int(row[lo])
        chunk = points[first_row:first_row + int(count.sum())]
        index = np.repeat(source[lo:hi], count)
        index += np.arange(first_row, first_row + len(chunk))
        x, y = xs[index], ys[index]   # column by column: numpy's loops then run along the chunk, not along 2 columns
        if advance is not None:
            x += np.repeat(advance[lo:hi], count)
        if np.ndim(scale):
            factor = np.repeat(scale[lo:hi], count)
            x *= factor
            y *= factor
        elif scale != 1.0:
            x *= scale
            y *= scale
        if shift is not None:
            x += np.repeat(shift[lo:hi, 0], count)
            y += np.repeat(shift[lo:hi, 1], count)
        chunk[:, 0], chunk[:, 1] = x, y
    instance = np.arange(len(which))
    first = np.cumsum(strokes) - strokes
    stroke_index = np.repeat(stroke_first[which] - first, strokes) + np.arange(strokes.sum())
    starts = block.starts[stroke_index] + np.repeat(row - point_first[which], strokes)
    return TextBlock(points, counts, starts, np.repeat(instance, strokes), block.widths[which])


def join_blocks(blocks: list[TextBlock]) -> TextBlock:
    """Several blocks as one, their strings numbered on from block to block (e.g. two glyph tables and arrows)."""
    strings = np.cumsum([0] + [len(b.widths) for b in blocks[:-1]])
    rows = np.cumsum([0] + [len(b.points) for b in blocks[:-1]])
    return TextBlock(np.concatenate([b.points for b in blocks]),
                     np.concatenate([b.point_counts for b in blocks]),
                     np.concatenate([b.starts + r for b, r in zip(blocks, rows)]),
                     np.concatenate([b.stroke_owner + k for b, k in zip(blocks, strings)]),
                     np.concatenate([b.widths for b in blocks]))


@dataclass(frozen=True)
class Characters:
    """Many strings as characters at cap height 1: the glyph table, per character its glyph and its advance from its
    string's start, per string its first character, character count and width. `gather` then places every
    character of many strings, scaled and moved, in one pass over the vertices."""

    table: TextBlock
    glyph: np.ndarray
    advance: np.ndarray
    first: np.ndarray
    lengths: np.ndarray
    widths: np.ndarray


def characters(texts: list[str]) -> Characters:
    """The characters of `texts`, each string starting at x = 0 (the advances of `layout`, by whole-array operations)."""
    codes = _codes(texts)
    alphabet, glyph = np.unique(codes, return_inverse=True)
    table = _glyph_table("".join(map(chr, alphabet.tolist())))
    glyph = glyph.ravel()
    lengths = np.array([len(text) for text in texts], dtype=int)
    string = np.repeat(np.arange(len(texts)), lengths)
    char_width = table.widths[glyph]
    before = np.cumsum(char_width) - char_width                     # advance from the block's start ...
    first = np.cumsum(lengths) - lengths
    start_of_string = np.repeat(before[first[lengths > 0]], lengths[lengths > 0])
    widths = np.bincount(string, weights=char_width, minlength=len(texts))
    return Characters(table, glyph, before - start_of_string, first, lengths, widths)  # ... made per string


@lru_cache(maxsize=65536)
def text_width(text: str) -> float:
    """Advance width of a string at cap height 1, without laying out its strokes (cached: node ids recur)."""
    return sum(_glyph(char).width for char in text)


def arrow(length: float, height: float) -> list[np.ndarray]:
    """An orientation arrow along +x: a shaft and an open head, as two polylines (origin at the shaft's start)."""
    head = min(height, length / 3.0)
    return [np.array([[0.0, 0.0], [length, 0.0]]),
            np.array([[length - head, head / 2.0], [length, 0.0], [length - head, -head / 2.0]])]
