"""AprilTag 36h11 detection with sub-pixel corners, usable on its own (`fabline survey detect`).

OpenCV's aruco finds the quads without corner refinement (its AprilTag refinement silently drops tags,
its sub-pixel refinement is about 1 px off on real photos), on an image pyramid: one threshold window per level, the
coarse levels for blurred large tags, full resolution for small, dim or grazing ones; each tag's four edges are then
located to sub-pixel precision along the edge normal (the intensity-gradient peak, on a cubic spline of the image),
a line is fitted per edge and the corners are the line intersections, as in the AprilTag library. Pixel centres lie at
integer coordinates (OpenCV's convention; the AprilTag library's are at +0.5). Corners come in the AprilTag library's
order, p0..p3 at (-s, s), (s, s), (s, -s), (-s, -s) in its tag frame (x right, y down, z into the tag's face, centre at
the middle, s half the black square's edge: `tag_object_points`); on the tag as OpenCV draws it, upright (`tag_image`),
that is top-right, top-left, bottom-left, bottom-right (counter-clockwise in the image). Every tag is reported, several
of one id included (a tag printed twice is a mistake on site that the survey must name).
A tag cut by the photo's edge is reported `partial` when its data cells are all inside and each edge at least
half: the corner outside is extrapolated from the edges' parts inside. A tag with a corner hidden under the quiet zone
of a tag in front of it is found from that tag, its hidden corner likewise extrapolated from the edges' visible parts.
`detect_expected_tags` looks for known tags at predicted corners (the survey's second look).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path

import cv2
import numpy as np
from scipy.ndimage import map_coordinates, spline_filter

from fabline.errors import FablineError
from fabline.fileio import atomic_output
from fabline.survey.photos import check_photo
from fabline.survey.camera import Camera
from fabline.survey.tagmap import TAG_CELLS, TAG_DICTIONARY

# Each edge is sampled at one point per EDGE_SAMPLE_SPACING_PX of its middle 70 %, at least EDGE_SAMPLES, at most
# MAX_EDGE_SAMPLES: a large tag's edge line is fitted on many crossings (the AprilTag library samples every pixel)
EDGE_SAMPLES, MAX_EDGE_SAMPLES, EDGE_SAMPLE_SPACING_PX = 20, 80, 2.0
# of a quad's corners (and edges, corner i to i + 1) in order, the next, opposite and previous one (np.roll's, faster)
NEXT_CORNER, OPPOSITE_CORNER, PREVIOUS_CORNER = [1, 2, 3, 0], [2, 3, 0, 1], [3, 0, 1, 2]
REFINE_PASSES = 2
# Edge profiles reach 0.45 cell, so a quad whose edges are off by more than that (the coarse quad of a small tag, or of
# one the photo's edge cuts) moves part of the way per pass: a tag once read gets up to this many more passes, while
# the last one moved a corner by more than CONVERGED_PX (passes converge fast: after one that moved 0.1-0.4 px the next
# moved 0.003-0.03 px, and corners on the benchmark's photos came out the same to 0.0001 px mean with 0.1 px here)
MAX_EXTRA_PASSES = 2
CONVERGED_PX = 0.25
# aruco drops quads whose thresholded contour reaches the image border; a padding keeps tags near it, and closes the
# black square of a tag cut by the border so its quad is found. It is as light as the photo's edge nearby (its brightest
# pixel in the outermost PAD_LIGHT_ROWS rows, within a padding's width along the edge): a uniform grey came out darker
# than a light quiet zone beside it, thresholded dark there and joined a cut tag's black tip to a dark lamella beside.
BORDER_PAD_PX = 16
PAD_LIGHT_ROWS = 2
# Quads are searched for on an image pyramid, as the AprilTag library's quad_decimate but at every scale: aruco's
# adaptive threshold at one window per search, at full resolution each of SEARCH_WINDOWS_PX, at each coarser level (the
# photo halved, up to MAX_SEARCH_LEVEL times while its shorter side keeps MIN_LEVEL_SIDE_PX: 1056 x 792 photos get the
# twice-halved level, where alone 70 px tags of 25 grey levels from black to white are found, issue 30) each of
# COARSE_WINDOWS_PX in a search of its own (aruco keeps one of the quads its windows find at one place: the quiet
# zone's outline, not the black square's). A 3 px window keeps the thin black border of small tags of about 2 px cells, and of tags seen at
# 60-80 degrees whose cells are a pixel or less across, whole; in the noise of a dim or low-contrast tag (25-40 grey
# levels from black to white) its mean is too noisy and the border breaks up, where a 5 px window's holds, at full
# resolution for tags of 2-4 px cells, on the halved photo for larger ones (issue 30: with coarser levels only for
# photos of 960 px a side, 47 of 241 tags pupil-apriltags finds on camera-like photos of 640 x 480 and 1056 x 792 were
# missed, nearly all low contrast or dim). A window sees a blurred large tag's border no longer (on a linear ramp the
# window's mean is the centre's value), but a level where that blur is a pixel or two does. A small photo where none is
# found gets levels down to OUT_OF_FOCUS_MIN_LEVEL_SIDE_PX (out of focus). Each quad is refined and read at full
# resolution (`_refine_and_read`).
SEARCH_WINDOWS_PX, COARSE_WINDOWS_PX = (3, 5), (5,)
MAX_SEARCH_LEVEL, MIN_LEVEL_SIDE_PX, OUT_OF_FOCUS_MIN_LEVEL_SIDE_PX = 2, 200, 120
# Blurred, small tags' black border falls below aruco's default threshold offset (7 grey levels) and breaks up: at full
# resolution a lower offset keeps it whole (2: small low-contrast and thin-quiet-zone tags of 17-21 px whose border
# broke up at 3, issue 30); at the coarser levels, where halving has taken out half the noise, a slightly higher one
# finds fewer false outlines (at 3 large tags of 25 grey levels from black to white are found, but also a small tag in
# a 4 px blur whose corners come out 1.4-2.7 px off).
FULL_RESOLUTION_THRESHOLD_OFFSET, COARSE_THRESHOLD_OFFSET = 2, 5
# quads found at a coarser level are at least this many of its pixels across (smaller ones are found at the finer)
COARSE_MIN_SIDE_PX = 8.0
COARSE_MIN_CORNER_DISTANCE_RATE = 0.1
# aruco identifies a quad whose black border reads with up to this share of its bits wrong; it compares the data bits
# with one code at a time, 2 ms for each quad that is no tag. Quads it does not identify are read by `_decode` (which
# leaves out plain dark patches at a glance, `_plain_dark`, and identifies at once): a whole border only, at a third of
# the CPU time per search.
ARUCO_BORDER_ERROR_RATE = 0.0
# At full resolution polygons are fitted to the contours more finely than aruco's default (3 % of a contour's length):
# a tag seen past 80 degrees is a sliver whose two obtuse corners lie within 3 % of its contour's length of its long
# diagonal.
SLIVER_POLYGON_ACCURACY = 0.028
# A tag in front can hide a corner of the black square of one behind it under its white quiet zone: that square's
# outline is then a 5-7-gon, cut or notched at the corner, and aruco passes it by. Around each found tag of cells of at
# least OCCLUDER_MIN_CELL_PX, within OCCLUDED_SEARCH_REACH of its longest side, the photo is thresholded at half
# resolution (where the cells of such neighbours are still about 2 px), and outlines whose four longest edges make up
# CUT_POLYGON_MIN_KEPT of them and a convex quad whose missing corners lie under that tag's quiet zone (give or take
# HIDDEN_CORNER_TOLERANCE_CELLS) are read, with the cells under that tag left out (see `_decode`).
OCCLUDER_MIN_CELL_PX = 5.0
OCCLUDED_SEARCH_REACH = 1.2
OCCLUDED_THRESHOLD_WINDOW_PX, OCCLUDED_THRESHOLD_OFFSET = 5, 10
CUT_POLYGON_MIN_KEPT = 0.75
HIDDEN_CORNER_TOLERANCE_CELLS = 0.25
# The AprilTag library's corners (`TagDetection.corners`) from the order detection works in (top-left, top-right,
# bottom-right, bottom-left of the upright tag as OpenCV draws it, clockwise in the image) and back: its own inverse
APRILTAG_ORDER = [1, 0, 3, 2]
# a tag's black square and its quiet zone's outline in the tag's cell coordinates, corners in detection's order
TAG_SQUARE = np.array([[0, 0], [TAG_CELLS, 0], [TAG_CELLS, TAG_CELLS], [0, TAG_CELLS]], dtype=float)
QUIET_ZONE_OUTLINE = np.array([[-1, -1], [TAG_CELLS + 1, -1], [TAG_CELLS + 1, TAG_CELLS + 1], [-1, TAG_CELLS + 1]],
                              dtype=float)
# Aruco's quad of a small tag on a darker background is the outline of its light quiet zone; blurred, with the 3 px
# threshold window, that outline lies two cells outside the black square rather than one (issue 30: four tags of 14-18
# px, dim or plain, that pupil-apriltags finds, read only so). Such a quad is read as either, nearest first.
OUTLINES_AROUND_SQUARE = (QUIET_ZONE_OUTLINE, QUIET_ZONE_OUTLINE + np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]))
DECODE_SHARPENING = 0.25  # of the cells' Laplacian, added to a blurred tag's cells for a second reading (see `_decode`)
# cell centres (TAG_CELLS + 2, TAG_CELLS + 2, 2) of a tag and its quiet zone, in cell coordinates, and which of them
# are the quiet zone's ring and the black border's
CELL_CENTRES = np.stack(np.meshgrid(np.arange(-1, TAG_CELLS + 1) + 0.5, np.arange(-1, TAG_CELLS + 1) + 0.5), axis=-1)
QUIET_ZONE_CELLS = np.pad(np.zeros((TAG_CELLS, TAG_CELLS), dtype=bool), 1, constant_values=True)
BORDER_CELLS = np.pad(np.pad(np.zeros((TAG_CELLS - 2, TAG_CELLS - 2), dtype=bool), 1, constant_values=True), 1)
# grey levels from a tag's black border to its quiet zone, at least (a low-contrast tag of 17 px, 27 grey levels apart
# as printed, is 18 apart on its cells once blurred)
MIN_CONTRAST = 12
PLAIN_DARK_RATE = 0.4
# A tag is reported when its code reads with at most REPORTED_BITS wrong, as the AprilTag library decodes by default
# (pupil-apriltags' and apriltag's hamming limit, 2); a quad that reads only with FLAGGED_BITS corrected (as OpenCV's
# detector does: 60 % of what 36h11's minimum distance allows) is no tag reported but flagged (issue 30: such reads on
# real photos included a sliver seen edge-on). Data bits hidden under a tag in front count as wrong towards
# FLAGGED_BITS, not REPORTED_BITS: the distance left keeps the read unique (36h11's minimum distance is 11).
REPORTED_BITS, FLAGGED_BITS = 2, 3
ARUCO_CORRECTION_RATE = 0.4  # of the dictionary's maxCorrectionBits (5): aruco identifies with 2 bits corrected
# a read tag whose narrowest cell (its depth across an edge over the 8 cells) is under this is flagged, not reported:
# seen edge-on, 4-7 px across, the corners along its thin side mean nothing
MIN_CELL_PX = 1.0
MIN_REACH_PX = 0.75  # edge profiles reach 0.45 cell either side of the edge, at least this far (at most 4 px)
COARSE_REACH_PX = 2.0  # ... and in a first pass on a coarse quad of a small tag
# ... at most MAX_REACH_PX; but a quad of a large tag found on the photo halved twice may be 4-7 px off (issue 30: a
# 68 px tag of 25 grey levels, which only that level finds): where the passes fail on a quad of cells of LARGE_CELL_PX
# or more, they are tried again after a first pass reaching 0.9 cell, up to COARSE_MAX_REACH_PX
MAX_REACH_PX, COARSE_MAX_REACH_PX, LARGE_CELL_PX = 4.0, 8.0, 5.0
MIN_EDGE_INSIDE = 0.5  # a tag cut by the photo's edge: each of its edges at least half inside, to fix its line
# of the black border's 28 cells, all but a cut corner's few inside the photo (the corner cell and a neighbour or two
# along each edge; small tags lose more of them to the photo's edge than large ones, as cells are read on their middle)
MIN_BORDER_CELLS = 24
TRIED_QUAD_MATCH_PX = 1.0  # a quad within this of one read before (centre and shortest side) is not read again
MIN_QUIET_ZONE_CELLS = 18  # of the 36 cells of the quiet-zone ring, at least half inside the photo to read a tag


@dataclass
class TagDetection:
    """One tag seen in one image: its id and four corners (4, 2) in pixels, in the AprilTag library's order (see the
    module's docstring), pixel centres on integers."""

    tag_id: int
    corners: np.ndarray
    partial: bool = False  # a corner lies outside the photo: it is extrapolated from the edges inside, not measured
    quality: str = ""  # why a quad that reads is not reported as a tag ("" for every tag `detect_tags` returns)


def read_gray(path: str | os.PathLike, notes: list[str] | None = None) -> np.ndarray:
    """An image file as 8-bit grayscale; an unreadable, missing or too large file raises naming it (`check_photo`:
    the size is checked before decoding; a JPEG cut short is added to `notes`)."""
    check_photo(path, notes)
    try:
        image = cv2.imread(os.fspath(path), cv2.IMREAD_GRAYSCALE)
    except cv2.error as exc:
        raise FablineError(f"{path}: cannot read the image: {str(exc).strip().splitlines()[-1]}") from None
    if image is None:
        raise FablineError(f"{path}: cannot read the image (missing, unreadable or not an image)")
    return image


def write_image(path: str | os.PathLike, image: np.ndarray, params: tuple = (), suffix: str | None = None) -> None:
    """Encode an image as `suffix` says (default: as the file name says, with OpenCV `params`) and write it
    atomically."""
    ok, encoded = cv2.imencode(suffix or Path(path).suffix, image, list(params))
    if not ok:
        raise FablineError(f"{path}: could not encode the picture")
    with atomic_output(path, "wb") as handle:
        handle.write(encoded.tobytes())


def _detector(min_side_px: float, image_size: int, level: int, window_px: int) -> cv2.aruco.ArucoDetector:
    """OpenCV's aruco detector for 36h11 quads of at least `min_side_px` at pyramid `level` (of `image_size` px), one
    adaptive threshold window of `window_px`."""
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_NONE
    params.minMarkerPerimeterRate = max(4 * min_side_px / image_size, 1e-3)
    params.adaptiveThreshWinSizeMin = params.adaptiveThreshWinSizeMax = window_px
    params.adaptiveThreshConstant = COARSE_THRESHOLD_OFFSET if level else FULL_RESOLUTION_THRESHOLD_OFFSET
    params.maxErroneousBitsInBorderRate = ARUCO_BORDER_ERROR_RATE
    params.errorCorrectionRate = ARUCO_CORRECTION_RATE
    if level == 0:
        params.polygonalApproxAccuracyRate = SLIVER_POLYGON_ACCURACY
    else:
        params.minCornerDistanceRate = COARSE_MIN_CORNER_DISTANCE_RATE
    return cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(TAG_DICTIONARY), params)


def _search_levels(padded: np.ndarray, min_side_px: int) -> list[tuple[int, np.ndarray]]:
    """The pyramid levels (see SEARCH_WINDOWS_PX) of the padded photo, finest first, each with its image; a coarser level
    while its shorter side keeps `min_side_px`."""
    levels = [(0, padded)]
    while levels[-1][0] < MAX_SEARCH_LEVEL and min(levels[-1][1].shape) // 2 >= min_side_px:
        image = levels[-1][1]
        levels.append((levels[-1][0] + 1, cv2.resize(image, (image.shape[1] // 2, image.shape[0] // 2),
                                                       interpolation=cv2.INTER_AREA)))
    return levels


def _search_level(search: _Search, level: int, image: np.ndarray) -> None:
    """Search pyramid `level` (`image`, padded) for quads and read them (see `_read_candidates`)."""
    scale = 2 ** level
    min_side = max(search.min_side_px / scale, COARSE_MIN_SIDE_PX if level else 0.0)
    for window in COARSE_WINDOWS_PX if level else SEARCH_WINDOWS_PX:
        corners, ids, rejected = _detector(min_side, max(image.shape), level, window).detectMarkers(image)
        candidates = [(q, int(i)) for q, i in zip(corners, ids.ravel())] if ids is not None else []
        candidates += [(q, None) for q in rejected]
        # a pixel centre of the level at (x + 0.5) * scale - 0.5 at full resolution
        _read_candidates(search, [((q.reshape(4, 2).astype(float) + 0.5) * scale - 0.5 - BORDER_PAD_PX, i, None)
                                  for q, i in candidates])


def detect_tags(gray: np.ndarray, min_side_px: float = 8.0, flagged: list[TagDetection] | None = None
                ) -> list[TagDetection]:
    """Every 36h11 tag in a grayscale image, sorted by id, corners refined to sub-pixel precision.

    Quads OpenCV decodes are refined; quads it finds but cannot decode (small, oblique or blurred
    tags, where its bit sampling on the coarse quad fails) get a second chance: refined first, their
    bits are then read on the refined quad and identified with up to REPORTED_BITS corrected.
    Quads are searched for on an image pyramid, finest level first (see SEARCH_WINDOWS_PX): full resolution finds the
    small, dim or grazing tags, the coarse levels blurred large ones; quads inside tags already found are skipped.
    Last, black squares with a corner hidden under the quiet
    zone of a tag found in front of them are read (`_occluded_quads`). Tags with a corner outside the image come out
    `partial` (see the module's docstring). Quads that read only with more bits corrected than REPORTED_BITS, or whose
    cells are under MIN_CELL_PX across, are no tags: they go to `flagged` (when given) with their `quality`.
    """
    search = _Search(gray, min_side_px)
    padded = _padded(gray)
    levels = _search_levels(padded, MIN_LEVEL_SIDE_PX)
    for level, image in levels:
        _search_level(search, level, image)
    if not search.found and len(levels) <= 2:  # a small photo out of focus
        for level, image in _search_levels(padded, OUT_OF_FOCUS_MIN_LEVEL_SIDE_PX)[len(levels):]:
            _search_level(search, level, image)
    _read_candidates(search, [(q, None, cover) for q, cover in _occluded_quads(gray, [q for _, q in search.found])],
                     try_quiet_zone=False)
    if flagged is not None:  # once each, where no tag of its id was found
        kept: list[tuple[int, np.ndarray]] = []
        for tag_id, quad, quality in search.flagged:
            if not any(tag_id == other_id and _overlap(quad, other) for other_id, other in search.found + kept):
                kept.append((tag_id, quad))
                flagged.append(TagDetection(tag_id, quad[APRILTAG_ORDER],
                                            bool(_edge_inside_fraction(gray, quad).min() < 1), quality))
    search.found.sort(key=lambda tag: (tag[0], *tag[1].mean(axis=0)[::-1]))
    return [TagDetection(tag_id, quad[APRILTAG_ORDER], bool(_edge_inside_fraction(gray, quad).min() < 1))
            for tag_id, quad in search.found]


@dataclass
class _Search:
    """One photo's search: the photo, the smallest side of a quad read, the tags found (id, corners in detection's
    order), the quads flagged (id, corners, why) and the centres and shortest sides of the unidentified quads read so far
    (another search's quad at the same place, to a pixel, is not read again: it reads no better)."""

    gray: np.ndarray
    min_side_px: float
    found: list[tuple[int, np.ndarray]] = field(default_factory=list)
    flagged: list[tuple[int, np.ndarray, str]] = field(default_factory=list)
    tried: list[np.ndarray] = field(default_factory=list)

    def tried_before(self, quad: np.ndarray) -> bool:
        key = np.array([*quad.mean(axis=0), _shortest_side(quad)])
        if self.tried and np.min(np.abs(np.array(self.tried) - key).max(axis=1)) < TRIED_QUAD_MATCH_PX:
            return True
        self.tried.append(key)
        return False


def _read_candidates(search: _Search, candidates: list[tuple[np.ndarray, int | None, np.ndarray | None]],
                     try_quiet_zone: bool = True) -> None:
    """Refine and read candidate quads (4, 2) in px, each with aruco's id or None and the outline of what hides part of
    it or None (see `_decode`), into the search's found tags (id, corners) or flagged quads; quads cut by the image
    border, inside a tag found before or read before (`_Search.tried_before`) are skipped; a quad read as a tag
    already found at the same place keeps the larger of the two. `try_quiet_zone`: a quad whose edges cannot be
    located may be a tag's quiet zone outline, as aruco's quads of tags on a darker background are."""
    gray, found = search.gray, search.found
    centres = np.array([q.mean(axis=0) for _, q in found]).reshape(-1, 2)
    radii = np.array([0.5 * _shortest_side(q) for _, q in found])
    for quad, tag_id, hidden_by in candidates:
        if np.any(quad < 0) or np.any(quad > [gray.shape[1] - 1, gray.shape[0] - 1]):
            continue  # cut by the image border: its corners cannot be measured
        if tag_id is None and _shortest_side(quad) < search.min_side_px:
            continue
        if np.any(np.linalg.norm(centres - quad.mean(axis=0), axis=1) < radii):
            continue  # inside a tag found before
        if tag_id is None and hidden_by is None and (search.tried_before(quad) or _plain_dark(gray, quad)):
            continue
        read_id, refined, wrong = _refine_and_read(gray, quad, tag_id, hidden_by)
        for outline in OUTLINES_AROUND_SQUARE if try_quiet_zone and tag_id is None and read_id is None else ():
            # a tag on a darker background: the quad may be its quiet zone's outline, one cell outside the black square
            # (or two, blurred), whose edges, light inside, cannot be located as a black square's are, if that square
            # is darker
            square = _inside_quiet_zone(quad, outline)
            if _contrast(gray, square) > 0:
                read_id, refined, wrong = _refine_and_read(gray, square, None)
                if read_id is not None:
                    break
        if refined is None or read_id is None or _edge_inside_fraction(gray, refined).min() < MIN_EDGE_INSIDE:
            continue
        if wrong > REPORTED_BITS or _narrowest_cell(refined) < MIN_CELL_PX:
            search.flagged.append((read_id, refined, f"{wrong} bits wrong" if wrong > REPORTED_BITS else
                                   f"cells {_narrowest_cell(refined):.1f} px across"))
            continue
        same = [k for k, (other_id, other) in enumerate(found) if other_id == read_id and _overlap(refined, other)]
        if not same:
            found.append((read_id, refined))
        elif _area(refined) > _area(found[same[0]][1]):
            found[same[0]] = (read_id, refined)


def _plain_dark(gray: np.ndarray, quad: np.ndarray) -> bool:
    """Whether a candidate quad (4, 2) in px is a dark patch in a light surround with nothing light inside, so no tag
    (a lamella's end, a shadow): sampled on the photo at its cells' centres, the quiet zone's median at least
    MIN_CONTRAST above the black border's, and no data cell above PLAIN_DARK_RATE of the way from border to quiet zone
    (every 36h11 code has light cells; tags read on the benchmark's photos reach past 1.0). A cheap look, before the
    edges are located: it leaves out half the candidates that are no tags, at a twentieth of the cost of reading
    them."""
    values = _cell_values(gray, quad)
    dark, light = np.median(values[BORDER_CELLS]), np.median(values[QUIET_ZONE_CELLS])
    return bool(light - dark >= MIN_CONTRAST and values[2:-2, 2:-2].max() < dark + PLAIN_DARK_RATE * (light - dark))


def _contrast(gray: np.ndarray, quad: np.ndarray) -> float:
    """The median grey of the quiet-zone cells around a quad (4, 2) in px as a black square less its border cells'."""
    values = _cell_values(gray, quad)
    return float(np.median(values[QUIET_ZONE_CELLS]) - np.median(values[BORDER_CELLS]))


def _cell_values(gray: np.ndarray, quad: np.ndarray) -> np.ndarray:
    """The photo's grey (TAG_CELLS + 2, TAG_CELLS + 2) at the cell centres of a tag whose black square is `quad`."""
    return cv2.remap(gray, *_tag_points(quad, CELL_CENTRES).astype(np.float32).reshape(1, -1, 2).transpose(2, 0, 1),
                     cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).reshape(TAG_CELLS + 2, TAG_CELLS + 2)


def _overlap(quad: np.ndarray, other: np.ndarray) -> bool:
    """Whether two quads (4, 2) are one tag found twice: either's centre inside the other's inscribed half side."""
    gap = np.linalg.norm(quad.mean(axis=0) - other.mean(axis=0))
    return bool(gap < 0.5 * max(_shortest_side(quad), _shortest_side(other)))


def _occluded_quads(gray: np.ndarray, tags: list[np.ndarray]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Quads (4, 2) in px, clockwise, of black squares with a corner hidden under the quiet zone of one of `tags`
    (corners (4, 2) each) in front of them (see OCCLUDER_MIN_CELL_PX), each with that tag's quiet-zone outline (4, 2)
    in px."""
    occluders = [corners for corners in tags if _shortest_side(corners) >= TAG_CELLS * OCCLUDER_MIN_CELL_PX]
    if not occluders:
        return []
    height, width = gray.shape
    half = cv2.resize(gray, (width // 2, height // 2), interpolation=cv2.INTER_AREA)
    quads = []
    for corners in occluders:
        sides = np.linalg.norm(corners - corners[PREVIOUS_CORNER], axis=1)
        reach = OCCLUDED_SEARCH_REACH * sides.max()
        x0, y0 = np.maximum((corners.min(axis=0) - reach) / 2, 0).astype(int)
        x1, y1 = np.minimum((corners.max(axis=0) + reach) / 2 + 1, [width // 2, height // 2]).astype(int)
        dark = cv2.adaptiveThreshold(half[y0:y1, x0:x1], 255, cv2.ADAPTIVE_THRESH_MEAN_C, cv2.THRESH_BINARY_INV,
                                     OCCLUDED_THRESHOLD_WINDOW_PX, OCCLUDED_THRESHOLD_OFFSET)
        outlines, _ = cv2.findContours(dark, cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
        perimeter = sides.sum() / 2  # at half resolution
        outlines = [o for o in outlines if 0.3 * perimeter < len(o) < 2 * perimeter]
        if not outlines:
            continue
        quiet_zone = _tag_points(corners, QUIET_ZONE_OUTLINE)
        # where the hidden corners must lie, at half resolution in the window
        cover = _tag_points(corners, QUIET_ZONE_OUTLINE
                            + HIDDEN_CORNER_TOLERANCE_CELLS * np.sign(QUIET_ZONE_OUTLINE - TAG_CELLS / 2))
        cover = ((cover + 0.5) / 2 - 0.5 - [x0, y0]).astype(np.float32)
        for outline in outlines:
            polygon = cv2.approxPolyDP(outline, 0.03 * len(outline), True).reshape(-1, 2).astype(float)
            quad = _quad_of_cut_polygon(polygon)
            if quad is None:
                continue
            # corners the edges' lines make where the outline has none (over a half-resolution pixel from its vertices)
            hidden = quad[np.linalg.norm(quad[:, None, :] - polygon[None], axis=2).min(axis=1) > 1.0]
            if len(hidden) and all(cv2.pointPolygonTest(cover, (float(x), float(y)), False) >= 0 for x, y in hidden):
                quad = (quad + [x0, y0] + 0.5) * 2 - 0.5
                clockwise = _cross(quad[1] - quad[0], quad[2] - quad[1]) > 0
                quads.append((quad if clockwise else quad[::-1].copy(), quiet_zone))
    return quads


def _quad_of_cut_polygon(polygon: np.ndarray) -> np.ndarray | None:
    """The convex quad (4, 2) the four longest edges' lines of a 5-7-gon make (a square with a corner cut off or
    notched), when they are most of its outline; else None."""
    if not 5 <= len(polygon) <= 7:
        return None
    edges = np.roll(polygon, -1, axis=0) - polygon
    lengths = np.linalg.norm(edges, axis=1)
    longest = np.sort(np.argsort(lengths)[-4:])
    if lengths[longest].sum() < CUT_POLYGON_MIN_KEPT * lengths.sum():
        return None
    quad = _corners((polygon[longest], edges[longest] / lengths[longest, None]))
    if not np.all(np.isfinite(quad)) or not cv2.isContourConvex(quad.astype(np.float32)):
        return None
    return quad


def _tag_points(corners: np.ndarray, cells: np.ndarray, frame: np.ndarray = TAG_SQUARE) -> np.ndarray:
    """Points (n, 2) given in a tag's cell coordinates in the image, px, in perspective: `corners` (4, 2) are where the
    cell-coordinate quad `frame` (by default the black square, TAG_SQUARE) lies in the image."""
    to_image = cv2.getPerspectiveTransform(frame.astype(np.float32), corners.astype(np.float32))
    return cv2.perspectiveTransform(np.asarray(cells, dtype=float).reshape(1, -1, 2), to_image)[0]


def _padded(gray: np.ndarray) -> np.ndarray:
    """The photo with BORDER_PAD_PX of padding on every side at the local light level of the photo's edge beside it
    (see BORDER_PAD_PX); the corner squares at the photo's median grey."""
    pad = BORDER_PAD_PX
    padded = cv2.copyMakeBorder(gray, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=float(np.median(gray[::8, ::8])))
    along_edge = np.ones((1, 2 * pad + 1), np.uint8)

    def light(edge_rows: np.ndarray) -> np.ndarray:
        """Per position along an edge, its light level from the edge's outermost rows (rows, n) -> (n,)."""
        return cv2.dilate(edge_rows.max(axis=0)[None, :], along_edge)[0]

    padded[:pad, pad:-pad] = light(gray[:PAD_LIGHT_ROWS])
    padded[-pad:, pad:-pad] = light(gray[-PAD_LIGHT_ROWS:])
    padded[pad:-pad, :pad] = light(gray[:, :PAD_LIGHT_ROWS].T)[:, None]
    padded[pad:-pad, -pad:] = light(gray[:, -PAD_LIGHT_ROWS:].T)[:, None]
    return padded


def _edge_inside_fraction(image: np.ndarray, quad: np.ndarray) -> np.ndarray:
    """The fraction of each of the quad's four edges (corner i to i + 1) that lies within the image."""
    steps = np.linspace(0, 1, 33)[None, :, None]
    points = quad[:, None, :] + steps * (quad[NEXT_CORNER] - quad)[:, None, :]
    return _inside(image, points).mean(axis=1)


def _shortest_side(quad: np.ndarray) -> float:
    return float(np.min(np.linalg.norm(quad - quad[PREVIOUS_CORNER], axis=1)))


def _inside_quiet_zone(outline: np.ndarray, frame: np.ndarray = QUIET_ZONE_OUTLINE) -> np.ndarray:
    """The black square's corners (4, 2) of a tag whose quiet zone's outer outline is `outline`, in perspective (`frame`:
    that outline in the tag's cell coordinates)."""
    return _tag_points(outline, TAG_SQUARE, frame=frame)


def detect_expected_tags(gray: np.ndarray, expected: dict[int, np.ndarray], min_side_px: float = 12.0) -> list[TagDetection]:
    """The tags `expected` (id -> predicted corners (4, 2) in px, AprilTag order) that really are where predicted,
    sorted by id.

    For tags whose quad the image alone does not yield: cells under 2 px in a dim photo, whose blurred
    border breaks up even at the low-contrast pass's threshold offset, or a strap across a corner of the
    black square. The survey predicts them from the photos that did see them; each prediction is
    refined on the image edges as in `detect_tags` and kept only when its cells read as that very tag.
    """
    found = []
    for tag_id, predicted in sorted(expected.items()):
        quad = np.asarray(predicted, dtype=float).reshape(4, 2)[APRILTAG_ORDER]
        if (np.any(quad < 0) or np.any(quad > [gray.shape[1] - 1, gray.shape[0] - 1])
                or _shortest_side(quad) < min_side_px):
            continue
        read_id, refined, wrong = _refine_and_read(gray, quad, None)
        if read_id == tag_id and wrong <= REPORTED_BITS:
            found.append(TagDetection(tag_id, refined[APRILTAG_ORDER]))
    return found


def _refine_and_read(gray: np.ndarray, quad: np.ndarray, tag_id: int | None,
                     hidden_by: np.ndarray | None = None) -> tuple[int | None, np.ndarray | None, int]:
    """Refine a candidate quad on the image around it; without a known `tag_id`, read its cells on the refined quad
    (`hidden_by`: the outline (4, 2) in px of a tag in front hiding part of it, see `_decode`).

    Returns the id (None when unreadable), the refined corners in px (None when the edges cannot be
    located), in tag order once read, and the bits read wrong (0 for aruco's own reads, within REPORTED_BITS).
    """
    margin = 4 + 0.2 * np.ptp(quad, axis=0).max()
    x0, y0 = np.maximum(np.floor(quad.min(axis=0) - margin).astype(int), 0)
    x1, y1 = np.ceil(quad.max(axis=0) + margin).astype(int) + 1
    window = spline_filter(gray[y0:y1, x0:x1].astype(np.float64), order=3)
    refined, moved = _refine(window, quad - [x0, y0])
    if refined is None:
        return tag_id, None, 0
    wrong = 0
    if tag_id is None:
        tag_id, refined, wrong = _decode(window, refined, None if hidden_by is None else hidden_by - [x0, y0])
    if tag_id is not None:
        refined = _settle(window, refined, moved)
    return tag_id, refined + [x0, y0], wrong


def _decode(image: np.ndarray, quad: np.ndarray, hidden_by: np.ndarray | None = None
            ) -> tuple[int | None, np.ndarray, int]:
    """Read a refined quad's cells (spline image) and identify it; returns the id (or None), corners in tag order and
    the bits read wrong (up to FLAGGED_BITS, see there).

    The black border must be dark and the quiet zone around it light; data cells are thresholded
    halfway between the two and matched with OpenCV's dictionary (`read_code`), sharpened first when they do not match
    within REPORTED_BITS as they are (see DECODE_SHARPENING).
    Cells under `hidden_by` (a convex outline (4, 2) in px of a tag in front) are not measured, as cells outside the
    image; data cells under it are read anyway but each counts as a wrong bit towards FLAGGED_BITS.
    """
    ticks = np.arange(-1, TAG_CELLS + 1) + 0.5
    sub = np.array([-0.25, 0.0, 0.25])
    xs = (ticks[None, :, None, None] + sub[None, None, None, :]).repeat(len(ticks), 0).repeat(3, 2)
    ys = (ticks[:, None, None, None] + sub[None, None, :, None]).repeat(len(ticks), 1).repeat(3, 3)
    points = _tag_points(quad, np.stack([xs, ys], axis=-1))
    inside = _inside(image, points).reshape(len(ticks), len(ticks), 9).all(axis=2)
    measured = inside.copy()
    if hidden_by is not None:
        measured &= ~_in_convex(hidden_by, points).reshape(len(ticks), len(ticks), 9).any(axis=2)
    values = map_coordinates(image, [points[:, 1], points[:, 0]], order=3, mode="mirror", prefilter=False)
    cells = values.reshape(len(ticks), len(ticks), 9).mean(axis=2)
    ring, border = QUIET_ZONE_CELLS.copy(), BORDER_CELLS.copy()
    # the black square must lie in the image; of its quiet zone (which the photo's edge may cut) at least half
    if (not inside[2:-2, 2:-2].all() or measured[border].sum() < MIN_BORDER_CELLS
            or measured[ring].sum() < MIN_QUIET_ZONE_CELLS):
        return None, quad, 0
    ring &= measured
    border &= measured
    dark, light = cells[border], cells[ring]
    threshold = 0.5 * (np.median(dark) + np.median(light))
    if (np.median(light) - np.median(dark) < MIN_CONTRAST or np.sum(dark > threshold) > 2
            or np.sum(light < threshold) > 4):
        return None, quad, 0
    hidden_bits = ~measured[2:-2, 2:-2]
    tag_id, rotation, wrong = read_code(cells[2:-2, 2:-2] > threshold, hidden_bits)
    if tag_id is None or wrong > REPORTED_BITS:
        # blur spreads each cell into its neighbours: a lone light cell among dark ones reads dark. Sharpened as the
        # AprilTag library's decode_sharpening does (the cells' Laplacian, 0.25 of it), then read again.
        padded = np.pad(cells, 1, mode="edge")
        laplacian = 4 * cells - padded[:-2, 1:-1] - padded[2:, 1:-1] - padded[1:-1, :-2] - padded[1:-1, 2:]
        sharpened = read_code((cells + DECODE_SHARPENING * laplacian)[2:-2, 2:-2] > threshold, hidden_bits)
        if sharpened[0] is not None and (tag_id is None or sharpened[2] < wrong):
            tag_id, rotation, wrong = sharpened
    if tag_id is None:
        return None, quad, 0
    return tag_id, np.roll(quad, rotation, axis=0), wrong


BITS_SET = np.array([bin(byte).count("1") for byte in range(256)], dtype=np.uint8)  # per byte value, its bits set


@cache
def _codes() -> tuple[np.ndarray, np.ndarray]:
    """The dictionary's codes as integers, bit k the data bit k of the 6 x 6 in row order, of each tag in each of
    aruco's four rotations (4 * n,: tag i's at 4i..4i+3), and each rotation's number as aruco counts them (4,)."""
    dictionary = cv2.aruco.getPredefinedDictionary(TAG_DICTIONARY)
    size = dictionary.markerSize
    codes = np.array([cv2.aruco.Dictionary.getBitsFromByteList(dictionary.bytesList[i:i + 1], size)
                      for i in range(len(dictionary.bytesList))], dtype=bool)
    # aruco's rotation of a tag read as its code turned by np.rot90 k times: its own answer, once
    rotations = np.array([dictionary.identify(np.rot90(codes[0], turns).astype(np.uint8), 0)[2] for turns in range(4)])
    turned = np.stack([np.rot90(codes, turns, axes=(1, 2)) for turns in range(4)], axis=1).reshape(-1, size * size)
    return _as_integer(turned), rotations


def _as_integer(bits: np.ndarray) -> np.ndarray:
    """Rows of up to 64 bits (..., k) as unsigned integers, bit j the row's j-th."""
    return (bits.astype(np.uint64) << np.arange(bits.shape[-1], dtype=np.uint64)).sum(axis=-1, dtype=np.uint64)


def identify(bits: np.ndarray, hidden: np.ndarray | None = None) -> tuple[int | None, int]:
    """The tag whose code the data bits (6, 6, bool) read, with up to REPORTED_BITS wrong (as aruco's
    `Dictionary.identify` at ARUCO_CORRECTION_RATE), and aruco's rotation of it; (None, 0) if none. Bits `hidden`
    (6, 6) were not measured (see `read_code`)."""
    tag_id, rotation, wrong = read_code(bits, hidden)
    return (tag_id, rotation) if tag_id is not None and wrong <= REPORTED_BITS else (None, 0)


def read_code(bits: np.ndarray, hidden: np.ndarray | None = None) -> tuple[int | None, int, int]:
    """The tag whose code the data bits (6, 6, bool) are nearest, all codes compared at once (aruco's
    `Dictionary.identify` compares one at a time, 2 ms a miss), aruco's rotation of it and the measured bits that
    differ; (None, 0, 0) when more than FLAGGED_BITS differ. Bits `hidden` (6, 6) were not measured: they count
    towards FLAGGED_BITS, not among the bits returned (see REPORTED_BITS)."""
    codes, rotations = _codes()
    known = np.ones(bits.size, dtype=bool) if hidden is None else ~hidden.ravel()
    differ = (codes ^ _as_integer(bits.ravel())) & _as_integer(known)
    wrong = BITS_SET[differ.view(np.uint8)].reshape(-1, 8).sum(axis=1)
    best = int(np.argmin(wrong))
    if wrong[best] + (bits.size - known.sum()) > FLAGGED_BITS:
        return None, 0, 0
    return best // 4, int(rotations[best % 4]), int(wrong[best])


def _inside(image: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Which of `points` (..., 2) in px lie within `image`, where a cubic spline can be sampled."""
    h, w = image.shape
    return (points[..., 0] >= 0) & (points[..., 1] >= 0) & (points[..., 0] <= w - 1) & (points[..., 1] <= h - 1)


def _in_convex(polygon: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Which of `points` (n, 2) lie inside the convex `polygon` (k, 2), in either winding."""
    edges = np.roll(polygon, -1, axis=0) - polygon
    sides = _cross(edges[None], points[:, None, :] - polygon[None])
    return np.all(sides >= 0, axis=1) | np.all(sides <= 0, axis=1)


def _area(quad: np.ndarray) -> float:
    x, y = quad[:, 0], quad[:, 1]
    return 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def refine_corners(image: np.ndarray, quad: np.ndarray) -> np.ndarray | None:
    """Sub-pixel corners of one tag: fit a line to each edge's gradient peaks, intersect neighbours.

    `image` holds cubic B-spline coefficients (scipy.ndimage.spline_filter) of the region around the tag.
    Returns None when an edge cannot be located (too small, cut by the image border, no contrast).
    A small quad too coarse for that (a tag of 2 px cells whose quad is a pixel or two off, beyond the narrow
    edge profiles of small tags) gets a first pass with profiles reaching COARSE_REACH_PX, then the usual ones;
    larger tags' profiles reach that far anyway.
    """
    return _refine(image, quad)[0]


def _refine(image: np.ndarray, quad: np.ndarray) -> tuple[np.ndarray | None, float]:
    """`refine_corners`' corners and how far (px) its last pass moved them the most."""
    refined, moved = _refine_passes(image, quad, [MIN_REACH_PX] * REFINE_PASSES)
    if refined is None and _profile_reach(quad, MIN_REACH_PX) < COARSE_REACH_PX:
        refined, moved = _refine_passes(image, quad, [COARSE_REACH_PX] + [MIN_REACH_PX] * REFINE_PASSES)
    elif refined is None and _narrowest_cell(quad) >= LARGE_CELL_PX:
        refined, moved = _refine_passes(image, quad, [0.9 * _narrowest_cell(quad)] + [MIN_REACH_PX] * REFINE_PASSES,
                                        [COARSE_MAX_REACH_PX] + [MAX_REACH_PX] * REFINE_PASSES)
    return refined, moved


def _refine_passes(image: np.ndarray, quad: np.ndarray, min_reaches: list[float], max_reaches: list[float] | None = None
                   ) -> tuple[np.ndarray | None, float]:
    """Corners refined by one pass of edge fits per entry of `min_reaches` (each pass's shortest profile reach, px; its
    longest, of `max_reaches`, MAX_REACH_PX by default), and how far the last pass moved them the most; (None, inf) when
    a pass cannot locate the edges."""
    moved = np.inf
    for min_reach, max_reach in zip(min_reaches, max_reaches or [MAX_REACH_PX] * len(min_reaches)):
        lines = _fit_edges(image, quad, min_reach, max_reach)
        if lines is None:
            return None, np.inf
        new = _corners(lines)
        side = np.mean(np.linalg.norm(quad[NEXT_CORNER] - quad, axis=1))
        moved = float(np.max(np.linalg.norm(new - quad, axis=1))) if np.all(np.isfinite(new)) else np.inf
        if moved > max(3.0, 0.2 * side):
            return None, np.inf
        quad = new
    return quad, moved


def _settle(image: np.ndarray, quad: np.ndarray, moved: float) -> np.ndarray:
    """A read tag's corners, which the last pass moved by `moved` px, after further passes until none moves by more than
    CONVERGED_PX (at most MAX_EXTRA_PASSES); a pass that cannot locate the edges leaves the corners as they were."""
    for _ in range(MAX_EXTRA_PASSES):
        if moved <= CONVERGED_PX:
            break
        new, moved = _refine_passes(image, quad, [MIN_REACH_PX])
        if new is None:
            break
        quad = new
    return quad


def _fit_edges(image: np.ndarray, quad: np.ndarray, min_reach: float, max_reach: float = MAX_REACH_PX):
    """The four edges of `quad` as lines, points and unit directions (4, 2) each, from the intensity-gradient peaks
    of profiles across them (None when an edge has fewer than four).

    Each edge is sampled at EDGE_SAMPLES to MAX_EDGE_SAMPLES points (see there); along each point's outward normal (black border to white
    quiet zone) the profile's steepest rise, interpolated with a parabola, is the edge crossing.
    """
    starts, ends = quad, quad[NEXT_CORNER]
    directions = (ends - starts) / np.linalg.norm(ends - starts, axis=1)[:, None]
    normals = np.column_stack([-directions[:, 1], directions[:, 0]])
    outward = np.einsum("ij,ij->i", normals, (starts + ends) / 2 - quad.mean(axis=0))
    normals *= np.where(outward < 0, -1.0, 1.0)[:, None]
    reach = _profile_reach(quad, min_reach, max_reach)
    offsets = np.linspace(-reach, reach, 2 * int(np.ceil(4 * reach)) + 1)
    samples = int(np.clip(0.7 * np.linalg.norm(ends - starts, axis=1).mean() / EDGE_SAMPLE_SPACING_PX, EDGE_SAMPLES,
                          MAX_EDGE_SAMPLES))
    along = np.linspace(0.15, 0.85, samples)
    points = starts[:, None, :] + along[None, :, None] * (ends - starts)[:, None, :]  # (4, S, 2)
    grid = points[:, :, None, :] + offsets[None, None, :, None] * normals[:, None, None, :]  # (4, S, K, 2)
    profiles = map_coordinates(image, [grid[..., 1].ravel(), grid[..., 0].ravel()], order=3, mode="mirror",
                               prefilter=False).reshape(grid.shape[:3])
    # By the photo's edge a profile's quiet-zone end may lie outside the image: it is cut there (its last sample
    # inside repeated) and still measures the edge if the rise lies inside; profiles starting outside are left out.
    inside = _inside(image, grid)
    all_inside = bool(inside.all())
    if not all_inside:
        last_inside = np.maximum.accumulate(np.where(inside, np.arange(len(offsets)), 0), axis=2)
        profiles = np.take_along_axis(profiles, last_inside, axis=2)
    slope = np.empty_like(profiles)  # np.gradient's: central differences, one-sided at the ends
    slope[:, :, 1:-1] = 0.5 * (profiles[:, :, 2:] - profiles[:, :, :-2])
    slope[:, :, 0], slope[:, :, -1] = profiles[:, :, 1] - profiles[:, :, 0], profiles[:, :, -1] - profiles[:, :, -2]
    if all_inside:
        peak = np.argmax(slope[:, :, 1:-1], axis=2) + 1
        measurable = np.ones(peak.shape, dtype=bool)
    else:
        rise_inside = inside[:, :, :-2] & inside[:, :, 1:-1] & inside[:, :, 2:]
        peak = np.argmax(np.where(rise_inside, slope[:, :, 1:-1], -np.inf), axis=2) + 1
        measurable = inside[:, :, 0] & np.take_along_axis(rise_inside, (peak - 1)[..., None], axis=2)[..., 0]
    at_peak = (np.arange(peak.size) * len(offsets) + peak.ravel()).reshape(peak.shape)  # into slope's flat array
    before, at, after = (slope.ravel()[at_peak + d] for d in (-1, 0, 1))
    contrast = np.where(measurable, profiles[:, :, -1] - profiles[:, :, 0], -np.inf)
    curvature = before - 2 * at + after
    good = measurable & (contrast > 0.25 * contrast.max(axis=1, keepdims=True)) & (curvature < 0)
    shift = np.where(good, 0.5 * (before - after) / np.where(curvature < 0, curvature, -1.0), 0.0)
    crossings = points + ((offsets[peak] + shift * (offsets[1] - offsets[0]))[..., None] * normals[:, None, :])
    # per edge, the total-least-squares line through its good crossings: their mean and the scatter's main axis
    counts = good.sum(axis=1)
    if counts.min() < 4:
        return None
    means = np.einsum("es,esi->ei", good, crossings) / counts[:, None]
    spread = (crossings - means[:, None, :]) * good[..., None]
    sxx, syy, sxy = (np.einsum("es,es->e", spread[..., i], spread[..., j]) for i, j in ((0, 0), (1, 1), (0, 1)))
    angle = 0.5 * np.arctan2(2 * sxy, sxx - syy)  # of the 2 x 2 scatter's main axis, in closed form
    return means, np.column_stack([np.cos(angle), np.sin(angle)])


def _profile_reach(quad: np.ndarray, min_reach: float, max_reach: float = MAX_REACH_PX) -> float:
    """How far (px) the edge profiles reach either side of an edge: 0.45 of the narrowest cell, in [min_reach,
    max_reach].

    Cells are measured along the edges' normals (the depth of the tag from each edge to the opposite one's middle), as
    the profiles run: a tag seen at a grazing angle is a thin sheared quad whose cells are far narrower across than its
    side lengths say, and longer profiles would cross the cells inside and the background beyond the quiet zone.
    """
    return float(np.clip(0.45 * _narrowest_cell(quad), min_reach, max_reach))


def _narrowest_cell(quad: np.ndarray) -> float:
    """A quad's narrowest cell across, px: the least of its depths from each edge to the opposite one's middle over the
    TAG_CELLS cells (a tag seen edge-on is thin across, however long its sides)."""
    starts, ends = quad, quad[NEXT_CORNER]
    directions = (ends - starts) / np.linalg.norm(ends - starts, axis=1)[:, None]
    to_opposite = (quad[OPPOSITE_CORNER] + quad[PREVIOUS_CORNER]) / 2 - starts
    return float(np.abs(_cross(directions, to_opposite)).min() / TAG_CELLS)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The z component of the cross products of 2-D vectors (..., 2)."""
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _corners(lines: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Corner i (4, 2) where edge line i - 1 meets edge line i, from lines as points and unit directions (4, 2) each;
    NaN where two are parallel."""
    points, directions = lines
    previous_points, previous_directions = points[PREVIOUS_CORNER], directions[PREVIOUS_CORNER]
    crossing = _cross(previous_directions, directions)
    along = _cross(points - previous_points, directions) / np.where(np.abs(crossing) < 1e-9, np.nan, crossing)
    return previous_points + along[:, None] * previous_directions


def cell_width_px(corners: np.ndarray) -> float:
    """The tag's narrowest cell width in the photo, px: its shortest detected side over the 8 cells of the black square."""
    return _shortest_side(corners) / TAG_CELLS


def tag_object_points(tag_size: float) -> np.ndarray:
    """The four corners (4, 3) in the tag's own frame, the AprilTag library's: x right, y down, z into the tag's face,
    corners p0..p3 at (-s, s), (s, s), (s, -s), (-s, -s) for half size s (also the order IPPE_SQUARE requires)."""
    h = tag_size / 2
    return np.array([[-h, h, 0], [h, h, 0], [h, -h, 0], [-h, -h, 0]], dtype=float)


@dataclass
class TagPose:
    """A tag's pose in the camera frame from one view: rotation vector and translation (tag frame to camera frame, in
    the tag size's unit), RMS reprojection error px; the other of the two planar solutions and its error, and whether
    the two are too close to tell apart (`ambiguous`: best error over the other's above AMBIGUITY_RATIO)."""

    rotation: np.ndarray
    translation: np.ndarray
    error_px: float
    other_rotation: np.ndarray
    other_translation: np.ndarray
    other_error_px: float

    @property
    def ambiguity(self) -> float:
        """Best solution's reprojection error over the other's: near 0 clear, near 1 the two fit the corners alike."""
        return float(self.error_px / max(self.other_error_px, 1e-12))

    @property
    def ambiguous(self) -> bool:
        return self.ambiguity > AMBIGUITY_RATIO


# A planar square seen in one photo has two poses that fit its corners, mirror images about the line of sight; when the
# worse one's reprojection error is within this factor of the better one's, corner noise alone can swap them
AMBIGUITY_RATIO = 0.5


def tag_pose(corners: np.ndarray, camera: Camera, tag_size: float) -> TagPose:
    """Tag pose from one view: both IPPE solutions for a square (Collins & Bartoli 2014) and, as a guard where IPPE's
    closed form breaks down (exactly symmetric corners), SQPnP's, each refined by Levenberg-Marquardt on the
    reprojection error (distortion included); the best is chosen, the best one that differs from it (a rotation over
    1 degree apart: the mirror solution) kept to judge the ambiguity, or the best itself when all ended at one minimum.
    `corners` (4, 2) px in the AprilTag order; the pose is in the AprilTag tag frame."""
    image = np.ascontiguousarray(corners, dtype=np.float64).reshape(4, 1, 2)
    model = tag_object_points(tag_size)
    starts = []
    for flags in (cv2.SOLVEPNP_IPPE_SQUARE, cv2.SOLVEPNP_SQPNP):
        ok, rvecs, tvecs, _ = cv2.solvePnPGeneric(model, image, camera.matrix, camera.distortion, flags=flags)
        if ok:
            starts += [(r, t) for r, t in zip(rvecs, tvecs) if np.all(np.isfinite(r)) and np.all(np.isfinite(t))]
    solutions = []
    for rvec, tvec in starts:
        rvec, tvec = cv2.solvePnPRefineLM(model, image, camera.matrix, camera.distortion, rvec.copy(), tvec.copy(),
                                          (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12))
        projected, _ = cv2.projectPoints(model, rvec, tvec, camera.matrix, camera.distortion)
        error = float(np.sqrt(np.mean(np.sum((projected - image) ** 2, axis=2))))
        if tvec.ravel()[2] > 0:
            solutions.append((error, rvec.ravel(), tvec.ravel()))
    if not solutions:
        raise FablineError("pose estimation failed: the corners do not make a square seen from in front")
    solutions.sort(key=lambda solution: solution[0])
    error, rvec, tvec = solutions[0]
    best = cv2.Rodrigues(rvec)[0]
    other = next((s for s in solutions[1:]
                  if np.degrees(np.linalg.norm(cv2.Rodrigues(best.T @ cv2.Rodrigues(s[1])[0])[0])) > 1.0), solutions[0])
    return TagPose(rvec, tvec, error, other[1], other[2], other[0])
