"""The unroll stage: every lamella to flat parts, and the parts format that nest and export read."""

from fabline.unroll.materials import Material, Profile, get_material, load_materials, parse_profile
from fabline.unroll.options import SINGULARITY_MODES, UnrollOptions
from fabline.unroll.parts import (PART_KINDS, SCHEMA, Part, PartSet, Polylines, Slot, flatten_contour, load_parts,
                                  parts_from_dict, parts_to_dict, save_parts)
from fabline.unroll.structure import (bending_stress, check_lamella, helix_stresses, limits, max_twist,
                                      min_bending_radius, twist_shear_stress)
from fabline.unroll.unroller import unroll_network

__all__ = ["PART_KINDS", "SCHEMA", "SINGULARITY_MODES", "Material", "Part", "PartSet", "Polylines", "Profile", "Slot",
           "UnrollOptions", "bending_stress", "check_lamella", "flatten_contour", "get_material", "helix_stresses",
           "limits", "load_materials", "load_parts", "max_twist", "min_bending_radius", "parse_profile",
           "parts_from_dict", "parts_to_dict", "save_parts", "twist_shear_stress", "unroll_network"]
