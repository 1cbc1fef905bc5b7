"""CLI for the jobs stage: `fabline run JOB.toml` (the whole pipeline) and `fabline runner ...` (the shop-floor runner)."""

from __future__ import annotations

import argparse
import json
import os
import secrets
import shlex
import signal
import sys
import threading
from pathlib import Path

from fabline.cli import hidden_alias, positive, quiet_stdout
from fabline.units import duration
from fabline.errors import FablineError

RUNNER_ACTIONS = ("pause", "resume", "cancel", "confirm", "restart", "skip", "requeue", "frame")
_ACTION_HELP = {"pause": "pause a job (feed hold while cutting)", "resume": "resume a paused job, or a job that "
                "needs attention where its sheet stopped", "cancel": "cancel a job", "confirm": "confirm the job's "
                "next sheet is loaded", "restart": "restart the sheet of a job that needs attention from its first line",
                "skip": "skip the sheet of a job that needs attention",
                "requeue": "queue a failed or cancelled job again, as a new job",
                "frame": "trace the outline of the job's next sheet on its machine, laser off, before confirming it"}


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add `run` and `runner` (serve, submit, status, pause, resume, cancel, confirm)."""
    run = subparsers.add_parser("run", help="run a job file end to end: model, unroll, nest, export, stream, survey, report")
    run.add_argument("job", help="a job file (jobs/*.toml)")
    run.add_argument("-y", "--yes", action="store_true",
                     help="do not ask before each sheet on a real machine (the sheets are already loaded)")
    run.add_argument("-q", "--quiet", action="store_true", help="print only where the report is")
    again = run.add_mutually_exclusive_group()
    again.add_argument("--resume", action="store_true",
                       help="continue an interrupted run from the sheets' journals instead of cutting every sheet afresh")
    again.add_argument("--restart", action="store_true",
                       help="cut every sheet afresh although an earlier run of this job stopped before finishing")
    run.add_argument("--from-line", type=positive(int), metavar="N",
                     help="with --resume: continue the one interrupted sheet from its file line N (the operator's "
                          "choice, when the machine's position cannot tell)")
    run.set_defaults(func=run_job_command)

    runner = subparsers.add_parser("runner", help="the shop-floor runner: a persistent job queue with a web page")
    commands = runner.add_subparsers(dest="runner_command", metavar="ACTION", required=True)
    serve = commands.add_parser("serve", help="run the queue, the machines and the web page until interrupted")
    serve.add_argument("--host", default="127.0.0.1", help="address to bind; 127.0.0.1 is this computer only")
    web_port = serve.add_argument("--web-port", type=positive(int, 65535), default=8080, metavar="N",
                                  help="TCP port of the web page")
    hidden_alias(serve, web_port, "--port")
    serve.add_argument("--machine", action="append", default=[], metavar="NAME=PORT",
                       help="a machine and its serial port, repeatable (default: sim1=sim://sim1?machine=grbl-laser&time_scale=2000, "
                       "a simulator set up as the grbl-laser profile's machine: laser mode, 4100 x 2100 mm travel, 2000 times "
                       "the real speed)")
    serve.add_argument("--allow-host", action="append", default=[], metavar="NAME",
                       help="a host name the page may be reached by besides the loopback names and --host, repeatable "
                       "(requests naming any other host are refused)")
    serve.add_argument("--token", help="the token for everything but the bare page (default: a new random one, printed)")
    serve.add_argument("--auto-confirm", action="store_true",
                       help="start every sheet without an operator's confirmation (sheets fed automatically)")
    serve.add_argument("--scan", type=positive(float), default=2.0, metavar="SECONDS",
                       help="seconds between scans of the jobs folder")
    serve.set_defaults(func=run_serve)
    submit = commands.add_parser("submit", help="queue a job file, or ready G-code programs (one per sheet)")
    submit.add_argument("job", nargs="?", help="a job file")
    submit.add_argument("--gcode", nargs="+", metavar="PROGRAM", help="sheet programs to cut in this order, "
                        "instead of a job file (each gets a journal beside it)")
    submit.add_argument("--name", help="the job's name with --gcode (default: the first program's name)")
    submit.set_defaults(func=run_submit)
    status = commands.add_parser("status", help="the queue and the machines")
    status.add_argument("--json", action="store_true", help="print the state as JSON")
    status.set_defaults(func=run_status)
    for action in RUNNER_ACTIONS:
        sub = commands.add_parser(action, help=_ACTION_HELP[action])
        sub.add_argument("job_id", metavar="JOB", help="job number or name (the newest job of that name; "
                         "see `fabline runner status`)")
        if action == "resume":
            sub.add_argument("--from-line", type=positive(int), metavar="N",
                             help="resume a job that needs attention from this file line (the operator's override)")
        if action in ("resume", "restart", "skip", "cancel"):
            sub.add_argument("-y", "--yes", action="store_true",
                             help="do not ask before acting on a job that needs attention")
        sub.set_defaults(func=run_action, action=action)
    serve.add_argument("--jobs", default="jobs", help="the jobs folder it watches and keeps its queue in")
    serve.add_argument("--db", help="the queue database (default JOBS/runner.sqlite)")
    for sub in (submit, status, *(commands.choices[a] for a in RUNNER_ACTIONS)):
        sub.add_argument("--jobs", help="the runner's jobs folder (default: the running runner, else ./jobs)")
        sub.add_argument("--db", help="the runner's queue database (default: the running runner's, else JOBS/runner.sqlite)")


def _db(args: argparse.Namespace) -> Path:
    return Path(args.db) if args.db else Path(args.jobs) / "runner.sqlite"


def run_job_command(args: argparse.Namespace) -> int:
    """Run every stage of the job and print where the report is; Ctrl-C, SIGTERM and SIGHUP stop the machines
    safely (exit 130, resumable with --resume)."""
    from fabline.jobs.jobfile import load_job_file
    from fabline.jobs.pipeline import load_facts, run_job, structure_lines
    from fabline.jobs.queue import describe_load
    from fabline.locks import exclusive_lock, lock_path

    said = threading.Lock()  # the machines report from their own threads: one whole line at a time

    def say(text: str) -> None:
        if not args.quiet:
            with said:
                try:
                    print(text, flush=True)
                except BrokenPipeError:  # the reader of the output went away (`| head`): the job goes on unseen
                    quiet_stdout()

    def confirm(k: int, count: int, sheet: dict) -> None:
        facts = load_facts(sheet)
        print(f"load {describe_load(sheet['sheet'], k, count, facts)}\n  picture: {Path(facts['picture']).as_uri()}",
              flush=True)
        answer = _ask(f"load sheet {sheet['sheet']} on the machine, then press Enter ")
        if answer is None:
            raise FablineError(f"sheet {k + 1} of {count} ({sheet['sheet']}) was not confirmed: standard input closed; "
                               "nothing more is cut (run it again with --resume)")

    spec = load_job_file(args.job)
    real_machine = "stream" in spec.stages and any(not port.startswith("sim://") for port in spec.machine["ports"])
    if real_machine and not args.yes and not _can_ask():
        raise FablineError(f"{args.job}: the job cuts on a real machine and asks before each sheet, but standard input "
                           "is closed; run it from a terminal, or pass --yes if the sheets are loaded")
    stop_signals = _stop_on_signals()
    try:
        with exclusive_lock(lock_path(spec.output_folder), f"job output folder {spec.output_folder}"):
            result = run_job(spec, say, confirm if real_machine and not args.yes else None, resume=args.resume,
                             restart=args.restart, from_line=args.from_line)
    except KeyboardInterrupt:
        print(f"fabline run: interrupted; the machines stopped safely and their journals are kept: "
              f"{shlex.join(['fabline', 'run', args.job, '--resume'])} continues where they stopped", file=sys.stderr)
        return 130
    finally:
        stop_signals()
    total = sum(result.timings.values())
    for line in structure_lines(result):
        print(line)
    if result.report_path:
        print(f"report: {result.report_path} (JSON: {result.report_path.with_suffix('.json')}); {duration(total)}")
    else:
        print(f"done in {duration(total)}; outputs in {spec.output_folder} (no report stage)")
    return 0


def _job_number(jobs: list[dict], given: str, where: str) -> int:
    """A job named by its number, or by its name (the newest job of that name)."""
    if given.isdigit():
        return int(given)
    named = [job["id"] for job in jobs if job["name"] == given]
    if not named:
        raise FablineError(f"no job named {given!r} in {where} (see `fabline runner status`)")
    return named[-1]


def _can_ask() -> bool:
    """Whether standard input can answer a question (it is open; a pipe or a terminal)."""
    return sys.stdin is not None and not sys.stdin.closed


def _ask(question: str) -> str | None:
    """The operator's answer to `question`, or None when standard input is closed or at its end."""
    if not _can_ask():
        return None
    try:
        return input(question)
    except EOFError:
        return None


def _stop_on_signals():
    """SIGTERM and SIGHUP (a `kill`, a service stop, a closed terminal) stop the job like Ctrl-C does; returns
    the function that puts the previous handlers back."""
    from fabline.link import STOP_SIGNALS

    previous = {number: signal.signal(number, signal.default_int_handler) for number in STOP_SIGNALS
                if number != signal.SIGINT}
    return lambda: [signal.signal(number, handler) for number, handler in previous.items()]


def run_serve(args: argparse.Namespace) -> int:
    """Run the runner's threads and the web page until SIGINT, SIGTERM or SIGHUP; then stop everything it started
    (the export's worker processes included), withdraw its record and token, and exit the process with 130, 143 or
    129 after one line saying so (the queue keeps its state: a restart goes on from it)."""
    import uvicorn

    from fabline.jobs.discovery import page_url, queue_lock, remove_records, write_records
    from fabline.jobs.lifecycle import STOP_SIGNALS, end_descendants, exit_code, guard_forks
    from fabline.jobs.runner import Runner, default_machines, describe_machine, parse_machine
    from fabline.jobs.web import create_app
    from fabline.locks import exclusive_lock, lock_path

    jobs, db = Path(args.jobs), _db(args)
    if not jobs.is_dir():
        raise FablineError(f"--jobs {args.jobs}: not a folder")
    machines = [parse_machine(m) for m in args.machine] or default_machines()
    described = [describe_machine(m) for m in machines]  # a bad profile name is refused before anything starts
    token = args.token or secrets.token_urlsafe(18)
    hosts = (*args.allow_host, *([args.host] if args.host not in ("0.0.0.0", "::") else []))
    lock_file = queue_lock(db)  # the lock discovery checks a record's pid against
    received: list[int] = []
    stopping = threading.Event()

    def on_signal(number: int, frame) -> None:
        received.append(number)
        stopping.set()

    def taken_over(pid: int) -> None:
        print(f"fabline runner: process {pid} ended without stopping its runner of queue {db}; its lock "
              f"{lock_file} is taken over", flush=True)

    previous = {number: signal.signal(number, on_signal) for number in STOP_SIGNALS}
    try:
        with exclusive_lock(lock_file, f"runner queue {db}", taken_over), \
                _listen(args.host, args.web_port) as listening:  # one runner per queue
            guard_forks([listening.fileno()], [lock_file, lock_path(jobs).parent])
            runner = Runner(db, machines, auto_confirm=args.auto_confirm)
            for name in runner.removed:
                print(f"fabline runner: machine {name} removed (not given with --machine)", flush=True)
            runner.watch_folder(jobs, args.scan)
            runner.start()
            print(f"fabline runner: {len(machines)} machine(s); queue {db}", flush=True)
            print(f"token: {token}", flush=True)
            print(f"open http://{args.host}:{args.web_port}/?token={token}", flush=True)
            for line in described:
                print(f"  machine {line}", flush=True)
            records = write_records(db, page_url(args.host, args.web_port), token)
            print(f"found by `fabline runner status` and the other commands through {' and '.join(map(str, records))}",
                  flush=True)
            server = uvicorn.Server(uvicorn.Config(create_app(db, token, hosts=hosts, jobs=jobs), host=args.host,
                                                   port=args.web_port, log_level="warning"))
            web = threading.Thread(target=server.run, kwargs={"sockets": [listening]}, name="web", daemon=True)
            web.start()  # outside the main thread uvicorn leaves the signals to us
            try:
                while web.is_alive() and not stopping.wait(0.5):
                    pass
            finally:
                server.should_exit = True
                given_back = runner.stop()
                workers = end_descendants()
                web.join(10)
                remove_records(db)
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)
    if not received:
        raise FablineError(f"runner: the web page on {args.host}:{args.web_port} stopped by itself; the runner stopped")
    again = f"; job(s) {', '.join(map(str, given_back))} prepared afresh at the next start" if given_back else ""
    print(f"fabline runner: stopped by {signal.Signals(received[0]).name} ({workers} worker process(es) ended{again}); "
          f"queue {db} keeps its state", file=sys.stderr, flush=True)
    sys.stdout.flush()
    os._exit(exit_code(received[0]))  # not the interpreter's exit: it would join the export pool's manager thread,
    # which waits forever for the rest of a result a worker was writing when it was ended


def _listen(host: str, port: int):
    """The page's listening socket, bound now so that a port in use is one line, before anything starts."""
    import socket

    try:
        return socket.create_server((host, port), family=socket.AF_INET6 if ":" in host else socket.AF_INET,
                                    backlog=2048)
    except OSError as exc:
        raise FablineError(f"--web-port {port}: cannot listen on {host}:{port}: {exc.strerror}; stop what uses "
                           "it or choose another port") from None


def _runner(args: argparse.Namespace):
    """The running runner (over HTTP) or its queue database, found as `fabline.jobs.discovery` says."""
    from fabline.jobs.discovery import Search, find_runner

    return find_runner(Search(db=args.db, jobs=args.jobs))


def run_submit(args: argparse.Namespace) -> int:
    """Queue a job file (checked first) or ready sheet programs (checked by the link stage's parser) in the
    runner's queue."""
    from fabline.jobs.jobfile import load_job_file
    from fabline.jobs.queue import JobQueue

    if (args.job is None) == (args.gcode is None):
        raise FablineError("runner submit: give a job file or --gcode PROGRAM..., not both")
    try:
        db = _runner(args).db
    except FablineError:  # no runner yet: the queue `fabline runner serve` will open, made now
        db = Path(args.db) if args.db else Path(args.jobs or "jobs") / "runner.sqlite"
    queue = JobQueue(db)
    if args.gcode:
        programs = [(Path(p).stem, str(Path(p).resolve()), "") for p in args.gcode]
        name = args.name or programs[0][0]
        job_id = queue.submit(name, programs=programs)
        print(f"job {job_id}: {name} ready, {len(programs)} sheet(s) (queue {db})")
        return 0
    spec = load_job_file(args.job)
    job_id = queue.submit(spec.name, job_file=str(spec.path))
    print(f"job {job_id}: {spec.name} queued (queue {db})")
    return 0


def run_status(args: argparse.Namespace) -> int:
    """Print the queue and the machines, from the running runner or its database."""
    runner = _runner(args)
    state = runner.state()
    if args.json:
        print(json.dumps(state, indent=1))
        return 0
    print(runner.where)
    for machine in state["machines"]:
        x, y, z = machine["position"]
        job = f", job {machine['job_id']}" if machine["job_id"] is not None else ""
        print(f"machine {machine['name']} ({machine['port']}): {machine['state']}{job}, at X{x} Y{y} Z{z}")
    for job in state["jobs"]:
        print(f"job {job['id']:>4} {job['name']:<20} {job['status']}" + (f" on {job['machine']}" if job["machine"] else ""))
        if job["state"] == "ready" and job["confirmed"] < job["sheet"] < len(job["sheet_list"]):
            print(f"     load {job['sheet_list'][job['sheet']]['load']}")
    return 0


def run_action(args: argparse.Namespace) -> int:
    """Pause, resume, cancel a job, confirm its next sheet, and the rest, through the running runner or its
    database; a job that needs attention is described and the choice asked for first (unless --yes)."""
    runner = _runner(args)
    jobs = runner.state()["jobs"]
    job_id = _job_number(jobs, args.job_id, runner.where)
    if args.action == "requeue":
        print(f"job {job_id} queued again as job {runner.act(job_id, 'requeue')['id']}")
        return 0
    before = next((job for job in jobs if job["id"] == job_id), None)
    if before is not None and before["state"] == "attention" and args.action in ("resume", "restart", "skip", "cancel"):
        print(f"job {job_id}: {before['status']}")
        question = {"resume": "resume the sheet where it stopped (the same sheet on the bed, the origin unchanged)",
                    "restart": "restart the sheet from its first line (a new sheet loaded)",
                    "skip": "skip the sheet (its parts stay uncut)", "cancel": "cancel the job"}[args.action]
        if not args.yes:
            answer = _ask(f"{question}? [y/N] ")
            if answer is None:
                raise FablineError(f"job {job_id}: cannot ask for confirmation (standard input closed); add --yes")
            if answer.strip().lower() not in ("y", "yes"):
                print("nothing done")
                return 1
    after = runner.act(job_id, args.action, getattr(args, "from_line", None))
    print(f"job {after['id']}: {after['status']}" + (f" ({args.action} requested)" if after.get("request") else ""))
    return 0
