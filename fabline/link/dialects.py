"""Controller dialects: what differs between the firmware families fabline streams to (Grbl 1.1, grblHAL, FluidNC).

All three speak Grbl 1.1's line protocol (ok/error:N, `<...>` status reports, real-time bytes, `$I`, `$$`, `$G`,
`$C`, `$X`), so one streamer drives them; a dialect says only what differs: how its banner reads, where its build
and settings are reported, and how a setting the compatibility check asks for is changed. Compatibility is checked
in Grbl's setting numbers (`$32` laser mode, `$110..` max rates, `$130..` travel): each dialect reads its controller
into that common form. A machine profile's `controller = "Grbl 1.1"` names the G-code its programs are written in;
all three dialects run it, so a profile drives any of them whose settings meet its `[requires]` (a grbl-laser profile
runs on Grbl, grblHAL or FluidNC with laser mode on).

- Grbl 1.1 (gnea/grbl report.c): banner `Grbl 1.1h ['$' for help]`; `$I` `[OPT:V,15,128]`; `$$` every setting.
- grblHAL (grblHAL/core report.c): banner `GrblHAL 1.1f ['$' or '$HELP' for help]` (`Grbl 1.1f ['$' for help]`
  when built with COMPATIBILITY_LEVEL > 0, then `[FIRMWARE:grblHAL]` in `$I` tells it); `$I`
  `[OPT:VNMSL,100,1024,3,0]` (blocks, RX bytes, axes, tools); `$$` Grbl's numbers ($32 is its mode: 1 laser).
- FluidNC (bdring/FluidNC Report.cpp, SettingsDefinitions.cpp): banner `Grbl 3.9 [FluidNC v3.9.5 (noradio) '$' for
  help]`; `$I` has no buffer sizes; `$$` only proxies of its YAML config ($10, $13, $20-$22, $100-$132: no $11,
  $30-$32); the config itself comes from `$CD` ($Config/Dump); laser mode is a `Laser:` spindle in it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from fabline.machine.build import STOCK_BUILDS, BuildInfo
from fabline.machine.codes import ALARM_CODES, ERROR_CODES

_AXES = "xyz"
_FLUIDNC_AXIS_KEYS = {100: "steps_per_mm", 110: "max_rate_mm_per_min", 120: "acceleration_mm_per_sec2",
                      130: "max_travel_mm"}
"""FluidNC config keys under axes/<axis>/ behind Grbl's per-axis settings (SettingsDefinitions.cpp FLOAT_PROXY)."""


@dataclass(frozen=True)
class Dialect:
    """One firmware family: its banner, the versions fabline streams to, and how its settings are read and set."""

    name: str
    label: str
    banner: re.Pattern
    version_prefix: str
    """The `$I` version fabline accepts (Grbl and grblHAL: 1.1; FluidNC numbers its own releases)."""
    config_command: bytes | None = None
    """The command that prints the YAML configuration the numbered settings stand for (FluidNC: `$CD`)."""
    changes: dict[int, str] = field(default_factory=dict)
    """How a numbered setting is changed where it is not by `$N=value`."""
    alarms: dict[int, str] = field(default_factory=dict)
    """Its alarm codes beyond Grbl 1.1's 1-9 (which all three share)."""
    errors: dict[int, str] = field(default_factory=dict)
    """Its error codes beyond Grbl 1.1's (1-38, which all three share)."""

    @property
    def stock_build(self) -> BuildInfo:
        return STOCK_BUILDS[self.name]

    def change(self, number: int, value: float) -> str:
        """The fix for a setting the controller has wrong, in this dialect's terms."""
        if number in self.changes:
            return self.changes[number].format(value=value, kind="a Laser:" if value else "a PWM: (not Laser:)")
        if self.name == "fluidnc" and number // 10 in (10, 11, 12, 13) and number % 10 < 3:
            return (f"set axes/{_AXES[number % 10]}/{_FLUIDNC_AXIS_KEYS[number // 10 * 10]}: {value:g} in the "
                    "FluidNC config (config.yaml; $CD shows it)")
        return f"send ${number}={value:g} to the controller"

    def explain_alarm(self, code: int) -> str:
        """`ALARM:N` in words, in this dialect's numbering."""
        return f"ALARM:{code} ({ALARM_CODES.get(code) or self.alarms.get(code, f'unknown {self.label} alarm code')})"

    def explain_error(self, code: int) -> str:
        """`error:N` in words, in this dialect's numbering."""
        return f"error:{code} ({ERROR_CODES.get(code) or self.errors.get(code, f'unknown {self.label} error code')})"

    def read_settings(self, command) -> dict[int, float]:
        """The controller's settings in Grbl's numbers, read with `command(line, every_line)` (Connection.command)."""
        settings = {}
        for text in command(b"$$\n", False):
            key, _, value = text.partition("=")
            try:
                settings[int(key[1:])] = float(value)
            except ValueError:
                continue
        if self.config_command is not None:
            settings.update(fluidnc_settings(read_config(command(self.config_command, True))))
        return settings


def read_config(lines: list[str]) -> dict[str, str]:
    """FluidNC's config dump (Configuration/Generator.cpp: one `key: value` per line, two spaces of indent per
    section level, a section a bare `key:`) as `section/key` paths -> values (sections -> "")."""
    paths: dict[str, str] = {}
    stack: list[str] = []
    for line in lines:
        text = line.split("#", 1)[0].rstrip()
        if not text.strip() or ":" not in text:
            continue
        depth = (len(text) - len(text.lstrip(" "))) // 2
        key, _, value = text.strip().partition(":")
        del stack[depth:]
        stack.append(key.strip())
        paths["/".join(stack)] = value.strip()
    return paths


def fluidnc_settings(config: dict[str, str]) -> dict[int, float]:
    """Grbl's numbers from a FluidNC config: $32 = 1 with a `Laser:` spindle, else 0; $20 from soft limits; $11
    and $12 (junction deviation, arc tolerance); travel, rate, acceleration and resolution per axis."""
    settings: dict[int, float] = {32: 1.0 if "Laser" in config else 0.0}
    for index, axis in enumerate(_AXES):
        for number, key in _FLUIDNC_AXIS_KEYS.items():
            value = config.get(f"axes/{axis}/{key}")
            if value:
                settings[number + index] = float(value)
    for number, key in ((11, "junction_deviation_mm"), (12, "arc_tolerance_mm")):  # MachineConfig.cpp items
        if config.get(key):
            settings[number] = float(config[key])
    soft = config.get("axes/x/soft_limits")
    if soft is not None:
        settings[20] = 1.0 if soft.lower() == "true" else 0.0
    return settings


GRBL = Dialect("grbl", "Grbl 1.1", re.compile(r"^Grbl (1\.\S+) \['\$' for help\]$"), "1.1")
GRBLHAL = Dialect("grblhal", "grblHAL", re.compile(r"^GrblHAL (\S+) \['\$' or '\$HELP' for help\]$"), "1.1",
                  changes={32: "send $32={value:g} to the controller (grblHAL's mode of operation: 1 is laser)"},
                  alarms={10: "EStop asserted; clear and reset", 11: "homing required; home ($H) to continue",
                          12: "limit switch engaged; clear before continuing",
                          13: "probe protection triggered; clear before continuing",
                          14: "spindle at speed timeout; clear before continuing",
                          15: "homing fail: second limit switch of an auto-squared axis not found",
                          16: "power on self test failed", 17: "motor fault", 18: "homing fail: bad configuration"},
                  errors={39: "value out of range", 40: "g-code command not allowed when tool change is pending",
                          41: "spindle not running when motion commanded in CSS or spindle sync mode",
                          42: "plane must be ZX for threading", 43: "max. feed rate exceeded", 44: "RPM out of range",
                          45: "only homing is allowed when a limit switch is engaged", 46: "home machine to continue",
                          47: "ATC: current tool is not set", 48: "value word conflict",
                          49: "power on self test failed; a hard reset is required", 50: "emergency stop active",
                          51: "motor fault", 52: "setting value is out of range", 53: "setting is not available",
                          54: "retract position is less than drill depth",
                          55: "attempt to home two auto squared axes at the same time",
                          56: "coordinate system is locked"})
"""grblHAL/core alarms.c (alarm_detail) and errors.c (status_detail), numbered by alarm_code_t and status_code_t."""
FLUIDNC = Dialect("fluidnc", "FluidNC", re.compile(r"^Grbl (\S+) \[FluidNC (\S+).*'\$' for help\]$"), "",
                  config_command=b"$CD\n",
                  changes={32: "make the spindle of the FluidNC config (config.yaml; $CD shows it) {kind} spindle",
                           20: "set axes/x/soft_limits in the FluidNC config (config.yaml)"},
                  alarms={10: "spindle control", 11: "control pin initially on", 12: "ambiguous switch",
                          13: "hard stop", 14: "unhomed", 15: "init"})
"""bdring/FluidNC Protocol.h (ExecAlarm) and Protocol.cpp (AlarmNames)."""
DIALECTS = {dialect.name: dialect for dialect in (GRBL, GRBLHAL, FLUIDNC)}
"""Every dialect by name (the names of fabline.machine.build.STOCK_BUILDS)."""


def recognise(banner: str) -> Dialect | None:
    """The dialect whose banner `banner` is (FluidNC's starts `Grbl` too: it is tried first); None if none."""
    return next((dialect for dialect in (FLUIDNC, GRBLHAL, GRBL) if dialect.banner.match(banner)), None)
