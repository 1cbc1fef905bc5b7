"""Read and write the `fabline.network/1` JSON format, with validation that names the element at fault."""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from fabline.errors import FablineError
from fabline.fileio import read_json, write_json
from fabline.model.network import Lamella, Network, Node, validate

SCHEMA = "fabline.network/1"


def network_to_dict(network: Network) -> dict[str, Any]:
    """The JSON-ready form of a network; coordinates kept to 1e-6 mm, normals to 1e-9."""
    decimals = 6 + int(np.ceil(np.log10(network.mm_per_unit)))

    def rows(a: np.ndarray, places: int = decimals) -> list:
        return np.round(a, places).tolist()

    return {
        "schema": SCHEMA,
        "name": network.name,
        "units": network.units,
        "meta": network.meta,
        "nodes": [
            {"id": n.id, "xyz": rows(n.xyz), "normal": rows(n.normal, 9), "kind": n.kind}
            for n in network.nodes.values()
        ],
        "lamellas": [
            {"id": lam.id, "family": lam.family, "nodes": list(lam.nodes),
             "curve": rows(lam.curve), "normals": rows(lam.normals, 9)}
            for lam in network.lamellas
        ],
    }


def network_from_dict(data: Any, source: str = "model") -> Network:
    """Build and validate a network from its JSON form; errors name `source` and the element."""
    if not isinstance(data, dict):
        raise FablineError(f"{source}: expected a JSON object at the top level")
    if data.get("schema") != SCHEMA:
        raise FablineError(f"{source}: schema is {data.get('schema')!r}, expected {SCHEMA!r}")
    if "units" not in data:
        raise FablineError(f"{source}: missing 'units' (declare the model's units, e.g. \"m\" or \"mm\")")
    nodes: dict[str, Node] = {}
    for i, raw in enumerate(_list(data, "nodes", source)):
        where = f"{source}: nodes[{i}]"
        nid = _id(raw, where)
        where = f"{source}: node {nid}"
        if nid in nodes:
            raise FablineError(f"{where}: duplicate node id")
        nodes[nid] = Node(nid, _array(raw, "xyz", where, (3,)), _array(raw, "normal", where, (3,)),
                          str(raw.get("kind", "grid")))
    lamellas = []
    for i, raw in enumerate(_list(data, "lamellas", source)):
        where = f"{source}: lamellas[{i}]"
        lid = _id(raw, where)
        where = f"{source}: lamella {lid}"
        node_ids = raw.get("nodes")
        if not isinstance(node_ids, list):
            raise FablineError(f"{where}: 'nodes' must be a list of node ids")
        curve = _array(raw, "curve", where, (-1, 3))
        lamellas.append(Lamella(lid, str(raw.get("family", "")), [str(n) for n in node_ids], curve,
                                _array(raw, "normals", where, (-1, 3))))
    meta = data.get("meta", {})
    if not isinstance(meta, dict):
        raise FablineError(f"{source}: 'meta' must be an object")
    network = Network(str(data["units"]), nodes, lamellas, str(data.get("name", "")), dict(meta))
    return validate(network, source)


def load_network(path: str | os.PathLike) -> Network:
    """Load and validate a `fabline.network/1` file."""
    return network_from_dict(read_json(path), str(path))


def save_network(network: Network, path: str | os.PathLike) -> None:
    """Write a network atomically as `fabline.network/1` JSON."""
    write_json(path, network_to_dict(network))


def _list(data: dict, key: str, source: str) -> list:
    value = data.get(key)
    if not isinstance(value, list):
        raise FablineError(f"{source}: missing or malformed '{key}' (expected a list)")
    return value


def _id(raw: Any, where: str) -> str:
    if not isinstance(raw, dict) or "id" not in raw:
        raise FablineError(f"{where}: expected an object with an 'id'")
    if not isinstance(raw["id"], (str, int)) or isinstance(raw["id"], bool):
        raise FablineError(f"{where}: id must be a string or an integer")
    return str(raw["id"])


def _array(raw: dict, key: str, where: str, shape: tuple[int, ...]) -> np.ndarray:
    if key not in raw:
        raise FablineError(f"{where}: missing '{key}'")
    try:
        value = np.asarray(raw[key], dtype=float)
    except (TypeError, ValueError):
        raise FablineError(f"{where}: '{key}' must contain only numbers") from None
    if value.ndim != len(shape) or any(s != -1 and s != d for s, d in zip(shape, value.shape)):
        expected = "[x, y, z]" if shape == (3,) else "a list of [x, y, z]"
        raise FablineError(f"{where}: '{key}' must be {expected}")
    return value
