"""Request and response models: one per purpose (``JobCreate`` in, ``JobPublic`` out)."""

from __future__ import annotations

import enum
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from wandcal.calib.errors import CalibrationError
from wandcal.calib.run.options import (
    DEFAULT_METHOD,
    MAX_FRAME_RATE_HZ,
    MAX_LP_SECONDS,
    MAX_PAPER_ROUNDS,
    MAX_SYNC_OFFSET,
    CalibrationOptions,
    options_from,
)
from wandcal.service.jobs.records import JobState


class ErrorPublic(BaseModel):
    """Every 4xx/5xx answer: a message that names the problem and says what to do."""

    detail: str = Field(examples=["no capture with id 'abc'; list captures with GET /api/v1/captures"])


class ValidationErrorPublic(ErrorPublic):
    errors: list[dict[str, Any]] = Field(default_factory=list, description="one entry per invalid field")


class CameraCoverage(BaseModel):
    id: str
    blobs: int = Field(description="wand blobs stored for this camera")
    pairs: int = Field(description="frames in which this camera saw both wand markers")
    framesets: dict[str, int] | None = Field(
        None, description="streamed frame sets by blobs detected: '0', '1', '2', 'more'"
    )


class StaticCameraPublic(BaseModel):
    id: str
    ok: bool
    R: list[list[float]] | None = Field(None, description="(3, 3) world->camera rotation")
    t: list[float] | None = Field(None, description="(3,) world->camera translation, metres")
    center: list[float] | None = Field(None, description="(3,) camera centre in the static object's frame, metres")
    rms_px: float | None = Field(None, description="PnP reprojection RMS, pixels")
    reason: str | None = Field(None, description="why PnP failed for this camera")


class StaticSolutionPublic(BaseModel):
    cameras: list[StaticCameraPublic]


class CapturePublic(BaseModel):
    id: str
    created: float = Field(description="Unix time, seconds")
    source: str = Field(description="'upload', 'replay' or 'stream' (rig.json alone, filled by frame sets)")
    name: str
    cameras: list[str]
    frames: int = Field(description="distinct frames with wand blobs")
    framesets: int = Field(description="frame sets received by POST /captures/{id}/framesets")
    has_static: bool
    coverage: list[CameraCoverage]
    static_solution: StaticSolutionPublic | None = None


class CaptureList(BaseModel):
    captures: list[CapturePublic]


class FrameSetPublic(BaseModel):
    capture_id: str
    frame: int
    blobs: dict[str, int] = Field(description="blobs detected per camera")
    wand_cameras: list[str] = Field(description="cameras that saw exactly two blobs and added wand rows")


MAX_BLOB_SETS = 5000  # per request: 50 s of a 100 fps rig, about 1 MB of JSON for 8 cameras
MAX_BLOBS_PER_CAMERA = 64  # more bright spots than any wand frame shows; a camera seeing more is flooded
FRAME_LIMIT = 10**12  # as the image frame sets' 12 digits


class BlobSet(BaseModel):
    """One synchronised frame set as centroids, as a camera that detects on board sends it."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    frame: int = Field(ge=0, lt=FRAME_LIMIT, description="frame-set index")
    trigger_count: int | None = Field(None, ge=0, lt=FRAME_LIMIT)
    blobs: dict[str, list[tuple[float, float]]] = Field(
        description="camera id -> blob centres [u, v] in pixels of the raw image (origin at the top-left "
        "pixel's centre, docs/conventions.md); a camera that saw nothing may be left out or given []",
    )


class BlobSetsCreate(BaseModel):
    model_config = ConfigDict(extra="forbid")

    sets: list[BlobSet] = Field(min_length=1, max_length=MAX_BLOB_SETS)


class BlobSetsPublic(BaseModel):
    capture_id: str
    stored: int = Field(description="frame sets stored by this request (all it sent)")
    wand_rows: int = Field(description="wand.csv rows they added: two per camera that saw exactly two blobs")
    framesets: int = Field(description="frame sets the capture now holds")


class Method(str, enum.Enum):
    """The methods, as wandcal.calib.run.options.METHODS (tests/service/test_options_drift.py)."""

    ba = "ba"
    lp = "lp"
    paper = "paper"


MAX_CAMERAS = 1024  # solve_only names at most this many ids (a rig of 128 cameras is the largest measured)
# the job options that are not CalibrationOptions fields, with why (tests/service/test_options_drift.py)
NOT_CALIBRATION_OPTIONS = {
    "use_static": "the service's choice to fix the world by the capture's static object (the command line always does)",
    "from_job": "the command line's --from RESULT: a result on the server is a done job",
    "solve_only": "the command line's --solve-only: which cameras a re-solve places again, not how a calibration solves",
}

# the choices as JSON Schema enums; the same as the lists calibrate checks against, and the
# defaults as CalibrationOptions' (LOSSES, SYNC_MODES, INTRINSICS: tests/service/test_options_drift.py)
Loss = Literal["cauchy", "linear"]
Sync = Literal["none", "auto"]
Intrinsic = Literal["focal", "principal", "k1"]


class JobOptions(BaseModel):
    """A job's calibration options: every field of :class:`CalibrationOptions` but ``method`` (the
    job's own field) and ``sync_start`` (from timestamps the service's captures do not keep), the
    command line's flags by the same names (tests/service/test_options_drift.py), ``use_static``,
    and ``from_job`` with ``solve_only`` (``--from RESULT --solve-only CAM``). Every field has a default, so a job stored before a field was added still reads."""

    model_config = ConfigDict(extra="forbid")

    use_static: bool = Field(True, description="use the capture's static object (if any) to fix the world frame")
    loss: Loss = Field("cauchy", description="ba: robust loss ('linear' is plain least squares)")
    time_limit: float | None = Field(None, gt=0, le=MAX_LP_SECONDS,
                                     description="lp and paper: seconds allowed for each LP solve (default: no limit)")
    max_rounds: int | None = Field(None, ge=1, le=MAX_PAPER_ROUNDS,
                                   description="paper: most rotation/LP rounds (default: the method's own)")
    reject_outliers: bool = Field(True, description="drop gross-outlier camera-frames and refine again")
    refine_intrinsics: list[Intrinsic] = Field(default_factory=list,
                                               description="ba: also refine these per camera (default: none)")
    sync: Sync = Field("none", description="auto: find each camera's time offset from the wand, for "
                       "cameras without a trigger (docs/sync.md)")
    sync_max_offset: int | None = Field(None, ge=1, le=MAX_SYNC_OFFSET,
                                        description="with sync auto: frames searched either side (default 8)")
    sync_drift: bool = Field(False, description="with sync auto: also each camera's clock rate difference (ppm)")
    frame_rate_hz: float | None = Field(None, gt=0, le=MAX_FRAME_RATE_HZ,
                                        description="the cameras' frame rate: offsets are then also given in ms")
    from_job: str | None = Field(None, max_length=64, description="with solve_only: the done job whose result "
                                 "stands; every camera not named keeps its pose exactly (the command line's --from)")
    solve_only: list[str] = Field(default_factory=list, max_length=MAX_CAMERAS,
                                  description="with from_job: re-solve only these camera ids, e.g. the ones "
                                  "POST /captures/{id}/check names (--solve-only; method ba, intrinsics held)")

    def calibration(self, method: str) -> CalibrationOptions:
        """The options ``calibrate`` takes for a job of ``method`` (not checked)."""
        return options_from(self.model_dump(exclude=set(NOT_CALIBRATION_OPTIONS)) | {"method": method})

    def check_solve_only(self, method: str) -> None:
        """Refuse (CalibrationError naming the field) a re-solve the command line refuses."""
        if bool(self.from_job) != bool(self.solve_only):
            raise CalibrationError("from_job and solve_only go together (--from RESULT --solve-only CAM): name the "
                                   "done job whose result stands and the camera ids to re-solve")
        if self.solve_only and (method != "ba" or self.refine_intrinsics):
            raise CalibrationError("solve_only (--solve-only) re-solves poses with method ba only, intrinsics held: "
                                   "drop refine_intrinsics, or calibrate afresh")



class JobCreate(BaseModel):
    model_config = ConfigDict(extra="forbid")

    capture_id: str = Field(max_length=64)
    method: Method = Method(DEFAULT_METHOD)
    options: JobOptions = Field(default_factory=JobOptions)

    @model_validator(mode="after")
    def _runnable(self) -> JobCreate:
        """Refuse (422) options the method cannot run (e.g. max_rounds without paper), as the
        command line refuses its flags: CalibrationOptions.check's message names the field."""
        self.options.calibration(self.method.value).check()
        self.options.check_solve_only(self.method.value)
        return self


class JobProgress(BaseModel):
    stage: str | None = None
    iteration: int | None = None
    cost: float | None = None
    message: str | None = None


class JobPublic(BaseModel):
    id: str
    capture_id: str
    method: Method
    options: JobOptions
    state: JobState
    attempts: int = Field(description="runs started; a job re-queued after a crash has 2")
    created: float
    started: float | None = None
    finished: float | None = None
    progress: JobProgress | None = None
    error: str | None = None
    cancel_requested: bool = False
    result: dict[str, Any] | None = Field(None, description="the wandcal-result/1 document, once done")


class JobSummary(BaseModel):
    """A job without its result document (lists stay small)."""

    id: str
    capture_id: str
    method: Method
    state: JobState
    attempts: int
    created: float
    finished: float | None = None
    progress: JobProgress | None = None
    error: str | None = None


class JobList(BaseModel):
    jobs: list[JobSummary]


class ResultFormat(str, enum.Enum):
    json = "json"
    anipose_toml = "anipose-toml"
    opencv_yaml = "opencv-yaml"
    dlt_csv = "dlt-csv"
    qca = "qca"
    xcp = "xcp"


class Health(BaseModel):
    status: str = "ok"
    version: str
    queue: str
    workers: int
    jobs_queued: int
    jobs_running: int


class LiveCaptureState(str, enum.Enum):
    idle = "idle"
    running = "running"
    waiting_for_wand = "waiting_for_wand"  # the static object is recorded; POST /capture/continue starts the wand run
    stopping = "stopping"
    done = "done"
    failed = "failed"


class LiveCaptureCreate(BaseModel):
    """Arming settings of a live capture (``wandcal capture`` over HTTP). The folder is chosen by the server."""

    model_config = ConfigDict(extra="forbid")

    cameras: list[str] = Field(
        min_length=1, max_length=64,
        description="camera driver URLs, in rig order (one URL may stand for several), e.g. sim://?cameras=3",
    )
    trigger: str | None = Field(
        None, max_length=500, description="strobe trigger: serial:///dev/ttyACM0 or a device path; null: free-run",
    )
    frames: int = Field(ge=1, le=10_000_000, description="wand frame sets to record")
    static_frames: int = Field(0, ge=0, le=100_000, description="first record this many sets of the static object")
    pause_after_static: bool = Field(
        True, description="after the static recording, wait in state waiting_for_wand (remove the L-frame, take the "
        "wand) until POST /capture/continue (free-running cameras are drained meanwhile). false: record the wand run "
        "at once (scripted use)",
    )
    rate_hz: float = Field(100.0, gt=0, le=10_000, description="trigger / frame rate, Hz")
    wand_length_m: float | None = Field(None, gt=0, le=100, description="wand marker distance, metres")
    rig: dict[str, Any] | None = Field(
        None, description="rig.json document with the cameras' intrinsics (simulated and replayed cameras bring "
        "their own)",
    )
    images: str = Field(
        "all", max_length=20, pattern=r"^(all|none|static|[1-9][0-9]{0,8})$",
        description="images written beside the centroids: 'all', 'none', 'static' (the static recording only) "
        "or N (every N-th wand set and the static recording). Centroids are always recorded; 'none' keeps up "
        "with 8 cameras at 100 fps",
    )
    guidance: bool = Field(True, description="keep the wanding guidance up to date while recording "
                           "(GET /captures/{capture_id}/guidance)")
    stop_when_enough: bool = Field(False, description="end the wand run, keeping it, as soon as the guidance "
                                   "says enough (needs guidance)")


class LiveCaptureUpdate(BaseModel):
    """What may change while a live capture records."""

    model_config = ConfigDict(extra="forbid")

    stop_when_enough: bool = Field(description="end the wand run, keeping it, once the guidance says enough")


class LiveCapturePublic(BaseModel):
    """The live capture: the one running, or the last one since the server started."""

    id: str | None = Field(None, description="live-capture id; null when none ran since the server started")
    capture_id: str | None = Field(None, description="the stored capture it becomes (GET /captures/{id} once done)")
    state: LiveCaptureState
    phase: str | None = Field(
        None, description="'open', 'static', 'waiting', 'wand' or 'register'"
    )
    cameras: list[str] = Field(default_factory=list, description="camera ids")
    frames_total: int = Field(0, description="frame sets asked for: static_frames + frames")
    frames_recorded: int = Field(0, description="frame sets recorded so far (static and wand)")
    fps: float = Field(0.0, description="frame sets recorded per second")
    dropped: dict[str, int] = Field(default_factory=dict, description="per camera: frames missed or unreadable")
    stopped: bool = Field(False, description="ended early by POST /capture/stop (what was recorded is kept)")
    error: str | None = Field(None, description="why it failed")
    prompt: str | None = Field(None, description="what the operator is asked to do now (while waiting_for_wand)")
    wait_deadline: float | None = Field(
        None, description="Unix time, seconds, at which waiting_for_wand gives up (settings: "
        "capture_continue_timeout_s); the static recording is then kept",
    )
    messages: list[str] = Field(default_factory=list, description="the latest drift / realignment / fault events")
    images: str | None = Field(None, description="the images it writes beside the centroids (see LiveCaptureCreate)")
    enough: bool | None = Field(None, description="the latest guidance says the wanding is enough; null without "
                                "guidance")
    stop_when_enough: bool = False
    started: float | None = Field(None, description="Unix time, seconds")
    finished: float | None = None


class CameraGuidancePublic(BaseModel):
    id: str
    frames: int = Field(description="wand frames in which it saw both ends")
    shared_frames: int = Field(description="of those, frames in which another camera saw both ends too")
    coverage: float = Field(description="share of the grid's cells over its image that hold wand samples, 0-1")
    grid: list[list[int]] = Field(description="wand samples per cell, rows top to bottom (8 x 8 by default)")
    linked: dict[str, int] = Field(description="frames it shares with each other camera (both saw both ends)")
    center_std_mm: float | None = Field(
        None, description="predicted 1-sigma of its centre relative to the rest of the rig, millimetres, from the "
        "information matrix of a fast solve on the frames so far; null while it is not in the solve")
    rotation_std_deg: float | None = Field(None, description="the same for its orientation, degrees")
    advice: str | None = Field(None, description="what the operator should do for this camera; null when it "
                               "needs nothing")


class GuidanceTarget(BaseModel):
    center_std_mm: float
    coverage: float


class GuidanceSolve(BaseModel):
    ok: bool = Field(description="the fast solve succeeded")
    message: str | None = Field(None, description="why it did not")
    left_out: dict[str, str] = Field(default_factory=dict, description="cameras left out of the solve (it could not "
                                     "place them), with why; the others were solved without them")
    frames_used: int = Field(description="frames in the (subsampled) solve")
    cameras: int = Field(description="cameras in the solve")
    warm_start: bool = Field(description="started from the previous update's solution")
    iterations: int | None = None
    seconds: float = Field(description="time this update took")
    out_of_time: dict[str, int] = Field(default_factory=dict, description="under sync none: cameras whose wand matches "
                                        "the others' only that many frames away (a trigger fault)")
    offsets: dict[str, int] | None = Field(None, description="under sync auto: each camera's whole-frame offset found "
                                           "from the wand (cameras at 0 left out); null under none or while the "
                                           "frames cannot tell yet")
    points_only: bool = Field(False, description="a rig without a wand: coverage and links from its point tracks "
                              "(points.csv), and no centre sigma in mm (no scale)")


class GuidancePublic(BaseModel):
    """``wandcal-guidance/1``: where each camera still needs the wand, and whether to stop."""

    format: str = "wandcal-guidance/1"
    frames: int = Field(description="wand frames so far (at least one camera saw both ends)")
    enough: bool = Field(description="every camera's center_std_mm is below the target and its coverage reaches "
                         "the goal: the operator can stop")
    advice: list[str] = Field(description="what to do, worst camera first; only cameras that need something")
    target: GuidanceTarget
    cameras: list[CameraGuidancePublic]
    solve: GuidanceSolve
    updated: float | None = Field(None, description="Unix time of this update, seconds")
    live: bool = Field(False, description="from a live capture still recording (updates every second or so)")
