"""Service settings: one ``BaseSettings``, read from ``WANDCAL_*`` environment variables or a TOML file.

Precedence, highest first: keyword arguments, environment variables, the TOML file named by
``WANDCAL_CONFIG`` (or passed to :meth:`Settings.load`), the defaults below.
"""

from __future__ import annotations

import ipaddress
import os
from pathlib import Path
from typing import Literal, cast

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator
from pydantic_settings import BaseSettings, PydanticBaseSettingsSource, SettingsConfigDict, TomlConfigSettingsSource

from wandcal.calib.detect.config import DEFAULT_CONFIG as DETECT
from wandcal.calib.detect.config import Background, DetectConfig
from wandcal.calib.errors import CalibrationError
from wandcal.calib.run.guidance import (
    DEFAULT_FRAMES_PER_CAMERA,
    DEFAULT_MIN_COVERAGE,
    DEFAULT_TARGET_STD_MM,
    MIN_SOLVE_FRAMES,
)
from wandcal.capture.recording.live_guidance import UPDATE_INTERVAL_S

DEFAULT_PORT = 8750
DEFAULT_HOST = "127.0.0.1"  # loopback: a rig PC should not expose the API unless someone asks for it
# 64 MiB holds a points-level capture of hours of waving (a row is ~30 bytes) and one frame set
# of 8 uncompressed 1280x1024 8-bit images (~10 MiB), with room to spare.
DEFAULT_MAX_UPLOAD_BYTES = 64 * 1024 * 1024
# Lab cameras for wand calibration run at 30-120 Hz; streaming is usually decimated, and 60
# frame sets per second per capture is above what detection keeps up with on a small PC.
DEFAULT_FRAMESETS_PER_SECOND = 60.0
# Removing the L-frame and picking up the wand takes a minute or two; ten minutes also covers
# walking to a rig in the next room, and still frees the cameras if the operator forgets.
DEFAULT_CONTINUE_TIMEOUT_S = 600.0
# A client on the lab network sends its whole request header in milliseconds; 10 s covers a
# congested Wi-Fi link, and a connection that takes longer is a stuck or hostile one.
DEFAULT_HEADER_TIMEOUT_S = 10.0
DEFAULT_KEEP_ALIVE_S = 5  # uvicorn's own default: the page polls once a second, so it keeps its connection
# Far below the unit's LimitNOFILE (65536, deploy/wandcal.service) and above what a lab uses (a
# page, a few scripts and tools, 16 streaming clients); when full, the connection waiting longest
# for a header is closed to make room.
DEFAULT_MAX_CONNECTIONS = 512
# Guidance keeps about this many frames per camera at most: the fast solve is meant to take well
# under a second (400 by default); past 20,000 it is as slow as the calibration it is to predict.
MAX_GUIDANCE_FRAMES = 20_000


class SettingsError(CalibrationError):
    """A setting with a wrong value: the command exits 2 naming it, not with a traceback."""


class GuidanceConfig(BaseModel):
    """The ``[guidance]`` group: when wanding is enough (``GET /captures/{id}/guidance``, docs/api.md)."""

    model_config = ConfigDict(extra="forbid")

    target_std_mm: float = Field(DEFAULT_TARGET_STD_MM, gt=0, description="every camera's predicted centre "
                                 "1-sigma (relative to the rig) must be below this, millimetres")
    min_coverage: float = Field(DEFAULT_MIN_COVERAGE, ge=0, le=1, description="every camera's share of its "
                                "8 x 8 image grid holding wand samples must reach this")
    frames_per_camera: int = Field(DEFAULT_FRAMES_PER_CAMERA, ge=MIN_SOLVE_FRAMES, le=MAX_GUIDANCE_FRAMES,
                                   description="frames each camera keeps in the fast solve")
    update_interval_s: float = Field(UPDATE_INTERVAL_S, gt=0, description="least time between two updates of "
                                     "a live or streamed capture's guidance, seconds")


def _connectivity(value: int) -> Literal[4, 8]:
    """DetectConfig's default connectivity, as the literal a detect group allows."""
    if value == 4:
        return 4
    if value == 8:
        return 8
    raise ValueError(f"DetectConfig's default connectivity is {value}, not 4 or 8")


def _per_frame(background: Background) -> Literal["auto", "none", "highpass"]:
    """DetectConfig's default background model, one that needs no camera's own history (the
    per-camera models, "empty" and "running", are not a detect group's to choose)."""
    if background in {"empty", "running"}:
        raise ValueError(f"DetectConfig's default background is {background!r}, which needs a camera's history")
    return cast(Literal["auto", "none", "highpass"], background)


class DetectGroup(BaseModel):
    """The ``[detect]`` group: the blob detector of streamed frame sets, static images and live
    capture. Defaults and rules are :class:`wandcal.calib.detect.config.DetectConfig`'s."""

    model_config = ConfigDict(extra="forbid")

    threshold: int | None = Field(DETECT.threshold, ge=0, description="grey level a blob pixel must exceed after "
                                  "the background is subtracted; null: automatic")
    seed_ratio: float = Field(DETECT.seed_ratio, ge=1, description="each 4-connected piece of a blob must reach "
                              "this times the threshold (1: off; OpenPTV: 2)")
    min_area_px: int = Field(DETECT.min_area_px, ge=1, description="smallest blob, pixels")
    max_area_px: int = Field(DETECT.max_area_px, ge=1, description="largest blob, pixels")
    min_roundness: float | None = Field(DETECT.min_roundness, ge=0, le=1, description="smallest minor/major axis "
                                        "ratio; null: automatic (0.5 on a flat background, 0.1 after the high-pass)")
    connectivity: Literal[4, 8] = _connectivity(DETECT.connectivity)
    weights: Literal["excess", "signal"] = Field(DETECT.weights, description="centroid weights: grey level above "
                                                 "the threshold, or the grey level (OpenPTV's)")
    # The per-camera models ("empty", "running") need each camera's own recording or history.
    background: Literal["auto", "none", "highpass"] = Field(_per_frame(DETECT.background), description="subtracted before "
                                                           "thresholding; auto: a high-pass where uneven")
    highpass_px: int = Field(DETECT.highpass_px, ge=1, description="high-pass half-width, pixels")

    @model_validator(mode="after")
    def _valid_together(self) -> DetectGroup:
        try:
            self.config()  # the rules across fields (max_area_px >= min_area_px) live in DetectConfig
        except CalibrationError as exc:
            raise ValueError(str(exc)) from None
        return self

    def config(self) -> DetectConfig:
        return DetectConfig(**self.model_dump())


class Settings(BaseSettings):
    """Everything the service needs to know; nothing is created until :func:`wandcal.service.main.create_app`."""

    model_config = SettingsConfigDict(env_prefix="WANDCAL_", extra="forbid", validate_default=True)

    data_dir: Path = Field(Path("wandcal-data"), description="SQLite database, stored captures and results")
    replay_root: Path | None = Field(None, description="folder under which POST /captures may name capture folders")
    token: str | None = Field(None, description="bearer token; required for a non-loopback bind",
                              repr=False)  # never in a log line or a traceback's locals
    host: str = DEFAULT_HOST
    allowed_hosts: list[str] = Field(default_factory=list, description="names the Host header may give besides "
                                     "the bound address, localhost and IP addresses (DNS rebinding guard); "
                                     "'*' turns the check off")
    port: int = Field(DEFAULT_PORT, ge=1, le=65535)
    max_upload_bytes: int = Field(DEFAULT_MAX_UPLOAD_BYTES, gt=0, description="largest request body, bytes")
    framesets_per_second: float = Field(DEFAULT_FRAMESETS_PER_SECOND, gt=0, description="per-capture ingest limit")
    capture_continue_timeout_s: float = Field(
        DEFAULT_CONTINUE_TIMEOUT_S, gt=0, description="live capture: longest wait for POST /capture/continue, seconds"
    )
    header_timeout_s: float = Field(DEFAULT_HEADER_TIMEOUT_S, gt=0, description="a connection that has not sent a "
                                    "whole request header this long after opening (or its last answer) is closed")
    keep_alive_s: int = Field(DEFAULT_KEEP_ALIVE_S, ge=1, description="an idle connection is closed after this")
    max_connections: int = Field(DEFAULT_MAX_CONNECTIONS, ge=2, description="open connections; past it the one "
                                 "waiting longest for a header is closed")
    workers: int = Field(1, ge=0, description="solver processes; 0 leaves jobs queued (tests call drain())")
    guidance: GuidanceConfig = Field(default_factory=GuidanceConfig, description="wanding guidance: target and "
                                     "coverage goal (TOML [guidance], or WANDCAL_GUIDANCE as JSON)")
    detect: DetectGroup = Field(default_factory=DetectGroup, description="blob detection of streamed frame sets "
                                "and live capture (TOML [detect], or WANDCAL_DETECT as JSON)")
    keep_results_days: float | None = Field(None, gt=0, description="finished jobs (record, result, report) "
                                            "older than this many days are deleted; unset (the default): kept")
    keep_captures_days: float | None = Field(None, gt=0, description="captures older than this many days whose "
                                             "jobs all finished as long ago are deleted with them; unset: kept")
    queue: Literal["sqlite", "redis"] = "sqlite"
    redis_url: str = "redis://127.0.0.1:6379/0"
    redis_queue_name: str = "wandcal"

    @classmethod
    def load(cls, config_file: str | Path | None = None, **overrides) -> Settings:
        """Settings from ``overrides``, the environment and ``config_file`` (default ``$WANDCAL_CONFIG``)."""
        path = config_file or os.environ.get("WANDCAL_CONFIG")
        if path is not None and not Path(path).is_file():
            raise FileNotFoundError(f"settings file {path} not found; see deploy/wandcal.toml for an example")
        _TOML.file = Path(path) if path else None
        try:
            return cls(**overrides)
        except ValidationError as exc:  # a wrong value in the file, the environment or an option: name it
            where = f"settings ({path or 'WANDCAL_* environment variables and options'})"
            problems = "; ".join(f"{'.'.join(map(str, e['loc']))}: {e['msg']}" for e in exc.errors())
            raise SettingsError(f"{where}: {problems}; see deploy/wandcal.toml for every setting") from None
        finally:
            _TOML.file = None

    @classmethod
    def settings_customise_sources(
        cls,
        settings_cls: type[BaseSettings],
        init_settings: PydanticBaseSettingsSource,
        env_settings: PydanticBaseSettingsSource,
        dotenv_settings: PydanticBaseSettingsSource,
        file_secret_settings: PydanticBaseSettingsSource,
    ) -> tuple[PydanticBaseSettingsSource, ...]:
        sources = [init_settings, env_settings]
        if _TOML.file is not None:
            sources.append(TomlConfigSettingsSource(settings_cls, toml_file=_TOML.file))
        return tuple(sources)

    @property
    def loopback(self) -> bool:
        return is_loopback(self.host)

    @property
    def db_path(self) -> Path:
        return self.data_dir / "wandcal.sqlite3"


class _TOML:
    """The TOML file of the :meth:`Settings.load` call in progress (pydantic-settings builds sources per class)."""

    file: Path | None = None


def is_loopback(host: str) -> bool:
    """True for ``localhost`` and loopback addresses; a name that resolves elsewhere is not loopback."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False
