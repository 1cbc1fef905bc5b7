"""GrblSimulator, the controller composed of its protocol, status report, firmware, planner and clock; `timed_run`."""

from __future__ import annotations

import threading
from collections import deque
from pathlib import Path

from fabline.link.simulator.clock import Clock, check_time_scale
from fabline.link.simulator.faults import Faults
from fabline.link.simulator.firmware import DEFAULT_SETTINGS, Firmware, banner, default_settings
from fabline.link.simulator.planner import Pending, Planned, Planner
from fabline.link.simulator.protocol import LineProtocol
from fabline.link.simulator.status import StatusReport
from fabline.machine.build import STOCK_BUILD, BuildInfo
from fabline.machine.gcode import ModalState


class GrblSimulator(LineProtocol, StatusReport, Firmware, Planner, Clock):
    """A GRBL 1.1h controller in a background thread; `time_scale` > 1 makes motion run faster.

    `line_time` is the firmware's time (real seconds, not scaled) to parse and plan one line before it
    answers and reads the next: an 8-bit Grbl needs a few milliseconds, 0 makes the controller instant.
    `threaded=False` runs no main loop: the caller drives machine time with `step` (deterministic timing).
    """

    def __init__(self, *, time_scale: float = 1.0, executed_log: str | Path | None = None,
                 faults: Faults | None = None, tick: float = 0.001, settings: dict[int, float] | None = None,
                 line_time: float = 0.0, build: BuildInfo = STOCK_BUILD, threaded: bool = True):
        self.build = build
        self.time_scale = check_time_scale(time_scale)
        self.line_time = line_time
        self.faults = faults or Faults()
        unknown = sorted(set(settings or {}) - set(DEFAULT_SETTINGS))
        if unknown:
            raise ValueError(f"unknown Grbl setting(s) {', '.join(f'${n}' for n in unknown)}")
        self.settings = {**default_settings(build.firmware), **(settings or {})}
        self.position: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self.received = 0
        self.connection = 0
        self._log = open(executed_log, "a", encoding="ascii") if executed_log else None
        self._lock = threading.RLock()
        self._output = bytearray()
        self._output_ready = threading.Condition(self._lock)
        self._connected = False
        self._tick = tick
        self._input_arrived = threading.Event()
        self._stall_until = 0.0
        self._stopping = False
        self.completed: list[tuple[str, float]] | None = None
        """When a list: (line, machine time) appended as each line completes (see `step`)."""
        self.machine_time = 0.0
        """Seconds of machine time the controller has run (moving or dwelling) since it was created."""
        self._power_on()
        self._thread = threading.Thread(target=self._run, name="grbl-sim", daemon=True) if threaded else None
        if self._thread is not None:
            self._thread.start()

    def close(self) -> None:
        """Stop the controller thread and close the executed-line log."""
        self._stopping = True
        if self._thread is not None:
            self._thread.join(timeout=2)
        if self._log:
            self._log.close()
            self._log = None

    def _power_on(self) -> None:
        self._rx = bytearray()
        self.overflowed = 0
        self.state = "Idle"
        self._critical = False
        self._reset_runtime()
        self._say(banner(self.build))

    def _reset_runtime(self) -> None:
        """What a reset clears: input, partial line, planner, parser state, hold; position is kept."""
        self._rx.clear()
        self._line = bytearray()
        self._line_overflow = False
        self._comment = False
        self._pending: Pending | None = None
        self._parsing: tuple[str, bool] | None = None  # a complete line the firmware is still parsing ...
        self._parsed_at = 0.0                           # ... until this time.monotonic()
        self.planner: deque[Planned] = deque()
        self._moves: deque[Planned] = deque()  # the motion blocks of the planner, in order
        self._optimal = 0  # Grbl's block_buffer_planned: index in _moves before which the plan cannot improve
        self.modal = ModalState()
        self._parse_position = self.position
        self._hold = None
        self._hold_stopped_motion = False  # a reset aborts a cycle (ALARM:3) only if the hold stopped a motion
        self._speed = 0.0
        self._idle_lock = 0.0  # machine seconds of the $1 stepper lock still to wait (see Clock._go_idle)
        self._wco_counter = 0
        self._ovr_counter = 0

    def _soft_reset(self) -> None:
        lost = self.state in ("Run", "Jog") or (self.state == "Hold" and self._hold_stopped_motion)
        was_alarm = self.state == "Alarm"
        self._critical = False
        self._reset_runtime()
        if lost:
            self._say("ALARM:3")
        self._say(banner(self.build))
        if lost or was_alarm:
            self.state = "Alarm"
            self._say("[MSG:'$H'|'$X' to unlock]")
        else:
            self.state = "Idle"

    def _alarm(self, code: int) -> None:
        """A critical alarm (limit): stop at once, flush everything, wait for a reset."""
        self._rx.clear()
        self._line = bytearray()
        self.planner.clear()
        self._moves.clear()
        self._optimal = 0
        self._pending = None
        self._parsing = None
        self._hold = None
        self.state = "Alarm"
        self._critical = True
        self._say(f"ALARM:{code}")
        self._say("[MSG:Reset to continue]")


def timed_run(lines: list[str], *, settings: dict[int, float] | None = None,
              build: BuildInfo = STOCK_BUILD) -> list[tuple[str, float]]:
    """Run program `lines` in machine time on a controller whose host keeps its receive buffer full (a line is
    sent as soon as it fits): (line as executed, machine time in s when it completed) for every line, in order.
    Deterministic: no wall clock, no thread. A line the controller refuses is a ValueError."""
    simulator = GrblSimulator(settings=settings, build=build, threaded=False)
    simulator.completed = []
    simulator.attach()
    waiting = deque(line.encode("ascii") + b"\n" for line in lines)
    while waiting or simulator.planner or simulator._pending is not None or simulator._rx:
        while waiting and len(waiting[0]) <= build.rx_buffer - len(simulator._rx):
            simulator.receive(waiting.popleft())
        progress = (len(simulator.completed), len(simulator._rx), simulator.machine_time)
        simulator.step()
        answers = simulator.read(1 << 20, None).decode("ascii")
        if "error" in answers or "ALARM" in answers:
            raise ValueError(f"the controller refused a line: {answers.strip()}")
        if progress == (len(simulator.completed), len(simulator._rx), simulator.machine_time):
            raise ValueError(f"the controller stopped: state {simulator.state}")
    simulator.close()
    return simulator.completed
