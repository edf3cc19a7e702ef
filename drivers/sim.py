"""Simulated IR cameras: ``sim://?cameras=4&seed=1[&frames=300&static=25&drop=cam2:17]``.

The twin of a triggered rig. The scene comes from :mod:`wandcal.calib.sim.simulate` (cameras on a ring, a
smooth wand path, the L-frame :data:`~wandcal.calib.sim.simulate.L_FRAME_M` on the floor) and each frame is
drawn with :func:`wandcal.calib.sim.render.render_blobs`. Sequence numbers count frames from 0: the first
``static`` frames show the L-frame alone (the static recording), the next ``frames`` the wand
(and, with ``lframe=keep``, the L-frame still lying on the floor).

Like a rig with its operator, the scene plays what the capture asks for: a capture of K static
sets and F wand sets (:func:`wandcal.capture.recording.session.record` calls :meth:`SimCamera.script`)
shows the L-frame for K frames and then the wand for F. ``frames`` and ``static`` in the URL fix
the script instead (a run that ends early, for tests of a camera that runs out). While a
free-running capture pauses for the L-frame to leave, it grabs and discards frames
(:meth:`SimCamera.discard`): the scene holds, as the operator waits, so the wand's F frames all
come after the pause.

Query options, with their limits (a value outside them is refused, naming the option):
``cameras`` (4; 2 to :data:`MAX_CAMERAS`), ``seed`` (0; 0 to 2**32 - 1), ``frames`` (what the
capture asks; 300 outside a capture; 1 to :data:`MAX_WAND_FRAMES`), ``static`` (what the capture
asks, else 0; 0 to :data:`MAX_STATIC_FRAMES`), ``drop`` (lost frames, ``cam2:17,cam3:40-45`` by
sequence number, below ``MAX_STATIC_FRAMES + MAX_WAND_FRAMES``), ``noise`` (read noise, grey levels
of 8 bits; 2; 0 to :data:`MAX_NOISE`), ``lframe`` (``remove`` or ``keep``), ``bits`` (8 or 16),
``take`` (N markers on moving bodies in place of the wand, an ordinary take as ``wandcal simulate
--take`` draws it; 0, the wand; up to :data:`MAX_TAKE_MARKERS`) and ``move`` (with a take:
``CAM:FRAME:DEG:MM``, camera CAM turned DEG degrees and moved MM mm at wand frame FRAME, a knock).
"""

from __future__ import annotations

import queue
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from wandcal.calib.errors import CalibrationError
from wandcal.calib.geometry import depth, distort_points, project_normalized
from wandcal.calib.rig import Camera, Rig
from wandcal.calib.sim.render import RENDER_HALF_WIDTH_SIGMAS, render_blobs
from wandcal.calib.sim.simulate import L_FRAME_M, Truth, ring_cameras, wand_path
from wandcal.calib.sim.takes import TAKE_STREAM, CameraMove, body_markers
from wandcal.drivers.camera import CameraDriver, CameraSettings, Frame, TriggerMode
from wandcal.drivers.errors import CameraUrlError, DriverError, FrameTimeout

# A 14 mm retro-reflective marker, the common mocap size: its image radius f * r / z is ~2.5 px
# at 3 m for f ~ 1100 px. The spot is drawn as a Gaussian of that sigma, clipped to the 1.5-2.5 px
# of real IR footage (optics blur keeps far markers from getting smaller than that).
MARKER_RADIUS_M = 0.007
SIGMA_RANGE_PX = (1.5, 2.5)
PEAK_8BIT = 200.0  # bright but not saturated, as an IR camera's exposure is set for markers
BACKGROUND_8BIT = 8.0  # a dark IR-filtered background
DEFAULT_PERIOD_US = 10_000  # the camera clock's frame period without a configured rate: 100 fps
CLOCK_PPM = 30.0  # crystal tolerance of a camera clock: timestamps drift by up to this much
NOISE_FRAMES = 4  # precomputed background-noise frames per camera, cycled (noise is 5% of the cost)
WAND_LENGTH_M = 0.5  # the simulated wand, as wandcal simulate's
UNSCRIPTED_WAND_FRAMES = 300  # a scene read outside a capture (tests, replay) without frames= in its URL
# Limits of the URL's options. Each simulated camera keeps NOISE_FRAMES background frames of up to
# 1280 x 1024 x 2 bytes (10 MB), so 32 cameras hold 340 MB: the largest rig of our benchmarks.
MAX_CAMERAS = 32
# An hour of wanding at 100 Hz; the wand path is 48 bytes a frame (17 MB), built at once.
MAX_WAND_FRAMES = 360_000
MAX_STATIC_FRAMES = 100_000  # the service's own limit for static_frames
MAX_SEED = 2**32 - 1
MAX_TAKE_MARKERS = 200  # take=: as wandcal simulate --take's --markers
TAKE_BODIES = 5  # the take's rigid bodies, as wandcal simulate --take's
MAX_NOISE = 1000.0  # grey levels: far past any sensor's read noise, still a finite image


@dataclass(eq=False)
class SimScene:
    """Everything the simulated cameras share: rig, truth and the frame script."""

    rig: Rig
    truth: Truth
    static_frames: int
    wand_frames: int
    keep_lframe: bool = False
    noise: float = 2.0
    bits: int = 8
    drops: dict[str, list[tuple[int, int]]] = field(default_factory=dict)  # inclusive sequence ranges
    seed: int = 0
    url: str = "sim://"
    fixed_static: bool = False  # static= given in the URL: the capture's script does not change it
    fixed_wand: bool = False  # frames= given in the URL
    # the strobe box's counter at the capture's first pulse, whichever camera saw it: every camera
    # numbers its frames from it, so a camera armed a pulse late shows the same instant as the rest
    # (numbered from its own first pulse, it showed the scene one frame behind: an out-of-time
    # camera in a trigger-synchronised recording, which the wanding guidance caught)
    first_counter: int | None = None
    # a take instead of the wand (``take=N``, issue 36): (F, N, 3) markers on moving bodies, and
    # cameras that move during it (``move=cam2:300:0.3:2``: turned 0.3 deg, moved 2 mm at wand frame 300)
    take: np.ndarray | None = None
    moves: tuple[CameraMove, ...] = ()

    @property
    def total_frames(self) -> int:
        return self.static_frames + self.wand_frames

    def script(self, static_frames: int, wand_frames: int) -> None:
        """Play a capture of ``static_frames`` sets of the L-frame, then ``wand_frames`` of the
        wand: what the operator of a real rig does. Counts the URL fixes stay as they are."""
        static = self.static_frames if self.fixed_static else static_frames
        wand = self.wand_frames if self.fixed_wand else wand_frames
        if static > MAX_STATIC_FRAMES or wand > MAX_WAND_FRAMES:
            raise CameraUrlError(f"{self.url}: a simulated rig plays at most {MAX_STATIC_FRAMES} static and "
                                 f"{MAX_WAND_FRAMES} wand frames (an hour at 100 Hz); asked for {static} and {wand}: "
                                 "ask for fewer --frames / --static-frames")
        if wand != self.wand_frames:
            self.truth = _truth(len(self.rig.cameras), self.seed, wand)[1]
            if self.take is not None:
                self.take = _take_markers(self.seed, wand, self.take.shape[1])
        self.static_frames, self.wand_frames = static, wand
        self.first_counter = None  # a new capture numbers its frames from its own first pulse

    def dropped(self, camera_id: str, sequence: int) -> bool:
        return any(lo <= sequence <= hi for lo, hi in self.drops.get(camera_id, ()))

    def points(self, sequence: int) -> np.ndarray:
        """(P, 3) marker positions in the world at frame ``sequence``, metres."""
        if sequence < self.static_frames:
            return L_FRAME_M
        if self.take is not None:
            return self.take[sequence - self.static_frames]
        wand = self.truth.wand[sequence - self.static_frames]
        return np.vstack([wand, L_FRAME_M]) if self.keep_lframe else wand

    def spots(self, index: int, sequence: int) -> tuple[np.ndarray, np.ndarray]:
        """Pixel centres (K, 2) and Gaussian sigmas (K,) of the markers camera ``index`` sees."""
        cam = self.rig.cameras[index]
        R, t = self.truth.R[index], self.truth.t[index]
        for move in self.moves:
            if move.camera == index and sequence >= self.static_frames:
                Rm, tm = move.poses(R, t, np.array([sequence - self.static_frames]))
                R, t = Rm[0], tm[0]
        pts = self.points(sequence)
        z = depth(R, t, pts)
        front = z > 0.1
        uv = distort_points(cam, project_normalized(R, t, pts[front]))
        sigma = np.clip(cam.K[0, 0] * MARKER_RADIUS_M / z[front], *SIGMA_RANGE_PX)
        return uv, sigma


class SimCamera(CameraDriver):
    """One simulated camera of a :class:`SimScene`.

    In external-trigger mode the camera exposes once per pulse on its simulated trigger input,
    :meth:`trigger_input`, which ``capture/`` wires to the strobe trigger's pulses as the cable
    would; its timestamps are then the pulse times on its own (offset, slightly fast or slow)
    clock. In free-run mode frames are paced at ``settings.fps``, or come as fast as they can be
    drawn when it is None. ``clock``/``sleep`` are injected for tests.
    """

    def __init__(self, camera_id: str, url: str, scene: SimScene, index: int,
                 clock: Callable[[], float] = time.monotonic, sleep: Callable[[float], None] = time.sleep):
        super().__init__(camera_id, url)
        self.scene = scene
        self.index = index
        self.intrinsics: Camera = scene.rig.cameras[index]  # a simulated camera always knows its own
        self._clock, self._sleep = clock, sleep
        rng = np.random.default_rng([scene.seed, index])
        self._rng = rng
        self._clock_offset_us = int(rng.integers(0, 10**9))
        self._clock_scale = 1.0 + rng.uniform(-CLOCK_PPM, CLOCK_PPM) * 1e-6
        self._next = 0
        self._start: float | None = None
        self._held = 0
        self._drained = False  # discarded grabs since the last read: the scene held, the clock did not
        self._backgrounds: list[np.ndarray] = []
        self._line: queue.Queue[tuple[int, int]] = queue.Queue()

    def script(self, static_frames: int, wand_frames: int) -> None:
        """The capture about to start: see :meth:`SimScene.script` (shared by the scene's cameras)."""
        self.scene.script(static_frames, wand_frames)

    def trigger_input(self, counter: int, t_us: int) -> None:
        """A pulse on the trigger input: pulse ``counter`` of the strobe box at ``t_us`` (its clock)."""
        self._line.put((counter, t_us))

    def _open(self) -> None:
        self._next = 0
        self._start = None
        self._held = 0  # frame periods the camera ran while its scene held (discarded grabs)
        self._drained = False
        self._line = queue.Queue()
        cam = self.intrinsics
        scale = (1 << (self.scene.bits - 8))
        empty = np.zeros((0, 2))
        self._backgrounds = [
            render_blobs((cam.height, cam.width), empty, 2.0, PEAK_8BIT * scale, BACKGROUND_8BIT * scale,
                         self.scene.noise * scale, self.scene.bits, self._rng)
            for _ in range(NOISE_FRAMES)
        ]

    def _close(self) -> None:
        self._backgrounds = []

    def _apply(self, settings: CameraSettings) -> None:
        cam = self.intrinsics
        for name, want, have in (("width", settings.width, cam.width), ("height", settings.height, cam.height)):
            if want is not None and want != have:
                raise DriverError(f"camera {self.camera_id}: the simulated sensor is {cam.width}x{cam.height}; "
                                  f"{name}={want} is not available")

    def _read(self, timeout: float | None) -> Frame | None:
        while True:
            if self._next >= self.scene.total_frames:
                return None
            if self.settings.trigger_mode is TriggerMode.EXTERNAL:
                seq, stamp = self._wait_pulse(timeout)
            else:
                seq, stamp = self._next, None
                self._next += 1
            if not self.scene.dropped(self.camera_id, seq):
                break  # a dropped frame was exposed but lost in transfer: a gap in the sequence
        if seq >= self.scene.total_frames:
            return None
        if stamp is None:
            self._catch_up(seq)
            self._pace(seq + self._held)
        at_us = (seq + self._held) * self._period_us() if stamp is None else stamp
        return Frame(image=self.render(seq), sequence=seq, timestamp_us=self._clock_us(at_us),
                     camera_id=self.camera_id)

    def _discard(self, timeout: float | None) -> int | None:
        """A grab the capture throws away (its pause for the L-frame to leave): free-running, the
        camera's clock runs on by a frame period but its scene does not, so the script keeps every
        wand frame for after the pause; its sequence numbers then show no gap, its timestamps do.
        Triggered, the camera exposes on each pulse as a real one does."""
        if self.settings.trigger_mode is TriggerMode.EXTERNAL:
            return super()._discard(timeout)
        if self._next >= self.scene.total_frames:
            return None
        if self.settings.fps:
            self._pace(self._next + self._held)  # the camera's frame clock runs on at its rate
        else:
            self._sleep(DEFAULT_PERIOD_US / 1e6)
        self._held += 1
        self._drained = True
        return self._next - 1

    def _wait_pulse(self, timeout: float | None) -> tuple[int, int]:
        try:
            counter, t_us = self._line.get(timeout=timeout)
        except queue.Empty:
            raise FrameTimeout(f"camera {self.camera_id}: no trigger pulse within {timeout:.2f} s") from None
        if self.scene.first_counter is None or counter < self.scene.first_counter:
            self.scene.first_counter = counter
        seq = counter - self.scene.first_counter  # a pulse whose line the host lost still exposed a frame
        self._next = seq + 1
        return seq, t_us

    def render(self, sequence: int) -> np.ndarray:
        """(H, W) image of frame ``sequence``: spots drawn in small patches on a noisy background."""
        uv, sigma = self.scene.spots(self.index, sequence)
        out = self._backgrounds[sequence % NOISE_FRAMES].copy()
        height, width = out.shape
        peak = PEAK_8BIT * (1 << (self.scene.bits - 8))
        full_scale = (1 << self.scene.bits) - 1
        for (u, v), s in zip(uv, sigma):
            # The patch reaches as far as render_blobs itself draws a spot (its 6-sigma window).
            half = int(np.ceil(RENDER_HALF_WIDTH_SIGMAS * s)) + 2
            x0, y0 = max(int(u) - half, 0), max(int(v) - half, 0)
            x1, y1 = min(int(u) + half + 1, width), min(int(v) + half + 1, height)
            if x0 >= x1 or y0 >= y1:
                continue
            spot = render_blobs((y1 - y0, x1 - x0), np.array([(u - x0, v - y0)]), s, peak, 0.0, 0.0, self.scene.bits)
            patch = out[y0:y1, x0:x1].astype(np.int32) + spot
            out[y0:y1, x0:x1] = np.minimum(patch, full_scale)
        return out

    def _period_us(self) -> float:
        return 1e6 / self.settings.fps if self.settings.fps else DEFAULT_PERIOD_US

    def _clock_us(self, true_us: float) -> int:
        """The camera clock's reading at true time ``true_us``: its own origin and rate."""
        return self._clock_offset_us + int(round(true_us * self._clock_scale))

    def _catch_up(self, seq: int) -> None:
        """The first frame after a pause comes at the time the camera's clock has reached: a real
        free-running camera runs on while the host drains it, however few grabs a busy host made
        in the pause (a starved reader drained 13 of 100 periods, CI, session 23)."""
        if not (self._drained and self.settings.fps and self._start is not None):
            return
        self._drained = False
        ran = int((self._clock() - self._start) * self.settings.fps)  # periods since its first frame
        self._held = max(self._held, ran - seq)

    def _pace(self, seq: int) -> None:
        if not self.settings.fps:
            return
        if self._start is None:
            self._start = self._clock() - seq / self.settings.fps
        delay = self._start + seq / self.settings.fps - self._clock()
        if delay > 0:
            self._sleep(delay)


def parse_drops(text: str, camera_ids: list[str], url: str) -> dict[str, list[tuple[int, int]]]:
    """``cam2:17,cam3:40-45`` -> {"cam2": [(17, 17)], "cam3": [(40, 45)]} (inclusive ranges)."""
    drops: dict[str, list[tuple[int, int]]] = {}
    last = MAX_STATIC_FRAMES + MAX_WAND_FRAMES - 1
    for item in filter(None, text.split(",")):
        cid, _, span = item.partition(":")
        if cid not in camera_ids:
            raise CameraUrlError(f"{url}: drop names camera {cid!r}; the simulated cameras are {', '.join(camera_ids)}")
        try:
            lo_text, _, hi_text = span.partition("-")
            lo, hi = int(lo_text), int(hi_text or lo_text)
        except ValueError:
            raise CameraUrlError(f"{url}: drop item {item!r} must look like cam2:17 or cam2:40-45") from None
        if not 0 <= lo <= hi <= last:
            raise CameraUrlError(f"{url}: drop item {item!r} must name frames from 0 to {last}, the first one first")
        drops.setdefault(cid, []).append((lo, hi))
    return drops


def _truth(cameras: int, seed: int, wand_frames: int) -> tuple[Rig, Truth]:
    """The rig and truth of ``wandcal.calib.sim.simulate.simulate_capture(cameras, wand_frames,
    seed=seed)`` (the same draws in the same order), without its observations: the rig depends on
    the seed alone, so a capture of any length sees the same cameras."""
    rng = np.random.default_rng(seed)
    cams, R, t = ring_cameras(cameras, rng)
    wand = wand_path(wand_frames, WAND_LENGTH_M, rng)
    rig = Rig(cameras=tuple(cams), wand_length=WAND_LENGTH_M, static_markers=L_FRAME_M.copy())
    return rig, Truth(R=R, t=t, wand=wand)


def _take_markers(seed: int, frames: int, markers: int) -> np.ndarray:
    """(F, M, 3) the markers of ``wandcal simulate --take``'s bodies (its draws), metres."""
    return body_markers(frames, markers, TAKE_BODIES, np.random.default_rng([seed, TAKE_STREAM]))


def _parse_move(text: str, rig: Rig, seed: int, url: str) -> CameraMove:
    """``CAM:FRAME:DEG:MM`` (as ``wandcal simulate --move``): a knock at wand frame FRAME."""
    try:
        cam, frame, deg, mm = text.split(":")
        return CameraMove(rig.index(cam), int(frame), float(deg), float(mm), seed=seed)
    except (ValueError, CalibrationError):
        raise CameraUrlError(f"{url}: move={text!r} is not CAM:FRAME:DEG:MM with CAM one of {', '.join(rig.ids)}, "
                             "e.g. move=cam2:300:0.3:2") from None


def open_sim(url: str, query: dict[str, str]) -> list[SimCamera]:
    def number(key: str, default, kind=int, low=0, high=None):
        try:
            value = kind(query.get(key, default))
        except ValueError:
            raise CameraUrlError(f"{url}: {key}={query[key]!r} is not a number") from None
        if not low <= value <= (value if high is None else high):  # NaN fails too
            raise CameraUrlError(f"{url}: {key} must be at least {low}" + (f" and at most {high}" if high else "")
                                 + f"; got {query[key]}")
        return value

    n = number("cameras", 4, low=2, high=MAX_CAMERAS)
    seed = number("seed", 0, high=MAX_SEED)
    frames = number("frames", UNSCRIPTED_WAND_FRAMES, low=1, high=MAX_WAND_FRAMES)
    static = number("static", 0, high=MAX_STATIC_FRAMES)
    noise = number("noise", 2.0, float, high=MAX_NOISE)
    lframe = query.get("lframe", "remove")
    bits = number("bits", 8)
    if lframe not in ("remove", "keep") or bits not in (8, 16):
        raise CameraUrlError(f"{url}: lframe must be 'remove' or 'keep' and bits 8 or 16")
    markers = number("take", 0, high=MAX_TAKE_MARKERS)
    rig, truth = _truth(n, seed, frames)
    if "move" in query and not markers:
        raise CameraUrlError(f"{url}: move= needs a take (take=N markers on moving bodies)")
    scene = SimScene(rig=rig, truth=truth, static_frames=static, wand_frames=frames,
                     keep_lframe=lframe == "keep", noise=noise, bits=bits,
                     drops=parse_drops(query.get("drop", ""), rig.ids, url), seed=seed, url=url,
                     fixed_static="static" in query, fixed_wand="frames" in query,
                     take=_take_markers(seed, frames, markers) if markers else None,
                     moves=(_parse_move(query["move"], rig, seed, url),) if "move" in query else ())
    return [SimCamera(cid, url, scene, i) for i, cid in enumerate(rig.ids)]
