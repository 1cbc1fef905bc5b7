"""Write a network's lamella centrelines for CAD: OBJ polylines and DXF 3D polylines, one group/layer per family.

The curves are the model's own samples, which contain every node as a vertex, and every node is written as a
named point (OBJ `p` in group NODES, object "<id> <kind>"; DXF POINT on layer NODES, id and kind in XDATA), so
importing them again (`fabline.model.importers`) gives the same nodes, ids and kinds, lamella ends included. A reference surface mesh may be written alongside
(OBJ faces, a DXF MESH entity) so the file carries its own normals.
"""

from __future__ import annotations

import os

import ezdxf
import numpy as np
import trimesh

from fabline.errors import FablineError
from fabline.fileio import atomic_output
from fabline.model.importers.dxf import INSUNITS, XDATA_APP
from fabline.model.network import Network

SURFACE_NAME = "SURFACE"
"""OBJ group and DXF layer of the reference surface; it names no family, so importers never read it as curves."""
NODES_NAME = "NODES"
"""OBJ group and DXF layer of the nodes, one named point each (id and kind), so an import gets them all back."""


def write_obj(network: Network, path: str | os.PathLike, mesh: trimesh.Trimesh | None = None) -> None:
    """Each lamella as one `l` polyline in group `A` or `B` and object named by its id; `mesh` as faces."""
    digits = _digits(network)
    with atomic_output(path) as out:
        out.write(f"# fabline network {network.name or ''} in {network.units}: "
                  f"{len(network.lamellas)} lamellas, {len(network.nodes)} nodes\n")
        count = 0
        for lam in network.lamellas:
            out.write(f"o {lam.id}\ng {lam.family}\n")
            out.write(_vertex_block(lam.curve, digits))
            out.write("l " + " ".join(map(str, range(count + 1, count + len(lam.curve) + 1))) + "\n")
            count += len(lam.curve)
        for node in network.nodes.values():
            out.write(f"o {node.id} {node.kind}\ng {NODES_NAME}\n")
            out.write(_vertex_block(np.asarray(node.xyz, dtype=float).reshape(1, 3), digits))
            count += 1
            out.write(f"p {count}\n")
        if mesh is not None:
            out.write(f"o {SURFACE_NAME}\ng {SURFACE_NAME}\n")
            out.write(_vertex_block(np.asarray(mesh.vertices), digits))
            faces = np.asarray(mesh.faces) + count + 1
            out.write("".join(f"f {a} {b} {c}\n" for a, b, c in faces.tolist()))


def write_dxf(network: Network, path: str | os.PathLike, mesh: trimesh.Trimesh | None = None) -> None:
    """Each lamella as a 3D POLYLINE on layer `A` or `B`, its id in XDATA; `$INSUNITS` from the model; `mesh` as a MESH."""
    codes = {name: code for code, name in INSUNITS.items()}
    if network.units not in codes:
        raise FablineError(f"{network.name or 'model'}: units {network.units} cannot be declared in DXF")
    doc = ezdxf.new("R2010", setup=False)
    doc.header["$INSUNITS"] = codes[network.units]
    doc.appids.add(XDATA_APP)
    for layer, colour in (("A", 1), ("B", 5), (SURFACE_NAME, 8), (NODES_NAME, 3)):
        doc.layers.add(layer, color=colour)
    modelspace = doc.modelspace()
    for lam in network.lamellas:
        polyline = modelspace.add_polyline3d(lam.curve.tolist(), dxfattribs={"layer": lam.family})
        polyline.set_xdata(XDATA_APP, [(1000, lam.id)])
    for node in network.nodes.values():
        point = modelspace.add_point(np.asarray(node.xyz, dtype=float).tolist(), dxfattribs={"layer": NODES_NAME})
        point.set_xdata(XDATA_APP, [(1000, node.id), (1000, node.kind)])
    if mesh is not None:
        surface = modelspace.add_mesh(dxfattribs={"layer": SURFACE_NAME})
        with surface.edit_data() as data:
            data.vertices = np.asarray(mesh.vertices).tolist()
            data.faces = np.asarray(mesh.faces).tolist()
    with atomic_output(path) as out:
        doc.write(out)


def _digits(network: Network) -> int:
    """Decimals that keep coordinates to 1e-6 mm, as the JSON format does."""
    return 6 + int(np.ceil(np.log10(network.mm_per_unit)))


def _vertex_block(points: np.ndarray, digits: int) -> str:
    return "".join(f"v {x:.{digits}f} {y:.{digits}f} {z:.{digits}f}\n" for x, y, z in points.tolist())
