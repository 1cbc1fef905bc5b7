"""Read lamella curves from Wavefront OBJ: `l` polylines named by `g`/`o` groups, faces as the surface.

OBJ declares no units. A curve's family and id come from its group name, else its object name
(`g A-017`, `o B-003`, or a group `A` holding many lines); consecutive `l` elements that continue one
another (the last vertex of one is the first of the next) form one curve.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fabline.errors import FablineError
from fabline.fileio import read_text
from fabline.model.importers.curves import CurveSource, NamedPoint, assign_ids, clean_points, family_and_id
from fabline.model.importers.surface import mesh_from_arrays

UNSUPPORTED = {"curv", "curv2", "surf", "cstype", "bmat", "step"}


def read_obj(path: str | Path) -> CurveSource:
    """The curves of an OBJ file, and its faces as a surface mesh when it has any."""
    path = str(path)
    lines = _read_lines(path)
    vertex_rows: list[str] = []
    vertex_lines: list[int] = []
    faces: list[list[int]] = []
    chains: list[tuple[list[str], list[int], int]] = []  # names, vertex indices, line number
    point_refs: list[tuple[list[str], int, int]] = []  # names, vertex index, line number of `p` elements
    group = obj = ""
    for number, line in lines:
        if line.startswith("v "):  # the bulk of a file: converted together at the end
            vertex_rows.append(line)
            vertex_lines.append(number)
            continue
        parts = line.split()
        keyword = parts[0]
        if keyword == "v":
            vertex_rows.append(line)
            vertex_lines.append(number)
        elif keyword == "l":
            indices = _indices(parts[1:], len(vertex_rows), path, number)
            if len(indices) < 2:
                raise FablineError(f"{path}:{number}: a line element needs at least two vertices")
            names = [group, obj]
            if chains and chains[-1][0] == names and chains[-1][1][-1] == indices[0]:
                chains[-1][1].extend(indices[1:])
            else:
                chains.append((names, indices, number))
        elif keyword == "f":
            indices = _indices(parts[1:], len(vertex_rows), path, number)
            if len(indices) < 3:
                raise FablineError(f"{path}:{number}: a face needs at least three vertices")
            faces.extend([indices[0], indices[i], indices[i + 1]] for i in range(1, len(indices) - 1))
        elif keyword == "p":
            point_refs += [([group, obj], k, number) for k in _indices(parts[1:], len(vertex_rows), path, number)]
        elif keyword == "g":
            group = " ".join(parts[1:])
        elif keyword == "o":
            obj = " ".join(parts[1:])
        elif keyword in UNSUPPORTED:
            raise FablineError(f"{path}:{number}: free-form curves and surfaces ({keyword}) are not supported; "
                               "export the curves as polylines")
    points = _vertices(vertex_rows, vertex_lines, path)
    found, unnamed = [], []
    for names, indices, number in chains:
        family, lamella_id = family_and_id(names)
        where = f"line {number}" + (f" ({lamella_id})" if lamella_id else "")
        if family is None:
            unnamed.append(str(number))
            continue
        found.append((family, lamella_id, clean_points(points[indices], path, where), where))
    source = CurveSource(path, assign_ids(found, path), None,
                         points=[NamedPoint(names, points[k], f"line {number}") for names, k, number in point_refs])
    if unnamed:
        source.notes.append(f"{path}: ignored {len(unnamed)} polyline(s) in groups that name no family "
                            f"(lines {', '.join(unnamed[:5])}{', ...' if len(unnamed) > 5 else ''})")
    if faces:
        source.mesh = mesh_from_arrays(points, faces, path)
    return source


def _read_lines(path: str) -> list[tuple[int, str]]:
    """Non-empty, non-comment lines with their numbers, backslash continuations joined."""
    text = read_text(path, " as OBJ text", kind="model")
    result: list[tuple[int, str]] = []
    pending, start = "", 0
    for number, line in enumerate(text.splitlines(), 1):
        if "#" in line:
            line = line.split("#", 1)[0]
        if "\\" in line and line.rstrip().endswith("\\"):
            pending, start = pending + line.rstrip()[:-1] + " ", start or number
            continue
        if pending:
            line, number = pending + line, start
            pending, start = "", 0
        if line and not line.isspace():
            result.append((number, line))
    return result


def _vertices(rows: list[str], numbers: list[int], path: str) -> np.ndarray:
    """The `v` lines as an (n, 3) array, converted in one go; a malformed vertex is named by its line.

    Extra values after x, y, z (a weight, a colour) are ignored.
    """
    tokens = " ".join(rows).split()
    if len(tokens) == 4 * len(rows):  # the common case: exactly "v x y z" on every line
        try:
            return np.array(tokens, dtype=object).reshape(-1, 4)[:, 1:].astype(float)
        except ValueError:
            pass
    coordinates = []
    for row, number in zip(rows, numbers):
        parts = row.split()[1:4]
        try:
            if len(parts) < 3:
                raise ValueError
            coordinates.append([float(x) for x in parts])
        except ValueError:
            raise FablineError(f"{path}:{number}: malformed vertex {row.strip()!r} (needs x, y and z)") from None
    return np.array(coordinates, dtype=float).reshape(-1, 3)


def _indices(tokens: list[str], count: int, path: str, number: int) -> list[int]:
    """Zero-based vertex indices from OBJ references ("7", "7/2", "-1"), checked against the vertices so far."""
    try:
        given = np.array([token.split("/", 1)[0] for token in tokens] if "/" in "".join(tokens) else tokens,
                         dtype=np.int64)
    except ValueError:
        bad = next(t for t in tokens if not t.split("/", 1)[0].lstrip("+-").isdigit())
        raise FablineError(f"{path}:{number}: malformed vertex reference {bad!r}") from None
    resolved = np.where(given > 0, given - 1, count + given)
    wrong = np.flatnonzero((given == 0) | (resolved < 0) | (resolved >= count))
    if wrong.size:
        raise FablineError(f"{path}:{number}: vertex {given[wrong[0]]} does not exist ({count} defined so far)")
    return resolved.tolist()
