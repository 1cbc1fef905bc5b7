"""The export stage: nested sheets to DXF drawings and G-code programs, and a checker for G-code files.

The public names load their modules on first use (`fabline.lazy`): the link stage reads a machine profile
for every sheet it streams, and must not pay for the DXF writer, ezdxf and scipy to do it.
"""

from fabline.lazy import lazy_surface

__getattr__, __all__ = lazy_surface(__name__, {
    "check": ("CheckReport", "check_gcode", "check_program"),
    "job": ("ExportResult", "SheetExport", "export_job", "export_nesting", "load_job"),
    "machine": ("OPERATIONS", "MachineProfile", "Operation", "available_machines", "load_machine"),
    "motion": ("MotionSummary", "MoveLog", "estimate_time", "summarise"),
    "toolpath": ("Toolpath", "ToolpathOptions", "order_paths", "sheet_toolpaths", "travel_length"),
})
