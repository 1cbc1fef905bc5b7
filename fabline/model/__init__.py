"""The network model stage: the data type, its JSON format, importers from CAD, and built-in designs.

The names below load their modules on first use (`fabline.lazy`), so the command line's help and a command
that needs only the units or the JSON format do not import the importers and their CAD libraries.
"""

from fabline.lazy import lazy_surface

__getattr__, __all__ = lazy_surface(__name__, {
    "jsonio": ("SCHEMA", "load_network", "network_from_dict", "network_to_dict", "save_network"),
    "network": ("FAMILIES", "NODE_KINDS", "UNIT_TO_MM", "Lamella", "Network", "Node", "validate"),
    "importers": ("ImportReport", "import_model"),
})
