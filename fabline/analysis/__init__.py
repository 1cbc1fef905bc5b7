"""The analysis stage: the erected gridshell as a 3D frame on OpenSees, with the erection's residual stress, load cases,
deflections, support reactions, utilisation and the buckling factor (issue 31).

The names below load their module on first use (`fabline.lazy`); OpenSees itself only when a model is solved.
"""

from fabline.lazy import lazy_surface

__getattr__, __all__ = lazy_surface(__name__, {
    "frame": ("Frame", "Section", "chain"),
    "solve": ("Model", "Solution", "opensees"),
})
