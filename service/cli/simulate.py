"""``wandcal simulate OUT``: a simulated capture folder with its ``truth.json``; also the simulator's
options and run, which ``wandcal demo`` shares."""

from __future__ import annotations

import argparse
from pathlib import Path

from wandcal.service.cli.support.args import MAX_SEED, arg_number, arg_whole

TRUTH_FILE = "truth.json"
# The simulator holds every observation in memory (~100 bytes a camera-frame): 64 cameras by
# 100,000 frames is ~0.6 GB, the most a demo should ask of a workstation.
MAX_SIM_CAMERAS = 64
MAX_SHAPE_CAMERAS = 256  # simulate --shape: stadium rings have 200+ cameras (each frame kept in only 2-4)
MAX_SIM_FRAMES = 100_000
MAX_NOISE_PX = 100.0  # blob noise past this hides the wand in any image
MAX_TAKE_MARKERS = 200  # a full marker suit has ~50; a few people and props stay under this
MAX_REFERENCE_POINTS = 10_000  # floor points or drop frames: far more than any lab digitises
# simulate --intrinsics-error: a lens's nominal focal length is marked to 5%; 20% is a wrong lens, not an error
MAX_INTRINSICS_ERROR_PCT = 20.0
MAX_PRINCIPAL_ERROR_PX = 200.0  # a principal point tens of pixels off is common; hundreds is another sensor crop
MAX_DISTORTION_ERROR = 0.5  # the simulator's k1 is -0.15 to -0.05 (shapes: up to 0.1)
# the wands simulate --wand films (rig.json wand.markers_m, metres): an asymmetric split tells a
# collinear wand's ends apart (OptiTrack CW-500-like), an asymmetric bar a planar T's (Vicon-like)
WANDS = {
    "two": None,
    "three": [[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.5, 0.0, 0.0]],
    "five": [[0.0, 0.0, 0.0], [0.08, 0.0, 0.0], [0.2, 0.0, 0.0], [0.35, 0.0, 0.0], [0.6, 0.0, 0.0]],
    "tee": [[0.0, 0.0, 0.0], [0.18, 0.0, 0.0], [0.42, 0.0, 0.0], [0.18, 0.12, 0.0], [0.18, 0.30, 0.0]],
}


def register(sub: argparse._SubParsersAction, *, arguments: bool = True) -> None:
    p = sub.add_parser("simulate", help="write a simulated capture folder with its truth.json")
    p.set_defaults(run=run_simulate)
    if arguments:
        p.add_argument("out", type=Path, help="folder to write")
        sim_args(p, cameras=8, frames=1500, shapes=True)
        # the shapes of calib/sim/shapes.py (SHAPES; not imported here: building the parser loads no numerics)
        p.add_argument("--shape", choices=("ring", "dome", "tiers", "hallway"), default=None,
                       help="a rig of this shape instead of the small default ring: 8 to 256 cameras, each frame seen by "
                       "2-4 of them, |k1| up to --max-k1 (calib/sim/shapes.py)")
        p.add_argument("--size", type=arg_number(3, 120), default=None, metavar="M",
                       help="with --shape: the radius of a ring, dome or two tiers (3-15 m, default 10) or a hallway's "
                       "length (10-120 m, default 40)")
        p.add_argument("--max-k1", type=arg_number(0, 0.1), default=0.1, metavar="K",
                       help="with --shape: largest |k1| (default 0.1)")
        p.add_argument("--wand", choices=tuple(WANDS), default="two",
                       help="the wand: two markers 0.5 m apart (default), three or five collinear markers, or a planar "
                       "T of five (rig.json wand.markers_m); not with --shape")
        vertical = p.add_mutually_exclusive_group()
        vertical.add_argument("--floor", type=arg_whole(3, MAX_REFERENCE_POINTS), default=None, metavar="N",
                              help="also write floor.csv: N points on the floor, the world's vertical without an "
                              "L-frame (use with --no-static; default: none)")
        vertical.add_argument("--drop", type=arg_whole(5, MAX_REFERENCE_POINTS), default=None, metavar="N",
                              help="also write drop.csv: a ball dropped through the volume, N frames at 100 fps, "
                              "gravity as the world's vertical (use with --no-static; default: none)")
        intrinsics_args(p)
        take_args(p)


def arg_percent(text: str) -> float:
    """A per cent from 0 to :data:`MAX_INTRINSICS_ERROR_PCT`, "2" or "2%"."""
    return arg_number(0, MAX_INTRINSICS_ERROR_PCT)(text.strip().removesuffix("%"))


def arg_distortion(text: str) -> tuple[float, float | None]:
    """K or K,P: the radial and (default K) tangential distortion sigmas, each 0 to :data:`MAX_DISTORTION_ERROR`."""
    number = arg_number(0, MAX_DISTORTION_ERROR)
    parts = text.split(",")
    if len(parts) > 2:
        raise argparse.ArgumentTypeError(f"{text!r}: give K or K,P (e.g. 0.01 or 0.01,0.001)")
    return number(parts[0]), number(parts[1]) if len(parts) == 2 else None


def intrinsics_args(p: argparse.ArgumentParser) -> None:
    """``--intrinsics-error`` and its companions: rig.json's intrinsics off the truth, as real ones
    are (calib/sim/intrinsics.py); truth.json keeps the true ones."""
    p.add_argument("--intrinsics-error", type=arg_percent, default=0.0, metavar="PCT",
                   help="write each camera's focal length into rig.json off the truth by a random draw of this sigma, "
                   "per cent (e.g. 2%%; fx and fy together; default 0: exact); truth.json keeps each camera's true K "
                   "and dist")
    p.add_argument("--principal-error", type=arg_number(0, MAX_PRINCIPAL_ERROR_PX), default=0.0, metavar="PX",
                   help="also the principal point (cx, cy) off by draws of this sigma, pixels (default 0)")
    p.add_argument("--distortion-error", type=arg_distortion, default=(0.0, None), metavar="K[,P]",
                   help="also k1, k2 off by draws of sigma K, and p1, p2 of sigma P (default K), absolute; real "
                   "lenses' p1, p2 are known to some 0.0007 (default 0)")
    p.add_argument("--focal-std", action="store_true",
                   help="with --intrinsics-error: write each camera's focal_std_px as the sigma its focal length was "
                   "drawn from (as a lens calibration states it; docs/capture-format.md); default: left out, the "
                   "judgement assumes 2%%")
    p.add_argument("--intrinsics-seed", type=arg_whole(0, MAX_SEED), default=None, metavar="SEED",
                   help="the draws' seed (default: --seed); another seed draws other errors for the same capture")


def take_args(p: argparse.ArgumentParser) -> None:
    """``--take``: an ordinary take of the same rig (the ring of the same --cameras and --seed) instead
    of a wand capture, for ``wandcal watch``."""
    p.add_argument("--take", action="store_true",
                   help="write a take (rig.json, take.csv: unlabelled blobs of markers on moving bodies) of the rig "
                   "that the same --cameras and --seed give, for 'wandcal watch'; --frames is its length")
    p.add_argument("--markers", type=arg_whole(1, MAX_TAKE_MARKERS), default=40, metavar="N",
                   help="with --take: markers on the moving bodies (default 40)")
    p.add_argument("--spurious", type=arg_number(0, 50), default=0.5, metavar="N",
                   help="with --take: spurious blobs a camera-frame on average (default 0.5)")
    p.add_argument("--dropped", type=arg_number(0, 1, high_open=True), default=0.03, metavar="SHARE",
                   help="with --take: share of marker blobs a camera misses (default 0.03)")
    p.add_argument("--move", default=None, metavar="CAM:FRAME:DEG:MM",
                   help="with --take: camera CAM (its id) turned DEG degrees and its centre moved MM mm at frame FRAME "
                   "(a knock), e.g. cam4:500:0.2:2 (default: none, no camera moves)")
    p.add_argument("--drift", type=arg_whole(0, MAX_SIM_FRAMES), default=0, metavar="FRAMES",
                   help="with --move: the move grows evenly over this many frames (a warming mount; default 0, a knock)")


def sim_args(p: argparse.ArgumentParser, cameras: int, frames: int, shapes: bool = False) -> None:
    """The simulated rig's options, with the command's own defaults for its size (``shapes``: up to
    :data:`MAX_SHAPE_CAMERAS` cameras, for ``--shape``)."""
    most = MAX_SHAPE_CAMERAS if shapes else MAX_SIM_CAMERAS
    p.add_argument("--cameras", type=arg_whole(2, most), default=cameras, metavar="N",
                   help=f"cameras on a ring around the volume, 2 to {MAX_SIM_CAMERAS} (default {cameras})"
                   + (f"; with --shape 8 to {MAX_SHAPE_CAMERAS}" if shapes else ""))
    p.add_argument("--frames", type=arg_whole(10, MAX_SIM_FRAMES), default=frames, metavar="N",
                   help=f"wand frames, 10 to {MAX_SIM_FRAMES} (default {frames})")
    p.add_argument("--noise", type=arg_number(0, MAX_NOISE_PX), default=0.3, metavar="PX",
                   help="blob noise, pixels (std; default 0.3)")
    p.add_argument("--outliers", type=arg_number(0, 1, high_open=True), default=0.0, metavar="SHARE",
                   help="share of camera-frames with a gross outlier, 0 to below 1 (default 0)")
    p.add_argument("--no-static", action="store_true", help="no L-frame")
    p.add_argument("--seed", type=arg_whole(0, MAX_SEED), default=1,
                   help="random seed: the same seed gives the same rig (default 1)")


def simulated(args):
    """The scene :func:`sim_args`' options ask for (a :class:`wandcal.calib.sim.simulate.SimulatedCapture`),
    its rig's intrinsics off the truth where :func:`intrinsics_args`' ask for it."""
    from wandcal.calib.sim.intrinsics import IntrinsicsError, with_intrinsics_error

    radial, tangential = getattr(args, "distortion_error", (0.0, None))
    error = IntrinsicsError(getattr(args, "intrinsics_error", 0.0) / 100.0, getattr(args, "principal_error", 0.0),
                            radial, getattr(args, "focal_std", False), tangential)
    if error.write_std and not error.focal_rel:
        from wandcal.calib.errors import CalibrationError

        raise CalibrationError("simulate --focal-std writes the sigma --intrinsics-error draws the focal lengths "
                               "from: give --intrinsics-error PCT too (e.g. --intrinsics-error 2%)")
    seed = getattr(args, "intrinsics_seed", None)
    return with_intrinsics_error(_simulated(args), error, args.seed if seed is None else seed)


def _simulated(args):
    from wandcal.calib.errors import CalibrationError
    from wandcal.calib.sim.simulate import simulate_capture  # simulate and demo only: calibrate does not pay for it

    if getattr(args, "shape", None) is not None and getattr(args, "wand", "two") == "two":
        return _simulate_shape(args)
    if args.cameras > MAX_SIM_CAMERAS:
        raise CalibrationError(f"--cameras {args.cameras}: the default ring holds 2 to {MAX_SIM_CAMERAS} cameras; "
                               f"give --shape ring for up to {MAX_SHAPE_CAMERAS}")
    layout = WANDS[getattr(args, "wand", "two")]
    if layout is not None and getattr(args, "shape", None) is not None:
        raise CalibrationError("simulate --wand: the --shape rigs film a two-marker wand; leave out --shape or --wand")
    import numpy as np

    return simulate_capture(args.cameras, args.frames, args.noise, args.outliers, not args.no_static, args.seed,
                            wand_markers=None if layout is None else np.array(layout))


def _simulate_shape(args):
    from wandcal.calib.errors import CalibrationError
    from wandcal.calib.sim.shapes import RigShape, default_size, simulate_shape

    try:
        shape = RigShape(args.shape, args.cameras, args.size or default_size(args.shape), args.max_k1)
    except ValueError as exc:
        raise CalibrationError(f"simulate --shape: {exc}") from None
    return simulate_shape(shape, args.frames, args.noise, args.outliers, args.seed, static=not args.no_static)


def write_simulated(folder: Path, sim, vertical=None) -> None:
    """The capture folder (with ``vertical``'s floor.csv or drop.csv when given) and its truth.json."""
    import json

    from wandcal.capture.folder import write_capture

    write_capture(folder, sim.rig, sim.wand, sim.static, vertical=vertical)
    (folder / TRUTH_FILE).write_text(json.dumps(sim.truth.to_json(sim.rig)) + "\n")


def simulated_vertical(args, sim):
    """floor.csv's or drop.csv's observations that ``--floor`` or ``--drop`` ask for, or None."""
    from wandcal.calib.errors import CalibrationError

    if args.floor is None and args.drop is None:
        return None
    if sim.static is not None:
        raise CalibrationError(f"--{'floor' if args.floor else 'drop'} sets the world's vertical, which the L-frame "
                               "already sets; add --no-static")
    import numpy as np

    from wandcal.calib.sim import references

    rng = np.random.default_rng([args.seed, 7])
    X = references.floor_points(args.floor, rng) if args.floor else references.drop_track(args.drop, rng)
    return references.observe(sim.rig, sim.truth.R, sim.truth.t, "floor" if args.floor else "drop", X, args.noise, rng)


def run_simulate(args) -> int:
    if getattr(args, "take", False):
        return _run_take(args)
    sim = simulated(args)
    write_simulated(args.out, sim, simulated_vertical(args, sim))
    print(f"wrote {args.out}: {len(sim.rig.cameras)} cameras, {args.frames} frames, {len(sim.wand)} wand blobs")
    return 0


def _run_take(args) -> int:
    """``simulate --take``: a take folder and its truth.json (the standing poses and the move)."""
    import json

    from wandcal.calib.errors import CalibrationError
    from wandcal.calib.sim.takes import simulate_take, take_rig
    from wandcal.capture.take_file import write_take

    if args.shape is not None or args.cameras > MAX_SIM_CAMERAS:
        raise CalibrationError(f"--take: takes are of the default ring of 3 to {MAX_SIM_CAMERAS} cameras; leave out --shape")
    if args.intrinsics_error or args.principal_error or any(args.distortion_error) or args.focal_std:
        raise CalibrationError("--take writes the rig's true intrinsics (a take is checked against a result, which holds "
                               "its own); leave out --intrinsics-error, --principal-error, --distortion-error and --focal-std")
    rig = take_rig(args.cameras, args.seed)[0]
    moves = () if args.move is None else (_parse_move(args.move, args.drift, rig),)
    sim = simulate_take(args.cameras, args.frames, markers=args.markers, noise_px=args.noise, dropped=args.dropped,
                        spurious=args.spurious, moves=moves, seed=args.seed)
    write_take(args.out, sim.rig, sim.blobs)
    (args.out / TRUTH_FILE).write_text(json.dumps(sim.truth.to_json(sim.rig)) + "\n")
    print(f"wrote {args.out}: a take of {len(sim.rig.cameras)} cameras, {args.frames} frames, {args.markers} markers, "
          f"{len(sim.blobs)} blobs" + (f"; {args.move}" if moves else ""))
    return 0


def _parse_move(text: str, drift: int, rig):
    """CAM:FRAME:DEG:MM (the id may hold colons: the last three fields are numbers) as a
    :class:`wandcal.calib.sim.takes.CameraMove` over ``drift`` frames."""
    from wandcal.calib.errors import CalibrationError
    from wandcal.calib.sim.takes import CameraMove

    try:
        cam, frame, deg, mm = text.rsplit(":", 3)
        move = CameraMove(rig.index(cam), int(frame), float(deg), float(mm), drift)
    except (ValueError, TypeError):
        raise CalibrationError(f"--move {text!r}: give CAM:FRAME:DEG:MM, e.g. cam4:500:0.2:2 (cameras "
                               f"{', '.join(rig.ids[:4])}, ...)") from None
    if move.frame < 0 or not (0 <= move.rotation_deg <= 90 and 0 <= move.translation_mm <= 1000):
        raise CalibrationError(f"--move {text!r}: FRAME is a frame from 0, DEG 0-90 and MM 0-1000")
    return move
