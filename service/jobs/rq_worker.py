"""The rq worker for wandcal's jobs, with the solver loaded once:
``rq worker -w wandcal.service.jobs.rq_worker.Worker --url redis://HOST:6379/0 wandcal``.

rq runs each job in a work horse forked from the worker. A plain ``rq worker`` has not imported
wandcal, so every horse imports NumPy, SciPy, OpenCV and the solver again before it solves (about
1 s on an idle core, 3 s on a busy one: most of a small job's time). This class is imported by the
worker at its start, and with it the solver, so each horse starts with them loaded. A plain
``rq worker`` still runs the jobs (docs/deploy.md).
"""

from __future__ import annotations

import importlib

from rq import Worker as _RqWorker

# the solver, and the task rq looks up by name: loaded here, before the first fork
PRELOAD = ("wandcal.calib.run.calibrate", "wandcal.service.jobs.redis_queue")
for _name in PRELOAD:
    importlib.import_module(_name)


class Worker(_RqWorker):
    """:class:`rq.Worker`, in a process that has loaded the solver (module docstring)."""
