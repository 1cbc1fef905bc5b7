"""The hardware link: stream G-code to GRBL 1.1 controllers over pyserial, journaled and resumable.

Public surface: `Streamer` (with `Progress`, `StreamResult`, `StreamInterrupted`), `check_port`,
`read_journal`/`default_journal_path` and the controller simulator (`GrblSimulator`, `Faults`,
`SimulatorServer`, `executed_file_lines`); the G-code language, programs and the controller's codes are the
ground floor's (`fabline.machine`). The names load their modules on first use (`fabline.lazy`). Importing
this package registers the `sim://` URL scheme with pyserial, so `serial.serial_for_url("sim://grbl?time_scale=100")`
works.
"""

import serial

from fabline.lazy import lazy_surface

if "fabline.link" not in serial.protocol_handler_packages:
    serial.protocol_handler_packages.append("fabline.link")

__getattr__, __all__ = lazy_surface(__name__, {
    "journal": ("default_journal_path", "read_journal"),
    "server": ("SimulatorServer", "executed_file_lines"),
    "simulator": ("Faults", "GrblSimulator"),
    "streamer": ("STOP_SIGNALS", "Progress", "Streamer", "StreamInterrupted", "StreamResult"),
    "ports": ("check_port",),
})
