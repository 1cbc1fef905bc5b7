"""Checking a program against the controller before it moves: `stream --check` on the simulator, exported
sheets of every profile, every refused line listed, and resumes refused after offset changes."""

from __future__ import annotations

import uuid

import pytest
import serial

from fabline.errors import FablineError
from fabline.link import Streamer
from fabline.link.protocol_sim import close_simulator, get_simulator
from fabline.machine.build import BuildInfo
from fabline.machine.gcode import ModalState
from fabline.machine.program import load_program
from fabline.nest.layout import save_nesting
from fabline.unroll.parts import save_parts

from export_helpers import every_kind_nesting, every_kind_partset

ARCS = "G21\nG90\nG0 X10 Y0\nG2 X0 Y10 I-10 J0 F1000\nG3 X10 Y0 I0 J-10\nG2 X0 Y10 R10\nG0 X0 Y0\n"


@pytest.fixture
def url(tmp_path):
    name = f"check{uuid.uuid4().hex[:8]}"
    yield f"sim://{name}?time_scale=500&log={tmp_path / 'executed.log'}", name
    close_simulator(name)


@pytest.fixture(scope="module")
def sheets(tmp_path_factory):
    """The every-kind job exported for each built-in profile: {profile: G-code path}."""
    from fabline.cli import main

    folder = tmp_path_factory.mktemp("sheets")
    save_parts(every_kind_partset(), folder / "parts.json")
    save_nesting(every_kind_nesting(), folder / "nesting.json")
    paths = {}
    for machine in ("grbl-laser", "grbl-plotter", "rs274-mill"):
        assert main(["export", str(folder / "nesting.json"), "--gcode", str(folder / machine), "--machine", machine,
                     "--lead-in", "2", "--tabs", "2"]) == 0
        paths[machine] = folder / machine / "nesting_S1.gcode"
    return paths


def test_check_mode_keeps_the_parser_position_through_arcs(cli, url, tmp_path):
    """Grbl tracks its parser position in check mode; the simulator answered error:33 at the first arc."""
    path = tmp_path / "arcs.gcode"
    path.write_text(ARCS)
    code, out, err = cli("stream", path, "--port", url[0], "--check")
    assert code == 0, err
    assert "7 lines streamed" in out


@pytest.mark.parametrize("machine", ["grbl-laser", "grbl-plotter", "rs274-mill"])
def test_exported_sheets_pass_the_controllers_check_mode(cli, url, sheets, machine):
    text = sheets[machine].read_text()
    assert " G2 " in text or "\nG2 " in text or "\nG3 " in text or " G3 " in text   # the sheet has arcs
    program = load_program(sheets[machine])           # the rs274-mill header (G40 G49 G80) was error:20 here
    assert len(program.lines) > 100
    from fabline.machine import load_machine

    settings = ",".join(f"{key}:{value:g}" for key, value in load_machine(machine).controller_settings().items())
    port = url[0].replace("time_scale=500", f"time_scale=50000&settings={settings}")  # the machine the profile is for
    code, out, err = cli("stream", sheets[machine], "--port", port, "--check")
    assert code == 0, err


class _RefuseLines:
    """Simulator faults that make the controller refuse each of `lines` (file line numbers) once with `code`."""

    def __init__(self, lines: list[int], code: int):
        self.pending, self.error_code = list(lines), code
        self.drop_at, self.corrupt_at, self.alarm_line, self.stall_at, self.stall_seconds = [], [], None, None, 0.0

    @property
    def error_line(self) -> int | None:
        return self.pending[0] if self.pending else None

    @error_line.setter
    def error_line(self, value) -> None:
        self.pending.pop(0)


def test_check_mode_lists_every_line_the_controller_refuses(cli, url, tmp_path):
    path = tmp_path / "job.gcode"
    path.write_text("G21\nG90\n" + "".join(f"G1 X{i} Y{i % 3} F2000\n" for i in range(1, 60)))
    serial.serial_for_url(url[0]).close()              # the controller exists from the first connection on
    get_simulator(url[1]).faults = _RefuseLines([7, 30, 55], 33)
    code, out, err = cli("stream", path, "--port", url[0], "--check")
    assert code == 2 and out == ""
    lines = err.splitlines()
    assert lines[0] == "fabline stream: error: check mode: the controller refuses 3 lines:"
    assert lines[1:] == [f"{path}:{n}: check mode: error:33 (the motion command has an invalid target; G2, G3, and "
                         f"G38.2 generates this error): G1 X{n - 2} Y{(n - 2) % 3} F2000" for n in (7, 30, 55)]
    assert not (tmp_path / "executed.log").exists() or (tmp_path / "executed.log").read_text() == ""


def test_offline_plan_lists_every_line_the_firmware_would_refuse(tmp_path):
    path = tmp_path / "job.gcode"
    path.write_text("G21\nM7\nG1 X5\nG43 Z1\nG0 X1\n")
    with pytest.raises(FablineError) as error:
        load_program(path)
    assert str(error.value).splitlines() == [
        "3 lines the controller would refuse:",
        f"{path}:2: error:20 (unsupported or invalid g-code command found in block): M7",
        f"{path}:3: error:22 (feed rate has not yet been set or is undefined): G1 X5",
        f"{path}:4: error:20 (unsupported or invalid g-code command found in block): G43 Z1"]


def test_a_resume_after_a_work_offset_change_is_refused(cli, url, tmp_path):
    path = tmp_path / "job.gcode"
    path.write_text("G21\nG90\nG0 X50 Y50\nG92 X0 Y0\n" + "".join(f"G1 X{i} Y{i % 3} F2000\n" for i in range(1, 40)))
    code, _, err = cli("stream", path, "--port", url[0] + "&error_line=20&error_code=33")
    assert code == 2 and f"{path}:20: controller answered error:33" in err
    code, _, err = cli("stream", path, "--port", url[0], "--resume")
    assert code == 2
    assert err == (f"fabline stream: error: {path}:4: cannot resume after this line: G92 depends on offsets or "
                   "positions stored in the controller, which a resume cannot re-establish; start the sheet over "
                   "with --restart\n")


def test_a_program_with_mist_coolant_loads_for_a_build_with_option_m(tmp_path):
    path = tmp_path / "mist.gcode"
    path.write_text("G21\nM7\nG1 X5 F100\nM9\n")
    with pytest.raises(FablineError, match=r"mist.gcode:2: error:20"):
        load_program(path)
    assert [block.modal.coolant for block in load_program(path, BuildInfo(options="VM")).plan(
        ModalState(), (0.0, 0.0, 0.0), BuildInfo(options="VM"))] == ["M9", "M7", "M7", "M9"]


def test_check_mode_gives_up_on_a_silent_controller_with_a_message(url, tmp_path):
    path = tmp_path / "job.gcode"
    path.write_text("G21\nG90\n" + "".join(f"G1 X{i} Y{i % 3} F2000\n" for i in range(1, 60)))
    streamer = Streamer(url[0] + "&stall_at=400&stall_seconds=5", silence_timeout=0.5)
    with pytest.raises(FablineError, match=r"check mode: no answer for 0.5 s after \d+ of 61 lines"):
        streamer.run(path, check=True)


def test_a_resume_before_the_offset_change_goes_on(cli, url, tmp_path):
    path = tmp_path / "late.gcode"
    path.write_text("G21\nG90\n" + "".join(f"G1 X{i} Y{i % 3} F2000\n" for i in range(1, 30)) + "G92 X0 Y0\nG0 X1 Y1\n")
    code, _, err = cli("stream", path, "--port", url[0] + "&error_line=12&error_code=33")
    assert code == 2 and f"{path}:12: controller answered error:33" in err
    code, out, err = cli("stream", path, "--port", url[0], "--resume")
    assert code == 0, err
