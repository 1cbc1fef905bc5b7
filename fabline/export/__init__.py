"""The export stage: nested sheets to DXF drawings and G-code programs, and a checker for G-code files."""

from fabline.export.check import CheckReport, check_gcode, check_program
from fabline.export.job import ExportResult, SheetExport, export_job, export_nesting, load_job
from fabline.export.machine import OPERATIONS, MachineProfile, Operation, available_machines, load_machine
from fabline.export.motion import MotionSummary, MoveLog, estimate_time, summarise
from fabline.export.toolpath import Toolpath, ToolpathOptions, order_paths, sheet_toolpaths, travel_length

__all__ = ["OPERATIONS", "CheckReport", "ExportResult", "MachineProfile", "MotionSummary", "MoveLog", "Operation",
           "SheetExport", "Toolpath", "ToolpathOptions", "available_machines", "check_gcode", "check_program",
           "estimate_time", "export_job", "export_nesting", "load_job", "load_machine", "order_paths",
           "sheet_toolpaths", "summarise", "travel_length"]
