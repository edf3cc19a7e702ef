"""Every input kind through every command (issue 32; the table is docs/inputs.md): each cell works,
or refuses with a message that names what the method or command cannot hold.

Small rigs (4 cameras, 300 frames) keep it fast; the sparse hand-digitised session is Brown 1 of
../shared/data (skipped where the data are absent)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from bench.matrix_inputs import Kind, build
from wandcal.calib.errors import CalibrationError
from wandcal.calib.judge.bumps import check_rig
from wandcal.calib.run.calibrate import calibrate
from wandcal.calib.run.guidance import wanding_guidance
from wandcal.calib.run.options import CalibrationOptions
from wandcal.calib.run.resolve import solve_only

KINDS = ("lframe", "wand_only", "three_marker", "planar_wand", "wand_points", "sparse_digitised", "points_only")
COMMANDS = ("ba", "lp", "paper", "sync_auto", "check", "solve_only", "guidance", "export")
# the cells that refuse, and the words their message must hold: what the method or command cannot take
REFUSALS = {
    ("points_only", "paper"): "without a wand calibrates with --method ba or lp",
}


def _kind(name: str) -> Kind:
    """The input kind, built as bench/bench_matrix.py builds it; skipped where ../shared/data lacks it."""
    k = build(name)
    if k is None:
        pytest.skip(f"{name}: its data are absent from ../shared/data")
    return k


@pytest.fixture(scope="module")
def made():
    """{kind: (inputs, its ba result)}, built once."""
    cache: dict = {}

    def get(name: str):
        if name not in cache:
            k = _kind(name)
            cache[name] = (k, calibrate(k.rig, k.wand, k.static, points=k.points, axis=k.axis))
        return cache[name]

    return get


def _run(command: str, k: Kind, result, tmp_path):
    """One command on one input kind; returns what it made (raises CalibrationError on a refusal)."""
    if command in ("ba", "lp", "paper", "sync_auto"):
        options = CalibrationOptions(sync="auto") if command == "sync_auto" else CalibrationOptions(method=command)
        return calibrate(k.rig, k.wand, k.static, options=options, points=k.points, axis=k.axis)
    if command == "check":
        rms = [c.reprojection_rms_px for c in result.cameras]  # as wandcal check: None when a camera has none
        expected = None if any(v is None for v in rms) else np.array(rms)
        found = check_rig(result.rig, result.R, result.t, k.wand, expected, k.points)
        assert not found.rebuilt and not any(c.moved for c in found.cameras), found.cameras
        return found
    if command == "solve_only":
        out = solve_only(result.rig, k.wand, result.R, result.t, [result.rig.ids[1]], result.world, list(result.cameras),
                         points=k.points)
        sigma = result.cameras[1].uncertainty.center_std_mm
        moved = np.linalg.norm(out.centers[1] - result.centers[1])
        if sigma is not None:  # the same capture: the same pose within 2 sigma
            assert 1000 * moved <= 2 * sigma, (1000 * moved, sigma)
        else:  # points only: no scale, no sigma in metres; the same pose to a part in a thousand of the rig's size
            assert moved <= 1e-3 * np.linalg.norm(result.centers - result.centers.mean(axis=0), axis=1).max()
        return out
    if command == "guidance":
        doc = wanding_guidance(k.rig, k.wand, k.static, points=k.points if k.wand is None else None).document
        assert all(c["frames"] > 0 and c["coverage"] > 0 for c in doc["cameras"]), doc["cameras"]
        if k.wand is None:  # no scale: no sigma in mm, the coverage from the points
            assert all(c["center_std_mm"] is None for c in doc["cameras"]) and doc["solve"]["points_only"]
        return doc
    from wandcal.capture.formats.cameras_in import read_camera_file
    from wandcal.capture.formats.export import export

    path = tmp_path / "cameras.toml"
    path.write_text(export(result.to_json(), "anipose-toml", result.rig))
    posed = read_camera_file(path, "anipose-toml")
    np.testing.assert_allclose(posed.R, result.R, atol=1e-9)
    np.testing.assert_allclose(posed.t, result.t, atol=1e-9)
    return posed


# paper's solve takes 40-60 s on these captures (tests/calib/solve covers it on a two-marker wand):
# the matrix runs it on the sparse session and its refusal only
CELLS = [(k, c) for k in KINDS for c in COMMANDS if c != "paper" or k in ("sparse_digitised", "points_only")]


@pytest.mark.parametrize("kind, command", CELLS)
def test_every_input_kind_through_every_command(made, kind, command, tmp_path):
    k, result = made(kind)
    refusal = REFUSALS.get((kind, command))
    if refusal is None:
        assert _run(command, k, result, tmp_path) is not None
        return
    with pytest.raises(CalibrationError, match=re.escape(refusal)):
        _run(command, k, result, tmp_path)
