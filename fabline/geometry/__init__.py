"""The geometry stage: arc length, Darboux frame and curvatures along every lamella, crossing angles at nodes.

The names below load their module on first use (`fabline.lazy`).
"""

from fabline.lazy import lazy_surface

__getattr__, __all__ = lazy_surface(__name__, {
    "darboux": ("CurveFit", "LamellaGeometry", "NetworkGeometry", "analyse", "lamella_geometry", "lamella_table"),
})
