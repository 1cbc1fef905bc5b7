"""Mechanics of a bent strip, below the design and unroll stages that both check it: lamella materials (data
in materials.toml), the strip profile h x t, and the structural rule (bending, twist and helix stresses, the
combined verdict, the limits a profile allows).

The names load their modules on first use (`fabline.lazy`).
"""

from fabline.lazy import lazy_surface

__getattr__, __all__ = lazy_surface(__name__, {
    "materials": ("Material", "Profile", "get_material", "load_materials", "parse_profile"),
    "structure": ("bending_stress", "check_lamella", "helix_stresses", "limits", "max_twist", "min_bending_radius",
                  "twist_shear_stress"),
})
