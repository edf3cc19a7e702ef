"""Argus sessions written by the test in Argus's documented layout (y-up pixels, DLTdv column
order, a profile row per camera) from a simulated rig, imported and compared with the truth."""

import numpy as np
import pytest

from wandcal.calib.geometry import distort_points, project_normalized, project_pixels
from wandcal.calib.rig import Camera
from wandcal.calib.sim.simulate import simulate_capture
from wandcal.capture.folder import CaptureFormatError, read_capture
from wandcal.capture.importers.argus import read_argus
from wandcal.service.cli import main

N_CAMS = 3
FRAMES = 40
WAND_M = 0.5
TANGENTIAL = (0.0012, -0.0007)  # y-down p1, p2: the y flip must negate p1 and keep p2
HIDDEN = 0.2  # chance that Argus's user did not digitise a marker in a camera
DECIMALS = 6  # what the written CSV keeps: the comparison tolerance
ORIGIN_AND_AXES = np.array([[0.0, 0.0, 0.0], [0.4, 0.0, 0.0], [0.0, 0.3, 0.0], [0.0, 0.0, 0.5]])


@pytest.fixture(scope="module")
def scene():
    sim = simulate_capture(N_CAMS, FRAMES, 0.0, static=False, seed=7, wand_length=WAND_M)
    cams = [Camera(c.id, c.width, c.height, c.K, np.r_[c.dist[:2], TANGENTIAL, c.dist[4]]) for c in sim.rig.cameras]
    return sim, cams


def _y_up_pixels(cam: Camera, R, t, X):
    """What Argus stores: the same lens modelled in the y-up pixel frame (p1 negated, cy flipped),
    computed independently of the importer's conversion."""
    xy = project_normalized(R, t, X)
    xy_up = xy * [1, -1]
    K_up = cam.K.copy()
    K_up[1, 2] = cam.height - cam.K[1, 2]
    d = cam.dist
    up = Camera(cam.id, cam.width, cam.height, K_up, [d[0], d[1], -d[2], d[3], d[4]])
    return distort_points(up, xy_up)


def _profile_rows(cams):
    rows = []
    for i, c in enumerate(cams):
        k1, k2, p1, p2, k3 = c.dist
        rows.append(f"{i + 1} {c.K[0, 0]:.6f} {c.width} {c.height} {c.K[0, 2]:.6f} {c.height - c.K[1, 2]:.6f} 1 "
                    f"{k1:.8f} {k2:.8f} {-p1:.8f} {p2:.8f} {k3:.8f}")
    return "\n".join(rows) + "\n"


def _xypts(tracks, seen, header_names=True):
    """tracks (R, T, N, 2) y-up pixels, seen (R, T, N) -> Argus CSV text."""
    R, T, N, _ = tracks.shape
    header = ",".join(f"pt{t + 1}_cam_{c + 1}_{a}" for t in range(T) for c in range(N) for a in "xy")
    lines = [header] if header_names else []
    for r in range(R):
        cells = []
        for t in range(T):
            for c in range(N):
                cells += [f"{v:.{DECIMALS}f}" for v in tracks[r, t, c]] if seen[r, t, c] else ["NaN", "NaN"]
        lines.append(",".join(cells))
    return "\n".join(lines) + "\n"


@pytest.fixture
def session(scene, tmp_path):
    sim, cams = scene
    rng = np.random.default_rng(1)
    R, t = sim.truth.R, sim.truth.t
    ends = sim.truth.wand  # (F, 2, 3)
    wand_up = np.stack([[_y_up_pixels(c, R[i], t[i], ends[:, e]) for i, c in enumerate(cams)] for e in range(2)])
    wand_up = wand_up.transpose(2, 0, 1, 3)  # frame, end, camera, uv
    wand_seen = rng.random((FRAMES, 2, N_CAMS)) > HIDDEN
    unpaired_X = ends[:, 0] + [0.05, 0.0, 0.1]  # a single marker moving beside the wand
    unpaired_up = np.stack([_y_up_pixels(c, R[i], t[i], unpaired_X) for i, c in enumerate(cams)], 1)[:, None]
    unpaired_seen = rng.random((FRAMES, 1, N_CAMS)) > HIDDEN
    ref_up = np.stack([_y_up_pixels(c, R[i], t[i], ORIGIN_AND_AXES) for i, c in enumerate(cams)], 1)[:, None]
    ref_seen = np.ones((4, 1, N_CAMS), bool)
    ref_seen[3, 0, 1] = False  # camera 2 did not see the +z point
    files = {"wand-xypts.csv": _xypts(wand_up, wand_seen), "unpaired-xypts.csv": _xypts(unpaired_up, unpaired_seen),
             "reference-xypts.csv": _xypts(ref_up, ref_seen), "profile.txt": _profile_rows(cams)}
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    return sim, cams, tmp_path, wand_seen, unpaired_X, unpaired_seen, ref_seen


def test_import_matches_the_truth(session):
    sim, cams, folder, wand_seen, unpaired_X, unpaired_seen, ref_seen = session
    imp = read_argus(folder / "wand-xypts.csv", folder / "profile.txt", WAND_M, folder / "unpaired-xypts.csv",
                     folder / "reference-xypts.csv")
    cap = imp.capture
    tol = 10.0 ** -DECIMALS * 2
    assert cap.rig.wand_length == WAND_M and cap.rig.ids == [c.id for c in cams]
    for got, cam in zip(cap.rig.cameras, cams):
        assert np.allclose(got.K, cam.K, atol=1e-6) and np.allclose(got.dist, cam.dist, atol=1e-8)
    R, t = sim.truth.R, sim.truth.t
    both = wand_seen.all(axis=1)  # (F, N): camera-frames with both ends
    for c, cam in enumerate(cams):
        frames = np.flatnonzero(both[:, c])
        sel = cap.wand.camera == c
        assert np.array_equal(np.unique(cap.wand.frame[sel]), frames)
        for f in frames:
            got = cap.wand.uv[sel & (cap.wand.frame == f)]
            want = project_pixels(cam, R[c], t[c], sim.truth.wand[f])
            assert np.abs(got - want).max() < tol
        # unpaired points: frame 100 + row (the first power of ten above wand frames 0..39)
        psel = cap.points.camera == c
        rows = np.flatnonzero(unpaired_seen[:, 0, c])
        assert np.array_equal(cap.points.frame[psel], 100 + rows)
        assert np.abs(cap.points.uv[psel] - project_pixels(cam, R[c], t[c], unpaired_X[rows])).max() < tol
    # reference: 4 points are origin, +x, +y, +z (Argus's convention)
    assert list(dict.fromkeys(cap.axis.role)) == ["origin", "+x", "+y", "+z"]
    assert sorted(cap.axis.camera[cap.axis.role == "+z"]) == [0, 2]
    for role, X in zip(("origin", "+x", "+y", "+z"), ORIGIN_AND_AXES):
        for c in cap.axis.camera[cap.axis.role == role]:
            got = cap.axis.uv[(cap.axis.role == role) & (cap.axis.camera == c)]
            assert np.abs(got - project_pixels(cams[c], R[c], t[c], X[None])).max() < tol


def test_cli_round_trip_and_errors(session, tmp_path, capsys):
    _, _, folder, *_ = session
    out = tmp_path / "cap"
    args = ["import", "argus", str(folder / "wand-xypts.csv"), "--profile", str(folder / "profile.txt"),
            "--wand-length", str(WAND_M), "--unpaired", str(folder / "unpaired-xypts.csv"), "--out", str(out)]
    assert main(args) == 0
    assert "wand: 0.5 m" in capsys.readouterr().out
    cap = read_capture(out)
    assert len(cap.points.frame) > 0 and cap.axis is None
    # a profile for the wrong number of cameras
    (folder / "two.txt").write_text("\n".join((folder / "profile.txt").read_text().splitlines()[:2]) + "\n")
    args[4] = str(folder / "two.txt")
    assert main(args[:-1] + [str(tmp_path / "other")]) == 2
    assert "12 coordinate columns, expected 8 for 2 cameras" in capsys.readouterr().err


def test_bad_files_name_the_file(session):
    _, _, folder, *_ = session
    junk = folder / "junk-xypts.csv"
    junk.write_bytes(bytes(range(256)) * 4)
    with pytest.raises(CaptureFormatError, match="junk-xypts.csv: not a text file"):
        read_argus(junk, folder / "profile.txt", WAND_M)
    lines = (folder / "wand-xypts.csv").read_text().splitlines()
    lines[5] = lines[5].replace("NaN", "abc", 1) if "NaN" in lines[5] else "abc" + lines[5][lines[5].index(","):]
    (folder / "bad-xypts.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(CaptureFormatError, match=r"bad-xypts.csv line 6, column \d+: 'abc' is not a number"):
        read_argus(folder / "bad-xypts.csv", folder / "profile.txt", WAND_M)
    (folder / "omni.txt").write_text("1 4 1920 1440 0.99 -0.01 0.01 718 977 -847 0 0.0003 -0.0000001\n")
    with pytest.raises(CaptureFormatError, match=r"omni.txt line 1: 13 numbers.*omnidirectional"):
        read_argus(folder / "wand-xypts.csv", folder / "omni.txt", WAND_M)
