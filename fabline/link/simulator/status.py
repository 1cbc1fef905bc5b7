"""Status report text (`<Idle|MPos:...|FS:...>`): the fields per `$10`, and WCO/Ov/A: every few reports as Grbl does."""

from __future__ import annotations


class StatusReport:
    """GrblSimulator's answer to `?`."""

    def _status_report(self) -> str:
        state = self.state
        if state == "Hold":
            state = f"Hold:{0 if self._hold == 'complete' else 1}"
        mask = int(self.settings[10])
        position = self.position
        parts = [state, ("MPos:" if mask & 1 else "WPos:") + ",".join(f"{v:.3f}" for v in position)]
        if mask & 2:
            parts.append(f"Bf:{self.build.planner_blocks - self._motion_blocks()},{self.build.rx_buffer - len(self._rx)}")
        line_numbers = mask & 4 if self.build.firmware == "grblhal" else self.build.line_numbers  # grblHAL: $10 says
        if (line_numbers and self.planner and self.planner[0].line_number
                and self.state in ("Run", "Hold", "Jog")):
            parts.append(f"Ln:{self.planner[0].line_number}")
        feed, speed = self._current_feed_speed()
        parts.append(f"FS:{feed:.0f},{speed:.0f}")
        busy = self.state in ("Run", "Hold", "Jog")
        if self._wco_counter > 0:
            self._wco_counter -= 1
        else:
            self._wco_counter = 29 if busy else 9
            if self._ovr_counter == 0:
                self._ovr_counter = 1
            parts.append("WCO:0.000,0.000,0.000")
        if self._ovr_counter > 0:
            self._ovr_counter -= 1
        else:
            self._ovr_counter = 19 if busy else 9
            parts.append("Ov:100,100,100")
            spindle = self._spindle_state()
            coolant = {"M7": "M", "M8": "F"}.get(self.modal.coolant, "")
            if spindle != "M5" or coolant:
                parts.append("A:" + {"M3": "S", "M4": "C", "M5": ""}[spindle] + coolant)
        return "<" + "|".join(parts) + ">"

    def _spindle_state(self) -> str:
        return self.planner[0].spindle if self.planner and self.planner[0].segment is not None else self.modal.spindle

    def _current_feed_speed(self) -> tuple[float, float]:
        if not self.planner or self.planner[0].segment is None or self.state not in ("Run", "Hold", "Jog"):
            laser = self.settings[32] == 1
            return 0.0, 0.0 if laser or self.modal.spindle == "M5" else self.modal.speed
        block = self.planner[0]
        feed = self._speed * 60.0
        if block.spindle == "M5" or block.jog:
            return feed, 0.0
        if self.settings[32] == 1:
            if block.segment.rapid:
                return feed, 0.0
            if block.spindle == "M4" and block.programmed_rate:
                return feed, block.speed * feed / block.programmed_rate
        return feed, block.speed
