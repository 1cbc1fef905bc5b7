"""Designs from a designer's surface: asymptotic networks traced on any anticlastic mesh, minimal surfaces from boundaries.

`design_asymptotic(path, spacing, ...)` reads a mesh (OBJ, STL, PLY, .3dm), fits cubic jets per vertex,
traces the two asymptotic families with the rail layout and returns a validated `Network` with its
quality report; `quality_report` measures any network the same way. The names load their modules on first use
(`fabline.lazy`): `fabline inspect` prints a traced network's quality without importing the tracer.
"""

from fabline.lazy import lazy_surface

__getattr__, __all__ = lazy_surface(__name__, {
    "asymptotic": ("AsymptoticDesign", "design_asymptotic", "read_surface"),
    "mesh": ("SmoothMesh",),
    "quality": ("quality_report", "summary_lines"),
})
