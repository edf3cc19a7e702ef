"""A whole `wandcal calibrate` process whose stages are timed in CPU seconds, without a profiler.

Run as the child of bench_scale.py's ``--parts where``: ``python -m bench.stage_timer OUT.json calibrate
CAPTURE ...``. Each stage's function is wrapped where the command calls it by name, and the wrapper
adds the process's CPU time (``time.process_time``) spent inside; what no stage holds is Python's
start-up, the imports, the argument parsing and the summary ("other"). The stages do not nest.

cProfile's figures were the earlier stage table's (bench_scale ``--parts stages``), but its cost per
Python call distorts a stage by how much Python it runs: at ring:128x3000 it gave the result's JSON
0.55 s where unprofiled it takes 0.025 s, and the whole process 4.6 s against 2.2 s.
"""

from __future__ import annotations

import functools
import json
import resource
import sys
import time
from collections import defaultdict

# stage: (module, attribute) of the functions that make it, each called by that name there (since
# calibrate.py's split, the start's steps from calib/run/start_steps.py)
STAGE_FUNCTIONS = {
    "read": [("wandcal.capture.folder", "read_capture")],
    "observations": [("wandcal.calib.run.calibrate", "whole_frame_sync"), ("wandcal.calib.run.calibrate", "observations")],
    "static object": [("wandcal.calib.run.start_steps", "static_object_poses")],
    "start": [("wandcal.calib.run.start_steps", "check_capture"), ("wandcal.calib.run.start_steps", "initial_poses"),
              ("wandcal.calib.run.calibrate", "subframe_sync")],
    "labelling": [("wandcal.calib.run.start_steps", "label_ends")],
    "refinement": [("wandcal.calib.run.calibrate", "_refine")],
    "world frame": [("wandcal.calib.run.calibrate", "_world")],
    "reports": [("wandcal.calib.run.calibrate", "_figures")],
    "judgement": [("wandcal.calib.run.calibrate", "_judgement")],
    "write": [("wandcal.calib.run.result", "CalibrationResult.to_json"), ("wandcal.service.cli.calibrate", "_write_result")],
}


def _wrap(owner, name: str, stage: str, spent: dict[str, float]) -> None:
    inner = getattr(owner, name)

    @functools.wraps(inner)
    def timed(*args, **kwargs):
        start = time.process_time()
        try:
            return inner(*args, **kwargs)
        finally:
            spent[stage] += time.process_time() - start

    setattr(owner, name, timed)


def main(argv: list[str]) -> int:
    import importlib

    from wandcal.service.cli import main as cli

    spent: dict[str, float] = defaultdict(float)
    for stage, functions in STAGE_FUNCTIONS.items():
        spent[stage] = 0.0
        for module, attribute in functions:
            owner = importlib.import_module(module)
            *path, name = attribute.split(".")
            for part in path:
                owner = getattr(owner, part)
            _wrap(owner, name, stage, spent)
    code = cli(argv[1:])
    usage = resource.getrusage(resource.RUSAGE_SELF)
    whole = usage.ru_utime + usage.ru_stime
    spent["other"] = whole - sum(spent.values())
    spent["whole"] = whole
    with open(argv[0], "w") as f:
        json.dump(spent, f)
    return code


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
