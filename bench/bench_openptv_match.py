"""Correspondence on real data seen through water: OpenPTV's test cavity (4 cameras behind glass,
one particle frame), wandcal's matcher with the flat-window camera model beside OpenPTV's own
correspondences (issue 36, decision 0048).

    python bench/bench_openptv_match.py [--write-docs]

Reads ../shared/data/openptv_test_cavity in place (its SOURCE.md). OpenPTV's own figures need its
Python bindings (``pip install optv``; not a wandcal dependency): without them those rows say so.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one core, as the other watch benches

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from scipy.stats import chi2  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import publish  # noqa: E402

from wandcal.calib.refraction import project_through_window  # noqa: E402
from wandcal.calib.sim.cavity import FOCAL_PX, one_particle, simulate_cavity  # noqa: E402
from wandcal.calib.watch.match import MatchCounts, Tolerances, match_frames  # noqa: E402
from wandcal.calib.watch.refracted import Refracted  # noqa: E402
from wandcal.calib.watch.take import TakeBlobs, pad_frames  # noqa: E402
from wandcal.capture.formats.openptv import MM, PIXEL_CORNER, OpenPTVCameras, read_openptv_cameras, read_targets  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
ROOT = Path(os.environ.get("WANDCAL_SHARED_DATA", REPO.parent / "shared" / "data")) / "openptv_test_cavity"
CAMERAS = 4
FRAME = 10000
DOT_GATE_PX = 5.0  # a calibration dot's own detection: the target this near its projection (dots lie ~50 px apart)
# The matcher's gates were set for simulated 0.3 px blobs and a 0.1 px standing calibration; here the
# cameras' error on the calibration dots is ~1 px, so they are widened by this factor (its epipolar
# band, 4 px, is then OpenPTV's own eps0 = 0.05 mm = 4.2 px of criteria.par)
REAL_SCALE = 2.0
# a simulated target's pixel count, extent and grey sum: the real frame's typical (the correspondence's size and
# brightness criteria then pass alike for every candidate)
TARGET_N, TARGET_EXTENT, TARGET_SUMG = 13, 4, 200
AGREE_TAIL = 0.9973  # two 3D points of one particle agree inside the point's 3-sigma (99.73%) ellipsoid


def cameras() -> OpenPTVCameras:
    return read_openptv_cameras(ROOT / "parameters" / "ptv.par", [ROOT / f"cal/cam{i}.tif.ori" for i in range(1, 5)],
                                [ROOT / f"cal/cam{i}.tif.addpar" for i in range(1, 5)])


def dot_residuals(cams: OpenPTVCameras, windows=None) -> list[np.ndarray]:
    """Each camera's distances, px, from the 73 dots' projections to their nearest detections within
    :data:`DOT_GATE_PX` (the dots a camera's image holds)."""
    from scipy.spatial import cKDTree

    dots = np.loadtxt(ROOT / "cal" / "target_on_a_side.txt")[:, 1:] * MM
    out = []
    for c, cam in enumerate(cams.rig.cameras):
        window = (windows or cams.windows)[c]
        uv = project_through_window(window, cams.R[c], cams.t[c], dots) * cam.focal + cam.K[:2, 2]
        d, _ = cKDTree(read_targets(ROOT / "cal" / f"cam{c + 1}.tif_targets")[0]).query(uv)
        out.append(d[d < DOT_GATE_PX])
    return out


def frame_blobs() -> tuple[TakeBlobs, np.ndarray, np.ndarray]:
    """Frame 10000's targets as a take's blobs, each camera's first row, and the data's own tnr."""
    uv, cam, tnr = [], [], []
    for c in range(CAMERAS):
        u, n = read_targets(ROOT / "img" / f"cam{c + 1}.{FRAME}_targets")
        uv.append(u)
        cam.append(np.full(len(u), c))
        tnr.append(n)
    first = np.cumsum([0] + [len(u) for u in uv])[:-1]
    return TakeBlobs(np.full(sum(map(len, uv)), FRAME), np.concatenate(cam), np.concatenate(uv)), first, np.concatenate(tnr)


def volume_depths(cams: OpenPTVCameras) -> np.ndarray:
    """(C, 2) metres below each window between which criteria.par's volume lies (its Z range:
    Zmin_lay, Zmax_lay of both layers; the windows face +-Z)."""
    v = [float(x) for x in (ROOT / "parameters" / "criteria.par").read_text().split()]
    z = np.array([min(v[1], v[4]), max(v[2], v[5])]) * MM
    out = []
    for w in cams.windows:
        ends = w.distance - w.normal[2] * z  # depth of the volume's two Z planes (the normal is along Z here)
        out.append([ends.min(), ends.max()])
    return np.array(out)


def ours(cams: OpenPTVCameras, blobs: TakeBlobs, scale: float) -> dict:
    padded = pad_frames(cams.rig, blobs)
    focal = np.array([c.focal.mean() for c in cams.rig.cameras])
    model = Refracted(cams.R, cams.t, cams.windows, volume_depths(cams), focal)
    counts = MatchCounts()
    start = time.process_time()
    tr = match_frames(cams.rig, cams.R, cams.t, padded, model=model, counts=counts,
                      tolerances=Tolerances(*(scale * np.array(dataclasses.astuple(Tolerances())))))
    cpu = time.process_time() - start
    p, c = np.nonzero(tr.views >= 0)
    res = model.residuals(p, c, padded.xy_of(tr.views[p, c]), tr.X) * focal[c][:, None]
    return {"tracks": tr, "counts": counts, "cpu": cpu, "rms": float(np.sqrt((res ** 2).sum(1).mean())),
            "model": model, "padded": padded, "focal": focal}


def openptv(cwd: Path) -> dict | None:
    """OpenPTV's correspondences of frame 10000 with its own parameters (optv), or None without optv."""
    try:
        from optv.calibration import Calibration
        from optv.correspondences import MatchedCoords, correspondences
        from optv.orientation import point_positions
        from optv.parameters import ControlParams, VolumeParams
        from optv.tracking_framebuf import read_targets as optv_targets
    except ImportError:
        return None
    here = Path.cwd()
    os.chdir(cwd)  # OpenPTV's readers take the paths its parameter files name, relative to the project
    try:
        cpar = ControlParams(CAMERAS)
        cpar.read_control_par("parameters/ptv.par")
        vpar = VolumeParams()
        vpar.read_volume_par("parameters/criteria.par")
        cals = []
        for i in range(1, CAMERAS + 1):
            cal = Calibration()
            cal.from_file(f"cal/cam{i}.tif.ori", f"cal/cam{i}.tif.addpar")
            cals.append(cal)
        targets = [optv_targets(f"img/cam{i}.", FRAME) for i in range(1, CAMERAS + 1)]
        flat = [MatchedCoords(targets[i], cpar, cals[i]) for i in range(CAMERAS)]
        start = time.process_time()
        _, corresp, _ = correspondences(targets, flat, cals, vpar, cpar)
        cpu = time.process_time() - start
        points = []
        for cor in corresp:
            xy = np.array([flat[i].get_by_pnrs(cor[i]) for i in range(CAMERAS)]).transpose(1, 0, 2)
            points.append(point_positions(xy, cpar, cals, vpar)[0] * MM if len(xy) else np.zeros((0, 3)))
    finally:
        os.chdir(here)
    return {"views": np.concatenate([c.T for c in corresp]), "X": np.concatenate(points), "cpu": cpu,
            "sizes": [c.shape[1] for c in corresp]}


def agreement(views_a: np.ndarray, views_b: np.ndarray) -> np.ndarray:
    """(A,) for each match of a (views (A, C), each camera's target number or -1), the match of b
    holding the same target in every camera a has one in and no other target in them; -1 if none."""
    owner = {}
    for k, row in enumerate(views_b):
        for c, v in enumerate(row):
            if v >= 0:
                owner[(c, int(v))] = k
    out = np.full(len(views_a), -1)
    for k, row in enumerate(views_a):
        hits = {owner.get((c, int(v))) for c, v in enumerate(row) if v >= 0}
        if len(hits) == 1 and None not in hits:
            out[k] = hits.pop()
    return out


def table(cams, blobs, first, tnr) -> list[str]:
    ours_scaled = {s: ours(cams, blobs, s) for s in (1.0, REAL_SCALE)}
    mine = ours_scaled[REAL_SCALE]
    views = np.where(mine["tracks"].views >= 0, mine["tracks"].views - first[None], -1)
    n_targets = np.bincount(blobs.camera, minlength=CAMERAS)
    lines = ["| matcher | in 4 cameras | in 3 | in 2 | targets matched | reprojection rms | CPU |", "|---|---|---|---|---|---|---|"]
    for s, run in ours_scaled.items():
        n = (run["tracks"].views >= 0).sum(1)
        cnt = run["counts"]
        lines.append(f"| wandcal, flat-window model, gates x{s:g} ({Tolerances().epipolar_px * s:g} px epipolar) | "
                     f"{(n == 4).sum()} | {(n == 3).sum()} | not matched (a third camera must confirm) | "
                     f"{n.sum() / n_targets.sum():.1%} | {run['rms']:.2f} px | {run['cpu']:.2f} s |")
    opt = openptv(ROOT)
    sigma = float(np.sqrt(np.mean(np.concatenate(dot_residuals(cams)) ** 2)))
    if opt is None:
        lines.append("| OpenPTV (optv) | not installed here: `pip install optv` | | | | | |")
    else:
        n = (opt["views"] >= 0).sum(1)
        p, c = np.nonzero(opt["views"] >= 0)
        xy = mine["padded"].xy_of((opt["views"] + first[None])[p, c])
        res = mine["model"].residuals(p, c, xy, opt["X"]) * mine["focal"][c][:, None]
        lines.append(f"| OpenPTV 0.3.2 (optv), its criteria.par (eps0 0.05 mm) | {opt['sizes'][0]} | {opt['sizes'][1]} | "
                     f"{opt['sizes'][2]} | {n.sum() / n_targets.sum():.1%} ({n[n >= 3].sum() / n_targets.sum():.1%} in 3-4) | "
                     f"{np.sqrt((res[n[p] >= 3] ** 2).sum(1).mean()):.2f} px (3-4 cameras, its points) | {opt['cpu']:.2f} s |")
    data = _data_tnr(blobs, tnr)
    lines.append(f"| the data's own (`tnr` of img/camN.10000_targets, an earlier OpenPTV calibration) | {data[4]} | "
                 f"{data[3]} | {data[2]} | {sum(k * v for k, v in data.items()) / n_targets.sum():.1%} | | |")
    cnt = mine["counts"]
    lines += ["", f"Ambiguity (gates x{REAL_SCALE:g}): {cnt.pairs} pairs on the seed cameras' epipolar curves, {cnt.candidates} "
              f"candidates that a third camera confirmed; {cnt.dropped} candidates rejected because stronger ones took "
              f"their targets, {cnt.ambiguous_views} views left out because a second target lay within twice the "
              "nearest's distance.", "", *_agreement_lines(mine, views, opt, tnr, first, sigma)]
    return lines


def _data_tnr(blobs: TakeBlobs, tnr: np.ndarray) -> dict[int, int]:
    """How many of the data's correspondences (tnr >= 0) hold 2, 3, 4 cameras' targets."""
    seen = {}
    for cam, v in zip(blobs.camera.tolist(), tnr.tolist()):
        if v >= 0:
            seen.setdefault(v, set()).add(cam)
    sizes = np.bincount([len(s) for s in seen.values()], minlength=CAMERAS + 1)
    return {k: int(sizes[k]) for k in (2, 3, 4)}


def _agreement_lines(mine, views, opt, tnr, first, sigma) -> list[str]:
    tracks = mine["tracks"]
    limit = float(np.sqrt(chi2.ppf(AGREE_TAIL, 3)))
    lines = [f"Agreement: a wandcal track and another matcher's match agree when each camera's target is the same "
             f"(where both have one); their 3D points agree when their difference is within {limit:.2f} sigma of the "
             f"wandcal point's covariance from its views at the calibration dots' {sigma:.2f} px rms (chi-square, 3 "
             f"degrees of freedom, {AGREE_TAIL:.2%}): the cameras face each other across the cavity, so depth is the "
             "weak direction."]
    if opt is not None:
        match = agreement(views, opt["views"])
        same = match >= 0
        d = tracks.X[same] - opt["X"][match[same]]
        m = _mahalanobis(mine, np.flatnonzero(same), d, sigma)
        lines.append(f"- OpenPTV (optv): {same.sum()} of {len(tracks)} wandcal tracks are one of its matches "
                     f"(in 4 cameras: {(same & ((views >= 0).sum(1) == 4)).sum()}); of these, {(m < limit).sum()} "
                     f"3D points agree (median {np.median(np.linalg.norm(d, axis=1)) * 1e3:.3f} mm apart, "
                     f"{np.median(m):.2f} sigma).")
        rev = agreement(np.where(opt["views"] >= 0, opt["views"], -1), views)
        n_opt = (opt["views"] >= 0).sum(1)
        lines.append(f"- Of OpenPTV's {(n_opt >= 3).sum()} matches in 3-4 cameras, {(rev[n_opt >= 3] >= 0).sum()} are "
                     f"one of wandcal's tracks; of its {(n_opt == 2).sum()} pairs, {(rev[n_opt == 2] >= 0).sum()} lie "
                     "inside one.")
    data_views = np.full((int(tnr.max()) + 1, CAMERAS), -1)
    cam = np.repeat(np.arange(CAMERAS), np.diff(np.append(first, len(tnr))))
    has = tnr >= 0
    data_views[tnr[has], cam[has]] = (np.arange(len(tnr)) - first[cam])[has]
    match = agreement(views, data_views)
    lines.append(f"- The data's own `tnr`: {(match >= 0).sum()} of {len(tracks)} wandcal tracks are one of its "
                 "correspondences (made with the repository's first calibration, whose camera 1 stood 61 mm from "
                 "today's, and a 0.2 mm epipolar band).")
    return lines


def _mahalanobis(mine: dict, rows: np.ndarray, d: np.ndarray, sigma_px: float) -> np.ndarray:
    """(N,) sqrt(d^T Cov^-1 d) for the differences d (N, 3) from wandcal's tracks ``rows``: Cov the
    point's covariance sigma^2 (J^T J)^-1 from its views' projection Jacobians, in pixels."""
    views = mine["tracks"].views[rows]
    p, c = np.nonzero(views >= 0)
    J = mine["model"].jacobians(p, c, mine["tracks"].X[rows]) * (mine["focal"][c] / sigma_px)[:, None, None]
    info = np.zeros((len(rows), 3, 3))
    np.add.at(info, p, np.einsum("mki,mkj->mij", J, J))
    return np.sqrt(np.einsum("ni,nij,nj->n", d, info, d))


def simulated_lines(particles: int, sigma: float) -> list[str]:
    """Both matchers against the truth on simulated cavities (calib/sim/cavity.py) at the real frame's
    density: 0.3 px (the simulated takes' noise) and the calibration dots' rms."""
    lines = [f"Simulated cavity (calib/sim/cavity.py: the same shape, {particles} particles a frame as the real frame's "
             "largest camera holds, every particle seen by all four cameras, seed 1; OpenPTV given the same cameras "
             "and targets as its own project files, criteria.par as the real one's):", "",
             "| noise | matcher | in 4 / 3 / 2 cameras | matches that are one particle's | particles found in 3-4 | "
             "3D error, median |", "|---|---|---|---|---|---|"]
    for noise, scale in ((0.3, 1.0), (sigma, 1.0), (sigma, REAL_SCALE)):
        frame = simulate_cavity(particles, noise_px=noise, seed=1)
        model = Refracted(frame.R, frame.t, frame.windows, frame.depth, np.full(len(frame.R), FOCAL_PX))
        tol = Tolerances(*(scale * np.array(dataclasses.astuple(Tolerances()))))
        tr = match_frames(frame.rig, frame.R, frame.t, pad_frames(frame.rig, frame.blobs), model=model, tolerances=tol)
        n = (tr.views >= 0).sum(1)
        lines.append(_truth_row(f"{noise:.2f} px", f"wandcal, gates x{scale:g}", frame, tr.views, tr.X, n, particles))
        if scale != 1.0:
            continue
        with tempfile.TemporaryDirectory() as tmp:
            rows = write_openptv_project(frame, Path(tmp))
            opt = openptv(Path(tmp))
        if opt is None:
            continue
        views = np.where(opt["views"] >= 0, rows[np.arange(len(frame.R))[None], np.maximum(opt["views"], 0)], -1)
        lines.append(_truth_row(f"{noise:.2f} px", "OpenPTV (optv)", frame, views, opt["X"], (views >= 0).sum(1), particles))
    return lines


def _truth_row(noise: str, label: str, frame, views: np.ndarray, X: np.ndarray, n: np.ndarray, particles: int) -> str:
    who = one_particle(frame, views)
    big = n >= 3
    err = np.linalg.norm(X[who >= 0] - frame.X[who[who >= 0]], axis=1) * 1e3
    pairs = f"{(who[n == 2] >= 0).mean():.1%} of pairs" if (n == 2).any() else "no pairs"
    return (f"| {noise} | {label} | {(n == 4).sum()} / {(n == 3).sum()} / {(n == 2).sum()} | "
            f"{(who[big] >= 0).mean():.2%} of those in 3-4; {pairs} | "
            f"{len(np.unique(who[big & (who >= 0)])) / particles:.1%} | {np.median(err):.3f} mm |")


def write_openptv_project(frame, folder: Path) -> np.ndarray:
    """A simulated cavity frame as OpenPTV's project files in ``folder`` (ptv.par, criteria.par as
    the real one's, camN.tif.ori / .addpar, img/camN.10000_targets sorted by y as OpenPTV sorts
    them). Returns (C, K) each camera's target number -> the frame's blob row (-1 past its count)."""
    (folder / "parameters").mkdir()
    (folder / "cal").mkdir()
    (folder / "img").mkdir()
    cam0, w0 = frame.rig.cameras[0], frame.windows[0]
    pix = 0.012  # the cavity's pixel pitch, mm
    names = "\n".join(f"img/cam{i}.\ncal/cam{i}.tif" for i in range(1, 5))
    (folder / "parameters" / "ptv.par").write_text(
        f"{len(frame.R)}\n{names}\n1\n0\n1\n{cam0.width}\n{cam0.height}\n{pix}\n{pix}\n0\n{w0.n_air}\n"
        f"{w0.n_glass}\n{w0.n_water}\n{w0.thickness / MM}\n")
    (folder / "parameters" / "criteria.par").write_text((ROOT / "parameters" / "criteria.par").read_text())
    table = np.full((len(frame.R), np.bincount(frame.blobs.camera).max()), -1)
    for c, cam in enumerate(frame.rig.cameras):
        dm = frame.R[c].T @ np.diag([1.0, -1.0, -1.0])  # capture/formats/openptv.py's conversion, inverted
        angles = (np.arctan2(-dm[1, 2], dm[2, 2]), np.arcsin(dm[0, 2]), np.arctan2(-dm[0, 1], dm[0, 0]))
        centre = -frame.R[c].T @ frame.t[c] / MM
        glass = frame.windows[c].normal * frame.windows[c].distance / MM
        rows = "\n".join(" ".join(f"{v:.12f}" for v in r) for r in dm)
        (folder / "cal" / f"cam{c + 1}.tif.ori").write_text(
            f"{' '.join(f'{v:.12f}' for v in centre)}\n{' '.join(f'{v:.15f}' for v in angles)}\n\n{rows}\n\n"
            f"{(cam.K[0, 2] + PIXEL_CORNER - cam.width / 2) * pix:.8f} {(cam.height / 2 - cam.K[1, 2] - PIXEL_CORNER) * pix:.8f}\n"
            f"{cam.K[0, 0] * pix:.8f}\n\n{' '.join(f'{v:.12f}' for v in glass)}\n")
        (folder / "cal" / f"cam{c + 1}.tif.addpar").write_text("0 0 0 0 0 1 0\n")
        mine = np.flatnonzero(frame.blobs.camera == c)
        mine = mine[np.argsort(frame.blobs.uv[mine, 1], kind="stable")]
        table[c, :len(mine)] = mine
        uv = frame.blobs.uv[mine] + PIXEL_CORNER
        body = "\n".join(f"{k:4d} {x:9.4f} {y:9.4f} {TARGET_N} {TARGET_EXTENT} {TARGET_EXTENT} {TARGET_SUMG} -1"
                         for k, (x, y) in enumerate(uv))
        (folder / "img" / f"cam{c + 1}.{FRAME}_targets").write_text(f"{len(mine)}\n{body}\n")
    return table


def model_lines(cams: OpenPTVCameras) -> list[str]:
    lines = ["| camera model on the 73 calibration dots | dots found (of 73) | median | rms | largest |", "|---|---|---|---|---|"]
    variants = [("flat window, ptv.par as OpenPTV reads it (glass n2 = 1.33, water n3 = 1.46)", None),
                ("flat window, indices swapped (glass 1.46, water 1.33)",
                 [dataclasses.replace(w, n_glass=w.n_water, n_water=w.n_glass) for w in cams.windows]),
                ("pinhole, no refraction", [dataclasses.replace(w, n_glass=1.0, n_water=1.0) for w in cams.windows])]
    for label, windows in variants:
        res = dot_residuals(cams, windows)
        all_d = np.concatenate(res)
        lines.append(f"| {label} | {', '.join(str(len(r)) for r in res)} | {np.median(all_d):.2f} px | "
                     f"{np.sqrt(np.mean(all_d ** 2)):.2f} px | {all_d.max():.2f} px |" if len(all_d) else
                     f"| {label} | none within {DOT_GATE_PX:g} px | | | |")
    diff = _against_optv(cams)
    lines += ["", f"Dots found: the nearest target within {DOT_GATE_PX:g} px of a dot's projection (cameras 1-4). "
              + (f"OpenPTV's own projection of the 73 dots (optv `image_coordinates`, same files) differs from wandcal's "
                 f"by at most {diff:.4f} px (its iteration stops at 1 um)." if diff is not None else
                 "optv is not installed: OpenPTV's own projection was not compared.")
              + " OpenPTV publishes no calibration rms for this data set."]
    return lines


def _against_optv(cams: OpenPTVCameras) -> float | None:
    try:
        from optv.calibration import Calibration
        from optv.imgcoord import image_coordinates
        from optv.parameters import ControlParams
        from optv.transforms import convert_arr_metric_to_pixel
    except ImportError:
        return None
    cpar = ControlParams(CAMERAS)
    cpar.read_control_par(str(ROOT / "parameters" / "ptv.par"))
    dots = np.loadtxt(ROOT / "cal" / "target_on_a_side.txt")[:, 1:]
    worst = 0.0
    for c, cam in enumerate(cams.rig.cameras):
        cal = Calibration()
        cal.from_file(str(ROOT / "cal" / f"cam{c + 1}.tif.ori"), str(ROOT / "cal" / f"cam{c + 1}.tif.addpar"))
        theirs = convert_arr_metric_to_pixel(image_coordinates(dots, cal, cpar.get_multimedia_params()), cpar)
        mine = project_through_window(cams.windows[c], cams.R[c], cams.t[c], dots * MM) * cam.focal + cam.K[:2, 2]
        worst = max(worst, float(np.abs(mine + PIXEL_CORNER - theirs).max()))
    return worst


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--write-docs", action="store_true", help="write the section of docs/benchmarks.md")
    args = ap.parse_args()
    if not ROOT.is_dir():
        print(f"{ROOT} not found: nothing to measure")
        return 0
    cams = cameras()
    blobs, first, tnr = frame_blobs()
    lines = ["OpenPTV's test cavity (../shared/data/openptv_test_cavity, SOURCE.md): 4 cameras behind 6 mm of glass, "
             f"frame {FRAME}'s targets as OpenPTV detected them ({', '.join(str(n) for n in np.bincount(blobs.camera))}), "
             "OpenPTV's orientations and ptv.par read by capture/formats/openptv.py; decision 0048.", "",
             *model_lines(cams), "", *table(cams, blobs, first, tnr), "",
             *simulated_lines(int(np.bincount(blobs.camera).max()),
                              float(np.sqrt(np.mean(np.concatenate(dot_residuals(cams)) ** 2))))]
    return publish("Watch on real data: OpenPTV's cavity (issue 36)", "\n".join(lines), args.write_docs)


if __name__ == "__main__":
    raise SystemExit(main())
