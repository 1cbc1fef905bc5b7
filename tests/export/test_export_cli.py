"""`fabline export` and `fabline gcode-check` end to end, machine profiles as data, and every bad-input case."""

from __future__ import annotations

import re

import pytest

from fabline.errors import FablineError
from fabline.export import ToolpathOptions, check_program, export_job
from fabline.machine import load_machine
from fabline.machine.profile import BUILTIN_DIR
from fabline.nest.layout import Placement, Sheet, save_nesting
from fabline.unroll.parts import save_parts

from export_helpers import every_kind_nesting, every_kind_partset, placed_contours, truth_ring


@pytest.fixture
def job(tmp_path):
    """A nesting.json and its parts.json with every part kind."""
    nesting, partset = every_kind_nesting(), every_kind_partset()
    save_parts(partset, tmp_path / "parts.json")
    save_nesting(nesting, tmp_path / "nesting.json")
    return tmp_path, nesting, partset


def _outputs(folder):
    return sorted(p.name for p in folder.rglob("*") if p.is_file()) if folder.exists() else []


def test_export_then_check_agrees_with_independent_truth(cli, job):
    folder, nesting, partset = job
    code, out, err = cli("export", folder / "nesting.json", "--dxf", folder / "out", "--gcode", folder / "out",
                         "--machine", "grbl-laser", "--kerf", "0", "--lead-in", "0", "--tabs", "0")
    assert code == 0, err
    assert _outputs(folder / "out") == ["cutlist.csv", "nesting_S1.dxf", "nesting_S1.gcode", "nesting_S1.order.svg",
                                        "nesting_all-sheets.dxf"]
    assert re.search(r"^total\s+6\s", out, re.M)
    code, out, err = cli("gcode-check", folder / "out" / "nesting_S1.gcode", "--machine", "grbl-laser")
    assert code == 0, out
    assert out.strip().endswith(": ok")
    cut = check_program((folder / "out" / "nesting_S1.gcode").read_text(), load_machine("grbl-laser")).summary.cut_length
    perimeters = sum(truth_ring(c, 0.0, role).exterior.length for _, role, c in placed_contours(nesting, partset))
    assert cut == pytest.approx(perimeters, abs=0.05)
    assert f"cut {cut / 1000:.3f} m," in out  # in m to the mm, as export's table prints it


def test_check_recomputes_what_the_writer_reported(cli, job):
    folder, _, _ = job
    assert cli("export", folder / "nesting.json", "--gcode", folder / "out")[0] == 0
    text = (folder / "out" / "nesting_S1.gcode").read_text()
    written = re.search(r"cut ([\d.]+) mm, mark ([\d.]+) mm, travel ([\d.]+) mm", text)
    report = check_program(text, load_machine("grbl-laser"))
    assert report.problems == []
    assert report.summary.cut_length == pytest.approx(float(written.group(1)), abs=0.05)
    assert report.summary.mark_length == pytest.approx(float(written.group(2)), abs=0.05)
    assert report.summary.travel == pytest.approx(float(written.group(3)), abs=0.05)


def test_check_reports_out_of_bed_moves_laser_on_travel_and_long_lines_and_warns_of_unexpected_codes(cli, tmp_path):
    program = "\n".join([
        "G21", "G90", "G28",                                # G28: Grbl takes it, the laser profile never writes it
        "M4 S1000",
        "G0 X10.000 Y10.000",                               # laser mode: G0 does not fire the laser
        "; cut-outer P1",
        "G1 X20.000 Y10.000 F1500.000",                     # travel to the path's start with the laser on
        "G0 X30.000 Y10.000",
        "G1 X5000.000 Y10.000",                             # beyond the 4100 mm bed
        "M5",
        "G1 X1.000 Y1.000 ; " + "x" * 80,                   # 99 characters, 14 once Grbl drops the comment
        "G1 X1." + "0" * 40 + " Y1." + "0" * 40,           # 88 characters without the spaces: Grbl's error:11
        "M2", ""])
    (tmp_path / "bad.gcode").write_text(program)
    code, out, err = cli("gcode-check", tmp_path / "bad.gcode", "--machine", "grbl-laser")
    assert code == 1
    assert err == (f"fabline gcode-check: warning: {tmp_path / 'bad.gcode'}: G28 (line 3): the controller accepts it, "
                   "but grbl-laser's exporter never writes it (not in the profile's words)\n")
    assert "line 3:" not in out and "line 5:" not in out and "characters" not in out.split("line 11:")[1].split("\n")[0]
    assert "line 7: travel with the laser on" in out
    assert "line 9: move reaches x" in out and "outside the bed" in out
    assert "line 12: error:11 (max characters per line exceeded; line was not processed and executed): 88 characters" in out
    program = "\n".join(["G21", "G90", "M3 S80", "G0 X10.000 Y10.000", "M3 S30", "G0 X0 Y0", "M2", ""])
    (tmp_path / "pen.gcode").write_text(program)                       # the plotter: pen down (S80) during G0
    code, out, _ = cli("gcode-check", tmp_path / "pen.gcode", "--machine", "grbl-plotter")
    assert code == 1 and "line 4: travel move (G0) with the tool on" in out and "line 6:" not in out


def test_a_user_profile_file_works_without_touching_code(cli, job, monkeypatch):
    folder, _, _ = job
    (folder / "machines").mkdir()
    (folder / "machines" / "shop-laser.toml").write_text('extends = "grbl-laser"\nname = "shop-laser"\nkerf = 0.15\n'
                                                         '[operations.cut-outer]\nfeed = 900.0\n')
    monkeypatch.setenv("FABLINE_MACHINE_PATH", str(folder / "machines"))
    code, out, err = cli("export", folder / "nesting.json", "--gcode", folder / "out", "--machine", "shop-laser")
    assert code == 0, err
    text = (folder / "out" / "nesting_S1.gcode").read_text()
    assert "machine shop-laser" in text and "kerf 0.150 mm" in text and "F900.000" in text


def _bad(cli, folder, *extra):
    code, out, err = cli("export", folder / "nesting.json", "--dxf", folder / "out", "--gcode", folder / "out", *extra)
    assert code == 2
    assert err.count("\n") == 1 and err.startswith("fabline export: error: ")
    assert _outputs(folder / "out") == []
    return err


def test_nesting_referring_to_a_missing_part(cli, job):
    folder, nesting, _ = job
    nesting.sheets[0].placements.append(Placement("NOPE", 10, 1500))
    save_nesting(nesting, folder / "nesting.json")
    err = _bad(cli, folder)
    assert "nesting.json" in err and "'NOPE'" in err and "sheet S1" in err


def test_sheet_larger_than_the_bed(cli, job):
    folder, nesting, _ = job
    nesting.sheets.append(Sheet("BIG", 5000.0, 2000.0, []))
    save_nesting(nesting, folder / "nesting.json")
    err = _bad(cli, folder)
    assert "sheet BIG" in err and "bed" in err and "grbl-laser.toml" in err


@pytest.mark.parametrize("edit, field", [
    (lambda t: t.replace("acceleration = 800.0", ""), "motion.acceleration: missing setting"),
    (lambda t: t.replace("kerf = 0.2 ", "kerf = -0.2 "), "kerf: -0.2 is out of range"),
    (lambda t: t.replace("power = 1000", "power = 1200", 1), "operations.cut-inner.power: 1200"),
    (lambda t: t.replace('tool_on = ["M4 S{power}"]', 'tool_on = ["M3 S{power}"]'), "tool_on: M3 is not in the profile's words"),
    (lambda t: t.replace("passes = 1", "passes = 0", 1), "operations.engrave-mark.passes"),
    (lambda t: t.replace('"G2", "G3", ', ""), "words: must include G2"),
    (lambda t: t.replace('mode = "laser"', 'mode = "plotter"'), "laser_mode: only a laser profile"),
])
def test_bad_machine_profiles_name_the_file_and_the_field(cli, job, edit, field):
    folder, _, _ = job
    text = (BUILTIN_DIR / "grbl-laser.toml").read_text()
    changed = edit(text)
    assert changed != text
    (folder / "bad.toml").write_text(changed)
    err = _bad(cli, folder, "--machine", folder / "bad.toml")
    assert "bad.toml" in err and field in err


@pytest.mark.parametrize("option, value", [("--kerf", "nan"), ("--kerf", "inf"), ("--lead-in", "nan"),
                                           ("--lead-in", "inf"), ("--tab-width", "nan"), ("--tab-width", "-1")])
def test_option_that_is_not_a_finite_number_is_named(cli, job, option, value):
    folder, _, _ = job
    err = _bad(cli, folder, option, value)
    assert f"{option}: " in err and f"got {value}" in err.replace("'", "")


def test_unknown_machine_and_missing_parts_file(cli, job):
    folder, _, _ = job
    err = _bad(cli, folder, "--machine", "no-such-machine")
    assert "no-such-machine" in err and "grbl-laser" in err
    (folder / "parts.json").unlink()
    err = _bad(cli, folder)
    assert "parts.json: file not found" in err


def test_toolpath_leaving_the_bed_through_an_arc_is_refused(cli, job):
    """A round part whose vertices lie on the bed but whose arc bulges past x = 0 (closed form: x = 40 - 50)."""
    import numpy as np

    from fabline.export.samplejob import circle
    from fabline.unroll.parts import Part, PartSet

    folder, nesting, partset = job
    disc = circle(0.0, 0.0, 50.0)
    turn = np.radians(45)
    disc[:, :2] = disc[:, :2] @ np.array([[np.cos(turn), np.sin(turn)], [-np.sin(turn), np.cos(turn)]])
    nesting.sheets[0].placements.append(Placement("DISC", 40.0, 1800.0))
    parts = {p.id: p for p in partset.parts + [Part("DISC", "washer", disc)]}
    with pytest.raises(FablineError) as error:  # the library's export (the command refuses the nesting before)
        export_job(nesting, parts, load_machine("grbl-laser"), ToolpathOptions(kerf=0.0), gcode_dir=folder / "out")
    err = str(error.value)
    assert "part DISC" in err and "outside the bed" in err
    assert float(re.search(r"spans x (-?[\d.]+)\.\.", err).group(1)) == pytest.approx(-10.0, abs=0.01)
    assert _outputs(folder / "out") == []


def test_a_failing_later_sheet_leaves_no_file_of_the_sheets_made_before_it(cli, job):
    """Sheets are made in worker processes; the first failing one names itself and nothing is written."""
    folder, nesting, partset = job
    nesting.sheets.append(Sheet("S2", 4000.0, 2000.0, [Placement("A", -30.0, 500.0)]))
    with pytest.raises(FablineError, match="sheet S2: part A.*outside the bed"):
        export_job(nesting, {p.id: p for p in partset.parts}, load_machine("grbl-laser"), ToolpathOptions(kerf=0.2),
                   folder / "out", folder / "out")
    assert _outputs(folder / "out") == []
    save_nesting(nesting, folder / "nesting.json")  # the command refuses it before making anything: A is off S2
    err = _bad(cli, folder)
    assert "part A: placed 2 times (on sheets " in err and "(and 1 more problems)" in err


@pytest.mark.parametrize("machine", ["grbl-laser", "fibre-laser", "grbl-plotter", "rs274-mill"])
def test_every_builtin_profile_exports_programs_that_check_clean(cli, job, machine):
    folder, _, _ = job
    code, out, err = cli("export", folder / "nesting.json", "--gcode", folder / machine, "--machine", machine,
                         "--lead-in", "2", "--tabs", "2")
    assert code == 0, err
    code, out, err = cli("gcode-check", folder / machine / "nesting_S1.gcode", "--machine", machine)
    assert code == 0 and err == "", out + err          # the exporter writes only its profile's words: no warning
    assert re.search(r"cut \d+\.\d{3} m, mark \d+\.\d{3} m", out) and not re.search(r"(cut|mark) 0\.000 ", out)


def test_gcode_check_of_a_missing_file_is_a_one_line_error(cli, tmp_path):
    code, _, err = cli("gcode-check", tmp_path / "none.gcode", "--machine", "grbl-laser")
    assert code == 2 and err == f"fabline gcode-check: error: {tmp_path / 'none.gcode'}: file not found\n"


@pytest.mark.parametrize("line", ["G1 X10 Y10 F-500", "G4 P-1", "G1 X20 Y20 S-5", "M4 S-5", "F-2"])
def test_gcode_check_reports_negative_feed_power_and_dwell_per_line(cli, tmp_path, line):
    path = tmp_path / "neg.gcode"
    path.write_text(f"G21\nG90\nG1 X5 Y5 F600\n{line}\nG1 X30 Y30\n")
    code, out, err = cli("gcode-check", path, "--machine", "grbl-laser")
    assert code == 1 and err == ""
    assert f"{path}: line 4: error:4 (negative value received for an expected positive value): {line}" in out
    assert re.search(r"estimated 0:00:\d\d \(\d+\.\d s\)", out) and f"{path}: 1 problem(s)" in out, out


def test_gcode_check_names_the_line_of_a_non_ascii_byte(cli, tmp_path):
    path = tmp_path / "text.gcode"
    path.write_bytes("G21\nG90\nG1 X1 Y1 F600 ; café\n".encode())
    code, out, err = cli("gcode-check", path, "--machine", "grbl-laser")
    assert code == 2 and out == ""
    assert err == f"fabline gcode-check: error: {path}:3: byte 0xc3 is not ASCII (G-code must be ASCII)\n"


def test_gcode_check_lists_every_problem_with_its_line(cli, tmp_path):
    path = tmp_path / "drawing.gcode"
    path.write_text("G21\n" + "E1 nonsense\n" * 500)
    code, out, _ = cli("gcode-check", path, "--machine", "grbl-laser")
    assert code == 1 and f"{path}: 500 problem(s)" in out
    listed = re.findall(r"line (\d+): error:20 \(unsupported or invalid g-code command", out)   # E, before the O
    assert [int(n) for n in listed] == list(range(2, 502))


@pytest.mark.parametrize("field, value, reason", [
    ("program_start", '["$RST=*"]', "'$' starts a Grbl system command"),
    ("program_start", '["G21", "$H"]', "'$' starts a Grbl system command"),
    ("program_end", '["$130=99999"]', "'$' starts a Grbl system command"),
    ("tool_on", '["M4 S{power} ~"]', "'~' is the Grbl real-time command cycle start / resume"),
    ("tool_off", '["M5!"]', "'!' is the Grbl real-time command feed hold"),
    ("program_start", '["G21 (ready?)"]', "'?' is the Grbl real-time command status report query"),
    ("program_start", '["G21\\u0018"]', "soft reset (ctrl-x)"),
    ("program_start", '["G21\\u0000"]', "holds a NUL byte"),
    ("program_end", '["M2\\nM30"]', "holds a line break"),
    ("program_start", '["G21 \\u00e9"]', "byte 0xe9 is not printable ASCII"),
    ("program_start", '["G21 G1.5"]', "Grbl refuses it: error:23"),
    ("program_start", '["G21 X"]', "Grbl refuses it: error:2"),
])
def test_a_profile_cannot_inject_controller_commands(cli, job, field, value, reason):
    """Issue 16: `program_start = ["$RST=*"]` loaded and went into every program; now the profile is refused."""
    folder, _, _ = job
    text = re.sub(rf"^{field} = .*$", lambda _: f"{field} = {value}", (BUILTIN_DIR / "grbl-laser.toml").read_text(), flags=re.M)
    (folder / "bad.toml").write_text(text)
    err = _bad(cli, folder, "--machine", folder / "bad.toml")
    assert err.startswith(f"fabline export: error: {folder / 'bad.toml'}: {field}: ") and reason in err


@pytest.mark.parametrize("field, value, reason", [
    ("program_start", '["G4 P{power}"]', "unknown placeholder {power} (allowed in program_start: none (a [vars] entry"),
    ("program_end", '["G0 Z{depth}"]', "unknown placeholder {depth} (allowed in program_end: none"),
    ("tool_off", '["M5 S{power}"]', "unknown placeholder {power}"),
    ("tool_on", '["M4 S{speed}"]', "unknown placeholder {speed} (allowed in tool_on: {depth}, {power})"),
    ("program_start", '["G1 {x"]', "expected '}' before end of string (a placeholder is {name}"),
    ("program_end", '["}"]', "Single '}' encountered in format string"),
    ("tool_on", '["M4 S{power:d}"]', "placeholder {power} takes no format or conversion"),
    ("tool_on", '["M4 S{power!r}"]', "placeholder {power} takes no format or conversion"),
])
def test_a_template_placeholder_it_is_not_rendered_with_is_refused_at_load(cli, job, field, value, reason):
    """Issue 25: `program_start = ["G4 P{power}"]` passed the check (power was offered to every template) and the
    export died of KeyError; unbalanced braces died of ValueError in the check itself."""
    folder, _, _ = job
    text = re.sub(rf"^{field} = .*$", lambda _: f"{field} = {value}", (BUILTIN_DIR / "grbl-laser.toml").read_text(), flags=re.M)
    (folder / "bad.toml").write_text(text)
    err = _bad(cli, folder, "--machine", folder / "bad.toml")
    assert err.startswith(f"fabline export: error: {folder / 'bad.toml'}: {field}: {value[2:-2]!r}: ") and reason in err


def test_a_vars_entry_is_a_placeholder_every_template_may_use(tmp_path):
    text = re.sub(r"^program_end = .*$", 'program_end = ["G4 P{dwell}", "M2"]', (BUILTIN_DIR / "grbl-laser.toml").read_text(),
                  flags=re.M) + "\n[vars]\ndwell = 0.5\n"
    (tmp_path / "vars.toml").write_text(text)
    profile = load_machine(str(tmp_path / "vars.toml"))
    assert profile.render("program_end") == ("G4 P0.500", "M2")
    with pytest.raises(TypeError):
        profile.render("program_end", power=1.0)


@pytest.mark.parametrize("profile, words, code", [
    ("grbl-laser", '["G0", "G1", "G2", "G3", "G4", "G17", "G21", "G43", "G90", "G94", "M2", "M4", "M5"]', "'G43'"),
    ("grbl-laser", '["G0", "G1", "G2", "G3", "G4", "G17", "G21", "G90", "G94", "M2", "M4", "M5", "M6"]', "'M6'"),
    ("rs274-mill", '["G0", "G1", "G2", "G3", "G4", "G17", "G21", "G40", "G49", "G54", "G80", "G90", "G94", "G95", '
                   '"M2", "M3", "M5"]', "'G95'"),
])
def test_profile_words_must_be_codes_its_controller_accepts(cli, job, profile, words, code):
    folder, _, _ = job
    text = re.sub(r"^words = \[[^]]*\]", lambda _: f"words = {words}", (BUILTIN_DIR / f"{profile}.toml").read_text(), flags=re.M)
    (folder / "bad.toml").write_text(text)
    err = _bad(cli, folder, "--machine", folder / "bad.toml")
    assert f"bad.toml: words: {code} is not a code the" in err


def test_gcode_check_names_system_commands_realtime_characters_nul_bytes_and_zero_feeds(cli, tmp_path):
    path = tmp_path / "hostile.gcode"
    path.write_bytes(b"G21\nG90\n$H\n$RST=*\nG1 X1 Y1 F0\nG0 X2 Y2 F0\nG1 X3 Y3 F600 ; hold!\n~\nG1 X4\x00 Y4\n"
                     b"M4 S10 ?\nG1 X5 Y5\x18\nM2\n")
    code, out, err = cli("gcode-check", path, "--machine", "grbl-laser")
    assert code == 1 and err == ""
    lines = [line[len(f"{path}: "):] for line in out.splitlines()]
    assert "line 3: '$H' is a Grbl system command ($), not G-code: a program must not contain it" in lines
    assert "line 4: '$RST=*' is a Grbl system command ($), not G-code: a program must not contain it" in lines
    assert any(line.startswith("line 5: F0 feed on a motion line") for line in lines)
    assert any(line.startswith("line 5: error:22 (feed rate has not yet been set") for line in lines)
    assert any(line.startswith("line 6: F0 feed on a motion line") for line in lines)
    assert any(line.startswith("line 7: '!' is the Grbl real-time command feed hold") for line in lines)
    assert any(line.startswith("line 8: '~' is the Grbl real-time command cycle start") for line in lines)
    assert "line 9: NUL byte (0x00) in the line: the file is damaged or not G-code" in lines
    assert any(line.startswith("line 10: '?' is the Grbl real-time command status report query") for line in lines)
    assert any(line.startswith("line 11: '\\x18' is the Grbl real-time command soft reset") for line in lines)
    assert lines[-1] == "10 problem(s)"


def test_gcode_check_applies_the_grbl_build_and_lists_every_refused_line(cli, tmp_path):
    path = tmp_path / "coolant.gcode"
    path.write_text("G21\nG90\nM7\nG1 X10 Y10 F600\nG43 Z1\nG1 X20 Y20\nM9\nN10000000 G0 X0 Y0\n")
    code, out, _ = cli("gcode-check", path, "--machine", "grbl-laser")
    assert code == 1
    assert f"{path}: line 3: error:20 (unsupported or invalid g-code command found in block): M7" in out
    assert f"{path}: line 5: error:20 (unsupported or invalid g-code command found in block): G43 Z1" in out
    assert "line 8" not in out                      # N10000000 is accepted by the firmware
    code, out, err = cli("gcode-check", path, "--machine", "grbl-laser", "--build-options", "VM")
    assert "line 3:" not in out and "line 5: error:20" in out
    assert f"warning: {path}: M7 (line 3): the controller accepts it" in err


def test_comments_never_carry_realtime_characters(cli, job):
    """Grbl acts on `? ! ~` wherever they are, even in a comment: a profile or part name with them is cleaned."""
    folder, _, _ = job
    text = (BUILTIN_DIR / "grbl-laser.toml").read_text().replace('name = "grbl-laser"', 'name = "shop laser?! ~"')
    (folder / "shop.toml").write_text(text)
    assert cli("export", folder / "nesting.json", "--gcode", folder / "out", "--machine", folder / "shop.toml")[0] == 0
    program = (folder / "out" / "nesting_S1.gcode").read_text()
    assert "shop laser__ _" in program and not set("?!~") & set(program)
    code, out, _ = cli("gcode-check", folder / "out" / "nesting_S1.gcode", "--machine", folder / "shop.toml")
    assert code == 0, out


def test_export_without_an_output_option_writes_beside_the_nesting(cli, job):
    """No -o, --dxf or --gcode: everything goes to `<nesting stem>-export/` beside the nesting file, said before the summary."""
    folder, _, _ = job
    code, out, err = cli("export", folder / "nesting.json")
    assert code == 0, err
    written = _outputs(folder / "nesting-export")
    assert {"nesting_S1.dxf", "nesting_S1.gcode", "nesting_all-sheets.dxf"} <= set(written)
    lines = out.strip().splitlines()
    assert f"{len(written)} files in {folder / 'nesting-export'}" in lines
    assert lines[-1].startswith("total ")  # the summary table comes last


def test_export_output_option_names_the_folder_and_dxf_or_gcode_send_one_kind_elsewhere(cli, job):
    folder, _, _ = job
    code, out, err = cli("export", folder / "nesting.json", "-o", folder / "all", "--no-preview")
    assert code == 0, err
    assert _outputs(folder / "all") == ["cutlist.csv", "nesting_S1.dxf", "nesting_S1.gcode", "nesting_all-sheets.dxf"]
    code, out, err = cli("export", folder / "nesting.json", "--output", folder / "g", "--dxf", folder / "d", "--no-preview")
    assert code == 0, err
    assert _outputs(folder / "g") == ["cutlist.csv", "nesting_S1.gcode"]
    assert _outputs(folder / "d") == ["nesting_S1.dxf", "nesting_all-sheets.dxf"]
    assert f"4 files in {folder / 'd'} and {folder / 'g'}" in out.splitlines()
