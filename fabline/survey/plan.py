"""A photo plan: camera stations from which every node's tag is seen in enough photos at a useful angle and size.

Candidate stations stand at one height above the ground (the lowest node): on rings around the shell's plan and on
a grid over or under it where the station clears the shell. Each candidate position looks at aim points spread
over the tags (farthest-point sampling). A tag counts as seen from a station when its face turns to the camera
within `max_angle_deg`, its black square is at least `min_side_px` on its foreshortened side, its centre is in the
frame with the whole tag inside, and the ray from it to the camera crosses no triangle of the shell's surface (the
nodes triangulated in plan, a conservative stand-in for the lamellas) and no other tag (a disc round its corners,
OCCLUSION_MARGIN_MM wider). A greedy set cover then picks stations
until every tag that any candidates can see from `views` different positions is seen from that many (two photos
from one position give no baseline, so they count once). Greedy set cover is within a factor ln(n) of the
fewest stations, not optimal.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.spatial import Delaunay
from shapely import MultiPoint, Point, Polygon, unary_union

from fabline.errors import FablineError
from fabline.fileio import atomic_output, read_json, write_json
from fabline.model import Network
from fabline.survey.camera import Camera, camera_from_dict, camera_to_dict
from fabline.survey.simulate import look_at, tag_centres
from fabline.survey.tagmap import TAG_CELLS, TagMap

PLAN_SCHEMA = "fabline.survey-plan/1"
AIM_POINTS = 16
"""Aim points each candidate position may look at: farthest-point samples of the tag centres."""
CLEARANCE_MM = 1000.0
"""A station over (under) the shell stands at least this far above (below) its surface."""
RAY_CHUNK = 256
OCCLUSION_MARGIN_MM = 40.0
"""Added to a tag's radius as an occluder: the built shell stands up to a tolerance or two off the design."""
"""Rays tested against every triangle at once (bounds the ray test's memory)."""


@dataclass
class PlanOptions:
    """Station height above the ground (the lowest node), the useful view limits, views a tag needs, candidate spacing."""

    height_mm: float = 1600.0
    max_angle_deg: float = 60.0
    min_side_px: float = 16.0
    views: int = 2
    spacing_mm: float = 1500.0


@dataclass
class Station:
    """One camera station: where it stands, the point it looks at, its world-to-camera pose and the tags it sees."""

    position_mm: np.ndarray
    aim_mm: np.ndarray
    rotation: np.ndarray
    where: str
    nodes: list[str] = field(default_factory=list)

    @property
    def direction(self) -> np.ndarray:
        """The unit view direction (the camera's optical axis) in design coordinates."""
        return self.rotation[2]


@dataclass
class Plan:
    """The chosen stations (numbered from 1 in walking order), the nodes each tagged node is seen from, and the
    tagged nodes no candidate set could show in `views` photos from different positions."""

    stations: list[Station]
    camera: Camera
    options: PlanOptions
    ground_z_mm: float
    seen_by: dict[str, list[int]]
    short: dict[str, int]
    candidates: int


def shell_surface(points_mm: np.ndarray) -> tuple[np.ndarray, Polygon]:
    """The shell's surface as triangles (M, 3) of node indices (plan Delaunay, triangles with an edge longer than
    2.5 times the median node spacing dropped: those bridge the boundary's notches) and its plan outline."""
    triangulation = Delaunay(points_mm[:, :2])
    simplices = triangulation.simplices
    edges = np.linalg.norm(points_mm[simplices] - points_mm[np.roll(simplices, 1, axis=1)], axis=2)
    spacing = np.median(edges.min(axis=1))
    keep = simplices[edges.max(axis=1) <= 2.5 * spacing]
    outline = unary_union([Polygon(points_mm[t, :2]) for t in keep]).buffer(0)
    if not isinstance(outline, Polygon):
        outline = MultiPoint(points_mm[:, :2]).convex_hull
    return keep, outline


def blocked(origins: np.ndarray, targets: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Whether each segment origin -> target (N, 3) crosses any triangle (M, 3, 3) strictly between its ends
    (Moller-Trumbore, vectorised in chunks of RAY_CHUNK rays)."""
    out = np.zeros(len(origins), dtype=bool)
    a = triangles[:, 0]
    e1, e2 = triangles[:, 1] - a, triangles[:, 2] - a
    for start in range(0, len(origins), RAY_CHUNK):
        o, d = origins[start:start + RAY_CHUNK], targets[start:start + RAY_CHUNK] - origins[start:start + RAY_CHUNK]
        p = np.cross(d[:, None, :], e2[None])
        det = np.einsum("mk,nmk->nm", e1, p)
        ok = np.abs(det) > 1e-9
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        s = o[:, None, :] - a[None]
        u = np.einsum("nmk,nmk->nm", s, p) * inv
        q = np.cross(s, e1[None])
        v = np.einsum("nk,nmk->nm", d, q) * inv
        t = np.einsum("mk,nmk->nm", e2, q) * inv
        hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-6) & (t < 1 - 1e-6)
        out[start:start + RAY_CHUNK] = hit.any(axis=1)
    return out


def blocked_by_discs(origins: np.ndarray, targets: np.ndarray, own: np.ndarray, centres: np.ndarray,
                     normals: np.ndarray, radius: float) -> np.ndarray:
    """Whether each segment origin -> target (N, 3) crosses a disc (centre, unit normal, `radius`) other than its
    own (`own` (N,): the index of the disc it starts from), strictly between its ends: the tags as occluders, as
    discs round their quiet zone's corners since a tag's turn about its normal is not known before it is mounted."""
    out = np.zeros(len(origins), dtype=bool)
    for start in range(0, len(origins), RAY_CHUNK):
        o, d = origins[start:start + RAY_CHUNK], targets[start:start + RAY_CHUNK] - origins[start:start + RAY_CHUNK]
        across = d @ normals.T
        ok = np.abs(across) > 1e-12
        t = np.einsum("mk,nmk->nm", normals, centres[None] - o[:, None, :]) / np.where(ok, across, 1.0)
        hit = o[:, None, :] + t[:, :, None] * d[:, None, :]
        near = np.linalg.norm(hit - centres[None], axis=2) <= radius
        crossing = ok & (t > 1e-6) & (t < 1 - 1e-6) & near
        crossing[np.arange(len(o)), own[start:start + RAY_CHUNK]] = False
        out[start:start + RAY_CHUNK] = crossing.any(axis=1)
    return out


def candidate_positions(points_mm: np.ndarray, triangles: np.ndarray, outline: Polygon, station_z: float,
                        reach_mm: float, spacing_mm: float) -> tuple[np.ndarray, list[str]]:
    """Station positions (K, 3) at height `station_z` and where each stands ("around", "over", "under"): rings at
    1 m, 0.2 and 0.4 of the camera's reach outside the plan outline, and a grid inside it where the station is at
    least CLEARANCE_MM above or below the surface."""
    positions, where = [], []
    for offset in sorted({1000.0, 0.2 * reach_mm, 0.4 * reach_mm}):
        ring = outline.buffer(offset).exterior
        count = max(int(ring.length // spacing_mm), 8)
        for k in range(count):
            point = ring.interpolate(k / count, normalized=True)
            positions.append((point.x, point.y, station_z))
            where.append("around")
    low, high = points_mm[:, :2].min(axis=0), points_mm[:, :2].max(axis=0)
    surface = Delaunay(points_mm[:, :2])
    kept = {tuple(sorted(t)) for t in triangles.tolist()}
    for x in np.arange(low[0] + spacing_mm / 2, high[0], spacing_mm):
        for y in np.arange(low[1] + spacing_mm / 2, high[1], spacing_mm):
            if not outline.contains(Point(x, y)):
                continue
            simplex = int(surface.find_simplex([x, y]))
            if simplex < 0 or tuple(sorted(surface.simplices[simplex])) not in kept:
                continue
            b = surface.transform[simplex, :2] @ (np.array([x, y]) - surface.transform[simplex, 2])
            z = float(np.dot(np.append(b, 1 - b.sum()), points_mm[surface.simplices[simplex], 2]))
            if station_z >= z + CLEARANCE_MM or station_z <= z - CLEARANCE_MM:
                positions.append((x, y, station_z))
                where.append("over" if station_z > z else "under")
    return np.array(positions, dtype=float), where


def _aim_points(centres: np.ndarray, count: int) -> np.ndarray:
    """`count` tag centres spread over the shell (farthest-point sampling from the one nearest the middle)."""
    chosen = [int(np.argmin(np.linalg.norm(centres - centres.mean(axis=0), axis=1)))]
    gap = np.linalg.norm(centres - centres[chosen[0]], axis=1)
    while len(chosen) < min(count, len(centres)):
        chosen.append(int(np.argmax(gap)))
        gap = np.minimum(gap, np.linalg.norm(centres - centres[chosen[-1]], axis=1))
    return centres[chosen]


def plan_survey(network: Network, tag_map: TagMap, camera: Camera, options: PlanOptions | None = None) -> Plan:
    """Choose camera stations so that every tagged node is seen from `options.views` different positions."""
    options = options or PlanOptions()
    if options.views < 1 or not 0 < options.max_angle_deg < 90 or not options.min_side_px > 0:
        raise FablineError("plan: views at least 1, a view angle limit between 0 and 90 degrees and a minimum tag "
                           "side of more than 0 px are needed")
    model = network.in_mm()
    ids, design, _ = model.node_array()
    nodes, centres, normals = tag_centres(model, tag_map)
    triangles, outline = shell_surface(design)
    ground = float(design[:, 2].min())
    focal = camera.focal_px
    reach = focal * tag_map.tag_size_mm / options.min_side_px
    positions, where = candidate_positions(design, triangles, outline, ground + options.height_mm, reach,
                                           options.spacing_mm)
    # per position: which tags turn to it within the angle, are large enough and are not hidden by the shell
    to_camera = positions[:, None, :] - centres[None]
    depth = np.linalg.norm(to_camera, axis=2)
    facing = np.einsum("pnk,nk->pn", to_camera, normals) / depth
    side = focal * tag_map.tag_size_mm * facing / depth
    usable = (facing >= np.cos(np.radians(options.max_angle_deg))) & (side >= options.min_side_px)
    pairs = np.argwhere(usable)
    lifted = centres + 5.0 * normals  # off the tag's own face
    hidden = blocked(lifted[pairs[:, 1]], positions[pairs[:, 0]], design[triangles])
    outer_radius = tag_map.tag_size_mm * 10 / TAG_CELLS / np.sqrt(2) + OCCLUSION_MARGIN_MM  # the quiet zone's corners
    rest = np.flatnonzero(~hidden)
    hidden[rest] = blocked_by_discs(lifted[pairs[rest, 1]], positions[pairs[rest, 0]], pairs[rest, 1], centres, normals,
                                    outer_radius)
    usable[pairs[hidden, 0], pairs[hidden, 1]] = False
    aims = _aim_points(centres, AIM_POINTS)
    stations, sees, position_of = [], [], []
    for p, position in enumerate(positions):
        if not usable[p].any():
            continue
        for aim in aims:
            if np.linalg.norm(aim[:2] - position[:2]) < 1.0 and abs(aim[2] - position[2]) < 1.0:
                continue
            rotation = look_at(position, aim, 0.0)
            cam = (centres - position) @ rotation.T
            front = cam[:, 2] > 0
            uv = np.full((len(centres), 2), -1e9)
            uv[front] = cam[front, :2] / cam[front, 2:3] * [camera.matrix[0, 0], camera.matrix[1, 1]] + camera.matrix[:2, 2]
            margin = 0.75 * side[p] + 2
            inside = front & np.all(uv >= margin[:, None], axis=1) & (uv[:, 0] <= camera.width - 1 - margin) \
                & (uv[:, 1] <= camera.height - 1 - margin)
            seen = usable[p] & inside
            if seen.any():
                stations.append(Station(position, aim, rotation, where[p]))
                sees.append(seen)
                position_of.append(p)
    if not stations:
        raise FablineError(f"plan: no station at {options.height_mm / 1000:g} m sees any tag (the camera's reach for "
                           f"{options.min_side_px:g} px tags is {reach / 1000:.1f} m); try another --height or camera")
    sees, position_of = np.array(sees), np.array(position_of)
    seen_from = np.zeros((len(positions), len(nodes)), dtype=bool)
    for k, p in enumerate(position_of):
        seen_from[p] |= sees[k]
    possible = np.minimum(seen_from.sum(axis=0), options.views)
    need = possible.copy()
    covered = np.zeros_like(seen_from)
    chosen = []
    while need.any():
        gain = (sees & (need > 0)[None] & ~covered[position_of]).sum(axis=1)
        best = int(np.argmax(gain))
        if gain[best] == 0:
            break
        chosen.append(best)
        fresh = sees[best] & ~covered[position_of[best]]
        covered[position_of[best]] |= sees[best]
        need = np.maximum(need - fresh, 0)
    centre_xy = design[:, :2].mean(axis=0)
    order = sorted(chosen, key=lambda k: (stations[k].where != "around",
                                          np.arctan2(*(stations[k].position_mm[:2] - centre_xy)[::-1])))
    picked = []
    for k in order:
        stations[k].nodes = [nodes[i] for i in np.flatnonzero(sees[k])]
        picked.append(stations[k])
    seen_by = {nid: [] for nid in nodes}
    for number, station in enumerate(picked, 1):
        for nid in station.nodes:
            seen_by[nid].append(number)
    short = {nodes[i]: int(possible[i]) for i in np.flatnonzero(possible < options.views)}
    return Plan(picked, camera, options, ground, seen_by, short, len(stations))


def _heading(direction: np.ndarray) -> tuple[float, float]:
    """Azimuth (degrees from +x, counter-clockwise) and tilt (degrees below the horizon) of a view direction."""
    return (float(np.degrees(np.arctan2(direction[1], direction[0])) % 360),
            float(np.degrees(np.arcsin(np.clip(-direction[2], -1, 1)))))


def plan_to_dict(plan: Plan, model_name: str) -> dict:
    """The JSON form of a plan (`fabline.survey-plan/1`): stations with their pose, as the simulator takes them."""
    stations = []
    for number, station in enumerate(plan.stations, 1):
        rvec, _ = cv2.Rodrigues(station.rotation)
        azimuth, tilt = _heading(station.direction)
        stations.append({"station": number, "where": station.where,
                         "position_mm": np.round(station.position_mm, 1).tolist(),
                         "aim_mm": np.round(station.aim_mm, 1).tolist(),
                         "direction": np.round(station.direction, 6).tolist(),
                         "azimuth_deg": round(azimuth, 1), "tilt_deg": round(tilt, 1),
                         "rotation": np.round(rvec.ravel(), 9).tolist(),
                         "translation_mm": np.round(-station.rotation @ station.position_mm, 4).tolist(),
                         "nodes": station.nodes})
    o = plan.options
    return {"schema": PLAN_SCHEMA, "model": model_name, "units": "mm", "camera": camera_to_dict(plan.camera),
            "height_mm": o.height_mm, "ground_z_mm": round(plan.ground_z_mm, 3), "max_angle_deg": o.max_angle_deg,
            "min_side_px": o.min_side_px, "views": o.views, "candidates": plan.candidates,
            "stations": stations, "seen_by": plan.seen_by, "short": plan.short}


def save_plan(plan: Plan, model_name: str, path: str | os.PathLike) -> dict:
    """Write the plan as JSON (atomically); return what was written."""
    data = plan_to_dict(plan, model_name)
    write_json(path, data)
    return data


def load_plan_poses(path: str | os.PathLike) -> tuple[Camera, list[tuple[np.ndarray, np.ndarray]]]:
    """A plan file's camera and its stations' world-to-camera poses (rotation matrix, translation mm), in order."""
    data = read_json(path)
    if not isinstance(data, dict) or data.get("schema") != PLAN_SCHEMA:
        raise FablineError(f"{path}: not a {PLAN_SCHEMA} file (missing or wrong 'schema')")
    camera = camera_from_dict(data.get("camera"), f"{path}: camera")
    poses = []
    try:
        for station in data["stations"]:
            rotation, _ = cv2.Rodrigues(np.array(station["rotation"], dtype=float).reshape(3, 1))
            poses.append((rotation, np.array(station["translation_mm"], dtype=float).reshape(3)))
    except (KeyError, TypeError, ValueError, cv2.error):
        raise FablineError(f"{path}: a station without a valid 'rotation' (3 numbers) and 'translation_mm' (3 numbers)") from None
    if len(poses) < 2:
        raise FablineError(f"{path}: a plan of {len(poses)} station(s); a survey needs at least 2 photos")
    return camera, poses


def unseen_with_stations(plan: Plan, survey: dict) -> list[tuple[str, str, list[int]]]:
    """After a survey: each node it did not measure, why, and the plan's stations that see its tag."""
    return [(nid, why, plan.seen_by.get(nid, [])) for nid, why in survey.get("not_seen", {}).items()]


def write_plan_svg(network: Network, plan: Plan, path: str | os.PathLike, width_px: int = 900) -> None:
    """The shell from above (lamellas grey, tagged nodes seen by fewer than `views` stations red) with the stations
    numbered and an arrow along each one's view direction."""
    model = network.in_mm()
    _, design, _ = model.node_array()
    xy = np.vstack([design[:, :2]] + [s.position_mm[None, :2] for s in plan.stations])
    low, high = xy.min(axis=0) - 800, xy.max(axis=0) + 800
    scale = width_px / max(high[0] - low[0], 1e-9)
    height_px = int(np.ceil((high[1] - low[1]) * scale)) + 40

    def at(point) -> str:
        return f"{(point[0] - low[0]) * scale:.1f},{(high[1] - point[1]) * scale + 40:.1f}"

    parts = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{width_px}" height="{height_px}" '
             f'viewBox="0 0 {width_px} {height_px}" font-family="sans-serif">',
             '<rect width="100%" height="100%" fill="white"/>',
             f'<text x="10" y="22" font-size="15">{model.name}: {len(plan.stations)} stations at '
             f'{plan.options.height_mm / 1000:g} m, every tag in {plan.options.views} photos from different stations'
             f'{f" but {len(plan.short)} (red)" if plan.short else ""}</text>']
    for lamella in model.lamellas:
        parts.append(f'<polyline fill="none" stroke="#bbb" stroke-width="1.5" points="{" ".join(at(p) for p in lamella.curve)}"/>')
    short = set(plan.short)
    for nid, node in model.nodes.items():
        colour = "#d00" if nid in short else "#555"
        parts.append(f'<circle cx="{at(node.xyz).split(",")[0]}" cy="{at(node.xyz).split(",")[1]}" r="{3 if nid in short else 1.5}" fill="{colour}"/>')
    arrow = 1200.0
    for number, station in enumerate(plan.stations, 1):
        horizontal = station.direction[:2] / max(np.linalg.norm(station.direction[:2]), 1e-9)
        tip = station.position_mm[:2] + arrow * horizontal * np.linalg.norm(station.direction[:2])
        x, y = at(station.position_mm).split(",")
        parts.append(f'<line x1="{x}" y1="{y}" x2="{at(tip).split(",")[0]}" y2="{at(tip).split(",")[1]}" '
                     'stroke="#06c" stroke-width="2"/>')
        parts.append(f'<circle cx="{x}" cy="{y}" r="9" fill="{"#06c" if station.where == "around" else "#0a6"}"/>')
        parts.append(f'<text x="{x}" y="{float(y) + 4:.1f}" font-size="10" fill="white" text-anchor="middle">{number}</text>')
    parts.append("</svg>")
    with atomic_output(path, "w") as handle:
        handle.write("\n".join(parts) + "\n")
