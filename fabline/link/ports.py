"""Port URLs checked as inputs and outputs before pyserial sees them, and the endpoint a port's lock is keyed by.

pyserial acts on a URL's options as it parses it, before the port opens: `spy://...?file=F` truncates F then,
and a `sim://...?log=F` simulator appends to F. So a URL is refused unless every option is one its handler
takes (`OPTIONS`, as pyserial 3.5 and fabline's sim:// know them), and a file a URL writes is checked like any
output (`fabline.fileio.check_outputs`: a regular file or a new name, never an input), inside a job never outside
its output folder, and refused outright where no file may be written (the runner's machines).
"""

from __future__ import annotations

import os
import re
import socket
import urllib.parse
from pathlib import Path

from fabline.errors import FablineError
from fabline.fileio import check_outputs
from fabline.link.protocol_sim import SIM_OPTIONS

LOG_LEVELS = ("debug", "info", "warning", "error")
"""The values pyserial's `logging=` option takes (to the standard error, no file)."""
OPTIONS: dict[str, tuple[str, ...]] = {
    "sim": SIM_OPTIONS,
    "spy": ("file", "color", "raw", "all"),
    "socket": ("logging",),
    "rfc2217": ("logging", "ign_set_control", "poll_modem", "timeout"),
    "loop": ("logging",),
    "alt": ("class",),
    "cp2110": (),
    "hwgrep": ("n", "skip_busy"),
}
"""Each URL scheme pyserial (or fabline) serves, with the options its handler takes; no other is accepted."""
WRITES = {"spy": "file", "sim": "log"}
"""The option of a scheme that names a file the port writes (a spy's trace, the simulator's executed-line log)."""


def _options(url: str, scheme: str) -> list[tuple[str, str]]:
    """The URL's options as its handler reads them (hwgrep's `REGEXP&n=2&skip_busy`, the others a query)."""
    if scheme == "hwgrep":
        return [(arg.partition("=")[0], arg.partition("=")[2]) for arg in url.split("://", 1)[1].split("&")[1:]]
    return urllib.parse.parse_qsl(urllib.parse.urlsplit(url).query, keep_blank_values=True)


def port_files(url: str) -> list[Path]:
    """The files a port URL makes pyserial or the simulator write (every value given, relative ones from the
    working folder, where they are opened)."""
    scheme = url.split("://", 1)[0].lower() if "://" in url else None
    key = WRITES.get(scheme or "")
    return [Path(os.path.abspath(value)) for name, value in _options(url, scheme) if name == key] if key else []


def check_port(url: str, *, inputs: tuple = (), outputs: tuple = (), within: str | os.PathLike | None = None,
               files: bool = True) -> list[Path]:
    """Refuse, with one line, a port URL of an unknown scheme or with an option its handler does not take, and a
    file the URL would write that is an input (`inputs`), another output (`outputs`), not a regular file, outside
    the folder `within` (a job's output folder) or there at all when `files` is false; returns those files.
    Nothing is opened or created: a device path or a well-formed URL passes, whether it opens is found later."""
    if "://" not in url:
        return []
    scheme = url.split("://", 1)[0]
    if scheme.lower() not in OPTIONS:
        raise FablineError(f"port {url}: unknown scheme {scheme}:// (use a device such as /dev/ttyUSB0, or "
                           f"{', '.join(f'{s}://' for s in OPTIONS)})")
    scheme = scheme.lower()
    for name, value in _options(url, scheme):
        if name not in OPTIONS[scheme]:
            takes = ", ".join(OPTIONS[scheme]) or "none"
            raise FablineError(f"port {url}: unknown option {name!r} for {scheme}:// (it takes: {takes})")
        if name == "logging" and value not in LOG_LEVELS:
            raise FablineError(f"port {url}: logging={value!r}: use one of {', '.join(LOG_LEVELS)}")
        if scheme == "sim":
            _check_sim_option(url, name, value)
    written = port_files(url)
    if not written:
        return []
    option = WRITES[scheme]
    if not files:
        raise FablineError(f"port {url}: {option}= would write {written[0]}, and no port may write a file here "
                           f"(drop {option}=)")
    if within is not None:
        base = Path(os.path.realpath(within))
        for path in written:
            target = Path(os.path.realpath(path))
            if base not in target.parents:
                raise FablineError(f"port {url}: {option}= would write {path}, outside the job's output folder "
                                   f"{base}; name a file inside it")
    try:
        check_outputs(files=(*written, *outputs), inputs=inputs)
    except FablineError as exc:
        raise FablineError(f"port {url}: {option}=: {exc}") from None
    return written


def _check_sim_option(url: str, name: str, value: str) -> None:
    """A sim:// option the simulator would refuse when it starts, refused now: `machine=` a known profile's name
    (a path is not taken: a URL must not make fabline read any file it names), `time_scale=` and every number
    option in its range."""
    if name == "machine":
        from fabline.machine.profile import available_machines

        if value not in available_machines():
            raise FablineError(f"port {url}: machine={value!r}: not a machine profile's name (use one of "
                               f"{', '.join(available_machines())})")
    elif name == "time_scale":
        from fabline.link.simulator import check_time_scale

        try:
            check_time_scale(float(value))
        except ValueError as exc:
            raise FablineError(f"port {url}: time_scale={value!r}: {exc if 'time_scale' in str(exc) else 'not a number'}") from None
    else:
        from fabline.link.protocol_sim import NUMBER_OPTIONS, sim_number

        if name in NUMBER_OPTIONS:
            try:
                sim_number(name, value)
            except ValueError as exc:
                raise FablineError(f"port {url}: {exc}") from None


def port_endpoints(url: str) -> list[str]:
    """What a port reaches, as lock keys: a device by its real path (a symlink and its target are one), a TCP
    port by every address its host resolves to (`localhost` and `127.0.0.1` meet at 127.0.0.1), a simulator
    within this process (another process has its own); sorted, so that locks are always taken in one order."""
    if "://" not in url:
        return [os.path.realpath(url)]
    scheme, rest = url.split("://", 1)
    scheme = scheme.lower()
    if scheme == "sim":
        return [f"sim://{urllib.parse.urlsplit(url).netloc or 'grbl'}#{os.getpid()}"]
    if scheme in ("socket", "rfc2217"):
        parts = urllib.parse.urlsplit(url)
        try:
            port = parts.port
            found = socket.getaddrinfo(parts.hostname, port, type=socket.SOCK_STREAM) if port is not None else []
        except (OSError, ValueError, UnicodeError):
            found = []
        addresses = sorted({info[4][0] for info in found}) or [str(parts.hostname).lower()]
        return [f"tcp://[{address}]:{port}" for address in addresses]
    if scheme in ("spy", "alt", "cp2110"):
        device = re.split(r"[?#]", rest, maxsplit=1)[0]
        return [os.path.realpath(device) if device.startswith("/") else f"{scheme}://{device}"]
    return [url.split("?", 1)[0]]
