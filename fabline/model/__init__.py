"""The network model stage: the data type, its JSON format, importers from CAD, and built-in designs."""

from fabline.model.jsonio import SCHEMA, load_network, network_from_dict, network_to_dict, save_network
from fabline.model.network import FAMILIES, NODE_KINDS, UNIT_TO_MM, Lamella, Network, Node, validate

__all__ = [
    "FAMILIES", "NODE_KINDS", "SCHEMA", "UNIT_TO_MM", "Lamella", "Network", "Node",
    "load_network", "network_from_dict", "network_to_dict", "save_network", "validate",
]
