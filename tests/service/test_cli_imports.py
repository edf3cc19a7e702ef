"""`wandcal calibrate` loads no web framework (STYLE.md, habit 1): the command line imports only
the module of the command that runs. Checked in fresh interpreters, as a user starts them."""

import json
import subprocess
import sys

import pytest

from wandcal.calib.sim.simulate import simulate_capture
from wandcal.capture.folder import write_capture

# the service's stack, and the solvers only `--method lp`/`paper` load when they run
NOT_FOR_CALIBRATE = ("fastapi", "uvicorn", "starlette", "pydantic", "pydantic_settings", "multipart", "httpx", "scipy", "highspy")
PROBE = (
    "import json, sys; from wandcal.service.cli import main\n"
    "try:\n    code = main(sys.argv[1:])\nexcept SystemExit as exc:\n    code = exc.code\n"
    "print(json.dumps(sorted({'.'.join(m.split('.')[:2]) if m.startswith('wandcal.') else m.split('.')[0]\n"
    "                         for m in sys.modules})), file=sys.stderr)\n"
    "sys.exit(code)"
)


def loaded_packages(*args: str, code: int = 0) -> set[str]:
    done = subprocess.run([sys.executable, "-c", PROBE, *args], capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == code, done.stderr
    return set(json.loads(done.stderr.strip().splitlines()[-1]))


# what --version and --help must not load: every numerical, imaging, plotting and web package the
# commands use (issue 33: --version took 0.9 s, building every command's options with the pipeline)
NOT_FOR_STARTUP = ("numpy", "scipy", "cv2", "matplotlib", "highspy", "threadpoolctl", "serial", *NOT_FOR_CALIBRATE)


@pytest.mark.parametrize("argv", [["--version"], ["--help"], []], ids=["--version", "--help", "no command"])
def test_version_and_help_load_no_numerical_or_web_package(argv):
    loaded = loaded_packages(*argv, code=0 if argv else 2)
    assert "wandcal.service" in loaded  # the probe saw the command line
    assert not loaded & set(NOT_FOR_STARTUP), sorted(loaded & set(NOT_FOR_STARTUP))
    assert not {m for m in loaded if m.startswith("wandcal.") and m != "wandcal.service"}, sorted(loaded)


def test_calibrate_help_imports_no_web_framework():
    loaded = loaded_packages("calibrate", "--help")
    assert not loaded & set(NOT_FOR_CALIBRATE), sorted(loaded & set(NOT_FOR_CALIBRATE))


def test_a_real_calibrate_imports_no_web_framework(tmp_path):
    sim = simulate_capture(3, 120, 0.3, 0.0, True, 5)
    folder = tmp_path / "cap"
    write_capture(folder, sim.rig, sim.wand, sim.static)
    loaded = loaded_packages("calibrate", str(folder), "--quiet", "--out", str(tmp_path / "result.json"))
    assert (tmp_path / "result.json").is_file()
    assert "wandcal.calib" in loaded  # the probe saw the calibration run
    assert not loaded & set(NOT_FOR_CALIBRATE), sorted(loaded & set(NOT_FOR_CALIBRATE))


def test_importtime_of_calibrate_help_shows_no_web_framework():
    """The same through `python -X importtime`, the tool to look with when this test fails."""
    done = subprocess.run([sys.executable, "-X", "importtime", "-m", "wandcal.service.cli", "calibrate", "--help"],
                          capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 0, done.stderr
    names = [line.rsplit("|", 1)[-1].strip() for line in done.stderr.splitlines() if line.startswith("import time:")]
    modules = {name.split(".")[0] for name in names}
    assert "wandcal.calib" in names
    assert not modules & {"fastapi", "uvicorn", "starlette", "pydantic"}, sorted(modules & {"fastapi", "uvicorn", "starlette", "pydantic"})


def test_serve_still_registers_and_help_lists_every_command():
    from wandcal.service.cli import COMMANDS

    done = subprocess.run([sys.executable, "-m", "wandcal.service.cli", "--help"], capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 0, done.stderr
    for command in COMMANDS:
        assert command in done.stdout


def _loaded_modules(*args: str) -> set[str]:
    """Every module (full dotted name) a fresh ``wandcal ARGS`` process has loaded at its exit."""
    probe = PROBE.replace("'.'.join(m.split('.')[:2]) if m.startswith('wandcal.') else m.split('.')[0]", "m")
    done = subprocess.run([sys.executable, "-c", probe, *args], capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 0, done.stderr
    return set(json.loads(done.stderr.strip().splitlines()[-1]))


def test_version_builds_no_command_and_help_registers_without_options():
    """--version imports no command's module at all; --help imports each command's module to list
    it, and none of what their options quote or their runs use (issue 33)."""
    from wandcal.service.cli import COMMANDS

    version = _loaded_modules("--version")
    exit_table = {"wandcal.service.cli.support", "wandcal.service.cli.support.exits"}  # constants, no imports
    assert not {m for m in version if m.startswith("wandcal.service.cli.")} - exit_table, sorted(version)
    assert not {m.split(".")[0] for m in version} & set(NOT_FOR_STARTUP)
    help_ = _loaded_modules("--help")
    assert set(COMMANDS.values()) <= help_
    ours = {m for m in help_ if m.startswith("wandcal.") and not m.startswith("wandcal.service.cli")}
    assert ours <= {"wandcal.service"}, sorted(ours)
    assert not {m.split(".")[0] for m in help_} & set(NOT_FOR_STARTUP)
