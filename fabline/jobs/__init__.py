"""The jobs stage: job files, the whole pipeline with its report, and the shop-floor runner with its web page.

Public surface: `load_job_file`/`JobSpec` (checked job files), `run_job`/`prepare_job`/`JobResult` (model to
cut parts and the report), `JobQueue` (the runner's SQLite queue), `Runner`/`MachineConfig` (the runner's
threads) and `create_app` (the web page, imported from `fabline.jobs.web` to keep this import light).
"""

from fabline.jobs.jobfile import JobSpec, load_job_file
from fabline.jobs.pipeline import JobResult, prepare_job, run_job
from fabline.jobs.queue import JobQueue
from fabline.jobs.runner import MachineConfig, Runner

__all__ = ["JobQueue", "JobResult", "JobSpec", "MachineConfig", "Runner", "load_job_file", "prepare_job", "run_job"]
