"""Resume after a fault: of the fault campaign's cases, how many fabline places itself, how many it refuses as
ambiguous (naming the candidate lines for the operator's --from-line), and in how many every line then ran exactly
once, per kind of fault ("end re-sent": of those, a line whose end the machine stood within 0.01 mm of was re-sent
and moved microns: fabline cannot tell such a stop from one microns short of the end).

The cases are the campaign's (tests/link/campaign_cases.py, same seed): random laser programs with retraced paths,
repeated segments, arcs, dwells and power changes on a stock Grbl 1.1h simulator (no `Ln:`), each interrupted once.
Run: python benchmarks/resume_bench.py [--cases 200]
"""

from __future__ import annotations

import argparse
import importlib.util
import random
import sys
import tempfile
import time
from collections import Counter, defaultdict
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from fabline.link import SimulatorServer  # noqa: E402


def _load_campaign():
    """The fault campaign's case generator, read from its file: tests/ is no package, and the benchmark must not
    depend on a module the project does not install."""
    spec = importlib.util.spec_from_file_location("campaign_cases", REPO / "tests" / "link" / "campaign_cases.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


campaign = _load_campaign()
CASES, FAULTS, FINISHED, MICRONS, REFUSED, SETTINGS = (campaign.CASES, campaign.FAULTS, campaign.FINISHED,
                                                       campaign.MICRONS, campaign.REFUSED, campaign.SETTINGS)
cases, run_case = campaign.cases, campaign.run_case


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=CASES, help=f"campaign cases to run (default {CASES})")
    args = parser.parse_args(argv)
    table: dict[str, Counter] = defaultdict(Counter)
    started = time.monotonic()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        server_log = tmp / "server.log"
        with SimulatorServer(log=server_log, time_scale=50, faults={"settings": SETTINGS}) as server:
            for number, rng in cases(args.cases):
                fault = random.Random()
                fault.setstate(rng.getstate())
                kind = fault.choice(FAULTS)  # the draw run_case makes first
                row = table[kind]
                row["cases"] += 1
                try:
                    outcome = run_case(number, rng, tmp, server, server_log)
                except Exception as exc:  # a case that went wrong is counted, not fatal
                    row["failed"] += 1
                    first = str(exc).splitlines()[0] if str(exc) else ""
                    print(f"case {number} ({kind}): {type(exc).__name__}: {first}", file=sys.stderr)
                    continue
                row["exactly once"] += 1
                row["end re-sent"] += MICRONS in outcome
                row["refused" if REFUSED in outcome else "before the fault" if FINISHED in outcome else "decided"] += 1
    columns = ("cases", "decided", "refused", "before the fault", "exactly once", "end re-sent", "failed")
    print(f"resume after a fault: {args.cases} campaign cases in {time.monotonic() - started:.0f} s")
    print(f"  {'fault':<12}" + "".join(f"{name:>17}" for name in columns))
    total = Counter()
    for kind in sorted(table):
        total.update(table[kind])
        print(f"  {kind:<12}" + "".join(f"{table[kind][name]:>17}" for name in columns))
    print(f"  {'all':<12}" + "".join(f"{total[name]:>17}" for name in columns))
    return 0 if total["failed"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
