"""The "Detection on real images" section of bench/bench_detect.py.

Part 1, OpenPTV's test_cavity frame 10000 (4 real cameras, ../shared/data; SOURCE.md there):
recall of OpenPTV's own detections and the centroid difference after the -0.5 px convention,
for the detector's defaults and for settings step by step closer to OpenPTV's.

Part 2, the background models on rendered 1280x1024 frames: speed on a flat dark frame, and
centroid error and recall on a frame with a glowing background.

Part 3, the present detector's speed against the one before this change, side by side.
"""

from __future__ import annotations

import contextlib
import os
import statistics
import subprocess
import sys
import time
import types
from pathlib import Path

import cv2
import numpy as np

from wandcal.calib.detect import CameraDetector, DetectConfig, detect_blobs
from wandcal.calib.detect.background import median_background
from wandcal.calib.sim.render import render_blobs

REPO = Path(__file__).resolve().parents[1]

OPENPTV = "openptv_test_cavity"
OFFSET_PX = 0.5  # docs/conventions.md: OpenPTV's centroids count from the pixel corner
MATCH_PX = 0.5  # SOURCE.md: "match centroids within about 0.5 px"
ISOLATED_PX = 10.0  # no other reference target this close
STRAY_PX = 2.0  # a blob this far from every reference target is light OpenPTV did not report
HIGHPASS_PX = 12  # OpenPTV's high-pass half-width
SHAPE = (1024, 1280)
SPOTS = 6
GLOW = 80.0  # grey levels of the glowing background's bright patch (8-bit)
REPEATS = 5


def _openptv_steps(thresholds, n_min, n_max):
    """(label, config per camera) rows: the defaults, one change to them at a time, then step by step to
    OpenPTV's settings."""
    like = {"min_area_px": n_min, "max_area_px": n_max, "min_roundness": 0.0, "background": "highpass",
            "highpass_px": HIGHPASS_PX}
    return [
        ("before: no background model (background none), defaults", lambda t: DetectConfig(background="none")),
        ("defaults (background auto: high-pass, noise threshold, roundness 0.1)", lambda t: DetectConfig()),
        ("defaults, min roundness 0.5 (the marker limit) on every frame", lambda t: DetectConfig(min_roundness=0.5)),
        ("defaults, min roundness 0", lambda t: DetectConfig(min_roundness=0.0)),
        ("defaults + seed ratio 2", lambda t: DetectConfig(seed_ratio=2.0)),
        ("defaults + signal weights", lambda t: DetectConfig(weights="signal")),
        ("high-pass 12, OpenPTV's thresholds and areas", lambda t: DetectConfig(threshold=t, **like)),
        ("  + seed ratio 2 (OpenPTV's peak rule)", lambda t: DetectConfig(threshold=t, seed_ratio=2.0, **like)),
        ("  + signal weights (OpenPTV's settings)", lambda t: DetectConfig(threshold=t, seed_ratio=2.0,
                                                                            weights="signal", **like)),
    ]


def openptv_rows(root: Path) -> tuple[list[str], str]:
    """Table lines for part 1 and a sentence on how they were made."""
    data = root / OPENPTV
    pars = (data / "parameters" / "targ_rec.par").read_text().split()
    thresholds, n_min, n_max = [int(v) for v in pars[:4]], int(pars[5]), int(pars[6])
    cams = []
    for cam in range(1, 5):
        image = cv2.imread(str(data / "img" / f"cam{cam}.10000"), cv2.IMREAD_UNCHANGED)
        ref = np.loadtxt(data / "img" / f"cam{cam}.10000_targets", skiprows=1, ndmin=2)
        ref_uv = ref[:, 1:3] - OFFSET_PX
        neighbour = np.sort(np.linalg.norm(ref_uv[:, None] - ref_uv[None], axis=2), axis=1)[:, 1]
        cams.append((image, ref_uv, neighbour >= ISOLATED_PX))
    lines = ["| settings | isolated recall | recall | median difference (px) | 90th pct (px) | blobs per camera "
             "| of them near no target | threshold per camera | background | ms / frame |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for label, make in _openptv_steps(thresholds, n_min, n_max):
        iso = hit = n_iso = n_all = 0
        diffs, counts, stray, levels, models, seconds = [], [], [], [], set(), []
        for (image, ref_uv, isolated), t in zip(cams, thresholds):
            detector = CameraDetector(make(t))
            times = []
            for _ in range(REPEATS):
                t0 = time.perf_counter()
                blobs = detector.detect(image)
                times.append(time.perf_counter() - t0)
            seconds.append(statistics.median(times))
            d = np.linalg.norm(ref_uv[:, None] - blobs.uv[None], axis=2).min(axis=1) if len(blobs) else \
                np.full(len(ref_uv), np.inf)
            ok = d < MATCH_PX
            iso, n_iso, hit, n_all = iso + ok[isolated].sum(), n_iso + isolated.sum(), hit + ok.sum(), n_all + len(ok)
            diffs.append(d[ok])
            counts.append(len(blobs))
            if len(blobs):  # blobs with no reference target within STRAY_PX: light OpenPTV did not report
                near = np.linalg.norm(blobs.uv[:, None] - ref_uv[None], axis=2).min(axis=1)
                stray.append(int(np.sum(near >= STRAY_PX)))
            else:
                stray.append(0)
            levels.append(f"{blobs.threshold:.0f}")
            models.add(blobs.background)
        d = np.concatenate(diffs)
        lines.append(f"| {label} | {iso / n_iso:.3f} ({iso}/{n_iso}) | {hit / n_all:.3f} | {np.median(d):.4f} | "
                     f"{np.percentile(d, 90):.3f} | {', '.join(map(str, counts))} | {', '.join(map(str, stray))} | "
                     f"{', '.join(levels)} | "
                     f"{', '.join(sorted(models))} | {1e3 * statistics.mean(seconds):.1f} |")
    about = (f"OpenPTV's test_cavity frame 10000, 4 cameras, 1280x1024 8-bit (`../shared/data/{OPENPTV}`, read in "
             f"place). Reference: OpenPTV's `img/camN.10000_targets`, {sum(len(c[1]) for c in cams)} targets, "
             f"shifted by -{OFFSET_PX} px on both axes (docs/conventions.md). A reference target is found when a "
             f"detection lies within {MATCH_PX} px; isolated targets have no other target within {ISOLATED_PX:.0f} px. "
             "The median and 90th percentile are over the found targets; 'near no target' counts the blobs "
             f"{STRAY_PX:.0f} px or more from every reference target (false blobs, as far as OpenPTV is the judge). "
             f"OpenPTV's thresholds and areas come from its `targ_rec.par` ({'/'.join(map(str, thresholds))}, {n_min}-{n_max} px); its high-pass half-width "
             f"is {HIGHPASS_PX}. One core, median of {REPEATS} runs per frame.")
    return lines, about


def _light(rng, bits: int) -> np.ndarray:
    """A glowing background: a wide bright patch plus a ramp, grey levels."""
    yy, xx = np.mgrid[: SHAPE[0], : SHAPE[1]]
    c = rng.uniform([0, 0], [SHAPE[1], SHAPE[0]])
    scale = GLOW if bits == 8 else GLOW * 257
    return scale * np.exp(-((xx - c[0]) ** 2 + (yy - c[1]) ** 2) / (2 * 300.0**2)) + 0.3 * scale * xx / SHAPE[1]


def _render(rng, bits: int, light: np.ndarray | None, spots: int = SPOTS) -> tuple[np.ndarray, np.ndarray]:
    uv = rng.uniform([30, 30], [SHAPE[1] - 30, SHAPE[0] - 30], (spots, 2))
    peak, background, noise = ((120.0, 240.0), 12.0, 2.0) if bits == 8 else ((20000.0, 60000.0), 2000.0, 300.0)
    image = render_blobs(SHAPE, uv, rng.uniform(1.0, 2.0, spots), rng.uniform(*peak, spots), background, noise,
                         bits, rng)
    if light is not None:
        image = np.clip(np.rint(image + light), 0, 2**bits - 1).astype(image.dtype)
    return image, uv


TOUCH_SEPARATION_PX = (2.0, 8.0)  # centre distances at which two spots of sigma 1-2 px touch above the threshold


def touching_rows(pairs: int) -> tuple[list[str], str]:
    """Table lines: how often two touching spots come out as one blob that is kept (a false blob: its
    centroid lies between the markers), with the default and the marker roundness limit."""
    configs = {"defaults": DetectConfig(), "roundness 0.5 on every frame": DetectConfig(min_roundness=0.5),
               "roundness 0": DetectConfig(min_roundness=0.0)}
    lines = ["| bits | background | background model used | " + " | ".join(f"merged blobs kept: {name}" for name in configs)
             + " | both spots found: defaults |", "|---|---|---|" + "---|" * (len(configs) + 1)]
    for bits in (8, 16):
        for kind in ("flat", "glowing"):
            rng = np.random.default_rng(50 + bits)
            light = _light(rng, bits) if kind == "glowing" else None
            kept, both, models = dict.fromkeys(configs, 0), 0, set()
            for _ in range(pairs):
                centre = rng.uniform([100, 100], [SHAPE[1] - 100, SHAPE[0] - 100])
                gap, angle = rng.uniform(*TOUCH_SEPARATION_PX), rng.uniform(0, np.pi)
                half = 0.5 * gap * np.array([np.cos(angle), np.sin(angle)])
                uv = np.array([centre + half, centre - half])
                peak, background, noise = ((120.0, 240.0), 12.0, 2.0) if bits == 8 else ((20000.0, 60000.0), 2000.0, 300.0)
                image = render_blobs(SHAPE, uv, rng.uniform(1.0, 2.0, 2), rng.uniform(*peak, 2), background, noise, bits, rng)
                if light is not None:
                    image = np.clip(np.rint(image + light), 0, 2**bits - 1).astype(image.dtype)
                for name, config in configs.items():
                    blobs = detect_blobs(image, config)
                    near = blobs.uv[np.linalg.norm(blobs.uv - centre, axis=1) < gap + 6.0]
                    true = [np.linalg.norm(uv - p, axis=1).min() < MATCH_PX for p in near]
                    kept[name] += len(true) - sum(true)
                    if name == "defaults":
                        both += int(len(near) == 2 and all(true))
                        models.add(blobs.background)
            lines.append(f"| {bits} | {kind} | {', '.join(sorted(models))} | "
                         + " | ".join(str(kept[name]) for name in configs) + f" | {both} |")
    about = (f"{pairs} pairs of spots per row (sigma 1-2 px, peaks as above), their centres "
             f"{TOUCH_SEPARATION_PX[0]:.0f}-{TOUCH_SEPARATION_PX[1]:.0f} px apart at a random angle, on the flat dark "
             "frame or under the glowing background above. A kept blob more than "
             f"{MATCH_PX} px from both spots is a merged one: for a wand it is a false marker between the two. "
             "Roundness limits below 0.3 reject almost none of them, 0.5 about half.")
    return lines, about


@contextlib.contextmanager
def one_core():
    """Pin this process to one CPU and OpenCV to one thread; restore both afterwards."""
    cores, threads = os.sched_getaffinity(0), cv2.getNumThreads()
    cv2.setNumThreads(1)
    os.sched_setaffinity(0, {min(cores)})
    try:
        yield
    finally:
        os.sched_setaffinity(0, cores)
        cv2.setNumThreads(threads)


def before_module(rev: str):
    """The detector as it was at git revision ``rev`` (``rev:calib/detect.py`` then) (self-contained: it imports wandcal.calib.errors
    only), loaded as a module beside the present one for a side-by-side timing."""
    source = subprocess.run(["git", "show", f"{rev}:calib/detect.py"], cwd=REPO, capture_output=True, text=True,
                            check=True).stdout
    module = types.ModuleType(f"detect_at_{rev}")
    sys.modules[module.__name__] = module  # dataclasses look their module up there
    exec(compile(source, f"{rev}:calib/detect.py", "exec"), module.__dict__)
    return module


def regression_rows(rev: str, frames: int, repeats: int) -> tuple[list[str], str]:
    """Time per frame of the present detector over the one at ``rev``, side by side in one run."""
    old = before_module(rev)
    lines = ["| bits | settings | frames/s before | frames/s now | time now / before: median (min-max) |",
             "|---|---|---|---|---|"]
    rng = np.random.default_rng(9)
    with one_core():
        for bits in (8, 16):
            flat = [_render(rng, bits, None)[0] for _ in range(frames)]
            fixed = 40 if bits == 8 else 7000  # bench_detect.py's FIXED_THRESHOLD
            before_fixed, now_fixed = old.DetectConfig(threshold=fixed), DetectConfig(threshold=fixed)
            pairs = [("automatic threshold (default)", old.detect_blobs, detect_blobs),
                     ("fixed threshold", lambda f, c=before_fixed: old.detect_blobs(f, c),
                      lambda f, c=now_fixed: detect_blobs(f, c))]
            for name, before, now in pairs:
                times = {"before": [], "now": []}
                for _ in range(repeats):  # round robin: a busy spell slows both alike
                    for key, run in (("before", before), ("now", now)):
                        t0 = time.perf_counter()
                        for f in flat:
                            run(f)
                        times[key].append(time.perf_counter() - t0)
                ratio = [n / b for n, b in zip(times["now"], times["before"])]
                lines.append(f"| {bits} | {name} | {frames / statistics.median(times['before']):,.0f} | "
                             f"{frames / statistics.median(times['now']):,.0f} | {statistics.median(ratio):.3f} "
                             f"({min(ratio):.2f}-{max(ratio):.2f}) |")
    about = (f"The detector before this section's change (`git show {rev}:calib/detect.py`) and now, on the same "
             f"{frames} flat rendered frames per bit depth, one core, {repeats} round-robin repeats; frames/s are "
             "medians. The default is now `background=\"auto\"`, which on these dark frames adds the flatness test "
             "to the threshold's sample.")
    return lines, about


def background_rows(frames: int) -> tuple[list[str], str]:
    """Table lines for part 2: every background model on flat and glowing rendered frames."""
    with one_core():
        return _background_rows(frames)


def _background_rows(frames: int) -> tuple[list[str], str]:
    lines = ["| bits | background | flat frames/s | time / frame copy | glowing: centroid RMS (px) | glowing: recall "
             "| glowing: false blobs |", "|---|---|---|---|---|---|---|"]
    rng = np.random.default_rng(5)
    for bits in (8, 16):
        flat = [_render(rng, bits, None)[0] for _ in range(frames)]
        light = _light(rng, bits)
        glowing = [_render(rng, bits, light) for _ in range(frames)]
        empty = {"flat": median_background([_render(rng, bits, None, 0)[0] for _ in range(9)]),
                 "glowing": median_background([_render(rng, bits, light, 0)[0] for _ in range(9)])}
        models = {
            "none": lambda kind: CameraDetector(DetectConfig(background="none")),
            "auto (default)": lambda kind: CameraDetector(),
            "highpass": lambda kind: CameraDetector(DetectConfig(background="highpass")),
            "highpass, signal weights (OpenPTV's)": lambda kind: CameraDetector(
                DetectConfig(background="highpass", weights="signal")),
            "running": lambda kind: CameraDetector(DetectConfig(background="running")),
            "empty": lambda kind, empty=empty: CameraDetector(DetectConfig(background="empty"),
                                                              background=empty[kind]),
        }
        best = dict.fromkeys(["frame copy", *models], np.inf)
        for _ in range(REPEATS):  # round robin: a busy spell of the shared machine slows one repeat of each
            for name in best:
                detector = None if name == "frame copy" else models[name]("flat")
                t0 = time.perf_counter()
                for f in flat:
                    f.copy() if detector is None else detector.detect(f)
                best[name] = min(best[name], time.perf_counter() - t0)
        for name, make in models.items():
            detector, errors, found, false = make("glowing"), [], 0, 0
            for image, uv in glowing:
                got = detector.detect(image).uv
                d = np.linalg.norm(uv[:, None] - got[None], axis=2) if len(got) else np.full((SPOTS, 1), np.inf)
                near = d.min(axis=1)
                errors.append(near[near < 2.0])
                found += int(np.sum(near < 2.0))
                false += int(np.sum(d.min(axis=0) >= 2.0)) if len(got) else 0
            e = np.concatenate(errors)
            rms = f"{np.sqrt(np.mean(e**2)):.4f}" if len(e) else "-"
            lines.append(f"| {bits} | {name} | {frames / best[name]:,.0f} | {best[name] / best['frame copy']:.1f} | {rms} | "
                         f"{found / (SPOTS * frames):.3f} | {false} |")
    about = (f"{frames} rendered {SHAPE[1]}x{SHAPE[0]} frames per bit depth with {SPOTS} spots as above. Speed: on the "
             f"flat dark frames, best of {REPEATS} round-robin runs on one core (`time / frame copy` compares across runs). "
             f"Accuracy: on {frames} other frames under one glowing background (a patch of {GLOW:.0f} grey levels at "
             "8 bits, 300 px wide, plus a ramp; 257 times that at 16 bits) with the spots moving, in order, so the "
             "running average learns the light; 'empty' subtracts the median of 9 frames of the same light "
             "without spots. Spots within 2 px count as found.")
    return lines, about
