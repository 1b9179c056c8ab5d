"""``splatreel batch``: many assets through the commands, N at a time, with a report (`jobs`: the jobs file;
`run`: the pool and the report)."""

from .jobs import STEPS, Job, JobsFileError, commands, read_jobs
from .run import run_batch, run_job

__all__ = ["STEPS", "Job", "JobsFileError", "commands", "read_jobs", "run_batch", "run_job"]
