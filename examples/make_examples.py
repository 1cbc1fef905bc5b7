"""Make the manual's sample inputs in this folder (committed; run again to rebuild them the same way):

- a small Enneper gridshell (3 x 4 m, nodes 0.5 m apart) as CAD curves: `curves.3dm` (rhino3dm), `curves.obj`
  and `curves.dxf` (with every node as a named point; the DXF also holds the surface as a MESH), and its
  reference surface as `surface.obj` and `surface.stl`;
- `stock.json`: two sheet sizes and a remnant;
- `charuco/`: 8 photos of the printed ChArUco board through a known lens (the survey's renderer);
- `survey/`: 6 photos of the built shell (40 mm sag) rendered by `fabline survey simulate`, with its camera.json,
  tagmap.json and truth.json.

    python examples/make_examples.py
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from fabline.model.designs import enneper_mesh, enneper_network
from fabline.model.writers import write_dxf, write_obj
from fabline.survey import BoardSpec, Camera, board_image, render_plane_photo
from fabline.survey.simulate import SyntheticSpec, simulate_survey

HERE = Path(__file__).resolve().parent


def write_3dm(network, path: Path) -> None:
    """The lamella centrelines as polyline curves on layers A and B, each named by its lamella id, in metres."""
    import rhino3dm

    model = rhino3dm.File3dm()
    model.Settings.ModelUnitSystem = rhino3dm.UnitSystem.Meters
    layers = {}
    for family in ("A", "B"):
        layer = rhino3dm.Layer()
        layer.Name = family
        layers[family] = model.Layers.Add(layer)
    for lam in network.lamellas:
        points = rhino3dm.Point3dList()
        for x, y, z in lam.curve.tolist():
            points.Add(x, y, z)
        attributes = rhino3dm.ObjectAttributes()
        attributes.LayerIndex = layers[lam.family]
        attributes.Name = lam.id
        model.Objects.AddPolyline(points, attributes)
    model.Write(str(path), 7)


def charuco_photos(folder: Path, count: int = 8) -> None:
    """Board photos through a known lens (960 x 720 px), as a phone would take them."""
    folder.mkdir(exist_ok=True)
    lens = Camera(np.array([[820.0, 0, 488.0], [0, 821.0, 353.0], [0, 0, 1]]), np.array([-0.1, 0.06, 4e-4, -2e-4, 0.0]),
                  960, 720)
    spec = BoardSpec()
    texture = board_image(spec, 8.0)
    centre = np.array([spec.squares_x * spec.square_mm / 2, spec.squares_y * spec.square_mm / 2, 0.0])
    rng = np.random.default_rng(5)
    for k in range(count):
        tilt = rng.uniform(-0.7, 0.7, 2) if k else np.zeros(2)
        aim = centre + np.append(rng.uniform([-100, -70], [100, 70]), 0.0)
        direction = np.array([tilt[0], tilt[1], -1.0])
        position = aim + rng.uniform(330, 400) * direction / np.linalg.norm(direction)
        forward = (aim - position) / np.linalg.norm(aim - position)
        right = np.cross(forward, [0.0, 1.0, 0.0])
        right /= np.linalg.norm(right)
        down = np.cross(forward, right)
        roll = rng.uniform(-0.3, 0.3)
        c, s = np.cos(roll), np.sin(roll)
        rotation = np.array([c * right + s * down, -s * right + c * down, forward])
        photo = render_plane_photo(texture, 1 / 8.0, lens, rotation, -rotation @ position)
        photo = cv2.GaussianBlur(photo, (0, 0), 0.6) + rng.normal(0, 1.5, photo.shape)
        cv2.imwrite(str(folder / f"board-{k:02d}.jpg"), np.clip(photo, 0, 255).astype(np.uint8),
                    [cv2.IMWRITE_JPEG_QUALITY, 90])


def main() -> None:
    network = enneper_network(size=(3.0, 4.0), spacing=0.5)
    mesh = enneper_mesh(network)
    write_3dm(network, HERE / "curves.3dm")
    write_obj(network, HERE / "curves.obj")
    write_dxf(network, HERE / "curves.dxf", mesh=mesh)
    mesh.export(HERE / "surface.obj")
    mesh.export(HERE / "surface.stl")
    (HERE / "stock.json").write_text(json.dumps({
        "schema": "fabline.stock/1",
        "sheets": [{"id": "4x2", "width": 4000, "height": 2000, "count": None},
                   {"id": "3x1.5", "width": 3000, "height": 1500, "count": 2}],
        "remnants": [{"id": "R-017", "width": 1200, "height": 700}]}, indent=1) + "\n")
    charuco_photos(HERE / "charuco")
    simulate_survey(network, HERE / "survey", SyntheticSpec(photos=6, width=2000, height=1334, focal_px=1667.0,
                                                            sag_mm=40.0, coverage=0.9, jpeg_quality=90, seed=3))


if __name__ == "__main__":
    main()
