"""Every input through every command (issue 32): each input kind of ../shared/data and the
simulator (bench/matrix_inputs.py, the builders tests/calib/test_input_matrix.py uses) against each
method and command, run as the commands run them. A cell is a figure when it works (the centre
error against the truth, or the reprojection RMS on a real session; check's exit status; the
re-solved camera's move against its sigma), or the refusal's message when it refuses: a refusal
must name what the input or method cannot hold and what to use instead. A cell that raises
anything but a refusal is a gap (marked **gap**).

Qualisys' .qca (a calibration, no observations) goes through the exports only; OpenPTV's test
cavity (images of a refractive target) takes none of these commands (docs/import.md).

    python bench/bench_matrix.py [--kinds a,b] [--commands x,y] [--no-write]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.common import aligned_rms_mm, publish
from bench.matrix_inputs import REAL, SIMULATED, Kind, build
from bench.real_sessions import SHARED_DATA
from wandcal.calib.errors import CalibrationError
from wandcal.capture.rig_file import CaptureFormatError

TITLE = "Every input through every command"
COMMANDS = ("ba", "lp", "paper", "sync_auto", "refine_intrinsics", "guidance", "check", "solve_only", "report",
            "export")
QCA = SHARED_DATA / "qualisys_pose2sim_demo" / "Calib.qca.txt"
REFUSED = (CalibrationError, CaptureFormatError)
# paper's solve took 95 s (L-frame) to 784 s (3-marker wand) a simulated cell on this machine
# (2 cores, load 15-25): it runs on the real sessions and the points-only refusal here, and on
# simulated rigs in bench/bench_methods.py and tests/calib/solve (as the test matrix does)
PAPER_KINDS = ("points_only", *REAL)


def figure(k: Kind, result, truth) -> str:
    """A calibration's figure: its centre error against the truth (simulated), else its median
    reprojection RMS."""
    if truth is not None:
        return f"{aligned_rms_mm(result.centers, truth):.2f} mm"
    rms = [c.reprojection_rms_px for c in result.cameras if c.reprojection_rms_px is not None]
    if not rms:  # no wand: the point tracks' RMS
        rms = [c.points.rms_px for c in result.cameras if c.points is not None and c.points.rms_px is not None]
    return f"{np.median(rms):.2f} px" if rms else "ok"


def _calibrate(k: Kind, **options):
    from wandcal.calib.run.calibrate import calibrate
    from wandcal.calib.run.options import CalibrationOptions

    return calibrate(k.rig, k.wand, k.static, options=CalibrationOptions(**options), points=k.points, axis=k.axis)


def _check(k: Kind, result) -> str:
    """``wandcal check RESULT CAPTURE`` against its own result: its exit status (service/cli/check.py)."""
    from wandcal.calib.judge.bumps import check_rig

    expected = np.array([c.reprojection_rms_px or np.nan for c in result.cameras], float)
    found = check_rig(result.rig, result.R, result.t, k.wand, None if np.isnan(expected).any() else expected, k.points)
    moved = [c.id for c in found.cameras if c.moved]
    unjudged = [c.id for c in found.cameras if c.moved is None]
    code = 3 if found.rebuilt else 1 if moved else 3 if unjudged else 0
    why = f": moved {', '.join(moved)}" if moved else f": not judged {', '.join(unjudged)}" if unjudged else ""
    return f"exit {code}{why}" + ("" if code == 0 else " **gap**")


def _solve_only(k: Kind, result) -> str:
    """``--solve-only`` of the second camera from the full result: its move, mm, against its sigma."""
    from wandcal.calib.run.resolve import solve_only

    out = solve_only(result.rig, k.wand, result.R, result.t, [result.rig.ids[1]], result.world, list(result.cameras),
                     points=k.points)
    moved = 1000 * float(np.linalg.norm(out.centers[1] - result.centers[1]))
    sigma = result.cameras[1].uncertainty.center_std_mm if result.cameras[1].uncertainty is not None else None
    if sigma is None:  # no scale: the move against the rig's size
        extent = 1000 * float(np.ptp(result.centers, axis=0).max())
        return f"{moved / extent:.1e} of the rig"
    return f"{moved:.2f} mm (sigma {sigma:.2f})" + ("" if moved <= 2 * sigma else " **gap**")


def _guidance(k: Kind) -> str:
    from wandcal.calib.run.guidance import wanding_guidance

    doc = wanding_guidance(k.rig, k.wand, k.static, points=k.points if k.wand is None else None).document
    wand_words = k.wand is None and any("wand" in a for a in doc["advice"])
    return (f"{'enough' if doc['enough'] else 'not enough'}, coverage {min(c['coverage'] for c in doc['cameras']):.0%}"
            + (" **gap** (advises a wand)" if wand_words else ""))


def _report(k: Kind, result, tmp: Path) -> str:
    from wandcal.capture.folder import Capture
    from wandcal.capture.result_file import read_result
    from wandcal.service.report import write_report

    path = tmp / "result.json"
    path.write_text(json.dumps(result.to_json()))
    cap = Capture(rig=k.rig, wand=k.wand if k.wand is not None else _no_wand(), static=k.static, points=k.points,
                  axis=k.axis)
    written = write_report(read_result(path), cap, tmp / "report")
    return f"{len(written)} files"


def _no_wand():
    from wandcal.calib.rig import WandObservations

    return WandObservations(np.zeros(0), np.zeros(0), np.zeros((0, 2)))


def _exports(result_json: dict, rig, R: np.ndarray, t: np.ndarray, tmp: Path) -> str:
    """Each export format written and read back: the formats whose poses come back (to 1e-6), and
    each refusal's message."""
    from wandcal.capture.formats.cameras_in import read_camera_file
    from wandcal.capture.formats.export import FORMAT_NAMES, export

    good, said = [], []
    for fmt in FORMAT_NAMES:
        try:
            path = tmp / f"cameras.{fmt}"
            path.write_text(export(result_json, fmt, rig))
            # DLT coefficients hold no image size nor names: given as `wandcal import --size` would
            sizes, ids = ([(c.width, c.height) for c in rig.cameras], list(rig.ids)) if fmt == "dlt-csv" else (None, None)
            back = read_camera_file(path, fmt, sizes=sizes, ids=ids)
            ok = np.allclose(back.R, R, atol=1e-6) and np.allclose(back.t, t, atol=1e-6)
            good.append(fmt if ok else f"{fmt} **gap** (poses differ)")
        except REFUSED as exc:
            said.append(f"{fmt} refused: {exc}")
    return ", ".join(good) + ("; " + "; ".join(said) if said else "")


def run_cell(command: str, k: Kind, base, truth, tmp: Path, everything: bool = False) -> str:
    """One command on one input kind: its figure, or 'refused: ...' with the message; ``paper``
    on the kinds of ``PAPER_KINDS`` only unless ``everything``."""
    try:
        if command == "paper" and k.name not in PAPER_KINDS and not everything:
            return "not run here (bench/bench_methods.py)"
        if command in ("ba", "lp", "paper"):
            return figure(k, base if command == "ba" else _calibrate(k, method=command), truth)
        if command == "sync_auto":
            return figure(k, _calibrate(k, sync="auto"), truth)
        if command == "refine_intrinsics":
            return figure(k, _calibrate(k, refine_intrinsics=("focal", "principal", "k1")), truth)
        if command == "guidance":
            return _guidance(k)
        if command == "check":
            return _check(k, base)
        if command == "solve_only":
            return _solve_only(k, base)
        if command == "report":
            return _report(k, base, tmp)
        return _exports(base.to_json(), base.rig, base.R, base.t, tmp)
    except REFUSED as exc:
        return f"refused: {exc}"
    except Exception as exc:  # a cell that breaks is a gap to report, not the bench's end
        return f"**gap** {type(exc).__name__}: {exc}"


def row(name: str, commands: tuple[str, ...], everything: bool = False) -> list[str] | None:
    """The cells of input kind ``name``; None when its data are absent."""
    k = build(name)
    if k is None:
        return None
    truth = _truth(name)
    with tempfile.TemporaryDirectory(prefix="wandcal-matrix-") as tmp:
        try:
            base = _calibrate(k)
        except REFUSED as exc:  # every command needs the calibration: its refusal once
            return [f"refused (calibrate, every method): {exc}"] + ["as calibrate"] * (len(commands) - 1)
        cells = []
        for command in commands:
            started = time.perf_counter()
            cells.append(run_cell(command, k, base, truth, Path(tmp), everything))
            print(f"  {name} x {command}: {cells[-1][:160]} ({time.perf_counter() - started:.0f} s)", file=sys.stderr,
                  flush=True)
        return cells


def _truth(name: str):
    """The simulated kind's true camera centres (N, 3), metres; None for a real session."""
    if name not in SIMULATED:
        return None
    from wandcal.calib.sim.simulate import simulate_capture

    markers = {"three_marker": "CW500_M", "planar_wand": "TEE_M"}.get(name)
    from bench import matrix_inputs

    layout = getattr(matrix_inputs, markers) if markers else None
    return simulate_capture(4, 300, 0.3, 0.0, name == "lframe", 1, wand_markers=layout).truth.centers


def qca_row(commands: tuple[str, ...]) -> list[str] | None:
    """Qualisys' .qca: a calibration without observations, read by ``wandcal import`` as cameras;
    the exports take a wandcal result, so only its reading is a cell."""
    if not QCA.is_file():
        return None
    from wandcal.capture.formats.cameras_in import read_camera_file

    try:
        posed = read_camera_file(QCA, "qca")
        read = f"read: {len(posed.cameras)} cameras, centres {np.ptp(posed.centers, axis=0).max():.1f} m apart"
    except REFUSED as exc:
        read = f"refused: {exc}"
    return [read if command == "export" else "n/a: a camera file, no observations" for command in commands]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--kinds", default=",".join(SIMULATED + REAL + ("qca",)))
    ap.add_argument("--commands", default=",".join(COMMANDS))
    ap.add_argument("--no-write", action="store_true", help="print the table only")
    ap.add_argument("--paper-everywhere", action="store_true", help="paper on the simulated rigs too (minutes a cell)")
    args = ap.parse_args(argv)
    commands = tuple(args.commands.split(","))
    lines = ["| input | " + " | ".join(commands) + " |", "|---|" + "---|" * len(commands)]
    absent = []
    for name in args.kinds.split(","):
        print(f"{name}:", file=sys.stderr, flush=True)
        cells = qca_row(commands) if name == "qca" else row(name, commands, args.paper_everywhere)
        if cells is None:
            absent.append(name)
            continue
        lines.append(f"| {name} | " + " | ".join(c.replace("|", "/").replace("\n", " ") for c in cells) + " |")
    gaps = sum(line.count("**gap**") for line in lines)
    text = "\n".join(lines) + f"\n\n{gaps} gap(s)" + (f"; absent here: {', '.join(absent)}" if absent else "") + "."
    return publish(TITLE, text, not args.no_write)


if __name__ == "__main__":
    raise SystemExit(main())
