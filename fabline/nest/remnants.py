"""Leftover rectangles of a nested sheet that are big enough to keep as remnants for later jobs."""

from __future__ import annotations

import cv2
import numpy as np

from fabline.nest.raster import Canvas


def largest_empty_rectangle(free: np.ndarray) -> tuple[int, int, int, int]:
    """Largest all-True axis-aligned rectangle of a boolean grid as (row, col, rows, cols); area 0 if none.

    The classic histogram method: per row, the heights of free runs above it and a monotone stack.
    """
    best = (0, 0, 0, 0)
    best_area = 0
    heights = np.zeros(free.shape[1] + 1, dtype=int)
    for row in range(free.shape[0]):
        heights[:-1] = np.where(free[row], heights[:-1] + 1, 0)
        stack: list[int] = []
        for col, height in enumerate(heights):
            while stack and heights[stack[-1]] >= height:
                top = stack.pop()
                left = stack[-1] + 1 if stack else 0
                area = heights[top] * (col - left)
                if area > best_area:
                    best_area = area
                    best = (row - heights[top] + 1, left, int(heights[top]), col - left)
            stack.append(col)
    return best


def _may_hold(free: np.ndarray, cols: float, rows: float) -> bool:
    """Whether a free rectangle of about `cols` x `rows` cells (either way round) may exist: a cheap erosion test."""
    for w, h in ((cols, rows), (rows, cols)):
        kernel = np.ones((max(1, int(h)), max(1, int(w))), dtype=np.uint8)
        if kernel.shape[0] <= free.shape[0] and kernel.shape[1] <= free.shape[1] and \
                cv2.erode(free.astype(np.uint8), kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0).any():
            return True
    return False


def leftover_rectangles(canvas: Canvas, width: float, height: float, min_width: float, min_height: float,
                        limit: int = 4) -> list[tuple[float, float, float, float]]:
    """Disjoint free rectangles (x, y, w, h in sheet mm) at least `min_width` x `min_height` (either way round).

    Rectangles that reach the usable area's border are extended to the sheet's edge, since the margin
    is sheet material too.
    """
    free = ~canvas.occupied
    found = []
    # A rectangle at the border grows by the margin on both sides, so the test asks for that much less.
    slack = 2 * canvas.x0 / canvas.res + 1
    while len(found) < limit and _may_hold(free, min_width / canvas.res - slack, min_height / canvas.res - slack):
        row, col, rows, cols = largest_empty_rectangle(free)
        if rows == 0:
            break
        free[row:row + rows, col:col + cols] = False
        x0, y0 = canvas.x0 + col * canvas.res, canvas.y0 + row * canvas.res
        x1, y1 = x0 + cols * canvas.res, y0 + rows * canvas.res
        x0 = 0.0 if col == 0 else x0
        y0 = 0.0 if row == 0 else y0
        x1 = width if col + cols == canvas.cols else x1
        y1 = height if row + rows == canvas.rows else y1
        w, h = x1 - x0, y1 - y0
        if not (min(w, h) >= min(min_width, min_height) and max(w, h) >= max(min_width, min_height)):
            break
        found.append((x0, y0, w, h))
    return found
