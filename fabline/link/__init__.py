"""The hardware link: stream G-code to GRBL 1.1 controllers over pyserial, journaled and resumable.

Public surface: `Streamer` (with `Progress`, `StreamResult`, `StreamInterrupted`), `check_port`, `load_program`,
`read_journal`/`default_journal_path`, the controller simulator (`GrblSimulator`, `Faults`,
`SimulatorServer`, `executed_file_lines`) and the code tables. Importing this package registers the
`sim://` URL scheme with pyserial, so `serial.serial_for_url("sim://grbl?time_scale=100")` works.
"""

import serial

from fabline.link.codes import ALARM_CODES, ERROR_CODES, explain_alarm, explain_error
from fabline.link.journal import default_journal_path, read_journal
from fabline.link.program import Program, load_program, parse_program
from fabline.link.server import SimulatorServer, executed_file_lines
from fabline.link.simulator import Faults, GrblSimulator
from fabline.link.ports import check_port
from fabline.link.streamer import STOP_SIGNALS, Progress, Streamer, StreamInterrupted, StreamResult

if "fabline.link" not in serial.protocol_handler_packages:
    serial.protocol_handler_packages.append("fabline.link")

__all__ = [
    "ALARM_CODES", "ERROR_CODES", "explain_alarm", "explain_error", "default_journal_path", "read_journal",
    "Program", "load_program", "parse_program", "Faults", "GrblSimulator", "SimulatorServer", "executed_file_lines", "Progress", "Streamer",
    "StreamInterrupted", "StreamResult", "check_port", "STOP_SIGNALS",
]
