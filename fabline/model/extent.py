"""The design's real size in plan beside the size asked for: a grid of nodes spaced along the lamellas fills a
footprint only up to its last whole node spacing, so the built shell is smaller than the `size` the design took
(the 9 x 12 m pavilion is 8.4 x 11.9 m)."""

from __future__ import annotations

import numpy as np

from fabline.model.network import Network


def plan_extent_m(network: Network) -> tuple[float, float]:
    """The network's bounding box in plan (x by y, metres): its nodes and lamella centrelines."""
    points = [network.node_array()[1]] + [lam.curve for lam in network.lamellas]
    xy = np.vstack([p[:, :2] for p in points if len(p)]) if any(len(p) for p in points) else np.zeros((1, 2))
    dx, dy = np.ptp(xy, axis=0) * network.mm_per_unit / 1000.0
    return float(dx), float(dy)


def _metres(value: float) -> str:
    return f"{value:.1f}" if value >= 1.0 else f"{value:.2f}"


def extent_text(network: Network) -> str:
    """"asked 9 x 12 m, built 8.4 x 11.9 m" for a design made to a size (meta size_m), else "8.4 x 11.9 m"."""
    dx, dy = plan_extent_m(network)
    built = f"{_metres(dx)} x {_metres(dy)} m"
    asked = network.meta.get("size_m")
    if isinstance(asked, (list, tuple)) and len(asked) == 2:
        return f"asked {asked[0]:g} x {asked[1]:g} m, built {built}"
    return built
