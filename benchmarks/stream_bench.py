"""Streaming throughput: character counting vs send-response over a real pseudo-terminal at 115200 baud.

A GRBL simulator runs in its own process behind `pty.openpty`, pacing bytes to 11520 bytes/s each way
like a 115200-baud serial line, with motion sped up so the controller is not the bottleneck. Three links:
a bare UART to an instant controller; an Arduino-Uno-like USB bridge (answers flushed every 4 ms) to an
instant controller; and that bridge to a controller that needs 1 ms to parse and plan each line. An 8-bit
Grbl needs more (2.4-3.6 ms per line with the steppers running, gnea/grbl#1144; about 5 ms by its author,
grbl/grbl#492); 1 ms stays below a 22-byte line's 1.9 ms on the wire, so the controller is still not the
bottleneck. Prints lines/s and the host-to-controller link utilisation (bytes sent / line capacity), then
character counting per firmware (stock Grbl 1.1h, 128 RX bytes; grblHAL, 1024; FluidNC, 128) on each link against
the link's limit (lines/s if every byte of the line went at the baud rate).
Run: python benchmarks/stream_bench.py [--lines 20000]
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fabline.link import SimulatorServer, Streamer, executed_file_lines
from fabline.machine import load_program  # noqa: E402

BAUD = 115200
BYTES_PER_SECOND = BAUD / 10
LINKS = {"UART, instant": (0.0, 0.0), "USB 4ms, instant": (0.004, 0.0), "USB 4ms, 1ms/line": (0.004, 0.001)}
"""Label -> (adapter latency s, firmware seconds per line): bare paced UART, Uno 16U2 bridge, bridge + parse time."""


def write_program(path: Path, lines: int) -> None:
    """Laser cuts along a spiral, like the export stage writes them: one short G1 per line."""
    body = ["G21", "G90", "G17", "G94", "M4 S800", "F6000"]
    for step in range(lines - len(body) - 1):
        radius = 20 + step * 0.01
        angle = step * 0.05
        body.append(f"G1 X{500 + radius * math.cos(angle):.3f} Y{500 + radius * math.sin(angle):.3f}")
    body.append("M5")
    path.write_text("\n".join(body) + "\n", encoding="ascii")


FIRMWARES = ("grbl", "grblhal", "fluidnc")


def measure(program: Path, mode: str, link: str, workdir: Path, firmware: str = "grbl") -> dict:
    latency, line_time = LINKS[link]
    run = f"{firmware}-{mode}-{latency}-{line_time}"
    log = workdir / f"executed-{run}.log"
    with SimulatorServer(log=log, time_scale=1e4, transport="pty", baud=BAUD, adapter_latency=latency,
                         line_time=line_time, faults={"settings": "32:1,130:1000,131:1000",  # stock build, laser
                                                      "firmware": firmware}) as server:
        streamer = Streamer(server.url, mode=mode, status_interval=0.2)
        result = streamer.run(program, journal=workdir / f"{run}.journal")
    executed = executed_file_lines(log)
    expected = [line.file_line for line in load_program(program).lines]
    assert result.completed and executed == expected, f"{mode}: controller did not execute the program exactly"
    return {"mode": mode, "link": link, "firmware": firmware, "rx": streamer.rx_buffer, "lines": result.total,
            "seconds": result.elapsed,
            "rate": result.total / result.elapsed, "bytes": result.bytes_sent,
            "utilisation": result.bytes_sent / (result.elapsed * BYTES_PER_SECOND)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lines", type=int, default=20000)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        workdir = Path(folder)
        program = workdir / "bench.gcode"
        write_program(program, args.lines)
        lines = load_program(program).lines
        rows = [measure(program, mode, link, workdir) for link in LINKS for mode in ("counting", "send-response")]
        dialects = {(row["link"], "grbl"): row for row in rows if row["mode"] == "counting"}
        dialects.update({(link, firmware): measure(program, "counting", link, workdir, firmware)
                         for link in LINKS for firmware in FIRMWARES if firmware != "grbl"})
    limit = len(lines) / (sum(len(line.wire) for line in lines) / BYTES_PER_SECOND)
    print(f"{'link':<18} {'mode':<14} {'lines':>7} {'seconds':>8} {'lines/s':>8} {'bytes':>9} {'link use':>9}")
    for row in rows:
        print(f"{row['link']:<18} {row['mode']:<14} {row['lines']:>7} {row['seconds']:>8.1f} {row['rate']:>8.0f} "
              f"{row['bytes']:>9} {row['utilisation']:>8.1%}")
    for counting, single in zip(rows[::2], rows[1::2]):
        print(f"{counting['link']}: character counting / send-response = {counting['rate'] / single['rate']:.2f}x")
    print(f"\ncharacter counting per firmware; link limit {limit:.0f} lines/s (the program's bytes at {BAUD} baud)")
    print(f"{'link':<18} {'firmware':<9} {'rx':>5} {'lines/s':>8} {'of limit':>9} {'link use':>9}")
    for link, firmware in ((link, firmware) for link in LINKS for firmware in FIRMWARES):
        row = dialects[(link, firmware)]
        print(f"{link:<18} {firmware:<9} {row['rx']:>5} {row['rate']:>8.0f} {row['rate'] / limit:>8.1%} "
              f"{row['utilisation']:>8.1%}")
    print(f"(link {BAUD} baud = {BYTES_PER_SECOND:.0f} bytes/s each way; controller motion sped up 10^4 times)")


if __name__ == "__main__":
    main()
