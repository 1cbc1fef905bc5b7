"""Machine time: the main loop that turns wall time (times `time_scale`) into motion, the blocks' trapezoidal
speed profiles, feed hold's deceleration, and line completion."""

from __future__ import annotations

import math
import time

from fabline.link.simulator.planner import Planned

TIME_SCALE_MAX = 1e6
"""The fastest a simulator runs (machine seconds per real second): at 1e6 one 1 ms tick is 17 min of machine time,
faster than any job needs; beyond it the tick arithmetic loses the planner's millisecond steps (1e308 overflows)."""


def check_time_scale(value: float) -> float:
    """`value` if it is a usable time scale (finite, above 0, at most TIME_SCALE_MAX), else ValueError saying so."""
    if not 0 < value <= TIME_SCALE_MAX:  # also refuses NaN
        raise ValueError(f"time_scale must be above 0 and at most {TIME_SCALE_MAX:g}, not {value:g}")
    return value


class Clock:
    """GrblSimulator's execution in time: runs the planner's first block, in a thread or by `step`."""

    def _run(self) -> None:
        last = time.monotonic()
        while not self._stopping:
            wait = self._tick if self._parsing is None else min(self._tick, max(0.0, self._parsed_at - time.monotonic()))
            self._input_arrived.wait(wait)  # GRBL's main loop picks a line up as soon as it is complete
            self._input_arrived.clear()
            now = time.monotonic()
            with self._lock:
                if now < self._stall_until:
                    last = now
                    continue
                self._advance((now - last) * self.time_scale)
                if not self._idle_lock:
                    self._process_input()
            last = now

    def _advance(self, dt: float, single: bool = False) -> float:
        """Run the planner for `dt` seconds of machine time (with `single`, stop once a block completes: `dt` may
        then be infinite); returns the machine time used."""
        spent, clock = 0.0, self.machine_time
        while not self._critical:
            block = self.planner[0] if self.planner else None
            if block is not None and block.segment is None and block.dwell <= 0:
                self.machine_time = clock + spent
                self._complete()
                continue
            if self._idle_lock:
                used = min(dt - spent, self._idle_lock)
                spent += used
                self._idle_lock -= used
                if self._idle_lock > 0:
                    break
                self._idle_lock = 0.0
                if self._hold == "decelerating":  # the hold is complete once the steppers are idle
                    self._hold = "complete"
                continue
            if block is None or self._hold == "complete" or dt - spent <= 0:
                break
            if block.segment is None:
                used = min(dt - spent, block.dwell)
                block.dwell -= used
                spent += used
                if single and block.dwell <= 0:
                    self.machine_time = clock + spent
                    self._complete()
                    break
                continue
            before = block.progress
            if self._hold == "decelerating":  # slow down at once, through the next blocks if need be
                accel, remaining, speed = block.accel, block.length - before, self._speed
                step = min(dt - spent, speed / accel)
                travel = speed * step - 0.5 * accel * step * step
                if travel >= remaining:
                    end = math.sqrt(max(speed * speed - 2.0 * accel * remaining, 0.0))
                    step, travel, speed = (speed - end) / accel, remaining, end
                else:
                    speed -= accel * step
                self._speed = speed if speed > 1e-9 else 0.0
                if self._speed == 0.0:
                    self._go_idle()
                block.progress += travel
                spent += step
            else:
                spent += self._profile(block, dt - spent)
            alarm = self.faults.alarm_line
            if alarm is not None and block.line_number == alarm and before < block.length / 2 <= block.progress:
                self.faults.alarm_line = None
                block.progress = block.length / 2
                self.position = block.segment.point_at(0.5)
                self._alarm(self.faults.alarm_code)
                break
            if block.progress >= block.length - 1e-9:
                self.machine_time = clock + spent
                self._complete()
                if not self._moves:
                    self._go_idle()
                elif self._pending is not None or self._rx:
                    self._process_input()  # the main loop refills the planner while the steppers run
                if single:
                    break
            else:
                self.position = block.segment.point_at(block.progress / block.length)
        if not self.planner and not self._idle_lock and self.state in ("Run", "Jog"):
            self.state = "Idle"
            self._speed = 0.0
        self.machine_time = clock + spent
        return spent

    def _go_idle(self) -> None:
        """The steppers have nothing left to run (stepper.c, st_go_idle): the stepper interrupt waits $1 ms to let
        the axes settle before the cycle ends (255: it keeps them enabled and does not wait). The main loop is
        stopped meanwhile, so no line is read and nothing that waits for the planner to empty goes on."""
        self._speed = 0.0
        lock = self.settings[1]
        self._idle_lock = 0.0 if lock == 255 else lock / 1000.0
        if not self._idle_lock and self._hold == "decelerating":
            self._hold = "complete"

    def _profile(self, block: Planned, dt: float) -> float:
        """Move along `block` for up to `dt` seconds on its trapezoid from the current speed: accelerate to the
        nominal speed, cruise, and decelerate to the next block's planned entry speed (0 if none) at its end.
        Returns the time used (less than `dt` if the block ends)."""
        accel, nominal = block.accel, block.rate
        exit2 = self._moves[1].entry2 if len(self._moves) > 1 else 0.0
        speed, used = self._speed, 0.0
        while dt - used > 1e-12:
            remaining = block.length - block.progress
            if remaining <= 1e-9:
                break
            braking = (speed * speed - exit2) / (2.0 * accel)
            if braking >= remaining - 1e-9:  # decelerate to the end of the block
                end = math.sqrt(max(speed * speed - 2.0 * accel * remaining, 0.0))
                phase = (speed - end) / accel
                if phase <= 1e-12:  # already at the exit speed: the rounding is the rest of the block
                    phase = remaining / max(speed, 1e-9)
                    end = speed
                if used + phase <= dt:
                    used, speed, block.progress = used + phase, end, block.length
                    break
                step = dt - used
                block.progress += speed * step - 0.5 * accel * step * step
                speed, used = speed - accel * step, dt
            elif speed < nominal - 1e-9 and (peak := min(nominal, math.sqrt(
                    (2.0 * accel * remaining + speed * speed + exit2) / 2.0))) > speed + 1e-9:
                # accelerate to the nominal speed, or to the peak of a triangle where braking must begin
                phase = (peak - speed) / accel
                if used + phase <= dt:
                    block.progress = min(block.progress + (peak * peak - speed * speed) / (2.0 * accel), block.length)
                    used, speed = used + phase, peak
                    continue
                step = dt - used
                block.progress += speed * step + 0.5 * accel * step * step
                speed, used = speed + accel * step, dt
            else:  # cruise until braking must begin
                cruise = remaining - max(braking, 0.0)
                phase = cruise / max(speed, 1e-9)
                if used + phase <= dt:
                    block.progress += cruise
                    used += phase
                    continue
                block.progress += speed * (dt - used)
                used = dt
        self._speed = speed
        return used

    def _complete(self) -> None:
        block = self.planner.popleft()
        if block.segment is not None:
            self.position = block.segment.end
            self._moves.popleft()
            self._optimal = max(0, self._optimal - 1)
            if not block.final:
                return
        if self.completed is not None:
            self.completed.append((block.text, self.machine_time))
        if self._log and not block.jog:
            self._log.write(block.text + "\n")
            self._log.flush()
        if block.pause:  # M0: the planner is empty (it synchronised); hold until cycle start
            self._hold, self.state, self._hold_stopped_motion = "complete", "Hold", False

    def step(self, seconds: float | None = None) -> float:
        """One turn of the main loop of a controller made with `threaded=False`: take input, then run `seconds` of
        machine time (None: until the next planner block or dwell completes). Returns the machine time used."""
        with self._lock:
            if not self._idle_lock:
                self._process_input()
            used = self._advance(math.inf if seconds is None else seconds, single=seconds is None)
            if not self._idle_lock:
                self._process_input()
            return used
