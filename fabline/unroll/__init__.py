"""The unroll stage: every lamella to flat parts, and the parts format that nest and export read.

The names below load their modules on first use, so reading a parts file does not import the unroller.
"""

from fabline.lazy import lazy_surface

__getattr__, __all__ = lazy_surface(__name__, {
    "options": ("SINGULARITY_MODES", "UnrollOptions"),
    "parts": ("PART_KINDS", "SCHEMA", "Part", "PartSet", "Polylines", "Slot", "flatten_contour", "load_parts",
              "parts_from_dict", "parts_to_dict", "save_parts"),
    "unroller": ("unroll_network",),
})
