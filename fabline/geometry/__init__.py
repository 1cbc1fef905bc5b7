"""The geometry stage: arc length, Darboux frame and curvatures along every lamella, crossing angles at nodes."""

from fabline.geometry.darboux import (CurveFit, LamellaGeometry, NetworkGeometry, analyse, lamella_geometry,
                                     lamella_table)

__all__ = ["CurveFit", "LamellaGeometry", "NetworkGeometry", "analyse", "lamella_geometry", "lamella_table"]
