"""Calibration jobs: their records and states, the queue the API talks to (SQLite and local
processes, or Redis and rq), and the worker function every backend runs.

| module | holds |
|---|---|
| :mod:`~wandcal.service.jobs.records` | ``JobRecord``, ``JobState`` and the job table in SQLite |
| :mod:`~wandcal.service.jobs.queue` | the ``JobQueue`` protocol and its local backend |
| :mod:`~wandcal.service.jobs.redis_queue` | the Redis/rq backend for several workers |
| :mod:`~wandcal.service.jobs.rq_worker` | the rq worker process a second machine runs against the same Redis |
| :mod:`~wandcal.service.jobs.worker` | ``solve``: one job run to its result |
| :mod:`~wandcal.service.jobs.watch_job` | a watch job: a take judged against a standing result, and the re-solved result on request |
"""
