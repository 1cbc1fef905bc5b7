"""The firmware's build and settings: the banner, `$` system commands (`$$`, `$I`, `$N`, `$#`, `$C`, `$X`,
`$J=`, `$RST=`) and the EEPROM settings they read and store; as Grbl 1.1h, grblHAL or FluidNC (the build's firmware).

grblHAL answers as grblHAL/core report.c (its banner, the extended `$I`) with its default `$10=511` (`Bf:` and
`Ln:` on); FluidNC as bdring/FluidNC Report.cpp and ProcessSettings.cpp: `$$` lists only the numbered proxies of
its config (SettingsDefinitions.cpp), `$CD` dumps the config as YAML (Configuration/Generator.cpp: two spaces a
level), with a `Laser:` spindle when laser mode (`$32`) is on. Inside, every setting keeps Grbl's number; FluidNC
refuses `$N=` but for $10 (error:3 here: its exact code for a read-only proxy is not modelled)."""

from __future__ import annotations

from dataclasses import replace

from fabline.link.simulator.planner import Pending
from fabline.machine.gcode import GcodeError, execute

VERSION = "1.1h"
BANNER = f"Grbl {VERSION} ['$' for help]"
HELP = "[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]"

_INT_SETTINGS = {0, 1, 2, 3, 4, 5, 6, 10, 13, 20, 21, 22, 23, 26, 30, 31, 32}
DEFAULT_SETTINGS: dict[int, float] = {
    0: 10, 1: 25, 2: 0, 3: 0, 4: 0, 5: 0, 6: 0, 10: 1, 11: 0.010, 12: 0.002, 13: 0, 20: 0, 21: 0, 22: 0,
    23: 0, 24: 25.0, 25: 500.0, 26: 250, 27: 1.0, 30: 1000, 31: 0, 32: 0,
    100: 250.0, 101: 250.0, 102: 250.0, 110: 500.0, 111: 500.0, 112: 500.0,
    120: 10.0, 121: 10.0, 122: 10.0, 130: 200.0, 131: 200.0, 132: 200.0,
}


GRBLHAL_SETTINGS = {10: 511}
"""grblHAL's defaults where they differ from Grbl's (config.h: every status report field on up to WCO sync)."""
FLUIDNC_NUMBERED = (10, 13, 20, 21, 22, 100, 101, 102, 110, 111, 112, 120, 121, 122, 130, 131, 132)
"""The numbered settings FluidNC's `$$` lists: $10 (Report/Status), $13 (Report/Inches) and the proxies."""
_FLUIDNC_AXIS = (("steps_per_mm", 100), ("max_rate_mm_per_min", 110), ("acceleration_mm_per_sec2", 120),
                 ("max_travel_mm", 130))


def default_settings(firmware: str) -> dict[int, float]:
    """A fresh controller's settings in Grbl's numbers, for `firmware`."""
    return {**DEFAULT_SETTINGS, **(GRBLHAL_SETTINGS if firmware == "grblhal" else {})}


def banner(build) -> str:
    """The line the firmware of `build` greets with after a reset."""
    if build.firmware == "grblhal":
        return f"GrblHAL {build.version.rsplit('.', 1)[0]} ['$' or '$HELP' for help]"
    if build.firmware == "fluidnc":
        grbl, _, git = build.version.partition(" FluidNC ")
        return f"Grbl {grbl} [FluidNC {git} (noradio) '$' for help]"
    return BANNER


class Firmware:
    """GrblSimulator's system commands: answers `$` lines from its settings, build and state."""

    def _system_command(self, line: str) -> None:
        status = self._system(line)
        if status is not None:
            self._say("ok" if status == 0 else f"error:{status}")

    def _system(self, line: str) -> int | None:
        if line == "$":
            self._say(HELP)
            return 0
        if line.startswith("$J="):
            if self.state not in ("Idle", "Jog"):
                return 8
            return self._jog(line[3:])
        if self.build.firmware == "fluidnc" and line in ("$CD", "$CONFIG/DUMP"):
            for text in self._config_dump():
                self._say(text)
            return 0
        if line in ("$$", "$G", "$C", "$X"):
            return self._query_command(line[1])
        if line[1:2] in "$GCXJ":
            return 3
        if self.state not in ("Idle", "Alarm"):
            return 8
        if line == "$#":
            for name in ("G54", "G55", "G56", "G57", "G58", "G59", "G28", "G30", "G92"):
                self._say(f"[{name}:0.000,0.000,0.000]")
            self._say("[TLO:0.000]")
            self._say("[PRB:0.000,0.000,0.000:0]")
            return 0
        if line == "$I":
            for text in self.build.lines():
                self._say(text)
            return 0
        if line == "$N":
            self._say("$N0=")
            self._say("$N1=")
            return 0
        if line == "$H":
            return 5 if not self.settings[22] else 3
        if line.startswith("$RST="):
            if line not in ("$RST=$", "$RST=#", "$RST=*"):
                return 3
            if line != "$RST=#":
                self.settings = default_settings(self.build.firmware)
            self._say("[MSG:Restoring defaults]")
            self._say("ok")
            self._soft_reset()
            return None
        return self._store_setting(line[1:])

    def _query_command(self, letter: str) -> int:
        if letter == "$":
            if self.state in ("Run", "Hold"):
                return 8
            fluidnc = self.build.firmware == "fluidnc"
            for key, value in self.settings.items():
                if fluidnc and key not in FLUIDNC_NUMBERED:
                    continue
                self._say(f"${key}={value:.0f}" if key in _INT_SETTINGS else f"${key}={value:.3f}")
        elif letter == "G":
            self._say(self.modal.report())
        elif letter == "C":
            if self.state == "Check":
                self._reset_runtime()
                self.state = "Idle"
                self._say("[MSG:Disabled]")
                self._say("ok")
                self._say(banner(self.build))
                return None
            if self.state != "Idle":
                return 8
            self.state = "Check"
            self._say("[MSG:Enabled]")
        elif letter == "X" and self.state == "Alarm":
            self._say("[MSG:Caution: Unlocked]")
            self.state = "Idle"
        return 0

    def _store_setting(self, text: str) -> int:
        key, equals, value = text.partition("=")
        try:
            number = int(key)
        except ValueError:
            return 3 if key.isalpha() else 2
        if not equals:
            return 3
        try:
            parsed = float(value)
        except ValueError:
            return 2
        if parsed < 0:
            return 4
        if number not in self.settings or (self.build.firmware == "fluidnc" and number != 10):
            return 3
        self.settings[number] = float(int(parsed)) if number in _INT_SETTINGS else parsed
        return 0

    def _config_dump(self) -> list[str]:
        """FluidNC's `$CD`: the config its numbered settings stand for, as YAML."""
        settings = self.settings
        lines = ["board: None", "name: fabline simulator", "planner_blocks: 16",
                 f"junction_deviation_mm: {settings[11]:.3f}", f"arc_tolerance_mm: {settings[12]:.3f}", "axes:"]
        for index, axis in enumerate("xyz"):
            lines.append(f"  {axis}:")
            lines += [f"    {key}: {settings[number + index]:.3f}" for key, number in _FLUIDNC_AXIS]
            lines.append(f"    soft_limits: {'true' if settings[20] else 'false'}")
        lines += ["Laser:" if settings[32] == 1 else "PWM:", "  pwm_hz: 5000", "  output_pin: gpio.2",
                  f"  speed_map: {settings[31]:.0f}=0.000% {settings[30]:.0f}=100.000%"]
        return lines

    def _jog(self, text: str) -> int:
        try:
            block = execute(text, replace(self.modal, motion="G1", feed=0.0), self.position)
        except GcodeError:
            return 16
        if block.segment is None or "F" not in text:
            return 16
        self._queue(Pending("$J=" + text, block, sync=False), jog=True)
        return 0
