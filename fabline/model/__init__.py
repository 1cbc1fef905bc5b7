"""The network model stage: the data type, its JSON format, importers from CAD, and built-in designs."""

from fabline.model.jsonio import SCHEMA, load_network, network_from_dict, network_to_dict, save_network
from fabline.model.network import FAMILIES, NODE_KINDS, UNIT_TO_MM, Lamella, Network, Node, validate
from fabline.model.importers import ImportReport, import_model

__all__ = [
    "FAMILIES", "NODE_KINDS", "SCHEMA", "UNIT_TO_MM", "ImportReport", "Lamella", "Network", "Node", "import_model",
    "load_network", "network_from_dict", "network_to_dict", "save_network", "validate",
]
