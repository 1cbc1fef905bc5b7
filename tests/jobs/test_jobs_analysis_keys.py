"""The job file's [analysis] table: loads with units, defaults as `fabline analyse`'s, and every bad key one line."""

from __future__ import annotations

import pytest

from fabline.cli import main
from fabline.errors import FablineError
from fabline.jobs.jobfile import load_job_file
from jobfiles import GOOD, write

STAGED = GOOD.replace('name = "small"', 'name = "small"\nstages = ["unroll", "analyse", "report"]')


def test_defaults_are_the_commands_and_units_convert(tmp_path):
    spec = load_job_file(write(tmp_path, STAGED))
    assert spec.stages == ("unroll", "analyse", "report")
    assert spec.analysis == {"snow": 0.75, "wind": 0.5, "person": 1000.0, "gamma_g": 1.35, "gamma_q": 1.5,
                             "supports": "pinned", "stations": 2, "buckling": True}
    spec = load_job_file(write(tmp_path, STAGED + '[analysis]\nsnow = "1200 N/m2"\nwind = "0.6 kPa"\n'
                                                  'person = "1.5 kN"\ngamma_q = 1.6\nsupports = "fixed"\nbuckling = false\n'))
    assert spec.analysis["snow"] == pytest.approx(1.2) and spec.analysis["wind"] == pytest.approx(0.6)
    assert spec.analysis["person"] == pytest.approx(1500.0)
    assert (spec.analysis["gamma_q"], spec.analysis["supports"], spec.analysis["buckling"]) == (1.6, "fixed", False)


@pytest.mark.parametrize("table, message", [
    ('snow = "3 kg"', "job.toml: analysis.snow: expected a number in kN/m2 or a string with a unit (kN/m2, kPa, N/m2, Pa), "
                      "got '3 kg'"),
    ("wind = -0.5", "job.toml: analysis.wind: must not be negative, got -0.5"),
    ('person = "2 kN/m2"', "job.toml: analysis.person: expected a number in N or a string with a unit (N, kN), "
                           "got '2 kN/m2'"),
    ('supports = "glued"', "job.toml: analysis.supports: must be 'pinned' or 'fixed', got 'glued'"),
    ("stations = 0", "job.toml: analysis.stations: must be 1 to 16, got 0"),
    ("gamma_g = 0.9", "job.toml: analysis.gamma_g: must be 1 to 10, got 0.9"),
    ('buckling = "no"', "job.toml: analysis.buckling: expected true or false, got string 'no'"),
    ("snowload = 1", "job.toml: analysis.snowload: unknown key (allowed: snow, wind, person, gamma_g, gamma_q, supports, "
                     "stations, buckling)"),
])
def test_bad_keys_are_one_line(tmp_path, table, message):
    with pytest.raises(FablineError) as err:
        load_job_file(write(tmp_path, STAGED + f"[analysis]\n{table}\n"))
    assert str(err.value) == message


def test_the_stage_needs_unroll_and_a_bad_key_exits_2(tmp_path, capsys):
    with pytest.raises(FablineError, match=r"^job.toml: stages: 'analyse' needs 'unroll' in the same job$"):
        load_job_file(write(tmp_path, GOOD.replace('name = "small"', 'name = "small"\nstages = ["analyse"]')))
    path = write(tmp_path, STAGED + '[analysis]\nsupports = "glued"\n')
    assert main(["run", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["fabline run: error: job.toml: analysis.supports: must be 'pinned' or 'fixed', got 'glued'"]
    assert not (tmp_path / "out").exists()
