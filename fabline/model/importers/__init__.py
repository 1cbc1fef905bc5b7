"""Importers: a network model from fabline JSON, or from CAD curves (OBJ, DXF, Rhino .3dm) plus a surface.

`import_model` dispatches on the file suffix. From curves alone, nodes are the crossings of the two
families (within a tolerance, near-misses reported) and normals come from a reference surface mesh.
"""

from __future__ import annotations

import os
from pathlib import Path

import trimesh

from fabline.errors import FablineError
from fabline.model.importers.assemble import ImportReport, NearMissReport, build_network
from fabline.model.importers.curves import CurveSource, check_extent, check_surface_units, settle_units
from fabline.model.importers.nodes import SupportRule
from fabline.model.importers.dxf import read_dxf, read_dxf_surface
from fabline.model.importers.obj import read_obj
from fabline.model.importers.rhino import read_3dm, read_3dm_surface
from fabline.model.importers.surface import load_mesh_file
from fabline.model.jsonio import load_network
from fabline.model.network import UNIT_TO_MM, Network

FORMATS = {".json": "json", ".obj": "obj", ".dxf": "dxf", ".3dm": "3dm"}
"""File suffixes import_model reads, and the format name each stands for."""

__all__ = ["FORMATS", "ImportReport", "NearMissReport", "import_model"]


def import_model(path: str | os.PathLike, surface: str | os.PathLike | None = None, units: str | None = None,
                 tolerance_mm: float = 1.0, supports: str | None = None) -> tuple[Network, ImportReport]:
    """Read a network model from `path` (.json, .obj, .dxf or .3dm) and report what was found and assumed.

    CAD curves become lamellas; nodes are their A-B crossings within `tolerance_mm`; normals come from
    `surface` (a mesh file) or the faces in the same file. `units` names the units of a file that
    declares none (without it, curves of an implausible gridshell size are refused); disagreeing declarations are
    a mixed-units error. `supports` marks support nodes (`SupportRule.parse`: 'z<0.05', a plan polygon, a name).
    """
    path = str(path)
    file_format = FORMATS.get(Path(path).suffix.lower())
    if file_format is None:
        raise FablineError(f"{path}: unknown file type {Path(path).suffix or '(no suffix)'!r} "
                           f"(use {', '.join(FORMATS)})")
    if not tolerance_mm > 0 or tolerance_mm == float("inf"):
        raise FablineError(f"--tolerance {tolerance_mm}: must be a positive number of millimetres")
    if units is not None and units not in UNIT_TO_MM:
        raise FablineError(f"--units {units!r}: unknown units (use one of {', '.join(UNIT_TO_MM)})")
    if file_format == "json":
        return _import_json(path, surface, units, tolerance_mm)
    if file_format == "obj":
        source = read_obj(path)
    elif file_format == "dxf":
        source = read_dxf(path, units)
    else:
        source = read_3dm(path, units)
    rule = SupportRule.parse(supports) if supports is not None else None
    model_units = settle_units(source, units)
    check_extent(source, model_units, assumed=source.declared_units is None and units is None)
    mesh, surface_label = _surface_for(source, model_units, surface)
    return build_network(source, model_units, tolerance_mm, mesh, surface_label, file_format, rule)


def _import_json(path: str, surface, units: str | None, tolerance_mm: float) -> tuple[Network, ImportReport]:
    """A fabline.network/1 file: loaded and validated as it is; it carries its own nodes and normals."""
    network = load_network(path)
    if units is not None and units != network.units:
        raise FablineError(f"mixed units: {path} declares {network.units} but --units {units} was given")
    report = ImportReport(path, "json", network.units, tolerance_mm, len(network.lamellas), len(network.nodes),
                          sum(n.kind == "singularity" for n in network.nodes.values()))
    if surface is not None:
        report.notes.append(f"{path} carries its own normals; --surface {surface} was not used")
    return network, report


def _surface_for(source: CurveSource, units: str, surface) -> tuple[trimesh.Trimesh | None, str | None]:
    """The reference mesh: the `--surface` file if given (its units checked against the curves'), else faces in the file."""
    if surface is None:
        if source.mesh is not None:
            check_surface_units(source, units, source.path, None, source.mesh)
        return source.mesh, (source.path if source.mesh is not None else None)
    surface = str(surface)
    suffix = Path(surface).suffix.lower()
    if suffix == ".dxf":
        mesh, surface_units = read_dxf_surface(surface)
    elif suffix == ".3dm":
        mesh, surface_units = read_3dm_surface(surface)
    else:
        mesh, surface_units = load_mesh_file(surface), None
    check_surface_units(source, units, surface, surface_units, mesh)
    return mesh, surface
