"""The unroll stage: every lamella to flat parts, and the parts format that nest and export read."""

from fabline.unroll.parts import (PART_KINDS, SCHEMA, Part, PartSet, Slot, flatten_contour, load_parts,
                                  parts_from_dict, parts_to_dict, save_parts)

__all__ = ["PART_KINDS", "SCHEMA", "Part", "PartSet", "Slot", "flatten_contour", "load_parts",
           "parts_from_dict", "parts_to_dict", "save_parts"]
