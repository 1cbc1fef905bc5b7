"""Lamella materials (data in materials.toml) and the rectangular strip profile h x t they are cut to."""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

from fabline.errors import FablineError
from fabline.fileio import finite_number, read_toml

BUILTIN_MATERIALS = Path(__file__).with_name("materials.toml")
MATERIAL_FIELDS = ("E", "G", "f_y", "density")
MAX_MATERIAL_VALUE = 1e7  # moduli and strengths in N/mm2, density in kg/m3: steel is 2.1e5 and 7850


@dataclass(frozen=True)
class Material:
    """Elastic moduli E and G, yield strength f_y (N/mm2) and density (kg/m3) of a lamella material."""

    name: str
    E: float
    G: float
    f_y: float
    density: float
    description: str = ""
    price_per_kg: float | None = None     # optional: what a kg of sheet costs, in `currency` (the bill of materials)
    currency: str = ""

    @property
    def tau_y(self) -> float:
        """Shear yield strength f_y / sqrt(3) (von Mises), N/mm2."""
        return self.f_y / 3.0 ** 0.5


@dataclass(frozen=True)
class Profile:
    """The strip cross-section: height h along the surface normal, thickness t sideways (mm)."""

    h: float
    t: float

    @property
    def polar_radius_sq(self) -> float:
        """Squared polar radius of gyration of the thin strip, i_p^2 = h^2 / 12 (thesis 6.10, h >> t), mm2.

        The helix fibres that matter lie across the height; the t^2 / 12 of the full rectangle is left
        out as in the thesis, which is what reproduces its reference stresses.
        """
        return self.h ** 2 / 12.0

    def __str__(self) -> str:
        return f"{self.h:g}x{self.t:g}"


def parse_profile(text: str) -> Profile:
    """Parse "HxT" in millimetres (height by thickness, e.g. "100x1.5"); the height must exceed the thickness."""
    match = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*[xX*]\s*([0-9]*\.?[0-9]+)\s*", str(text))
    if not match:
        raise FablineError(f"profile {text!r}: expected HEIGHTxTHICKNESS in mm, e.g. 100x1.5")
    h, t = float(match.group(1)), float(match.group(2))
    if h <= 0 or t <= 0:
        raise FablineError(f"profile {text!r}: height and thickness must be positive")
    if t >= h:
        raise FablineError(f"profile {text!r}: thickness {t:g} mm is not smaller than height {h:g} mm "
                           "(write height first, e.g. 100x1.5)")
    return Profile(h, t)


def load_materials(path: str | os.PathLike | None = None) -> dict[str, Material]:
    """The built-in materials, plus (overriding by name) those of the TOML file at `path`."""
    materials = _read_table(BUILTIN_MATERIALS)
    if path is not None:
        materials.update(_read_table(Path(path)))
    return materials


def get_material(name: str, path: str | os.PathLike | None = None) -> Material:
    """The material called `name` from the built-ins or the file at `path`."""
    materials = load_materials(path)
    if name not in materials:
        raise FablineError(f"material {name!r} is not known (use one of {', '.join(sorted(materials))}"
                           + (f" or add it to {path}" if path else " or give --materials FILE") + ")")
    return materials[name]


def _read_table(path: Path) -> dict[str, Material]:
    data = read_toml(path)
    materials = {}
    for name, raw in data.items():
        if not isinstance(raw, dict):
            raise FablineError(f"{path}: {name} must be a table [{name}] with {', '.join(MATERIAL_FIELDS)}")
        values = {}
        for key in MATERIAL_FIELDS:
            value = raw.get(key)
            if not finite_number(value, MAX_MATERIAL_VALUE) or value <= 0:
                raise FablineError(f"{path}: material {name}: {key} must be a positive number of at most "
                                   f"{MAX_MATERIAL_VALUE:g}, got {value!r}")
            values[key] = float(value)
        unknown = sorted(set(raw) - set(MATERIAL_FIELDS) - {"description", "price_per_kg", "currency"})
        if unknown:
            raise FablineError(f"{path}: material {name}: {unknown[0]}: unknown setting (use description, "
                               f"{', '.join(MATERIAL_FIELDS)}, price_per_kg, currency)")
        if not isinstance(raw.get("description", ""), str) or not isinstance(raw.get("currency", ""), str):
            raise FablineError(f"{path}: material {name}: description and currency must be text")
        price = raw.get("price_per_kg")
        if price is not None and (not isinstance(price, (int, float)) or isinstance(price, bool) or not 0 <= price < 1e9):
            raise FablineError(f"{path}: material {name}: price_per_kg must be a number, at least 0, got {price!r}")
        materials[name] = Material(name, description=raw.get("description", ""), **values,
                                   price_per_kg=None if price is None else float(price),
                                   currency=raw.get("currency", "EUR" if price is not None else ""))
    return materials
