"""The chaos run in little (bench/chaos.py has the full one): the Redis/rq deployment with three
rq workers, their work horses SIGKILLed mid-job, Redis restarted three ways and stopped, the API
SIGKILLed and restarted; every accepted job ends exactly once, none lost, none stuck.

Whole-worker kills are left to the bench and to tests/service/test_redis.py: rq notices them only
when the job's heartbeat lapses, 60 s or more after the kill."""

from __future__ import annotations

import shutil

import pytest

from bench.chaos import Plan, run, table

pytest.importorskip("rq", reason="pip install 'wandcal[redis]' to test the Redis queue")
pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(shutil.which("redis-server") is None, reason="redis-server is not installed "
                       "(apt-get install redis-server; .ci/run does)"),
]
# About a minute (jobs of about a second); the run ends as soon as every job has. A worker that dies
# with a job just taken (a Redis restart can make rq quit) leaves that job to rq's heartbeat lapse,
# 90 s later: once the queue stalls 10 s, the test runs rq's cleanup as if it had lapsed (lapse_after_s).
SHORT = Plan(jobs=20, workers=3, worker_kills=3, whole_worker_every=0, redis_restarts=("shutdown", "lost", "sigkill"),
             away_s=3.0, api_restarts=1, submit_s=12.0, settle_s=120.0, stall_s=40.0, lapse_after_s=10.0, captures=2)


# Quarantined once (2 of 6 runs reported an outcome changed, issue 34): the run's check compared the
# end first polled of a job whose POST answer an API kill cut off with nothing (its row was not an
# accepted job's), and a poll that had read a job's record before another poll recorded its end
# could write rq's older state over it. Both fixed (bench/chaos.py reads every row's end; the
# record is a compare-and-set, JobStore.set_outcome). Since then 35 of 36 runs passed: 21 of 22 at a
# load of 17-36 (the one failure's output was lost) and 14 of 14 in a row at a load of 8-21
# (2026-11-28, 11:25-11:59 UTC). It gates again; each assertion's message carries the run's report.
@pytest.mark.long
def test_every_accepted_job_ends_exactly_once_under_chaos(tmp_path):
    report = run(SHORT, tmp_path)
    why = "\n" + table(SHORT, report)  # the run's whole report beside any failed assertion
    assert len(report.accepted) == SHORT.jobs, why
    assert report.redis_restarts == list(SHORT.redis_restarts) and report.api_restarts == 1, why
    assert report.horse_kills >= 1, "no work horse was caught running a job; the captures solve too fast" + why
    # while Redis was stopped: reads from SQLite, a 503 with Retry-After for a new job
    assert report.away["ok"], f"{report.away}{why}"
    assert report.lost == [] and report.stuck == [] and report.changed == [], (
        report.lost, report.stuck, {j: (report.first_end[j], report.final.get(j)) for j in report.changed}, why)
    assert report.unaccepted_unfinished == 0, why
    states = report.states()
    assert sum(states.values()) == SHORT.jobs and states["done"] >= SHORT.jobs - SHORT.worker_kills // 2, why
    assert not report.errors, f"{report.errors}{why}"


def test_the_check_compares_each_polled_end_with_its_own_row():
    """The cause of the quarantine's 2 in 6: a job whose POST answer an API kill cut off is polled
    too (a page lists it), and its end was compared with nothing, reported as changed."""
    from bench.chaos import Report

    report = Report(accepted=["a"])
    report.first_end = {"a": ("done", "x"), "cut": ("done", "y")}
    report.final = {"a": ("done", "x"), "cut": ("done", "y")}
    assert report.changed == [] and report.lost == [] and report.stuck == []
    report.final["cut"] = ("failed", "z")  # a later outcome written over the first: reported
    assert report.changed == ["cut"]
    del report.final["a"]
    assert report.lost == ["a"] and report.changed == ["a", "cut"]
