"""The jobs stage: job files, the whole pipeline with its report, and the shop-floor runner with its web page.

Public surface: `load_job_file`/`JobSpec` (checked job files), `run_job`/`prepare_job`/`JobResult` (model to
cut parts and the report), `JobQueue` (the runner's SQLite queue), `Runner`/`MachineConfig` (the runner's
threads) and `create_app` (the web page, imported from `fabline.jobs.web` to keep this import light). The names
load their modules on first use (`fabline.lazy`): `fabline runner status` reads the queue without the pipeline.
"""

from fabline.lazy import lazy_surface

__getattr__, __all__ = lazy_surface(__name__, {
    "jobfile": ("JobSpec", "load_job_file"),
    "pipeline": ("JobResult", "prepare_job", "run_job"),
    "queue": ("JobQueue",),
    "runner": ("MachineConfig", "Runner"),
})
