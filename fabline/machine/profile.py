"""Machine profiles as data: TOML files that say what a controller accepts and how to run each operation.

Built-in profiles live in `fabline/machine/profiles/`; a user adds one by passing the path of a TOML file,
or by putting `<name>.toml` in a folder listed in the FABLINE_MACHINE_PATH environment variable. A profile
may start from another with `extends = "<name>"` and override only what differs.
"""

from __future__ import annotations

import math
import os
import re
import string
from dataclasses import dataclass, replace
from functools import lru_cache
from pathlib import Path
from typing import Any

from fabline.errors import FablineError
from fabline.fileio import read_toml
from fabline.machine.build import BuildInfo
from fabline.machine.codes import explain_error
from fabline.machine.gcode import REALTIME_COMMANDS, GcodeError, compact_line, parse_block

BUILTIN_DIR = Path(__file__).with_name("profiles")
OPERATIONS = ("engrave-mark", "engrave-text", "cut-inner", "cut-outer")
MODES = ("laser", "plotter", "mill")
WORD_PATTERN = re.compile(r"([A-Z])\s*([-+]?\d*\.?\d+)")
MOTION_PARAMETERS = frozenset("XYZIJKFSPR")
TEMPLATE_VALUES = {"program_start": (), "program_end": (), "tool_on": ("power", "depth"), "tool_off": ()}
"""The command templates and the values each is rendered with (MachineProfile.render takes exactly these), besides
the profile's [vars]: a profile is checked against this at load, so a placeholder it cannot fill is refused then."""
RS274NGC_CODES = frozenset(
    [f"G{n}" for n in (0, 1, 2, 3, 4, 10, 17, 18, 19, 20, 21, 28, 30, 40, 41, 42, 43, 49, 53, 54, 55, 56, 57, 58, 59,
                       61, 64, 80, 81, 82, 83, 84, 85, 86, 87, 88, 89, 90, 91, 93, 94, 98, 99)]
    + ["G38.2", "G59.1", "G59.2", "G59.3", "G61.1", "G92", "G92.1", "G92.2", "G92.3"]
    + [f"M{n}" for n in (0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 30, 48, 49, 60)])
"""The G and M codes of the NIST RS274/NGC interpreter (version 3, table 4: modal groups), for profiles whose
controller is not a Grbl (a Grbl profile is checked by Grbl 1.1h's own parser rules, fabline.machine.gcode)."""
ANY_GRBL_BUILD = BuildInfo(options="VMR")
"""A Grbl 1.1h with every option that adds a G-code (M7, M56): a profile may need them, a connected build is checked."""


@dataclass(frozen=True)
class Operation:
    """How one operation runs: feed (mm/min), tool power or pen position (S), passes, total depth (mill), and the
    dwell (s) after the tool goes on before it moves: a laser's pierce through the sheet (`G4 P` in the program)."""

    name: str
    feed: float
    power: float
    passes: int
    depth: float = 0.0
    pierce: float = 0.0


@dataclass(frozen=True)
class Cutting:
    """How closed cuts are made as a laser shop makes them ([cutting]; mm): a lead-in of `lead_in` from a pierce
    point at least `pierce_clearance` off every part on the sheet, and tabs `tab_width` wide (the uncut length of the
    toolpath) on each part whose bounding box's longer side is under `tabs_below`, one per `tab_every` of its
    perimeter, at least MIN_TABS (fabline.export.toolpath). Zeros: no lead-ins, no tabs."""

    lead_in: float = 0.0
    pierce_clearance: float = 0.0
    tab_width: float = 1.0
    tabs_below: float = 0.0
    tab_every: float = 250.0


CUTTING_RANGES = {"lead_in": (0.0, 100.0), "pierce_clearance": (0.0, 100.0), "tab_width": (0.01, 100.0),
                  "tabs_below": (0.0, 1e5), "tab_every": (1.0, 1e5)}
"""The range (mm) of each [cutting] key."""
MAIN_OUTPUTS = ("gcode", "dxf")
TOOLPATH_MINIMA = {"kerf": 0.0, "lead_in": 0.0, "pierce_clearance": 0.0, "tabs": 0, "tab_width": 1e-9,
                   "tabs_below": 0.0, "tab_every": 1e-9}
"""The least value of each toolpath option a command line or a job's [export] gives (`tab_width = 0` would leave
no bridge), by ToolpathOptions' names."""


@dataclass(frozen=True, eq=False)
class MachineProfile:
    """A machine and its controller: bed, motion limits, supported words, command templates, operations."""

    name: str
    source: str
    description: str
    controller: str
    mode: str
    kerf: float
    decimals: int
    max_line_length: int
    arcs: bool
    laser_mode: bool            # Grbl laser mode ($32=1): laser off on G0, S on cutting moves, no M5 between paths
    words: frozenset[str]
    program_start: tuple[str, ...]
    program_end: tuple[str, ...]
    tool_on: tuple[str, ...]
    tool_off: tuple[str, ...]
    requires: str
    bed_width: float
    bed_height: float
    rapid_rate: float
    acceleration: float
    junction_deviation: float
    s_min: float
    s_max: float
    operations: dict[str, Operation]
    variables: dict[str, float]
    required_settings: tuple["SettingRequirement", ...] = ()  # [requires]: what the controller's `$$` must say
    cutting: Cutting = Cutting()  # [cutting]: lead-ins, pierce clearance and tabs by part size
    main_output: str = "gcode"    # what the machine is run from: "gcode", or "dxf" (its own CAM; G-code for reference)

    def render(self, field_name: str, **values: float) -> tuple[str, ...]:
        """The command templates of `field_name` (program_start, tool_on ...) with the values TEMPLATE_VALUES
        names for it and the profile's [vars] filled in, numbers fixed-precision."""
        if sorted(values) != sorted(TEMPLATE_VALUES[field_name]):
            raise TypeError(f"{field_name} is rendered with {TEMPLATE_VALUES[field_name]}, not {tuple(values)}")
        return _render(self, getattr(self, field_name), tuple(sorted(values.items())))

    def controller_settings(self) -> dict[int, float]:
        """The Grbl `$N` settings this profile assumes (max rates, acceleration, bed, S range, laser mode), so
        that a simulated controller can be set up as the machine the program was written for."""
        return {11: self.junction_deviation, 110: self.rapid_rate, 111: self.rapid_rate, 120: self.acceleration,
                121: self.acceleration, 130: self.bed_width, 131: self.bed_height, 30: self.s_max, 31: self.s_min,
                32: 1 if self.laser_mode else 0}

    @property
    def grbl(self) -> bool:
        """The controller is a Grbl (its G-code parser and error codes apply)."""
        return self.controller.lower().startswith("grbl")

    def number(self, value: float) -> str:
        """A number in the profile's fixed precision, without a negative zero."""
        return f"{round(value, self.decimals) + 0.0:.{self.decimals}f}"


@dataclass(frozen=True)
class SettingRequirement:
    """One controller setting a profile's programs need: `$number` equal to, at least or at most `value`."""

    number: int
    relation: str  # "=", ">=" or "<="
    value: float

    def met_by(self, actual: float) -> bool:
        """Whether a controller whose `$number` is `actual` meets this."""
        if self.relation == ">=":
            return actual >= self.value - 1e-9
        if self.relation == "<=":
            return actual <= self.value + 1e-9
        return abs(actual - self.value) <= 1e-9

    def __str__(self) -> str:
        return f"${self.number}{self.relation}{self.value:g}"


def required_settings(table: dict, source: str, laser_mode: bool, mode: str) -> tuple[SettingRequirement, ...]:
    """The `[requires]` table (`32 = 1`, `110 = { min = 6000 }`, `130 = { max = 5000 }`) as requirements, with
    laser mode implied by the profile: `$32=1` for a laser-mode profile, `$32=0` for a mill or a plotter (laser
    mode would stop a spindle, or drop a pen servo to S0, on every G0)."""
    found: dict[int, SettingRequirement] = {}
    for key, value in table.items():
        where = f"{source}: requires.{key}"
        if not (isinstance(key, str) and key.isdigit() and int(key) <= 255):
            raise FablineError(f"{where}: must name a Grbl setting by its number, such as 32 or 110")
        number = int(key)
        if isinstance(value, dict) and len(value) == 1 and next(iter(value)) in ("min", "max"):
            relation, value = (">=" if "min" in value else "<="), next(iter(value.values()))
        else:
            relation = "="
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise FablineError(f"{where}: must be a number or {{ min = N }} / {{ max = N }}, got {value!r}")
        found[number] = SettingRequirement(number, relation, float(value))
    implied = 1.0 if laser_mode else 0.0 if mode in ("mill", "plotter") else None
    if implied is not None:
        if 32 in found and found[32] != SettingRequirement(32, "=", implied):
            raise FablineError(f"{source}: requires.32: {found[32]} contradicts laser_mode = {str(laser_mode).lower()}")
        found[32] = SettingRequirement(32, "=", implied)
    return tuple(found[number] for number in sorted(found))


@lru_cache(maxsize=1024)
def _render(profile: MachineProfile, templates: tuple[str, ...], values: tuple) -> tuple[str, ...]:
    """MachineProfile.render, remembered: a sheet renders the same few tool on/off blocks thousands of times."""
    merged = {**profile.variables, **dict(values)}
    return tuple(t.format(**{k: profile.number(v) for k, v in merged.items()}) for t in templates)


def resolve_machine(name_or_path: str) -> Path:
    """Where a profile lives: a path to a TOML file, or a name searched in FABLINE_MACHINE_PATH then built-ins."""
    candidate = Path(name_or_path)
    if candidate.suffix == ".toml" or os.sep in name_or_path:
        if "\0" not in name_or_path and not os.path.lexists(candidate):  # anything else: `read_text` says what it is
            raise FablineError(f"{name_or_path}: machine profile file not found")
        return candidate
    folders = [Path(p) for p in os.environ.get("FABLINE_MACHINE_PATH", "").split(os.pathsep) if p] + [BUILTIN_DIR]
    for folder in folders:
        if (folder / f"{name_or_path}.toml").is_file():
            return folder / f"{name_or_path}.toml"
    raise FablineError(f"unknown machine {name_or_path!r} (available: {', '.join(available_machines())}; "
                       "or give the path of a .toml profile)")


def available_machines() -> list[str]:
    """Names of the profiles found in FABLINE_MACHINE_PATH and the built-in folder."""
    folders = [Path(p) for p in os.environ.get("FABLINE_MACHINE_PATH", "").split(os.pathsep) if p] + [BUILTIN_DIR]
    return sorted({f.stem for folder in folders if folder.is_dir() for f in folder.glob("*.toml")})


def load_machine(name_or_path: str) -> MachineProfile:
    """Load and check a machine profile; a missing or out-of-range setting names the file and the field."""
    path = resolve_machine(name_or_path)
    return _profile_from_dict(_merged_table(path, seen=()), str(path))


MAX_EXTENDS = 16  # profiles in one `extends` chain


def _merged_table(path: Path, seen: tuple[str, ...]) -> dict[str, Any]:
    if len(seen) >= MAX_EXTENDS:
        raise FablineError(f"{path}: extends: more than {MAX_EXTENDS} profiles in one chain")
    table = read_toml(path, " (a TOML profile is UTF-8)")
    parent = table.pop("extends", None)
    if parent is None:
        return table
    if not isinstance(parent, str) or parent in seen:
        raise FablineError(f"{path}: extends: must name another profile, without cycles")
    base = _merged_table(resolve_machine(parent), seen + (parent,))
    return _deep_merge(base, table)


def _deep_merge(base: dict, override: dict) -> dict:
    merged = dict(base)
    for key, value in override.items():
        merged[key] = _deep_merge(merged[key], value) if isinstance(value, dict) and isinstance(merged.get(key), dict) else value
    return merged


class _Fields:
    """Typed, range-checked access to a profile table; every error names the file and the dotted field."""

    def __init__(self, table: dict, source: str):
        self.table, self.source = table, source
        self.read: set[str] = set()

    def get(self, dotted: str) -> Any:
        self.read.add(dotted)
        node: Any = self.table
        for key in dotted.split("."):
            if not isinstance(node, dict) or key not in node:
                raise FablineError(f"{self.source}: {dotted}: missing setting")
            node = node[key]
        return node

    def number(self, dotted: str, low: float, high: float, low_inclusive: bool = True) -> float:
        value = self.get(dotted)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise FablineError(f"{self.source}: {dotted}: must be a number, got {value!r}")
        if not (value >= low if low_inclusive else value > low) or value > high:
            bracket = "[" if low_inclusive else "("
            raise FablineError(f"{self.source}: {dotted}: {value} is out of range {bracket}{low}, {high}]")
        return float(value)

    def integer(self, dotted: str, low: int, high: int) -> int:
        value = self.get(dotted)
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            raise FablineError(f"{self.source}: {dotted}: must be a whole number in [{low}, {high}], got {value!r}")
        return value

    def text(self, dotted: str, default: str | None = None) -> str:
        self.read.add(dotted)
        value = self.get(dotted) if default is None else self.table.get(dotted, default)
        if not isinstance(value, str):
            raise FablineError(f"{self.source}: {dotted}: must be text, got {value!r}")
        return value

    def flag(self, dotted: str, default: bool) -> bool:
        self.read.add(dotted)
        value = self.table.get(dotted, default)
        if not isinstance(value, bool):
            raise FablineError(f"{self.source}: {dotted}: must be true or false, got {value!r}")
        return value

    def check_unknown(self, table: dict | None = None, prefix: str = "") -> None:
        """A setting that was never read is unknown (misspelt, or not one of this kind of profile): name it."""
        for key, value in (self.table if table is None else table).items():
            dotted = f"{prefix}{key}"
            if isinstance(value, dict) and dotted not in self.read:
                self.check_unknown(value, f"{dotted}.")
            elif dotted not in self.read:
                raise FablineError(f"{self.source}: {dotted}: unknown setting (misspelt, or not one of a "
                                   f"{self.table.get('mode')} profile)")

    def lines(self, dotted: str) -> tuple[str, ...]:
        value = self.get(dotted)
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            raise FablineError(f"{self.source}: {dotted}: must be a list of G-code lines")
        return tuple(value)


def _profile_from_dict(table: dict, source: str) -> MachineProfile:
    fields = _Fields(table, source)
    mode = fields.text("mode")
    if mode not in MODES:
        raise FablineError(f"{source}: mode: {mode!r} is not one of {', '.join(MODES)}")
    words = fields.lines("words")
    for word in words:
        if not re.fullmatch(r"[GM]\d+(\.\d+)?", word):
            raise FablineError(f"{source}: words: {word!r} is not a G- or M-word such as G1 or M4")
    s_min = fields.number("power.s_min", 0, 1e6)
    s_max = fields.number("power.s_max", s_min, 1e6, low_inclusive=False)
    operations = {}
    for op in OPERATIONS:
        key = f"operations.{op}"
        operations[op] = Operation(
            name=op,
            feed=fields.number(f"{key}.feed", 0, 1e6, low_inclusive=False),
            power=fields.number(f"{key}.power", s_min, s_max),
            passes=fields.integer(f"{key}.passes", 1, 100),
            depth=fields.number(f"{key}.depth", 0, 1000, low_inclusive=False) if mode == "mill" else 0.0,
            pierce=fields.number(f"{key}.pierce", 0, 60) if "pierce" in _table_at(table, key) else 0.0,
        )
    variables = {}
    if not isinstance(table.get("vars", {}), dict):
        raise FablineError(f"{source}: vars: must be a table of numbers ([vars] name = value)")
    for key, value in table.get("vars", {}).items():
        variables[key] = fields.number(f"vars.{key}", -1e6, 1e6)
    profile = MachineProfile(
        name=fields.text("name"), source=source, description=fields.text("description", ""),
        controller=fields.text("controller", ""), mode=mode,
        kerf=fields.number("kerf", 0, 20), decimals=fields.integer("decimals", 3, 4),
        max_line_length=fields.integer("max_line_length", 40, 256), arcs=fields.flag("arcs", True),
        laser_mode=fields.flag("laser_mode", False),
        words=frozenset(canonical_word(w) for w in words), program_start=fields.lines("program_start"),
        program_end=fields.lines("program_end"), tool_on=fields.lines("tool_on"), tool_off=fields.lines("tool_off"),
        requires="",
        bed_width=fields.number("bed.width", 0, 1e5, low_inclusive=False),
        bed_height=fields.number("bed.height", 0, 1e5, low_inclusive=False),
        rapid_rate=fields.number("motion.rapid_rate", 0, 1e6, low_inclusive=False),
        acceleration=fields.number("motion.acceleration", 0, 1e5, low_inclusive=False),
        junction_deviation=fields.number("motion.junction_deviation", 0, 10),
        s_min=s_min, s_max=s_max, operations=operations, variables=variables, cutting=_cutting(table, fields),
        main_output=fields.text("main_output", "gcode"),
    )
    if profile.main_output not in MAIN_OUTPUTS:
        raise FablineError(f"{source}: main_output: {profile.main_output!r} is not one of {', '.join(MAIN_OUTPUTS)}")
    fields.read.add("requires")
    requires = table.get("requires", {})
    if isinstance(requires, str):  # the free text of older profiles: shown in the program header, not checked
        profile = replace(profile, requires=requires)
    elif isinstance(requires, dict):
        settings = required_settings(requires, source, profile.laser_mode, mode)
        profile = replace(profile, required_settings=settings, requires=", ".join(map(str, settings)))
    else:
        raise FablineError(f"{source}: requires: must be a table of controller settings, such as {{ 32 = 1 }}")
    fields.check_unknown()
    pierced = [op.name for op in operations.values() if op.pierce > 0]
    if pierced and profile.laser_mode:
        raise FablineError(f"{source}: operations.{pierced[0]}.pierce: a dwell in laser mode ($32=1, M4) runs at no "
                           "power; a pierce needs a profile without laser_mode (M3)")
    if pierced and "G4" not in profile.words:
        raise FablineError(f"{source}: operations.{pierced[0]}.pierce: needs G4 (dwell) in the profile's words")
    if profile.laser_mode and mode != "laser":
        raise FablineError(f"{source}: laser_mode: only a laser profile (mode = \"laser\") can use laser mode")
    needed = {"G0", "G1"} | ({"G2", "G3"} if profile.arcs else set())
    missing = sorted(needed - profile.words)
    if missing:
        raise FablineError(f"{source}: words: must include {missing[0]}, which every program needs"
                           + (" (or set arcs = false)" if missing[0] in ("G2", "G3") else ""))
    for word in sorted(profile.words):
        if not _controller_accepts(profile, word):
            raise FablineError(f"{source}: words: {word!r} is not a code the {profile.controller or 'controller'} "
                               "accepts")
    for field_name in TEMPLATE_VALUES:
        _check_templates(profile, field_name)
    return profile


def _table_at(table: dict, dotted: str) -> dict:
    """The sub-table at a dotted path, or {} where there is none."""
    for key in dotted.split("."):
        table = table.get(key, {}) if isinstance(table, dict) else {}
    return table if isinstance(table, dict) else {}


def _cutting(table: dict, fields: _Fields) -> Cutting:
    """The [cutting] table; a key left out takes Cutting's default."""
    given = table.get("cutting", {})
    if not isinstance(given, dict):
        raise FablineError(f"{fields.source}: cutting: must be a table ([cutting] lead_in = 2.0 ...)")
    return Cutting(**{key: fields.number(f"cutting.{key}", *CUTTING_RANGES[key])
                      for key in CUTTING_RANGES if key in given})


def _controller_accepts(profile: MachineProfile, word: str) -> bool:
    """Whether a G or M word (canonical, as in `words`) is a code the profile's controller takes."""
    if not profile.grbl:
        return word in RS274NGC_CODES
    try:
        parse_block(word, ANY_GRBL_BUILD)
    except GcodeError:
        return False
    return True


def _emitted_line_problem(line: str) -> str | None:
    """Why a line fabline writes into programs would act on the controller instead of being G-code, or None:
    more than one line, a `$` system command, a real-time character, a byte outside printable ASCII."""
    for char in line:
        if char in "\r\n":
            return "holds a line break (one G-code line per entry)"
        if char in REALTIME_COMMANDS:
            return f"{char!r} is the Grbl real-time command {REALTIME_COMMANDS[char]}, which acts the moment it arrives"
        if char == "\0":
            return "holds a NUL byte"
        if not " " <= char <= "~" and char != "\t":
            return f"byte 0x{ord(char):02x} is not printable ASCII (Grbl takes 0x80-0xff as real-time commands)"
    if "$" in line:
        return "'$' starts a Grbl system command (settings, homing, reset), which a program must not send"
    return None


def _check_templates(profile: MachineProfile, field_name: str) -> None:
    """Every command template must fill in from the values it is rendered with (TEMPLATE_VALUES) and [vars], be
    one plain G-code line (for a Grbl, one its parser reads) and use only words the profile declares."""
    allowed = sorted(TEMPLATE_VALUES[field_name]) + sorted(profile.variables)
    offer = ", ".join(f"{{{name}}}" for name in allowed) if allowed else "none (a [vars] entry adds one)"
    for template in getattr(profile, field_name):
        where = f"{profile.source}: {field_name}: {template!r}"
        try:
            fields = list(string.Formatter().parse(template))
        except ValueError as exc:
            raise FablineError(f"{where}: {exc} (a placeholder is {{name}}; a literal brace is written {{{{ or }}}}; "
                               f"placeholders allowed here: {offer})") from None
        for _, name, spec, conversion in fields:
            if name is None:
                continue
            if name not in allowed:
                raise FablineError(f"{where}: unknown placeholder {{{name}}} (allowed in {field_name}: {offer})")
            if spec or conversion:
                raise FablineError(f"{where}: placeholder {{{name}}} takes no format or conversion (the number is "
                                   f"written in the profile's decimals); write {{{name}}}")
        values = dict.fromkeys(TEMPLATE_VALUES[field_name], 0.0)
        line = _render(profile, (template,), tuple(sorted(values.items())))[0]
        problem = _emitted_line_problem(line)
        if problem is None and profile.grbl:
            try:
                parse_block(compact_line(line), ANY_GRBL_BUILD)
            except GcodeError as exc:
                problem = f"Grbl refuses it: {explain_error(exc.code)}"
        if problem is not None:
            raise FablineError(f"{where}: {problem}")
        for word in unsupported_words(line, profile.words):
            raise FablineError(f"{profile.source}: {field_name}: {word} is not in the profile's words")


def canonical_word(word: str) -> str:
    """G01 -> G1, M04 -> M4, G91.1 stays."""
    letter, number = word[0], word[1:]
    value = float(number)
    return f"{letter}{int(value)}" if value == int(value) else f"{letter}{value:g}"


def strip_comment(line: str) -> str:
    """The code part of a G-code line without `;` and `( )` comments."""
    return re.sub(r"\([^)]*\)", "", line.split(";", 1)[0]).strip()


def unsupported_words(line: str, words: frozenset[str]) -> list[str]:
    """The G/M-words of a line that the controller does not accept, and parameter letters it does not know."""
    bad = []
    for letter, number in WORD_PATTERN.findall(strip_comment(line).upper()):
        if letter in "GM":
            word = canonical_word(letter + number)
            if word not in words:
                bad.append(word)
        elif letter not in MOTION_PARAMETERS:
            bad.append(letter + number)
    return bad
