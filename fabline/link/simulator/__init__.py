"""An in-process GRBL 1.1h controller simulator: receive buffer, planner, motion in (scaled) time, faults.

It answers like the firmware captured in `grbl-1.1h-transcript.txt` (banner, `$$`, `$I`, `$G`, `$#`,
`ok`/`error:N`, `ALARM:N`, status reports per `$10`, check mode, feed hold) and records every line it
executes, in execution order, to an append-only executed-line log. It is a stock build unless told
otherwise (`build=BuildInfo(options="VN")` adds `Ln:` to status reports, bigger `planner_blocks` or
`rx_buffer` model other boards): `$I` answers the build, and the buffers have the build's sizes.
M0 pauses like the firmware (planner emptied, then a completed feed hold until cycle start); M1 is
ignored (Grbl has no optional-stop switch).

Motion follows Grbl's planner (gnea/grbl `planner.c`, `motion_control.c`): arcs are split into chords by
the $12 arc tolerance, every chord and line is a planner block with its nominal speed and acceleration
limited per axis ($110-$112, $120-$122), junction speeds follow the $11 junction deviation rule, and each
new block replans the blocks in the planner buffer (15 on a stock build) with Grbl's backward and forward
passes, the newest block ending at rest. Blocks run trapezoidal speed profiles, so status reports (`MPos`,
`FS:`) follow the ramps, and a planner the host does not keep filled makes the machine slow down and stop.
Deviations from real firmware: no step timing (a profile is exact, not in 10 ms acceleration ticks), no
overrides, work offsets fixed at zero.
"""

from fabline.link.simulator.clock import TIME_SCALE_MAX, check_time_scale
from fabline.link.simulator.controller import GrblSimulator, timed_run
from fabline.link.simulator.faults import ConnectionDropped, Faults
from fabline.link.simulator.firmware import BANNER, DEFAULT_SETTINGS, HELP, VERSION
from fabline.link.simulator.protocol import LINE_BUFFER_SIZE

__all__ = ["BANNER", "DEFAULT_SETTINGS", "HELP", "LINE_BUFFER_SIZE", "TIME_SCALE_MAX", "VERSION", "ConnectionDropped",
           "Faults", "GrblSimulator", "check_time_scale", "timed_run"]
