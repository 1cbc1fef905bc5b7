"""`fabline design` says the size asked and the size built: the pavilion asked 9 x 12 m is 8.4 x 11.9 m in plan."""

from __future__ import annotations

import numpy as np

from fabline.model import load_network


def test_design_prints_the_size_asked_and_the_networks_bounding_box(cli, tmp_path):
    out_file = tmp_path / "pavilion.json"
    code, out, err = cli("design", "enneper", "-o", out_file)
    assert code == 0, err
    network = load_network(out_file)
    xy = np.vstack([np.array([n.xyz for n in network.nodes.values()])[:, :2]]
                   + [lam.curve[:, :2] for lam in network.lamellas])
    dx, dy = np.ptp(xy, axis=0)
    assert (round(dx, 1), round(dy, 1)) == (8.4, 11.9)
    assert out.rstrip("\n").endswith(f"lamellas (units m), asked 9 x 12 m, built {dx:.1f} x {dy:.1f} m")


def test_a_model_without_an_asked_size_gets_its_extent_alone():
    from fabline.model.designs import catenoid_network
    from fabline.model.extent import extent_text, plan_extent_m

    network = catenoid_network()
    dx, dy = plan_extent_m(network)
    xy = np.vstack([lam.curve[:, :2] for lam in network.lamellas])
    assert (dx, dy) == tuple(np.ptp(xy, axis=0))  # the nodes lie on the lamellas
    assert extent_text(network) == f"{dx:.1f} x {dy:.1f} m"
