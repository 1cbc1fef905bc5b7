"""Curves a designer gives the surface designs: boundary curves (`design minimal`) and seed curves (`design asymptotic`).

DXF (polylines, circles, ellipses, splines, arcs, lines; flattened within 0.01 mm at metre scale,
`$INSUNITS`) or JSON `{"units": "m", "curves": [[[x, y, z], ...], ...]}`.
"""

from __future__ import annotations

import json
from pathlib import Path

import ezdxf
import numpy as np

from fabline.errors import FablineError
from fabline.fileio import read_text
from fabline.model.importers.curves import check_flattening
from fabline.model.network import UNIT_TO_MM

DXF_CURVES = ("LWPOLYLINE", "POLYLINE", "CIRCLE", "ELLIPSE", "SPLINE", "ARC", "LINE")
FLATTENING = 1e-5  # model units: 0.01 mm at metre scale


def read_curves(path: str | Path, units: str | None = None) -> tuple[list[tuple[np.ndarray, str]], str]:
    """Every curve in the file as (points, where: the file and the curve, for messages), and the units."""
    path = str(path)
    suffix = Path(path).suffix.lower()
    curves = []
    if suffix == ".json":
        try:
            data = json.loads(read_text(path))
        except json.JSONDecodeError as exc:
            raise FablineError(f"{path}: not valid JSON (line {exc.lineno}, column {exc.colno}): {exc.msg}") from None
        if not isinstance(data, dict) or not isinstance(data.get("curves"), list):
            raise FablineError(f'{path}: expected {{"units": ..., "curves": [[[x, y, z], ...], ...]}}')
        declared = data.get("units")
        for k, raw in enumerate(data["curves"]):
            try:
                points = np.asarray(raw, dtype=float)
            except (TypeError, ValueError):
                raise FablineError(f"{path}: curve {k}: points must be [x, y, z] numbers") from None
            if points.ndim != 2 or points.shape[1] != 3 or len(points) < 2 or not np.isfinite(points).all():
                raise FablineError(f"{path}: curve {k}: needs at least 2 finite [x, y, z] points")
            curves.append((points, f"{path}: curve {k}"))
    elif suffix == ".dxf":
        from fabline.model.importers.dxf import _declared_units, _read_document

        doc = _read_document(path)
        declared = _declared_units(doc, path)
        for entity in doc.modelspace():
            if entity.dxftype() not in DXF_CURVES:
                continue
            check_flattening(entity, FLATTENING, path, f"{entity.dxftype()} #{entity.dxf.handle}")
            points = np.array([tuple(v) for v in ezdxf.path.make_path(entity).flattening(FLATTENING)], dtype=float)
            if entity.dxftype() in ("LWPOLYLINE", "POLYLINE") and entity.is_closed and len(points) > 2 \
                    and np.linalg.norm(points[0] - points[-1]) > 0:
                points = np.vstack([points, points[:1]])
            curves.append((points, f"{path}: {entity.dxftype()} #{entity.dxf.handle}"))
    else:
        raise FablineError(f"{path}: unknown curve file type {suffix or '(none)'} (use .dxf or .json)")
    if not curves:
        raise FablineError(f"{path}: no curves found")
    return curves, declared_or_given(path, declared, units)


def declared_or_given(path: str | Path, declared: str | None, given: str | None) -> str:
    """The units a file declares, else the ones given, else m; refused when the two disagree or are unknown."""
    if given is not None and declared is not None and given != declared:
        raise FablineError(f"{path}: the file is in {declared}, --units says {given}")
    units = given or declared or "m"
    if units not in UNIT_TO_MM:
        raise FablineError(f"{path}: unknown units {units!r} (use one of {', '.join(UNIT_TO_MM)})")
    return units
