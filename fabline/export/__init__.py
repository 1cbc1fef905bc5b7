"""The export stage: nested sheets to DXF drawings and G-code programs, and a checker for G-code files.

Machine profiles and the motion planner are the ground floor's (`fabline.machine`). The public names load their
modules on first use (`fabline.lazy`): checking a program does not pay for the DXF writer, ezdxf and scipy.
"""

from fabline.lazy import lazy_surface

__getattr__, __all__ = lazy_surface(__name__, {
    "check": ("CheckReport", "check_gcode", "check_program"),
    "job": ("ExportResult", "SheetExport", "export_job", "export_nesting", "load_job"),
    "toolpath": ("Toolpath", "ToolpathOptions", "order_paths", "sheet_toolpaths", "travel_length"),
})
