"""Controllers beyond Grbl 1.1: grblHAL and FluidNC recognised from their banners and `$I`, their settings read into
Grbl's numbers (FluidNC's from its YAML config), compatibility fixes said in their terms, and a job streamed to each
one's simulator exactly once through a killed host and a resume."""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

from fabline.errors import FablineError
from fabline.link import SimulatorServer, Streamer, executed_file_lines, read_journal
from fabline.link.connection import Connection
from fabline.link.controller import Grbl
from fabline.link.dialects import FLUIDNC, GRBL, GRBLHAL, fluidnc_settings, read_config, recognise
from fabline.link.protocol import LineSplitter, classify
from fabline.link.protocol_sim import close_simulator, get_simulator
from fabline.machine import load_program
from fabline.machine.build import BuildInfo

from .campaign_cases import HOST, REPO, SETTINGS, random_program, recover

FIRMWARES = ("grbl", "grblhal", "fluidnc")


@pytest.fixture
def sim(tmp_path):
    """sim(firmware, **options) -> URL of a uniquely named simulator of that firmware; closed afterwards."""
    names = []

    def url(firmware: str, **options) -> str:
        name = f"d{uuid.uuid4().hex[:8]}"
        names.append(name)
        query = {"time_scale": 50, "log": tmp_path / f"{name}.log", "firmware": firmware, **options}
        return f"sim://{name}?" + "&".join(f"{key}={value}" for key, value in query.items())

    yield url
    for name in names:
        close_simulator(name)


# ----- banners and $I, as the firmware sources print them -------------------------------------------------------
def test_banners_are_recognised_per_family():
    """The banners as the sources print them: gnea/grbl report.c report_init_message `"\\r\\nGrbl " GRBL_VERSION
    " ['$' for help]\\r\\n"`; grblHAL/core report.c report_init_message `"GrblHAL " GRBL_VERSION " ['$' or '$HELP'
    for help]"` (COMPATIBILITY_LEVEL 0; above it the Grbl form); bdring/FluidNC SettingsDefinitions.cpp
    start_message default `"Grbl \\V [FluidNC \\B (\\R) \\H]"` expanded by Report.cpp report_init_message (\\V the
    grbl version, \\B the git tag, \\R the radios or `noradio`, \\H `'$' for help`)."""
    grbl, grblhal, fluidnc = ("Grbl 1.1h ['$' for help]", "GrblHAL 1.1f ['$' or '$HELP' for help]",
                              "Grbl 3.7 [FluidNC v3.7.8 (wifi) '$' for help]")
    assert [recognise(banner) for banner in (grbl, grblhal, fluidnc)] == [GRBL, GRBLHAL, FLUIDNC]
    assert recognise("Grbl 3.9 [FluidNC v3.9.5 (bt+wifi) '$' for help]") is FLUIDNC
    assert recognise("Marlin 2.1.2") is None
    assert [classify(banner).kind for banner in (grbl, grblhal, fluidnc)] == ["banner"] * 3


def test_grblhal_build_info_gives_its_buffers_axes_and_family():
    """grblHAL/core report.c report_build_info: `[VER:` GRBL_VERSION `.` GRBL_BUILD `:` line `]`, then `[OPT:`
    letters `,` plan_get_buffer_size() `,` hal.rx_buffer_size `,` N_AXIS `,` N_TOOLS `]` (extended, always at
    COMPATIBILITY_LEVEL 0), `[AXS:3:XYZ]`, `[NEWOPT:ENUMS,RT+,...]`, `[FIRMWARE:grblHAL]`; the captured
    `[OPT:VNMSL,100,1024,3,0]` is from the README of bjerrep/grblHAL_core (an STM32H7 build)."""
    feedback = ["[VER:1.1f.20241222:]", "[OPT:VNMSL,100,1024,3,0]", "[AXS:3:XYZ]", "[NEWOPT:ENUMS,RT+,HOME,TC,SED]",
                "[FIRMWARE:grblHAL]", "[DRIVER:STM32H723]"]
    build = BuildInfo.parse(feedback)
    assert (build.firmware, build.version, build.options, build.planner_blocks, build.rx_buffer, build.axes) == \
        ("grblhal", "1.1f.20241222", "VNMSL", 100, 1024, 3)
    assert build.line_numbers and build.mist_coolant
    # a grblHAL reporting itself as Grbl (COMPATIBILITY_LEVEL 1) is still told by its FIRMWARE line
    compatible = ["[VER:1.1f.20241222:]", "[OPT:VNM,35,1024,3,0]", "[FIRMWARE:grblHAL]"]
    assert BuildInfo.parse(compatible).firmware == "grblhal"


def test_fluidnc_build_info_has_no_buffer_sizes_so_its_stock_ones_are_kept():
    """bdring/FluidNC Report.cpp report_build_info: `[VER:` grbl_version ` FluidNC ` git_info `:` line, then
    `[OPT:` letters only (M with mist, `PH`, A, B with bluetooth, `S`, R, E and W shown when disabled), then
    `[MSG:Machine: ...]`; Uart.cpp rx_buffer_available is UART_FIFO_LEN (128 on an ESP32) - available()."""
    build = BuildInfo.parse(["[VER:3.7 FluidNC v3.7.8:]", "[OPT:PHSEW]", "[MSG:Machine: K40 laser]"])
    assert (build.firmware, build.version, build.options, build.rx_buffer, build.planner_blocks) == \
        ("fluidnc", "3.7 FluidNC v3.7.8", "PHSEW", 128, 15)
    assert not build.line_numbers and not build.mist_coolant
    grbl = BuildInfo.parse(["[VER:1.1h.20190830:]", "[OPT:V,15,128]"])  # grbl-1.1h-transcript.txt, $I
    assert (grbl.firmware, grbl.rx_buffer, grbl.planner_blocks) == ("grbl", 128, 15)


# ----- FluidNC's config ---------------------------------------------------------------------------------------
FLUIDNC_DUMP = """name: K40
board: 6 Pack
junction_deviation_mm: 0.020
arc_tolerance_mm: 0.002
stepping:
  engine: RMT
  idle_ms: 250
axes:
  shared_stepper_disable_pin: NO_PIN
  x:
    steps_per_mm: 157.575
    max_rate_mm_per_min: 24000.000
    acceleration_mm_per_sec2: 2500.000
    max_travel_mm: 320.000
    soft_limits: true
    homing:
      cycle: 1
      mpos_mm: 0.000
  y:
    steps_per_mm: 157.575
    max_rate_mm_per_min: 24000.000
    acceleration_mm_per_sec2: 2500.000
    max_travel_mm: 220.000
    soft_limits: true
Laser:
  pwm_hz: 5000
  output_pin: gpio.26
  speed_map: 0=0.000% 1000=100.000%
""".splitlines()
"""A dump shaped as FluidNC's Configuration/Generator.cpp writes it (a section a bare `key:`, two spaces a level;
keys from Machine/Axis.cpp, Axes.cpp and the example configs of the FluidNC wiki), kept apart from what the
simulator prints."""


def test_fluidnc_laser_mode_and_travel_come_from_its_config():
    config = read_config(FLUIDNC_DUMP)
    assert config["axes/x/max_travel_mm"] == "320.000" and config["axes/x/homing/mpos_mm"] == "0.000"
    assert config["axes/y/max_travel_mm"] == "220.000" and "Laser" in config
    settings = fluidnc_settings(config)
    assert (settings[32], settings[130], settings[131], settings[110], settings[120], settings[20]) == \
        (1.0, 320.0, 220.0, 24000.0, 2500.0, 1.0)
    assert (settings[11], settings[12]) == (0.02, 0.002)
    plain = fluidnc_settings(read_config([line.replace("Laser:", "PWM:") for line in FLUIDNC_DUMP]))
    assert plain[32] == 0.0


def test_the_line_splitter_keeps_indents_for_the_yaml_dump():
    """FluidNC ends its lines with CR LF (UartChannel adds the CR); the indent is the config's structure."""
    assert LineSplitter().feed(b"axes:\r\n  x:\r\n    max_travel_mm: 320.000\r\n") == \
        ["axes:", "  x:", "    max_travel_mm: 320.000"]


# ----- each simulator answers as its firmware ----------------------------------------------------------------
@pytest.mark.parametrize("firmware, label, rx, blocks", [("grbl", "Grbl 1.1", 128, 15),
                                                         ("grblhal", "grblHAL", 1024, 100),
                                                         ("fluidnc", "FluidNC", 128, 15)])
def test_the_host_detects_each_simulated_firmware_and_its_settings(sim, firmware, label, rx, blocks):
    url = sim(firmware, settings="32:1,130:900")
    controller = Grbl(Connection(url))
    controller.open()
    try:
        assert (controller.dialect.label, controller.rx_buffer, controller.build.planner_blocks) == (label, rx, blocks)
        assert controller.settings[32] == 1 and controller.settings[130] == 900
        settings_listed = controller.connection.command(b"$$\n")
        assert ("$32=1" in settings_listed) == (firmware != "fluidnc")  # FluidNC's $$: proxies only, no $32
        if firmware == "fluidnc":
            dump = controller.connection.command(b"$CD\n", every_line=True)
            assert "Laser:" in dump and "    max_travel_mm: 900.000" in dump
            controller.connection.command(b"$32=0\n", expect_error=True)  # a proxy is not set by number
    finally:
        controller.connection.close()


@pytest.mark.parametrize("firmware", FIRMWARES)
def test_each_simulator_greets_with_its_own_banner_after_a_reset(sim, firmware):
    url = sim(firmware)
    connection = Connection(url)
    connection.connect()
    try:
        connection.write(b"\x18")
        deadline, banners = time.monotonic() + 3, []
        while not banners and time.monotonic() < deadline:
            banners = [response.text for response in connection.read(0.05) if response.kind == "banner"]
        assert recognise(banners[0]).name == firmware
    finally:
        connection.close()


def test_grblhal_reports_line_numbers_by_default_and_its_bigger_buffer(sim):
    """grblHAL report.c report_realtime_status: `|Bf:` blocks free, rx free and `|Ln:` when $10 has them (its
    default $10 reports both); a stock Grbl 1.1h ($10=1, no N option) reports neither."""
    url = sim("grblhal", time_scale=1)
    connection = Connection(url)
    connection.connect()
    try:
        connection.command(b"$X\n")
        connection.write(b"G21G90G1F60\nN7 G1 X5\n")
        time.sleep(0.2)
        status = connection.query_status()
        assert status.state == "Run" and status.line_number == 7 and status.rx_free == 1024
        assert status.planner_free == 99
    finally:
        connection.close()


# ----- compatibility in each dialect's terms --------------------------------------------------------------------
def laser_program(path: Path) -> Path:
    path.write_text("G21\nG90\nM4 S0\nG1 X10 Y10 S1000 F1500\nM5\nM2\n",
                    encoding="ascii")
    return path


@pytest.mark.parametrize("firmware, fix", [
    ("grbl", "send $32=1 to the controller"),
    ("grblhal", "send $32=1 to the controller (grblHAL's mode of operation: 1 is laser)"),
    ("fluidnc", "make the spindle of the FluidNC config (config.yaml; $CD shows it) a Laser: spindle"),
])
def test_laser_mode_off_is_refused_with_the_fix_of_each_dialect(tmp_path, sim, firmware, fix):
    url = sim(firmware, settings="32:0,110:20000,111:20000,130:2000,131:2000")
    with pytest.raises(FablineError) as refused:
        Streamer(url, status_interval=0.02).run(laser_program(tmp_path / "sheet.gcode"), machine="grbl-laser")
    message = str(refused.value)
    assert "$32=0" in message and fix in message and "nothing was sent" in message
    log = Path(url.split("log=")[1].split("&")[0])
    assert not log.exists() or executed_file_lines(log) == []


def test_fluidnc_travel_too_short_names_its_config_key(tmp_path, sim):
    url = sim("fluidnc", settings="32:1,110:20000,111:20000,130:5,131:2000")
    with pytest.raises(FablineError) as refused:
        Streamer(url, status_interval=0.02).run(laser_program(tmp_path / "sheet.gcode"), machine="grbl-laser")
    assert "X travel $130 is 5 mm" in str(refused.value)


# ----- exact-once through a killed host, per dialect -------------------------------------------------------------
def _killed_and_resumed(program: Path, share: int, server: SimulatorServer, log: Path) -> None:
    """Stream `program` from a host process, SIGKILL it once 1/`share` of the lines were answered, then recover as
    documented (--resume, or the operator's --from-line where fabline names the candidates): every line ran
    exactly once, in order, by the simulator's executed-line `log`."""
    lines = load_program(program).lines
    journal = Path(f"{program}.journal")
    host = subprocess.Popen([sys.executable, "-c", HOST, server.url, str(program)], stderr=subprocess.PIPE,
                            env={**os.environ, "PYTHONPATH": str(REPO)})
    deadline = time.monotonic() + 120
    while host.poll() is None and time.monotonic() < deadline and (
            not journal.exists() or journal.read_text().count('"event":"ok"') < len(lines) // share):
        time.sleep(0.005)
    host.send_signal(signal.SIGKILL)
    host.wait()
    assert not read_journal(journal).finished, "the job finished before the kill: make it longer or slower"
    executed = lambda: executed_file_lines(log)  # noqa: E731
    assert 0 < len(executed()) < len(lines)
    recover(server.url, program, executed, [])
    assert executed_file_lines(log) == [line.file_line for line in lines]


@pytest.mark.parametrize("firmware", FIRMWARES)
def test_a_job_killed_mid_stream_resumes_exactly_once_on_each_firmware(tmp_path, firmware):
    """The campaign's laser programs (out-and-back paths, arcs, dwells, power changes) on each firmware's stock
    build; the host is SIGKILLed after a quarter of its lines were answered and `--resume` finishes the job."""
    rng = random.Random(f"dialect-{firmware}")
    program = tmp_path / "sheet.gcode"
    program.write_text("\n".join(random_program(rng, (0.0, 0.0))) + "\n", encoding="ascii")
    log = tmp_path / "executed.log"
    with SimulatorServer(log=log, time_scale=20, faults={"settings": SETTINGS, "firmware": firmware}) as server:
        _killed_and_resumed(program, 4, server, log)


def test_alarms_beyond_grbl_are_explained_in_each_dialects_numbering():
    """grblHAL/core alarms.c: 11 is Alarm_HomingRequired "Homing required. Execute homing command ($H) to
    continue."; bdring/FluidNC Protocol.h: ExecAlarm 11 is ControlPin, AlarmNames "Control Pin Initially On";
    Grbl 1.1 has no alarm 11 (gnea/grbl report.c lists 1-9)."""
    assert "homing required" in GRBLHAL.explain_alarm(11)
    assert "control pin initially on" in FLUIDNC.explain_alarm(11)
    assert GRBL.explain_alarm(11) == "ALARM:11 (unknown Grbl 1.1 alarm code)"
    assert GRBL.explain_alarm(2) == GRBLHAL.explain_alarm(2) == FLUIDNC.explain_alarm(2)


def test_errors_beyond_grbl_are_explained_in_grblhals_numbering():
    """grblHAL/core gcode.h status_code_t: Status_HomingRequired = 46, Status_EStop = 50; errors.c: "Home machine
    to continue.", "Emergency stop active."; Grbl 1.1 stops at 38 (report.c)."""
    assert GRBLHAL.explain_error(46) == "error:46 (home machine to continue)"
    assert GRBLHAL.explain_error(50) == "error:50 (emergency stop active)"
    assert GRBL.explain_error(46) == "error:46 (unknown Grbl 1.1 error code)"
    assert GRBLHAL.explain_error(20) == GRBL.explain_error(20)


def test_a_sim_url_named_after_a_firmware_is_a_stock_build_of_it_and_a_bad_firmware_is_refused():
    for name in ("grblhal", "fluidnc"):
        controller = Grbl(Connection(f"sim://{name}?time_scale=50"))
        try:
            controller.open()
            assert controller.dialect.name == name and controller.build == BuildInfo.parse(
                get_simulator(name).build.lines())
        finally:
            controller.connection.close()
            close_simulator(name)
    with pytest.raises(FablineError, match="firmware must be one of grbl, grblhal, fluidnc, not 'marlin'"):
        Grbl(Connection("sim://m1?firmware=marlin")).open()


def test_status_reports_of_grblhal_and_fluidnc_are_read():
    """grblHAL/core report.c report_realtime_status: `|FS:` rate `,` programmed rpm, and `,` the measured rpm when
    the spindle reports it (get_data); `|Pn:`, `|WCO:`, `|A:`, `|H:`, `|FW:grblHAL` after. bdring/FluidNC
    Report.cpp: `Hold:0`/`Hold:1`, `|FS:` always, `|Pn:` when a pin is active, a running job's progress."""
    grblhal = classify("<Run|MPos:10.000,5.000,0.000,0.000|Bf:98,1012|Ln:42|FS:1500,12000,11985|Pn:P|WCO:0.000,0.000,"
                       "0.000,0.000|A:S|H:1,7|FW:grblHAL>")
    assert grblhal.kind == "status"
    status = grblhal.status
    assert (status.state, status.line_number, status.feed, status.speed, status.rx_free, status.pins) == \
        ("Run", 42, 1500.0, 12000.0, 1012, "P")
    fluidnc = classify("<Hold:0|MPos:1.000,2.000,0.000|FS:0,0|Pn:XY|SD:12.50,/sd/sheet.nc>")
    assert fluidnc.kind == "status" and fluidnc.status.substate == 0 and fluidnc.status.pins == "XY"


@pytest.fixture(scope="module")
def pavilion_sheet(tmp_path_factory) -> Path:
    """The first sheet of a pavilion-like job (lamella strips with slots, marks and labels, washers, clamps) as
    `export` writes it for the grbl-laser profile: lead-ins, tabs, arcs, the laser armed once."""
    from fabline.export.job import export_job
    from fabline.export.samplejob import pavilion_job
    from fabline.export.toolpath import ToolpathOptions
    from fabline.machine import load_machine

    nesting, partset = pavilion_job(strips=24, washers=60, clamps=12)
    nesting.sheets = nesting.sheets[:1]
    profile = load_machine("grbl-laser")
    folder = tmp_path_factory.mktemp("pavilion")
    export_job(nesting, {part.id: part for part in partset.parts}, profile, ToolpathOptions.for_profile(profile),
               gcode_dir=folder, name="pavilion")
    return next(folder.glob("pavilion_*.gcode"))


@pytest.mark.parametrize("firmware", FIRMWARES)
def test_a_pavilion_sheet_killed_mid_stream_resumes_exactly_once_on_each_firmware(pavilion_sheet, tmp_path, firmware):
    """An exported sheet streamed to each firmware's stock build set up as the grbl-laser machine (laser mode, a
    4100 x 2100 mm bed), the host SIGKILLed after a third of its lines were answered, then `--resume`: every
    program line ran exactly once, in order (the simulator's executed-line log)."""
    program = tmp_path / pavilion_sheet.name
    program.write_bytes(pavilion_sheet.read_bytes())
    assert len(load_program(program).lines) > 2000
    log = tmp_path / "executed.log"
    with SimulatorServer(log=log, time_scale=2000, machine="grbl-laser", faults={"firmware": firmware}) as server:
        _killed_and_resumed(program, 3, server, log)
