"""The machine: what export writes and link streams share, below both. The G-code language as Grbl reads it
(parser, modal state, segments), the controller's codes and build info, G-code programs, machine profiles
(TOML, built-ins in `profiles/`) and the motion planner that times a program on a profile.

The names load their modules on first use (`fabline.lazy`): reading a profile does not import the parser.
"""

from fabline.lazy import lazy_surface

__getattr__, __all__ = lazy_surface(__name__, {
    "build": ("STOCK_BUILD", "BuildInfo"),
    "codes": ("ALARM_CODES", "ERROR_CODES", "explain_alarm", "explain_error"),
    "gcode": ("GcodeError", "ModalState", "Segment", "execute"),
    "motion": ("MotionSummary", "MoveLog", "estimate_time", "summarise"),
    "profile": ("OPERATIONS", "MachineProfile", "Operation", "available_machines", "load_machine"),
    "program": ("Program", "load_program", "parse_program"),
})
