"""``wandcal capture`` prints the guidance as it records (and may stop on it) over the real
pty trigger; ``wandcal guidance CAPTURE`` judges a points-level capture offline."""

import csv
import json

import pytest

from wandcal.drivers.trigger_emulator import EmulatorProcess
from wandcal.service.cli import main

pytestmark = pytest.mark.usefixtures("patient_stall_limit")  # in-process recordings on a loaded box

WAND_SETS, STATIC = 3000, 20
SIM = f"sim://?cameras=4&seed=3&frames={WAND_SETS}&static={STATIC}"
# The simulated wand path covers about a quarter of each view (a smooth path through the middle
# of the volume), so the test asks for a tenth and a 1 mm centre: met after a few hundred sets.
LOOSE = ["--target-mm", "1", "--min-coverage", "0.1"]


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    out = tmp_path_factory.mktemp("guidance") / "cap"
    with EmulatorProcess() as emu:
        code = main(["capture", "--camera", SIM, "--trigger", emu.url, "--frames", str(WAND_SETS), "--static-frames",
                     str(STATIC), "--no-pause", "--rate", "200", "--images", "none", "--stop-when-enough", *LOOSE, "--out", str(out)])
    return out, code


def test_capture_prints_the_guidance_and_stops_when_it_is_enough(recorded, capsys):
    out, code = recorded
    assert code == 0
    with open(out / "sync.csv", newline="") as fh:
        sets = len(list(csv.DictReader(fh)))
    assert 0 < sets < WAND_SETS  # ended by the guidance, complete
    log = json.loads((out / "capture.json").read_text())
    assert log["error"] is None and any("guidance says enough" in m for m in log["messages"])
    assert not (out / "frames").exists()  # --images none: centroids only


def test_guidance_command_judges_the_recorded_capture(recorded, capsys):
    out, _ = recorded
    assert main(["guidance", str(out), *LOOSE, "--grid"]) == 0
    text = capsys.readouterr().out
    assert "enough: yes, you can stop waving" in text
    for cam in ("cam1", "cam2", "cam3", "cam4"):
        assert f"\n{cam} " in text
    assert main(["guidance", str(out), "--json"]) == 0  # the default goal: half of each image
    doc = json.loads(capsys.readouterr().out)
    assert doc["format"] == "wandcal-guidance/1" and not doc["enough"]
    assert len(doc["advice"]) == 4 and all("of its image" in a for a in doc["advice"])


def test_bad_input_names_the_problem(recorded, tmp_path, capsys):
    assert main(["guidance", str(tmp_path)]) == 2
    assert "rig.json: not found" in capsys.readouterr().err
    (tmp_path / "rig.json").write_text((recorded[0] / "rig.json").read_text())
    assert main(["guidance", str(tmp_path)]) == 2
    assert "wand.csv: not found" in capsys.readouterr().err
    with pytest.raises(SystemExit) as stop:
        main(["capture", "--camera", "sim://?cameras=2", "--frames", "5", "--images", "some", "--out",
              str(tmp_path / "x")])
    assert stop.value.code == 2 and "images 'some'" in capsys.readouterr().err
    assert main(["capture", "--camera", "sim://?cameras=2", "--frames", "5", "--no-guidance", "--stop-when-enough",
                 "--out", str(tmp_path / "y")]) == 2
    assert "--stop-when-enough needs the guidance" in capsys.readouterr().err
