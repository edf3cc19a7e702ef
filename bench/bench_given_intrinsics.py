"""How far a published session's given intrinsics lie from what its own tracks give, in units of
the honest sigma's defaults (calib/judge/lens_sigmas.py, docs/decisions/0070): the measurement
behind the principal point's default sigma.

The session is the eWand paper's test data (github.com/cogsys-tuebingen/ewand,
``calibration_framework/test``: four cameras' ``frame_N.yaml`` OpenCV intrinsics and ``frame_N.csv``
tracks of the wand's three markers, ``timestamp;x0;y0;x1;y1;x2;y2``, -1 where unseen, 10 Hz). It is
not in ../shared/data: give the folder of a checkout. Each marker is a labelled point track (no
scale: the wand's marker spacing is not in the data), calibrated with ``ba --refine-intrinsics``.

Usage: python bench/bench_given_intrinsics.py FOLDER [--refine focal,principal,k1]
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from wandcal.calib.judge.intrinsic_limits import DEFAULT_FOCAL_REL_STD
from wandcal.calib.judge.lens_sigmas import lens_sigmas
from wandcal.calib.rig import Camera, PointObservations, Rig, WandObservations
from wandcal.calib.run.calibrate import calibrate
from wandcal.calib.run.options import CalibrationOptions

FRAME_NS = 99_928_600  # the session's frame period (its timestamps, ns)


def load(folder: Path) -> tuple[Rig, PointObservations]:
    """The session's cameras (each yaml's camera_matrix and distortion_coefficients) and its
    markers as labelled point tracks (m0, m1, m2 a frame)."""
    cams, rows = [], []
    for i in range(4):
        text = (folder / f"frame_{i}.yaml").read_text()
        nums = [list(map(float, m.split(","))) for m in re.findall(r"data: \[([^\]]*)\]", text)]
        width, height = (int(re.search(rf"image_{k}: (\d+)", text).group(1)) for k in ("width", "height"))  # type: ignore[union-attr]
        cams.append(Camera(f"cam{i}", width, height, np.array(nums[0]).reshape(3, 3), np.array(nums[1])))
        a = np.loadtxt(folder / f"frame_{i}.csv", delimiter=";")
        frame = np.round((a[:, 0] - a[0, 0]) / FRAME_NS).astype(int)
        for m in range(3):
            uv = a[:, 1 + 2 * m: 3 + 2 * m]
            ok = uv[:, 0] >= 0
            rows += [(f, i, u, v, f"m{m}") for f, (u, v) in zip(frame[ok], uv[ok])]
    f, c, u, v, p = zip(*rows)
    return Rig(tuple(cams), None), PointObservations(np.array(f), np.array(c), np.column_stack([u, v]), point=np.array(p))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("--refine", default="focal,principal,k1")
    args = ap.parse_args()
    rig, points = load(args.folder)
    empty = WandObservations(np.zeros(0), np.zeros(0), np.zeros((0, 2)))
    doc = calibrate(rig, empty, None, points=points,
                    options=CalibrationOptions(refine_intrinsics=tuple(args.refine.split(",")))).to_json()
    print("| camera | point RMS px | focal: refined - given (std) | in 2% sigmas | principal point: refined - given, px (std) "
          "| in default sigmas | k1: refined - given (std) | in default sigmas |")
    print("|---|---|---|---|---|---|---|---|")
    for cam, entry in zip(rig.cameras, doc["cameras"]):
        intr, sig = entry.get("intrinsics") or {}, lens_sigmas(cam)
        f0 = cam.K[0, 0]
        fr = float(np.mean(intr["focal_px"])) if "focal_px" in intr else f0
        pp = np.array(intr.get("principal_px", cam.K[:2, 2])) - cam.K[:2, 2]
        dk = intr.get("k1", cam.dist[0]) - cam.dist[0]
        print(f"| {cam.id} | {entry.get('point_rms_px'):.3f} | {100 * (fr / f0 - 1):+.2f}% "
              f"({100 * float(np.mean(intr.get('focal_std_px') or 0)) / f0:.2f}%) | {(fr / f0 - 1) / DEFAULT_FOCAL_REL_STD:+.2f} | "
              f"{pp[0]:+.1f}, {pp[1]:+.1f} ({', '.join(f'{x:.1f}' for x in np.ravel(intr.get('principal_std_px') or [0, 0]))}) | "
              f"{pp[0] / sig['cx']:+.2f}, {pp[1] / sig['cy']:+.2f} | {dk:+.4f} ({intr.get('k1_std') or 0:.4f}) | {dk / sig['k1']:+.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
