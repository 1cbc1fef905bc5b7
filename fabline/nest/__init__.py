"""The nest stage: parts onto sheets, and the nesting format that export reads.

The names below load their modules on first use, so reading a nesting does not import the nester.
"""

from fabline.lazy import lazy_surface

__getattr__, __all__ = lazy_surface(__name__, {
    "layout": ("SCHEMA", "CommonCut", "Nesting", "Placement", "Sheet", "load_nesting", "nesting_from_dict",
               "nesting_to_dict", "parts_path", "place", "save_nesting"),
    "nester": ("NestOptions", "NestResult", "nest"),
    "svg": ("write_sheet_svgs",),
    "validate": ("validate_nesting",),
})
