"""The nest stage: parts onto sheets, and the nesting format that export reads."""

from fabline.nest.layout import (SCHEMA, CommonCut, Nesting, Placement, Sheet, load_nesting, nesting_from_dict,
                                 nesting_to_dict, parts_path, place, save_nesting)

__all__ = ["SCHEMA", "CommonCut", "Nesting", "Placement", "Sheet", "load_nesting", "nesting_from_dict",
           "nesting_to_dict", "parts_path", "place", "save_nesting"]
