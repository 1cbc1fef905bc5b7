"""pyserial URL handler for `sim://NAME?option=value&...`: a port wired to an in-process GRBL simulator.

Simulators live in a per-process registry by NAME, so a reconnect after a dropped connection reaches
the same controller, as a real one outlives its USB cable. Options (used when NAME is first opened):
time_scale, line_time (firmware seconds per line), log (executed-line log path), machine (a machine profile's name:
a URL names no file to read, `check_port` refuses a path): the controller is set up as that machine, its `$N` settings as the profile assumes them, e.g. `$32=1` for
a laser), settings (`$N` values as `110:12000,120:800`, over the machine's), drop_at, corrupt_at (comma-separated byte offsets),
error_line, error_code, alarm_line, alarm_code, stall_at, stall_seconds; and the build: firmware (grbl, grblhal or
fluidnc; by default the NAME if it is one of these, else grbl) sets a stock build of that firmware
(fabline.machine.build STOCK_BUILDS: Grbl 1.1h, grblHAL with 1024 RX bytes, FluidNC), unless build_options (the
`$I` option letters, e.g. `VN` for `Ln:` in status reports), planner_blocks or rx_buffer say otherwise.
"""

from __future__ import annotations

import re
import threading
import urllib.parse

from serial.serialutil import PortNotOpenError, SerialBase, SerialException, Timeout

from fabline.link.simulator import ConnectionDropped, Faults, GrblSimulator, check_time_scale
from fabline.machine.build import STOCK_BUILDS, BuildInfo

SIM_OPTIONS = ("time_scale", "line_time", "log", "machine", "settings", "drop_at", "corrupt_at", "error_line",
               "error_code", "alarm_line", "alarm_code", "stall_at", "stall_seconds", "build_options", "planner_blocks",
               "rx_buffer", "firmware")
"""The options a sim:// URL takes (the module's docstring says what each does)."""
_SIMULATORS: dict[str, GrblSimulator] = {}
_REGISTRY_LOCK = threading.Lock()


def get_simulator(name: str) -> GrblSimulator | None:
    """The simulator `sim://name` reaches, if one exists."""
    with _REGISTRY_LOCK:
        return _SIMULATORS.get(name)


def close_simulator(name: str) -> None:
    """Stop and forget the simulator `sim://name`."""
    with _REGISTRY_LOCK:
        simulator = _SIMULATORS.pop(name, None)
    if simulator is not None:
        simulator.close()


NUMBER_OPTIONS = {  # option: (type, lowest, highest) a sim:// URL may give it
    "line_time": (float, 0.0, 60.0), "stall_seconds": (float, 0.0, 3600.0),
    "error_line": (int, 0, 10**9), "alarm_line": (int, 0, 10**9), "stall_at": (int, 0, 10**9),
    "error_code": (int, 1, 255), "alarm_code": (int, 1, 255),
    "planner_blocks": (int, 1, 255), "rx_buffer": (int, 16, 65535),
}


def sim_number(key: str, text: str) -> float | int:
    """A sim:// number option, in its range (NaN, infinities and 400-digit integers are not numbers of any run);
    ValueError saying the range."""
    kind, lowest, highest = NUMBER_OPTIONS[key]
    try:
        value = kind(text)
    except (ValueError, OverflowError):
        value = None
    if value is None or not lowest <= value <= highest:  # NaN fails both comparisons
        what = "an integer" if kind is int else "a number"
        raise ValueError(f"{key}={text!r}: must be {what} from {lowest:g} to {highest:g}")
    return value


def simulator_from_options(query: str) -> GrblSimulator:
    """A new simulator configured by a `key=value&...` string (the options of a sim:// URL); ValueError if bad."""
    options = {key: values[-1] for key, values in urllib.parse.parse_qs(query).items()}

    def number(key: str, kind, default=None):
        if key not in options:
            return default
        return check_time_scale(float(options.pop(key))) if key == "time_scale" else sim_number(key, options.pop(key))

    def offsets(key: str) -> list[int]:
        return [int(v) for v in options.pop(key, "").split(",") if v]

    faults = Faults(drop_at=offsets("drop_at"), corrupt_at=offsets("corrupt_at"),
                    error_line=number("error_line", int), error_code=number("error_code", int, 20),
                    alarm_line=number("alarm_line", int), alarm_code=number("alarm_code", int, 1),
                    stall_at=number("stall_at", int), stall_seconds=number("stall_seconds", float, 0.0))
    time_scale = number("time_scale", float, 1.0)
    line_time = number("line_time", float, 0.0)
    log = options.pop("log", None)
    firmware = options.pop("firmware", "grbl")
    if firmware not in STOCK_BUILDS:
        raise ValueError(f"firmware must be one of {', '.join(STOCK_BUILDS)}, not {firmware!r}")
    stock = STOCK_BUILDS[firmware]
    build = BuildInfo(version=stock.version, firmware=firmware, options=options.pop("build_options", stock.options),
                      planner_blocks=number("planner_blocks", int, stock.planner_blocks),
                      rx_buffer=number("rx_buffer", int, stock.rx_buffer))
    if not re.fullmatch(r"[A-Z0-9*+]*", build.options):
        raise ValueError(f"build_options must be option letters such as VN, not {build.options!r}")
    settings = {}
    if "machine" in options:
        from fabline.machine import load_machine

        settings.update(load_machine(options.pop("machine")).controller_settings())
    for pair in options.pop("settings", "").split(","):
        if pair:
            key, _, value = pair.partition(":")
            settings[int(key)] = float(value)
    if options:
        raise ValueError(f"unknown simulator option(s) {sorted(options)}")
    return GrblSimulator(time_scale=time_scale, executed_log=log, faults=faults, settings=settings, line_time=line_time,
                         build=build)


def _simulator_from_url(url: str) -> GrblSimulator:
    parts = urllib.parse.urlsplit(url)
    if parts.scheme != "sim":
        raise SerialException(f"expected sim://NAME, got {url!r}")
    name = parts.netloc or "grbl"
    with _REGISTRY_LOCK:
        if name not in _SIMULATORS:
            try:
                query = parts.query
                if name in STOCK_BUILDS and "firmware=" not in query:
                    query = f"{query}&firmware={name}" if query else f"firmware={name}"
                _SIMULATORS[name] = simulator_from_options(query)
            except ValueError as exc:
                raise SerialException(f"bad sim:// option in {url!r}: {exc}") from None
        return _SIMULATORS[name]


class Serial(SerialBase):
    """A pyserial port whose far end is a GrblSimulator in this process."""

    def open(self) -> None:
        """Connect to (or create) the named simulator."""
        if self._port is None:
            raise SerialException("port must be configured before it can be used")
        if self.is_open:
            raise SerialException("port is already open")
        self._simulator = _simulator_from_url(self.portstr)
        self._connection = self._simulator.attach()
        self.is_open = True

    def close(self) -> None:
        """Disconnect; the simulator keeps running."""
        if self.is_open:
            self._simulator.detach(self._connection)
            self.is_open = False

    def _check(self) -> None:
        if not self.is_open:
            raise PortNotOpenError()
        if self._simulator.connection != self._connection or not self._simulator._connected:
            raise SerialException("device disconnected (connection to the simulator was dropped)")

    @property
    def machine_time(self) -> float:
        """The controller's own clock: seconds of machine time its planner has run (moving or dwelling) since it was
        made, whatever wall time the process took. A side channel of the simulated port, not part of the protocol."""
        return self._simulator.machine_time

    def _reconfigure_port(self, *args, **kwargs) -> None:
        """Nothing to configure on a simulated line."""

    @property
    def in_waiting(self) -> int:
        """Bytes the simulator sent that were not read yet."""
        self._check()
        return self._simulator.pending_output()

    def read(self, size: int = 1) -> bytes:
        """Read up to `size` bytes, honouring the port timeout."""
        self._check()
        data = bytearray()
        timeout = Timeout(self._timeout)
        while len(data) < size:
            chunk = self._simulator.read(size - len(data), None if timeout.expired() else min(timeout.time_left(), 0.05) if self._timeout is not None else 0.05)
            self._check()
            data += chunk
            if timeout.expired():
                break
        return bytes(data)

    def write(self, data) -> int:
        """Deliver bytes to the simulator; an injected drop raises SerialException like a vanished device."""
        self._check()
        try:
            self._simulator.receive(bytes(data))
        except ConnectionDropped as exc:
            raise SerialException(f"device disconnected: {exc}") from None
        return len(data)

    def reset_input_buffer(self) -> None:
        """Discard what the simulator sent so far."""
        self._check()
        while self._simulator.read(4096, None):
            pass

    def reset_output_buffer(self) -> None:
        """Nothing is buffered on the way out."""

    def flush(self) -> None:
        """Writes are delivered at once."""

    @property
    def cts(self) -> bool:
        return True

    @property
    def dsr(self) -> bool:
        return True

    @property
    def ri(self) -> bool:
        return False

    @property
    def cd(self) -> bool:
        return True

    def _update_rts_state(self) -> None:
        """No modem control lines on a simulated port."""

    def _update_dtr_state(self) -> None:
        """No modem control lines on a simulated port."""

    def _update_break_state(self) -> None:
        """No modem control lines on a simulated port."""


