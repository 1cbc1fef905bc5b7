"""The shop-floor runner: prepares queued jobs and cuts their sheets on several machines, one sheet at a time each.

One preparer thread turns queued job files into sheet programs (the pipeline up to export) inside the
job's own folder under the runner's `runs` folder, whatever output folder the job file names; one worker
thread per machine takes a ready job, waits for the operator to confirm the sheet is loaded, and streams
its program through the link stage, each run of a sheet with a journal of its own. Everything lives in the
SQLite queue and the journals, so a runner killed at any moment (kill -9 included) loses nothing: a sheet
that was being cut waits for the operator ("needs attention", with the last line known executed), who
resumes it from its journal without repeating or skipping a line, restarts it, skips it or cancels the job.
"""

from __future__ import annotations

import contextlib
import threading
import time
from dataclasses import dataclass, replace
from pathlib import Path

from fabline.errors import FablineError
from fabline.jobs import prepared as prepared_output
from fabline.jobs.queue import JobQueue, JobRow, SheetRow
from fabline.jobs.streaming import SheetStream, checkpoint, frame_sheet
from fabline.link import Streamer, check_port
from fabline.locks import exclusive_lock, lock_path


@dataclass(frozen=True)
class MachineConfig:
    """A machine the runner drives: its name (shown to the operator) and its port (serial device or sim:// URL)."""

    name: str
    port: str


DEFAULT_PROFILE = "grbl-laser"
"""The machine profile a job file names when it names none (`machine.profile`'s default): the runner's default
simulated machine is set up as that machine, so the example job cuts on it with no setting typed."""


DEFAULT_TIME_SCALE = 2000
"""The default simulator runs as many times faster than the real machine as the example job's simulators do, so the
example job cuts to its end in minutes (the runner reports machine time from the simulator's own clock)."""


def default_machines() -> list[MachineConfig]:
    """`runner serve` without `--machine`: one simulator set up as the default profile's machine."""
    return [MachineConfig("sim1", f"sim://sim1?machine={DEFAULT_PROFILE}&time_scale={DEFAULT_TIME_SCALE}")]


def describe_machine(machine: MachineConfig) -> str:
    """'NAME=PORT (PROFILE: ...)' for the start-up lines: which machine a simulator plays (its profile's laser mode
    and travel), or that a controller on a port keeps its own `$` settings (checked against each program's profile)."""
    import urllib.parse

    from fabline.machine import load_machine

    parts = urllib.parse.urlsplit(machine.port)
    if parts.scheme != "sim":
        return (f"{machine.name}={machine.port} (the controller on that port: its own $ settings, checked against each "
                "program's profile)")
    options = urllib.parse.parse_qs(parts.query)
    name = options.get("machine", [None])[-1]
    extra = " with its settings= values" if "settings" in options else ""
    if name is None:
        return (f"{machine.name}={machine.port} (no machine profile: a stock Grbl 1.1h{extra}; the stock one is "
                "laser mode off $32=0, 200 x 200 mm travel)")
    try:
        profile = load_machine(name)
    except FablineError as exc:
        raise FablineError(f"--machine {machine.name}={machine.port}: {exc}") from None
    laser = "laser mode $32=1" if profile.laser_mode else "laser mode off $32=0"
    return (f"{machine.name}={machine.port} (profile {profile.name}: {laser}, "
            f"{profile.bed_width:g} x {profile.bed_height:g} mm travel{extra})")


def parse_machine(text: str) -> MachineConfig:
    """'NAME=PORT' (e.g. 'laser1=/dev/ttyUSB0' or 'sim1=sim://sim1?time_scale=100')."""
    name, sep, port = text.partition("=")
    if not sep or not name or not port:
        raise FablineError(f"--machine {text!r}: expected NAME=PORT, e.g. laser1=/dev/ttyUSB0")
    return MachineConfig(name.strip(), port.strip())


class Runner:
    """The runner's threads over the queue at `db_path`; `start()` them, `stop()` to end (the state stays)."""

    def __init__(self, db_path: str | Path, machines: list[MachineConfig], auto_confirm: bool = False,
                 poll: float = 0.2, prepare: bool = True, runs: str | Path | None = None):
        if len({m.name for m in machines}) != len(machines):
            raise FablineError("runner: two machines with the same name")
        for machine in machines:  # the operator's ports, checked as `fabline stream` checks its --port
            try:
                check_port(machine.port)
            except FablineError as exc:
                raise FablineError(f"runner: machine {machine.name}: {exc}") from None
        self.db_path = Path(db_path)
        self.runs = Path(runs) if runs else self.db_path.parent / "runs"
        self.machines = machines
        self.auto_confirm = auto_confirm
        self.poll = poll
        self.prepare = prepare
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        queue = JobQueue(self.db_path)
        queue.recover()
        for job in queue.interrupted():  # no stream runs for them now: the operator decides how to go on
            sheet = queue.sheets(job.id)[job.sheet]
            where = checkpoint(sheet.program, sheet.journal, "the runner stopped while the sheet was being cut")
            position = next((m["position"] for m in queue.machines() if m["name"] == job.machine), None)
            queue.need_attention(job.id, {**where, "position": position})
        self.removed = queue.keep_machines([m.name for m in machines])
        """The machines of an earlier start that this one does not drive: forgotten."""
        for machine in machines:
            queue.register_machine(machine.name, machine.port)
        queue.close()

    def start(self) -> None:
        """Start the preparer and one worker per machine (daemon threads)."""
        targets = [(self._machine_loop, (m,), f"machine-{m.name}") for m in self.machines]
        if self.prepare:
            targets.append((self._prepare_loop, (), "preparer"))
        self._threads += [threading.Thread(target=target, args=args, name=name, daemon=True)
                          for target, args, name in targets]
        for thread in self._threads:
            thread.start()

    def watch_folder(self, folder: str | Path, every: float) -> None:
        """Queue each job file (*.toml) that appears in `folder`, once per file; a bad one is queued as failed
        with its one-line error, so the operator sees why it will not run."""
        thread = threading.Thread(target=self._watch_loop, args=(Path(folder), every), name="watch", daemon=True)
        self._threads.append(thread)

    def _watch_loop(self, folder: Path, every: float) -> None:
        from fabline.jobs.jobfile import load_job_file

        queue = JobQueue(self.db_path)
        while True:
            known = queue.job_files()
            for path in sorted(folder.glob("*.toml")):
                if str(path.resolve()) in known:
                    continue
                try:
                    spec = load_job_file(path)
                    queue.submit_once(spec.name, job_file=str(spec.path))
                except FablineError as exc:
                    queue.submit_once(path.stem, job_file=str(path.resolve()), error=str(exc))
            if self._stop.wait(every):
                break
        queue.close()

    def stop(self, timeout: float = 10.0) -> list[int]:
        """Ask every thread to stop after its current step and wait for them (a sheet being cut stops with a feed
        hold and a reset, its journal kept); a preparation still running is given back to the queue whole, to be
        prepared afresh at the next start, and its result, should it still come, is not recorded. Returns the
        ids of the jobs given back."""
        self._stop.set()
        for thread in self._threads:
            if thread.name != "preparer":
                thread.join(timeout)
        queue = JobQueue(self.db_path)
        try:
            given_back = queue.give_back_preparation()
            for machine in self.machines:
                queue.set_machine(machine.name, state="stopped: the runner is not running")
        finally:
            queue.close()
        for thread in self._threads:
            if thread.name == "preparer":
                thread.join(0.5)  # it ends now unless a stage holds it; a process exit ends it then
        return given_back

    def run_until_idle(self, timeout: float) -> None:
        """Block until no job is left unfinished (every one done, failed or cancelled) or `timeout` passes."""
        queue = JobQueue(self.db_path)
        deadline = time.monotonic() + timeout
        try:
            while time.monotonic() < deadline:
                if all(job.state in ("done", "failed", "cancelled") for job in queue.jobs()):
                    return
                time.sleep(self.poll)
            raise FablineError(f"runner: jobs still unfinished after {timeout:g} s")
        finally:
            queue.close()

    # --- preparation ------------------------------------------------------------------------------------

    def _prepare_loop(self) -> None:
        from fabline.jobs.jobfile import load_job_file
        from fabline.jobs.pipeline import prepare_job

        queue = JobQueue(self.db_path)
        while not self._stop.is_set():
            job = queue.claim_preparation()
            if job is None:
                self._stop.wait(self.poll)
                continue
            try:
                spec = replace(load_job_file(job.job_file), output_folder=self.runs / f"job-{job.id}")
                for port in spec.machine["ports"]:  # never opened here, but a queued job file writes nothing of its own
                    try:
                        check_port(port, files=False)
                    except FablineError as exc:
                        raise FablineError(f"{Path(job.job_file).name}: machine.ports: {exc}") from None
                key = prepared_output.job_key(spec)
                with exclusive_lock(lock_path(spec.output_folder), f"job folder {spec.output_folder}"):
                    earlier = prepared_output.find(self.runs, key, prefer=spec.output_folder)
                    if earlier is not None:  # the same job file and inputs: its sheets as they were prepared
                        programs, report, lines = prepared_output.reuse(earlier, spec.output_folder)
                        queue.log(job.id, None, f"job {job.id}: job file and inputs unchanged since {earlier.name}: "
                                  "its prepared sheets reused")
                    else:
                        result = prepare_job(spec)
                        programs = result.sheet_programs()
                        report = str(result.report_path) if result.report_path else None
                        lines = prepared_output.record(spec.output_folder, key, programs, report)
                queue.prepared(job.id, programs, report, str(spec.output_folder), lines)
            except Exception as exc:  # a bug in a stage must not take the runner down; the job records it
                if self._stop.is_set():  # the stop ended the stage's workers: the job goes back whole (stop())
                    break
                queue.fail(job.id, str(exc) if isinstance(exc, FablineError) else
                           f"internal error while preparing: {type(exc).__name__}: {exc}")
        queue.close()

    # --- machines ---------------------------------------------------------------------------------------

    def _machine_loop(self, machine: MachineConfig) -> None:
        queue = JobQueue(self.db_path)
        while not self._stop.is_set():
            self._console(queue, machine)
            job = queue.claim_for_machine(machine.name)
            if job is None:
                queue.set_machine(machine.name, state="idle")
                self._stop.wait(self.poll)
                continue
            sheet = self._next_sheet(queue, job, machine)
            if sheet is None:
                self._stop.wait(self.poll)
                continue
            try:
                self._cut(queue, job, sheet, machine)
            except Exception as exc:  # the job waits for the operator's choice; the machine's worker carries on
                reason = str(exc) if isinstance(exc, FablineError) else f"internal error: {type(exc).__name__}: {exc}"
                where = checkpoint(sheet.program, sheet.journal, f"on {machine.name}: {reason}")
                position = next((m["position"] for m in queue.machines() if m["name"] == machine.name), None)
                queue.need_attention(job.id, {**where, "position": position})
        queue.close()

    def _next_sheet(self, queue: JobQueue, job: JobRow, machine: MachineConfig) -> SheetRow | None:
        """The sheet to cut now, or None while it waits for the operator (confirmation or a choice)."""
        if job.state == "attention":
            queue.set_machine(machine.name, state=f"needs attention: job {job.id} sheet {job.sheet + 1} of {job.sheets}")
            return None
        if job.state == "paused":
            queue.set_machine(machine.name, state="paused")
            return None
        if job.state == "ready" and job.confirmed < job.sheet:
            if job.request == "frame" and queue.take_request(job.id) == "frame":
                self._frame(queue, job, machine)
            if not self.auto_confirm:
                queue.set_machine(machine.name, state=f"waiting: load sheet {job.sheet + 1} of {job.sheets}")
                return None
            queue.confirm_sheet(job.id, job.sheet)
        return queue.start_sheet(job.id, machine.name)

    def _frame(self, queue: JobQueue, job: JobRow, machine: MachineConfig) -> None:
        """Trace the outline of the job's next sheet with the laser off, as the operator asked."""
        sheet = queue.sheets(job.id)[job.sheet]
        queue.set_machine(machine.name, state=f"framing sheet {job.sheet + 1} of {job.sheets} (laser off)")
        try:
            frame_sheet(machine.port, sheet.program, queue.journals)
            queue.log(job.id, machine.name, f"job {job.id}: sheet {job.sheet + 1} framed on {machine.name}")
        except FablineError as exc:
            queue.log(job.id, machine.name, f"job {job.id}: framing sheet {job.sheet + 1} failed: {exc}")

    def _cut(self, queue: JobQueue, job: JobRow, sheet: SheetRow, machine: MachineConfig) -> None:
        """Stream one sheet to the end (resuming from its journal), carrying out operator requests meanwhile."""
        queue.set_machine(machine.name, state=f"cutting job {job.id} sheet {sheet.k + 1} of {job.sheets}")
        last_write = [0.0]

        waiting: list[str | None] = [None]

        def on_progress(done_lines: int, position: tuple[float, ...] | None, message: str | None) -> None:
            now = time.monotonic()
            if now - last_write[0] >= self.poll or done_lines >= sheet.lines:
                last_write[0] = now
                queue.sheet_progress(job.id, sheet.k, done_lines)
                if position is not None:
                    queue.set_machine(machine.name, position=list(position))
            if message and message != waiting[0]:  # the program paused itself (M0): the operator resumes it
                queue.set_cutting_state(job.id, "paused")
                queue.set_machine(machine.name, state=message)
                queue.log(job.id, machine.name, f"job {job.id} sheet {sheet.k + 1}: {message}")
            waiting[0] = message

        identity = {"job": str(job.id), "run": sheet.run_id} if sheet.run_id else None
        stream = SheetStream(machine.port, sheet.program, on_progress, journal=sheet.journal,
                             resume=bool(sheet.resume), from_line=sheet.from_line, identity=identity)
        watcher = threading.Thread(target=self._watch_requests, args=(job.id, stream, machine), daemon=True)
        folder = (exclusive_lock(lock_path(job.output), f"job folder {job.output}") if job.output
                  else contextlib.nullcontext())
        watcher.start()
        try:
            with folder:
                outcome = stream.run()
        except FablineError:
            if not stream.cancelled:  # a cancelled sheet is over, however its stop went (the journal may not tell
                raise                 # where the machine stopped on a path that passes a point twice)
            outcome = "aborted"
        finally:
            stream.closed.set()
            watcher.join()
        if outcome == "finished":
            after = queue.finish_sheet(job.id, sheet.k)
            queue.set_machine(machine.name, state="idle" if after.state == "done" else
                              f"waiting: load sheet {after.sheet + 1} of {after.sheets}")
        elif stream.cancelled:
            queue.set_cutting_state(job.id, "cancelled", checkpoint(sheet.program, sheet.journal, "cancelled by the operator"))
            queue.set_machine(machine.name, state="idle")
        else:
            queue.set_machine(machine.name, state="stopped (the operator decides how to go on)")

    def _console(self, queue: JobQueue, machine: MachineConfig, stream: SheetStream | None = None) -> None:
        """Carry out the operator's console commands for this machine (fabline.jobs.console): through the link
        stage on a machine that streams nothing; while a sheet streams (`stream`), only real-time overrides,
        anything else refused. Each command's answer goes into the queue's log."""
        for command in queue.pending_commands(machine.name):
            line, override = command["line"], command["override"]
            if stream is not None and line is not None:
                queue.finish_command(command["id"], "refused", [
                    f"{machine.name} is cutting: only feed, rapid and power overrides until the sheet stops"])
                continue
            try:
                if stream is not None:
                    stream.override(override)
                    answer = ["sent"]
                else:
                    replies = Streamer(machine.port).console([line] if line else [], [override] if override else [])
                    answer = replies[0][1] if replies else ["sent"]
            except FablineError as exc:
                queue.finish_command(command["id"], "failed", [str(exc)])
            else:
                queue.finish_command(command["id"], "done", answer)

    def _watch_requests(self, job_id: int, stream: SheetStream, machine: MachineConfig) -> None:
        """While a sheet streams: carry out pause, resume and cancel requests; a stopping runner stops the stream
        (feed hold and reset; the journal resumes the rest on the next start)."""
        queue = JobQueue(self.db_path)
        while not stream.closed.wait(self.poll):
            if self._stop.is_set():
                stream.stop()
                break
            self._console(queue, machine, stream)
            request = queue.take_request(job_id)
            if request == "pause":
                stream.pause()
                queue.set_cutting_state(job_id, "paused")
                queue.set_machine(machine.name, state="paused (feed hold)")
            elif request == "resume":
                stream.resume()
                queue.set_cutting_state(job_id, "cutting")
                queue.set_machine(machine.name, state="cutting")
            elif request == "cancel":
                stream.cancel()
        queue.close()
