"""Every option of `fabline unroll`, `nest` and `export` has its key in a job file ([unroll], [nest], [export]),
checked like the rest (one line naming file and key), and reaches the stage: the example job's compensated strips
are as long as the domain brief's helix formula says, computed here from the Enneper closed form."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pytest

from fabline.cli import export as export_cli, nest as nest_cli, unroll as unroll_cli
from fabline.errors import FablineError
from fabline.jobs.jobfile import SCHEMA, load_job_file
from jobfiles import GOOD

REPO = Path(__file__).resolve().parents[2]

# command-line options that have their job key elsewhere or have none, each with the reason
ELSEWHERE = {
    "unroll": {"model": "model.design / model.file", "output": "the job writes parts.json in output.folder",
               "profile": "lamella.profile", "material": "lamella.material", "materials": "lamella.materials_file",
               "no_hardware": "unroll.hardware", "svg": "unroll.previews (written to previews/)",
               "json": "the job writes its report"},
    "nest": {"parts": "the unroll stage's parts", "output": "the job writes nesting.json", "check": "not a nesting run",
             "sheet_size": "stock.sheet", "stock": "stock.file"},
    "export": {"nesting": "the nest stage's nesting", "output": "the job writes dxf/ and gcode/ in output.folder",
               "dxf": "the job writes dxf/", "gcode": "the job writes gcode/",
               "machine": "machine.profile", "no_optimise": "export.optimise", "no_preview": "export.previews"},
}
RENAMED = {"stock_out": "stock_out", "svg": "svg", "time_limit": "time_limit"}

def _command_options(module, command: str) -> set[str]:
    parser = argparse.ArgumentParser()
    module.register(parser.add_subparsers())
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[command]
    return {a.dest for a in sub._actions if a.dest != "help"}


@pytest.mark.parametrize("module, command", [(unroll_cli, "unroll"), (nest_cli, "nest"), (export_cli, "export")])
def test_every_command_line_option_has_a_job_key(module, command):
    options = _command_options(module, command)
    missing = sorted(o for o in options - set(ELSEWHERE[command]) if o not in SCHEMA[command])
    assert not missing, f"fabline {command} options with no [{command}] key: {missing}"


def _write(tmp_path: Path, extra: str) -> Path:
    path = tmp_path / "job.toml"
    path.write_text(GOOD + extra, encoding="utf-8")
    return path


@pytest.mark.parametrize("extra, message", [
    ("[unroll]\noverlap = -5", "job.toml: unroll.overlap: must be positive, got -5"),
    ("[unroll]\npair_spacing = 2", "job.toml: unroll.pair_spacing: 2 mm leaves no room"),
    ("[unroll]\nscrew_hole = 50", "job.toml: unroll.screw_hole: 50 mm does not fit a seam"),
    ("[unroll]\nsingularity = 'glue'", "job.toml: unroll.singularity: 'glue': use one of joint, slots"),
    ("[unroll]\ncompensate_twist = 'yes'", "job.toml: unroll.compensate_twist: expected true or false"),
    ("[unroll]\nmin_crossing_angle = 120", "job.toml: unroll.min_crossing_angle: 120 must lie in (0, 90]"),
    ("[unroll]\npairs = 25", "job.toml: unroll.pairs: unknown key (allowed: pair_spacing"),
    ("[nest]\nremnant_min = '400'", "job.toml: nest.remnant_min:"),
    ("[nest]\nstock_out = '../stock.json'", "would be written outside the output folder"),
    ("[export]\ntabs = -1", "job.toml: export.tabs: must be a finite number, at least 0, got -1"),
    ("[export]\nlead_in = 'long'", "job.toml: export.lead_in: expected a number in mm or with a unit: 3mm, 0.2 mm"),
    ("[export]\nlead_in = true", "job.toml: export.lead_in: expected a number, got boolean"),
    ("[nest]\ngap = '3 furlongs'", "job.toml: nest.gap: unknown unit 'furlongs' (use mm, cm, m, in, ft, pt or px)"),
    ("[nest]\nmargin = 10\nsheet_margin = 10", "job.toml: nest.margin: the old name of nest.sheet_margin"),
    ("[export]\nspeed = 3", "job.toml: export.speed: unknown key"),
    ("[unroll]\ncable_pretension = 'tight'", "job.toml: unroll.cable_pretension: expected a strain as '1 mm/m'"),
    ("[unroll]\ncable_pretension = [1]", "job.toml: unroll.cable_pretension: expected a strain"),
    ("[unroll]\ncable_pretension = '20 %'", "job.toml: unroll.cable_pretension: '20 %' must be at least 0 and under"),
    ("[unroll]\ncable_end_allowance = -1", "job.toml: unroll.cable_end_allowance: must be positive, got -1"),
    ("[unroll]\ncouplers = -1", "job.toml: unroll.couplers: -1 node intervals from each support"),
    ("[unroll]\nsupport_material = 'gold'", "job.toml: unroll.support_material: unknown material 'gold'"),
    ("[unroll]\nsupport_plate = '0 mm'", "job.toml: unroll.support_plate: must be positive, got 0"),
    ("[stock]\nplate_sheet = 'big'", "job.toml: stock.plate_sheet:"),
])
def test_bad_stage_options_are_one_line_naming_file_and_key(tmp_path, extra, message):
    with pytest.raises(FablineError) as err:
        load_job_file(_write(tmp_path, extra))
    assert message in str(err.value) and "\n" not in str(err.value)


def test_the_example_job_makes_double_lamellas_25_mm_apart_with_twist_compensation():
    spec = load_job_file(REPO / "jobs" / "pavilion.toml")
    assert spec.unroll["pair_spacing"] == 25.0 and spec.unroll["compensate_twist"] is True
    assert spec.unroll["supports"] is True and spec.unroll["couplers"] == 2 and spec.unroll["support_plate"] == 6.0


def _enneper_line(c: float, fixed: float, along: np.ndarray, family: str) -> dict[str, np.ndarray]:
    """Closed-form Darboux data (mm, 1/mm) along an Enneper asymptotic line: arc-length steps, k_g and |tau_g|.

    A-lamellas run along u at fixed v, B-lamellas along v at fixed u; the Enneper surface is symmetric under
    (u, v) -> (v, u), so both are the u-line formulas with the roles swapped."""
    u, v = (along, np.full_like(along, fixed)) if family == "A" else (np.full_like(along, fixed), along)
    s = 1000.0 * c
    xu = s * np.stack([12 * u * v, 6 * v * v - 6 * u * u - 6, -12 * v], axis=-1)
    xv = s * np.stack([6 * u * u - 6 * v * v - 6, 12 * u * v, -12 * u], axis=-1)
    xuu = s * np.stack([12 * v, -12 * u, 0 * u], axis=-1)
    xvv = s * np.stack([-12 * v, 12 * u, 0 * u], axis=-1)
    n = np.cross(xu, xv)
    n /= np.linalg.norm(n, axis=1)[:, None]
    d1, d2 = (xu, xuu) if family == "A" else (xv, xvv)
    speed = np.linalg.norm(d1, axis=1)
    t = d1 / speed[:, None]
    k_g = np.einsum("ij,ij->i", d2, np.cross(n, t)) / speed**2
    tau_g = 1.0 / (3 * s * (1 + u * u + v * v) ** 2)  # |k1| (domain.md 3), equal to |tau_g| on asymptotic lines
    return {"speed": speed, "k_g": k_g, "tau_g": tau_g}


def _compensated_length(c: float, fixed: float, a: float, b: float, family: str, offset: float, h: float,
                        t_mm: float) -> float:
    """Length (mm) of the flat strip between parameters a and b: the offset fibre's length element
    sqrt((1 - o k_g)^2 + (o tau_g)^2) ds stretched by 1 / (1 + eps_H,min), eps_H,min = -i_p^2 tau_g^2 / 2 (6.8),
    i_p^2 = (h^2 + t^2) / 12 — Gauss-Legendre on the closed form."""
    x, w = np.polynomial.legendre.leggauss(64)
    edges = np.linspace(a, b, 65)
    mid, half = (edges[1:] + edges[:-1]) / 2, (edges[1:] - edges[:-1]) / 2
    p = (mid[:, None] + half[:, None] * x[None, :]).ravel()
    line = _enneper_line(c, fixed, p, family)
    element = np.hypot(1 - offset * line["k_g"], offset * line["tau_g"])
    eps = -0.5 * (h * h + t_mm * t_mm) / 12.0 * line["tau_g"] ** 2
    return float(np.sum((line["speed"] * element / (1 + eps)).reshape(len(mid), -1) * w[None, :] * half[:, None]))


@pytest.fixture(scope="module")
def example_unroll(tmp_path_factory):
    """The example job's unroll stage as the job runs it (its model, [lamella], [unroll], stock and margin)."""
    from fabline.jobs.jobfile import unroll_options
    from fabline.jobs.pipeline import build_network
    from fabline.unroll import unroll_network

    spec = load_job_file(REPO / "jobs" / "pavilion.toml")
    network = build_network(spec)
    options = unroll_options(spec.lamella, spec.unroll, spec.stock, spec.nest)
    return network, options, unroll_network(network, options)


def test_compensated_strips_are_as_long_as_the_helix_formula_says(example_unroll):
    """Between its first and last node mark, every strip of the example job (pairs 25 mm apart, compensation on)
    is as long as the closed form says within 0.05 mm/m; uncompensated, the longest would be ~1 mm short."""
    network, options, partset = example_unroll
    meta = network.meta
    grid_a, grid_b = np.array(meta["grid"]["a"]), np.array(meta["grid"]["b"])
    marks: dict[str, dict[str, float]] = {}
    for part in partset.parts:
        if part.kind in ("strip", "curved-strip"):
            start = part.meta["strip_range_mm"][0]
            for node in part.nodes:
                marks.setdefault(part.meta["strip"], {})[node["id"]] = start + node["s"]
    lamellas = {lam.id: lam for lam in network.lamellas}
    worst, checked, largest_compensation = 0.0, 0, 0.0
    for row in partset.report["strips"]:
        lam = lamellas[row["lamella"]]
        first, last = lam.nodes[0], lam.nodes[-1]
        (i0, j0), (i1, j1) = ([int(k) for k in nid[1:].split("-")] for nid in (first, last))
        if lam.family == "A":  # along u (index i) at fixed v (index j)
            fixed, a, b = grid_b[j0], grid_a[i0], grid_a[i1]
        else:
            fixed, a, b = grid_a[i0], grid_b[j0], grid_b[j1]
        expected = _compensated_length(meta["scale_m_per_unit"], fixed, a, b, lam.family, row["offset_mm"],
                                       options.profile.h, options.profile.t)
        measured = marks[row["strip"]][last] - marks[row["strip"]][first]
        worst = max(worst, abs(measured - expected) / expected * 1000.0)
        largest_compensation = max(largest_compensation, row.get("twist_compensation_mm", 0.0))
        checked += 1
    assert checked == 2 * len(network.lamellas)
    assert worst < 0.05, f"worst strip off the compensated closed form by {worst:.4f} mm/m"
    assert largest_compensation > 1.0  # A-012's 11.9 m, which the uncompensated job cut 1.07 mm too long
