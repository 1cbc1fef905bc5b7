"""Designs from a designer's surface: asymptotic networks traced on any anticlastic mesh, minimal surfaces from boundaries.

`design_asymptotic(path, spacing, ...)` reads a mesh (OBJ, STL, PLY, .3dm), fits cubic jets per vertex,
traces the two asymptotic families with the rail layout and returns a validated `Network` with its
quality report; `quality_report` measures any network the same way.
"""

from fabline.model.surfaces.design import AsymptoticDesign, design_asymptotic, read_surface
from fabline.model.surfaces.mesh import SmoothMesh
from fabline.model.surfaces.quality import quality_report, summary_lines

__all__ = ["AsymptoticDesign", "SmoothMesh", "design_asymptotic", "quality_report", "read_surface", "summary_lines"]
