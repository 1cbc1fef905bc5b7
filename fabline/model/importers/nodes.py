"""Nodes an import names and kinds it gives: named node points (as `fabline.model.writers` writes them), lamella
ends as `edge-end`, and supports from `--supports` (a z level, a plan polygon, or the name of CAD points)."""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry import Polygon
from scipy.spatial import cKDTree

from fabline.errors import FablineError
from fabline.model.importers.curves import CurveSource
from fabline.model.network import NODE_KINDS, Node

NODES_LAYER = "NODES"
"""The OBJ group or DXF layer whose named points are nodes ("<id> <kind>" object name, or id and kind in XDATA)."""
Z_LEVEL = re.compile(r"^\s*z\s*(<=?)\s*([-+0-9.eE]+)\s*$")


@dataclass
class NamedNode:
    """A node the file names: its id, its kind if the file gives one, and where it is."""

    id: str
    kind: str | None
    xyz: np.ndarray
    where: str


def named_nodes(source: CurveSource) -> list[NamedNode]:
    """The point objects of the NODES group/layer: id from the object name or XDATA, then an optional kind."""
    nodes = []
    for point in source.points:
        if not point.names or point.names[0] != NODES_LAYER:
            continue
        words = " ".join(point.names[1:]).split()
        if not words:
            raise FablineError(f"{source.path}: {point.where}: a point on {NODES_LAYER} needs a node id as its name")
        kind = words[1] if len(words) > 1 else None
        if kind is not None and kind not in NODE_KINDS:
            raise FablineError(f"{source.path}: {point.where}: node {words[0]}: unknown kind {kind!r} "
                               f"(use one of {', '.join(NODE_KINDS)})")
        nodes.append(NamedNode(words[0], kind, point.xyz, point.where))
    seen: dict[str, str] = {}
    for node in nodes:
        if node.id in seen:
            raise FablineError(f"{source.path}: node id {node.id} named twice ({seen[node.id]} and {node.where})")
        seen[node.id] = node.where
    return nodes


def match_points(points: np.ndarray, targets: np.ndarray, tolerance: float) -> np.ndarray:
    """For each point, the index of the nearest target within `tolerance`, else -1."""
    if not len(points) or not len(targets):
        return np.full(len(points), -1, dtype=int)
    distance, index = cKDTree(targets).query(points)
    return np.where(distance <= tolerance, index, -1)


@dataclass
class SupportRule:
    """Which nodes stand on the ground: below a z level, inside a plan polygon, or at the file's points of a name."""

    text: str
    z_max: float | None = None
    inclusive: bool = False
    polygon: np.ndarray | None = None
    name: str | None = None

    @classmethod
    def parse(cls, text: str) -> "SupportRule":
        """'z<0.05' (model units), 'x,y x,y x,y ...' (a plan polygon, model units) or a layer/group/object name."""
        level = Z_LEVEL.match(text)
        if level:
            try:
                return cls(text, z_max=float(level.group(2)), inclusive=level.group(1) == "<=")
            except ValueError:
                pass
        if "," in text:
            try:
                corners = np.array([[float(v) for v in pair.split(",")] for pair in text.split()], dtype=float)
            except ValueError:
                raise FablineError(f"--supports {text!r}: a polygon is 'x,y x,y x,y ...' in model units") from None
            if corners.ndim != 2 or corners.shape[1] != 2 or len(corners) < 3 or not np.isfinite(corners).all():
                raise FablineError(f"--supports {text!r}: a polygon needs at least three x,y corners")
            return cls(text, polygon=corners)
        if not text.strip():
            raise FablineError("--supports: give 'z<LEVEL', a polygon 'x,y x,y x,y ...' or a layer/group name")
        return cls(text, name=text.strip())

    def select(self, nodes: dict[str, Node], source: CurveSource, tolerance: float) -> list[str]:
        """The ids of the nodes the rule picks; picking none is an error naming the rule."""
        ids = list(nodes)
        xyz = np.array([nodes[n].xyz for n in ids], dtype=float).reshape(-1, 3)
        if self.z_max is not None:
            picked = xyz[:, 2] <= self.z_max if self.inclusive else xyz[:, 2] < self.z_max
            what = f"below z {self.text.split('<')[-1].lstrip('=').strip()}"
        elif self.polygon is not None:
            picked = shapely.contains_xy(Polygon(self.polygon), xyz[:, 0], xyz[:, 1])
            what = "inside the polygon"
        else:
            marks = [p.xyz for p in source.points if self.name in p.names or self.name in " ".join(p.names[1:]).split()]
            if not marks:
                names = sorted({p.names[0] for p in source.points if p.names})
                raise FablineError(f"--supports {self.name!r}: {source.path} has no point objects of that layer, group "
                                   f"or name (point layers/groups: {', '.join(names) or 'none'})")
            near = cKDTree(xyz).query(np.array(marks))
            picked = np.zeros(len(ids), dtype=bool)
            picked[near[1][near[0] <= tolerance]] = True
            what = f"within the tolerance of a point named {self.name}"
        chosen = [n for n, flag in zip(ids, picked.tolist()) if flag]
        if not chosen:
            raise FablineError(f"--supports {self.text!r}: no node of {source.path} lies {what}")
        return chosen
