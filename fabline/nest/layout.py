"""The `fabline.nesting/1` format: which part lies where on which sheet; the interface from nest to export.

A placed contour is the part's contour rotated by `rotation` degrees (counter-clockwise) about the
part's own origin, then translated by (x, y), in sheet millimetres with the origin at a sheet corner.
`parts_file` names the parts.json the placements refer to, relative to the nesting file's folder.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fabline.errors import FablineError
from fabline.fileio import read_json, write_json

SCHEMA = "fabline.nesting/1"


@dataclass
class Placement:
    """One part on a sheet."""

    part: str
    x: float
    y: float
    rotation: float = 0.0


@dataclass
class CommonCut:
    """A straight edge shared by two neighbouring parts (common-line cutting): cut once, in sheet coordinates."""

    parts: tuple[str, str]
    start: tuple[float, float]
    end: tuple[float, float]


@dataclass
class Sheet:
    """One sheet with its placements; `stock` names the stock item it was cut from."""

    id: str
    width: float
    height: float
    placements: list[Placement] = field(default_factory=list)
    stock: str = ""
    common_cuts: list[CommonCut] = field(default_factory=list)


@dataclass
class Nesting:
    """A complete nesting: the sheets, the parts file they refer to, and the settings that produced them."""

    sheets: list[Sheet]
    parts_file: str
    kerf: float = 0.0
    gap: float = 0.0
    margin: float = 0.0
    summary: dict = field(default_factory=dict)
    remnants: list[dict] = field(default_factory=list)


def place(points: np.ndarray, placement: Placement) -> np.ndarray:
    """Part-frame points (N, 2+) -> sheet coordinates (N, 2); extra columns such as bulges are kept."""
    points = np.asarray(points, dtype=float)
    a = np.radians(placement.rotation)
    c, s = np.cos(a), np.sin(a)
    out = points.copy()
    out[:, 0] = c * points[:, 0] - s * points[:, 1] + placement.x
    out[:, 1] = s * points[:, 0] + c * points[:, 1] + placement.y
    return out


def nesting_to_dict(nesting: Nesting) -> dict[str, Any]:
    """The JSON-ready form of a nesting."""
    return {
        "schema": SCHEMA,
        "units": "mm",
        "parts_file": nesting.parts_file,
        "kerf": nesting.kerf,
        "gap": nesting.gap,
        "margin": nesting.margin,
        "summary": nesting.summary,
        "remnants": nesting.remnants,
        "sheets": [
            {
                "id": s.id, "width": s.width, "height": s.height, "stock": s.stock,
                "placements": [{"part": p.part, "x": round(p.x, 4), "y": round(p.y, 4), "rotation": p.rotation}
                               for p in s.placements],
                "common_cuts": [{"parts": list(c.parts), "start": list(c.start), "end": list(c.end)}
                                for c in s.common_cuts],
            }
            for s in nesting.sheets
        ],
    }


def nesting_from_dict(data: Any, source: str = "nesting") -> Nesting:
    """Build a nesting from its JSON form; errors name the sheet or placement at fault."""
    if not isinstance(data, dict) or data.get("schema") != SCHEMA:
        raise FablineError(f"{source}: not a {SCHEMA} file")
    if not isinstance(data.get("parts_file"), str):
        raise FablineError(f"{source}: missing 'parts_file'")
    sheets = []
    for i, raw in enumerate(data.get("sheets") or []):
        where = f"{source}: sheets[{i}]"
        try:
            sheet = Sheet(str(raw["id"]), float(raw["width"]), float(raw["height"]), stock=str(raw.get("stock", "")))
            where = f"{source}: sheet {sheet.id}"
            for k, p in enumerate(raw.get("placements", [])):
                sheet.placements.append(Placement(str(p["part"]), float(p["x"]), float(p["y"]), float(p.get("rotation", 0.0))))
            for c in raw.get("common_cuts", []):
                sheet.common_cuts.append(CommonCut(tuple(map(str, c["parts"])), tuple(map(float, c["start"])),
                                                   tuple(map(float, c["end"]))))
        except (KeyError, TypeError, ValueError) as exc:
            raise FablineError(f"{where}: malformed entry ({exc})") from None
        if sheet.width <= 0 or sheet.height <= 0:
            raise FablineError(f"{where}: width and height must be positive")
        sheets.append(sheet)
    return Nesting(sheets, data["parts_file"], float(data.get("kerf", 0.0)), float(data.get("gap", 0.0)),
                   float(data.get("margin", 0.0)), dict(data.get("summary", {})), list(data.get("remnants", [])))


def load_nesting(path: str | os.PathLike) -> Nesting:
    """Load a `fabline.nesting/1` file."""
    return nesting_from_dict(read_json(path), str(path))


def parts_path(nesting_path: str | os.PathLike, nesting: Nesting) -> Path:
    """Where the parts file of a nesting lies: `parts_file` resolved against the nesting file's folder."""
    return Path(nesting_path).parent / nesting.parts_file


def save_nesting(nesting: Nesting, path: str | os.PathLike) -> None:
    """Write a nesting atomically."""
    write_json(path, nesting_to_dict(nesting))
