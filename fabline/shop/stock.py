"""The `fabline.stock/1` format: sheet sizes on hand and remnants of earlier jobs, read and written back.

    {"schema": "fabline.stock/1",
     "sheets":   [{"id": "4x2", "width": 4000, "height": 2000, "count": null}],   # null = unlimited
     "remnants": [{"id": "R-017", "width": 1200, "height": 700}]}

A remnant is a rectangle cut off an earlier sheet; it is used like a sheet of its size, once.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Any

from fabline.errors import FablineError
from fabline.fileio import MAX_MM, read_json, write_json

SCHEMA = "fabline.stock/1"


@dataclass
class StockItem:
    """A kind of sheet: its size, how many there are (None = unlimited) and whether it is a remnant."""

    id: str
    width: float
    height: float
    count: int | None = None
    remnant: bool = False

    @property
    def area(self) -> float:
        """Sheet area, mm²."""
        return self.width * self.height


def usable_extent(sheet_side: float, margin: float) -> float:
    """The longest part (mm) a sheet holds along a side: the side less a margin at both ends. The one rule of both
    stages: unroll splits strips to it, and nest places every strip up to it (in rows, so no clearance is added)."""
    return sheet_side - 2.0 * margin


def parse_sheet_size(text: str) -> tuple[float, float]:
    """'4000x2000', '4m x 2m', '4000x2000mm' -> (4000.0, 2000.0) in mm; a malformed or non-positive size is a
    FablineError."""
    from fabline.units import parse_size

    try:
        width, height = parse_size(text, "mm")
    except ValueError as exc:
        raise FablineError(f"--sheet-size {text!r}: {exc}") from None
    if not (0 < width <= MAX_MM and 0 < height <= MAX_MM):
        raise FablineError(f"--sheet-size {text!r}: width and height must be positive, at most {MAX_MM:g} mm")
    return width, height


def stock_from_dict(data: Any, source: str = "stock") -> list[StockItem]:
    """Sheet kinds then remnants from the JSON form; errors name the sheet or remnant at fault."""
    if not isinstance(data, dict) or data.get("schema") != SCHEMA:
        raise FablineError(f"{source}: not a {SCHEMA} file")
    items: list[StockItem] = []
    seen: set[str] = set()
    for section, remnant in (("sheets", False), ("remnants", True)):
        raw_list = data.get(section, [])
        if not isinstance(raw_list, list):
            raise FablineError(f"{source}: '{section}' must be a list")
        for k, raw in enumerate(raw_list):
            where = f"{source}: {section}[{k}]"
            if not isinstance(raw, dict):
                raise FablineError(f"{where}: must be an object with id, width and height")
            sid = raw.get("id", f"{section}-{k + 1}")
            if not isinstance(sid, (str, int)) or isinstance(sid, bool):
                raise FablineError(f"{where}: 'id' must be a string")
            sid = str(sid)
            where = f"{source}: {'remnant' if remnant else 'sheet'} {sid}"
            try:
                width, height = float(raw["width"]), float(raw["height"])
                count = None if raw.get("count") is None else int(raw["count"])
            except (KeyError, TypeError, ValueError, OverflowError):
                raise FablineError(f"{where}: needs numeric 'width' and 'height' (mm)") from None
            if not (0 < width <= MAX_MM and 0 < height <= MAX_MM):  # NaN fails too
                raise FablineError(f"{where}: width and height must be positive, at most {MAX_MM:g} mm, got "
                                   f"{width:g} x {height:g}")
            if count is not None and count < 0:
                raise FablineError(f"{where}: count must not be negative, got {count}")
            if sid in seen:
                raise FablineError(f"{where}: duplicate id")
            seen.add(sid)
            items.append(StockItem(sid, width, height, 1 if remnant else count, remnant))
    if not items:
        raise FablineError(f"{source}: no sheets and no remnants")
    return items


def load_stock(path: str | os.PathLike) -> list[StockItem]:
    """Load and check a `fabline.stock/1` file."""
    return stock_from_dict(read_json(path), str(path))


def stock_after(stock: list[StockItem], used: list[str], new_remnants: list[dict], prefix: str) -> list[StockItem]:
    """The stock left after a job: counts less the sheets used (`used` = stock ids, one per sheet), used
    remnants gone, and the job's leftover rectangles added as remnants named `<prefix>-<remnant id>`."""
    taken = {item_id: used.count(item_id) for item_id in set(used)}
    left = []
    for item in stock:
        if item.remnant and taken.get(item.id):
            continue
        count = item.count if item.count is None or item.remnant else max(0, item.count - taken.get(item.id, 0))
        left.append(StockItem(item.id, item.width, item.height, count, item.remnant))
    left += [StockItem(f"{prefix}-{r['id']}", float(r["width"]), float(r["height"]), 1, True) for r in new_remnants]
    return left


def save_stock(stock: list[StockItem], path: str | os.PathLike) -> None:
    """Write sheet kinds and remnants atomically (the stock after a job)."""
    write_json(path, {
        "schema": SCHEMA,
        "sheets": [{"id": s.id, "width": s.width, "height": s.height, "count": s.count} for s in stock if not s.remnant],
        "remnants": [{"id": r.id, "width": r.width, "height": r.height} for r in stock if r.remnant],
    })
