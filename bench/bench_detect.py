"""Blob detection speed and centroid accuracy on rendered 1280x1024 frames.

Compares ``wandcal.calib.detect.detect_blobs`` (one core, and ``detect_many`` on two threads) with
``cv2.SimpleBlobDetector`` and with the plain whole-frame OpenCV building blocks it was chosen
against (docs/decisions/0003-blob-detector.md). Then times ``wandcal detect`` on a written
image-level folder (PNG decode + detection) on 1 and 2 worker threads
(docs/decisions/0006-parallel-detection.md). Prints the tables and writes them to the
"Blob detection" section of docs/benchmarks.md.

Also writes the section "Detection on real images" (bench/detect_real.py): OpenPTV's cavity images
against OpenPTV's own detections (when ../shared/data is present), and every background model's
speed and accuracy on rendered frames.

Run: python bench/bench_detect.py [--frames 120] [--folder-frames 300] [--real-only] [--no-write]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from bench.common import replace_section  # noqa: E402
from bench.detect_real import background_rows, openptv_rows, regression_rows, touching_rows  # noqa: E402
from wandcal.calib.detect import DetectConfig, detect_blobs, detect_many  # noqa: E402
from wandcal.calib.sim.render import render_blobs  # noqa: E402
from wandcal.calib.sim.simulate import simulate_capture  # noqa: E402
from wandcal.capture.folder import rig_to_json  # noqa: E402
from wandcal.capture.images import detect_capture  # noqa: E402
from wandcal.capture.recording.writer import PNG_PARAMS  # noqa: E402

SHAPE = (1024, 1280)  # (H, W), the sensor size
MARKERS = 6  # 2 wand markers + 4 L-frame markers: "a handful of blobs"
SIGMA_RANGE_PX = (1.0, 2.0)
PEAK_RANGE = {8: (120.0, 240.0), 16: (20000.0, 60000.0)}
BACKGROUND = {8: 12.0, 16: 2000.0}
NOISE = {8: 2.0, 16: 300.0}
FIXED_THRESHOLD = {8: 40, 16: 7000}  # background + a quarter of the dimmest peak
MATCH_PX = 2.0  # a detection this close to a rendered spot is that spot
SECTION = "## Blob detection"
REAL_SECTION = "## Detection on real images"
BEFORE_REV = "f6d8965"  # the last commit before background models and masks came in (docs/decisions/0012)
SHARED_DATA = Path(os.environ.get("WANDCAL_SHARED_DATA", REPO.parent / "shared" / "data"))
REPEATS = 5  # best of 5 round-robin runs per method
FOLDER_CAMERAS = 3  # "several cameras": the folder's frames are split between them
FOLDER_REPEATS = 7  # runs of a few seconds each: more of them catch a spell when both cores are free


def render_frames(n: int, bit_depth: int, seed: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    rng = np.random.default_rng(seed)
    frames, truths = [], []
    for _ in range(n):
        uv = []
        while len(uv) < MARKERS:
            p = rng.uniform([20, 20], [SHAPE[1] - 20, SHAPE[0] - 20])
            if all(np.hypot(*(p - q)) > 20 for q in uv):
                uv.append(p)
        uv = np.array(uv)
        sigma = rng.uniform(*SIGMA_RANGE_PX, MARKERS)
        peak = rng.uniform(*PEAK_RANGE[bit_depth], MARKERS)
        frames.append(render_blobs(SHAPE, uv, sigma, peak, BACKGROUND[bit_depth], NOISE[bit_depth], bit_depth, rng))
        truths.append(uv)
    return frames, truths


def score(found: list[np.ndarray], truths: list[np.ndarray]) -> tuple[float, float, int]:
    """Centroid RMS error (px) over matched spots, recall, and false detections."""
    errors, hits, false = [], 0, 0
    for spots, truth in zip(found, truths):
        uv = np.asarray(spots, float).reshape(-1, 2)
        if len(uv) == 0:
            continue
        d = np.linalg.norm(truth[:, None] - uv[None], axis=2)
        near = d.min(axis=1)
        errors.append(near[near < MATCH_PX])
        hits += int(np.sum(near < MATCH_PX))
        false += int(np.sum(d.min(axis=0) >= MATCH_PX))
    e = np.concatenate(errors) if errors else np.array([np.nan])
    return float(np.sqrt(np.mean(e**2))), hits / sum(len(t) for t in truths), false


def time_once(run, frames: list[np.ndarray], cores: int, all_cores: set[int]) -> tuple[float, list]:
    """Seconds for ``run(frames)`` and its output, on ``cores`` CPUs.

    One core: pin this thread to one CPU and stop OpenCV from spreading work to its own pool.
    """
    if cores == 1:
        cv2.setNumThreads(1)
        os.sched_setaffinity(0, {min(all_cores)})
    try:
        t0 = time.perf_counter()
        out = run(frames)
        return time.perf_counter() - t0, out
    finally:
        os.sched_setaffinity(0, all_cores)
        cv2.setNumThreads(-1)


def simple_blob_detector(bit_depth: int):
    params = cv2.SimpleBlobDetector_Params()
    params.filterByColor = True
    params.blobColor = 255  # bright blobs
    params.minThreshold = 30  # above the 8-bit background (12, or 2000 >> 8 = 8)
    params.maxThreshold = 220
    params.thresholdStep = 20
    params.filterByArea = True
    params.minArea = 4
    params.maxArea = 1500
    params.filterByCircularity = False
    params.filterByConvexity = False
    params.filterByInertia = True
    params.minInertiaRatio = 0.25
    detector = cv2.SimpleBlobDetector_create(params)

    def run(frames):
        out = []
        for f in frames:
            img = f if f.dtype == np.uint8 else (f >> 8).astype(np.uint8)  # it takes 8-bit only
            out.append(np.array([k.pt for k in detector.detect(img)]))
        return out

    return run


def whole_frame_cc(threshold: int):
    """Threshold + connectedComponentsWithStats over the whole frame; unweighted centroids."""

    def run(frames):
        out = []
        for f in frames:
            _, mask = cv2.threshold(f, threshold, 255, cv2.THRESH_BINARY)
            n, _, stats, cents = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
            keep = stats[1:, cv2.CC_STAT_AREA] >= 4
            out.append(cents[1:][keep])
        return out

    return run


def whole_frame_nonzero(threshold: int):
    """Threshold + findNonZero: only locates the bright pixels (no labelling, no centroids)."""

    def run(frames):
        for f in frames:
            _, mask = cv2.threshold(f, threshold, 255, cv2.THRESH_BINARY)
            cv2.findNonZero(mask.astype(np.uint8))
        return [np.zeros((0, 2)) for _ in frames]

    return run


def copy_only(frames):
    for f in frames:
        f.copy()
    return [np.zeros((0, 2)) for _ in frames]


def ours(config: DetectConfig):
    return lambda frames: [detect_blobs(f, config).uv for f in frames]


def ours_many(config: DetectConfig, workers: int):
    return lambda frames: [b.uv for b in detect_many(frames, config, workers=workers)]


def write_folder(folder: Path, frames: int) -> int:
    """An image-level capture of ``frames`` rendered 8-bit PNGs over FOLDER_CAMERAS cameras,
    written with the capture writer's PNG settings; returns its size in bytes."""
    rig = simulate_capture(FOLDER_CAMERAS, 10, 0.3, seed=1).rig
    (folder / "rig.json").write_text(json.dumps(rig_to_json(rig)))
    images, _ = render_frames(frames, 8, seed=99)
    size = 0
    for i, image in enumerate(images):
        path = folder / "frames" / rig.ids[i % FOLDER_CAMERAS] / f"{i // FOLDER_CAMERAS:06d}.png"
        path.parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(path), image, PNG_PARAMS)
        size += path.stat().st_size
    return size


def cpu_seconds() -> float:
    """CPU time of this process so far, all threads, user + system."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def decode_then_detect_many(folder: Path, workers: int) -> None:
    """What ``wandcal detect`` did before docs/decisions/0006: decode 64 images in the calling
    thread, then detect them with ``detect_many`` on ``workers`` threads."""
    paths = sorted(folder.glob("frames/*/*.png"))
    for start in range(0, len(paths), 64):
        images = [cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in paths[start:start + 64]]
        detect_many(images, None, workers)


def folder_rows(frames: int) -> tuple[list[str], str]:
    """Table lines timing detection over a written folder, and a sentence on how it was made."""
    workers = min(2, len(os.sched_getaffinity(0)))
    with tempfile.TemporaryDirectory(prefix="bench-detect-") as tmp:
        folder = Path(tmp)
        size = write_folder(folder, frames)
        methods = [
            ("wandcal detect (decode + detect per file)", 1, lambda: detect_capture(folder, workers=1)),
            ("wandcal detect (decode + detect per file)", workers, lambda: detect_capture(folder, workers=workers)),
            ("decode in one thread, then detect_many (before 0006)", workers,
             lambda: decode_then_detect_many(folder, workers)),
        ]
        seconds = [[] for _ in methods]
        busy = [[] for _ in methods]
        for _ in range(FOLDER_REPEATS):  # round robin, as above: a busy spell slows one repeat of each
            for k, (_, _, run) in enumerate(methods):
                c0, t0 = cpu_seconds(), time.perf_counter()
                run()
                seconds[k].append(time.perf_counter() - t0)
                busy[k].append((cpu_seconds() - c0) / seconds[k][-1])
    best = [min(s) for s in seconds]
    median = [statistics.median(s) for s in seconds]
    lines = ["| method | workers | best frames/s | median frames/s | best speed-up over 1 worker "
             "| median speed-up | cores busy (median CPU s / s) |", "|---|---|---|---|---|---|---|"]
    for (name, n, _), b, m, u in zip(methods, best, median, busy):
        lines.append(f"| {name} | {n} | {frames / b:,.0f} | {frames / m:,.0f} | {best[0] / b:.2f}x "
                     f"| {median[0] / m:.2f}x | {statistics.median(u):.2f} |")
    about = (f"{frames} rendered {SHAPE[1]}x{SHAPE[0]} 8-bit frames as above, split over {FOLDER_CAMERAS} "
             f"cameras and written as PNGs with the capture writer's settings ({size / frames / 1e6:.2f} MB "
             "per file, in the page cache), timed from the folder to wand.csv with "
             f"`wandcal.capture.images.detect_capture`. Best and median of {FOLDER_REPEATS} round-robin runs; the "
             "speed-ups compare each row with the 1-worker row of the same statistic. 'Cores busy' is this "
             "process's CPU time over the wall time: near 2 means both cores decoded at once, near 1 that "
             "the GIL or other jobs on the machine left it one core.")
    return lines, about


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=120)  # distinct frames: 160 MB at 8 bits, never cache-hot
    parser.add_argument("--folder-frames", type=int, default=300,
                        help="PNGs in the folder-detection rows (0 skips them)")
    parser.add_argument("--no-write", action="store_true", help="print only; leave docs/benchmarks.md alone")
    parser.add_argument("--real-only", action="store_true", help="only the section 'Detection on real images'")
    parser.add_argument("--background-frames", type=int, default=40,
                        help="rendered frames per bit depth for the background models' rows")
    parser.add_argument("--touching-pairs", type=int, default=200,
                        help="rendered pairs of touching spots per row of the touching-spots table")
    parser.add_argument("--before", default=BEFORE_REV, metavar="REV",
                        help=f"git revision of the detector (rev:calib/detect.py then) to time side by side (default {BEFORE_REV})")
    args = parser.parse_args()
    real_section(args)
    if args.real_only:
        return 0

    load = os.getloadavg()[0]
    rows = []
    all_cores = os.sched_getaffinity(0)
    for bit_depth in (8, 16):
        frames, truths = render_frames(args.frames, bit_depth, seed=bit_depth)
        fixed = DetectConfig(threshold=FIXED_THRESHOLD[bit_depth])
        single = [
            ("detect_blobs, fixed threshold", ours(fixed)),
            ("detect_blobs, automatic threshold", ours(DetectConfig())),
            ("cv2.SimpleBlobDetector (8-bit input)", simple_blob_detector(bit_depth)),
            ("threshold + connectedComponentsWithStats", whole_frame_cc(FIXED_THRESHOLD[bit_depth])),
        ]
        if bit_depth == 8:
            single.append(("threshold + findNonZero (no centroids)", whole_frame_nonzero(FIXED_THRESHOLD[bit_depth])))
        single.append(("memory copy of the frame (floor)", copy_only))
        workers = min(2, len(all_cores))
        methods = [(name, run, 1) for name, run in single]
        methods.append((f"detect_many, fixed threshold, {workers} threads", ours_many(fixed, workers), workers))
        # Round-robin repeats, best of each: other jobs sharing the machine come and go, and this
        # way a busy spell slows one repeat of every method rather than all repeats of one.
        best = {name: np.inf for name, _, _ in methods}
        outputs = {}
        for _name, run, _cores in methods:
            run(frames[:5])  # warm up
        for _ in range(REPEATS):
            for name, run, cores in methods:
                seconds, outputs[name] = time_once(run, frames, cores, all_cores)
                best[name] = min(best[name], seconds)
        for name, _, cores in methods:
            measured = "no centroids" not in name and "copy" not in name
            quality = score(outputs[name], truths) if measured else (np.nan,) * 3
            rows.append((bit_depth, name, cores, len(frames) / best[name], *quality))

    # Time per frame in units of one memory copy of the frame: other jobs sharing the machine
    # slow every row alike, so this column compares across runs where frames/s cannot.
    copy_rate = {bits: rate for bits, name, _, rate, *_ in rows if name.startswith("memory copy")}
    header = "| bits | method | cores | frames/s | time / frame copy | centroid RMS (px) | recall | false blobs |"
    lines = [header, "|---|---|---|---|---|---|---|---|"]
    for bits, name, cores, rate, rms, recall, false in rows:
        acc = "-" if np.isnan(rms) else f"{rms:.4f}"
        rec = "-" if np.isnan(recall) else f"{recall:.3f}"
        fal = "-" if np.isnan(false) else f"{int(false)}"
        lines.append(
            f"| {bits} | {name} | {cores} | {rate:,.0f} | {copy_rate[bits] / rate:.1f} | {acc} | {rec} | {fal} |"
        )
    table = "\n".join(lines)
    print(table)
    folder_text = ""
    if args.folder_frames > 0:
        folder_lines, about = folder_rows(args.folder_frames)
        print("\n".join(folder_lines))
        folder_text = ("\n### Folder detection (`wandcal detect`)\n\n" + about + "\n\n"
                       + "\n".join(folder_lines) + "\n")
    text = (
        f"{SECTION}\n\n"
        f"Command: `python bench/bench_detect.py --frames {args.frames} --folder-frames {args.folder_frames}`  \n"
        f"Machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
        f"Python {platform.python_version()}, OpenCV {cv2.__version__}, NumPy {np.__version__}; "
        f"load average {load:.1f} when it started (other jobs share the machine: compare the "
        "'time / frame copy' column across runs).\n\n"
        f"{args.frames} rendered {SHAPE[1]}x{SHAPE[0]} frames per bit depth, {MARKERS} Gaussian spots each "
        f"(sigma {SIGMA_RANGE_PX[0]}-{SIGMA_RANGE_PX[1]} px, peaks {PEAK_RANGE[8][0]:.0f}-{PEAK_RANGE[8][1]:.0f} "
        f"of 255 / {PEAK_RANGE[16][0]:.0f}-{PEAK_RANGE[16][1]:.0f} of 65535, read noise {NOISE[8]:.0f} / "
        f"{NOISE[16]:.0f} grey levels), rendered with `wandcal.calib.sim.render.render_blobs` (pixel-integrated, so the "
        f"true centre is exact). Centroid RMS is over spots found within {MATCH_PX:.0f} px; recall is the "
        f"fraction of spots found. Each rate is the best of {REPEATS} round-robin runs; one-core rows pin the "
        "process to one CPU with `cv2.setNumThreads(1)`. "
        "The whole-frame OpenCV rows are the alternatives of docs/decisions/0003-blob-detector.md "
        "(connected-component centroids are unweighted).\n\n"
        f"{table}\n"
        f"{folder_text}"
    )
    if not args.no_write:
        replace_section(SECTION.removeprefix("## "), text.removeprefix(SECTION))
    return 0


def real_section(args) -> None:
    """Print and write the section 'Detection on real images'."""
    load = os.getloadavg()[0]
    parts = []
    if (SHARED_DATA / "openptv_test_cavity").is_dir():
        lines, about = openptv_rows(SHARED_DATA)
        print("\n".join(lines))
        parts.append("### OpenPTV test_cavity against OpenPTV's detections\n\n" + about + "\n\n" + "\n".join(lines))
    else:
        print(f"{SHARED_DATA / 'openptv_test_cavity'} not found: the real-image rows are left out")
    lines, about = background_rows(args.background_frames)
    print("\n".join(lines))
    parts.append("### Background models on rendered frames\n\n" + about + "\n\n" + "\n".join(lines))
    lines, about = touching_rows(args.touching_pairs)
    print("\n".join(lines))
    parts.append("### Touching spots on rendered frames\n\n" + about + "\n\n" + "\n".join(lines))
    lines, about = regression_rows(args.before, args.frames, REPEATS * 2 + 1)
    print("\n".join(lines))
    parts.append("### Speed against the detector before\n\n" + about + "\n\n" + "\n".join(lines))
    command = f"python bench/bench_detect.py --real-only --frames {args.frames}" + (
        f" --background-frames {args.background_frames}" if args.background_frames != 40 else "")
    text = (f"Command: `{command}`  \nMachine: {platform.processor() or platform.machine()}, {os.cpu_count()} "
            f"cores, Python {platform.python_version()}, OpenCV {cv2.__version__}, NumPy {np.__version__}; load "
            f"average {load:.1f} when it started. Why these settings and models: "
            "docs/decisions/0012-detection-background.md.\n\n" + "\n\n".join(parts) + "\n")
    if not args.no_write:
        replace_section(REAL_SECTION.removeprefix("## "), text)


if __name__ == "__main__":
    raise SystemExit(main())
