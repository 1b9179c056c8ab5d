"""Interactive camera and playback state of the desktop app (pure math: no window, no GL).

`CameraController` keeps a look-at rig: a target point, a distance, and the eye's azimuth/elevation around the
target in the world-up frame of `splatreel.cameras.orbit_position`. Orbit rotates the eye around the target, pan
slides both, zoom changes the distance, fly (WASD/QE) moves both along the view axes and mouse-look turns the view
around the eye. Snapping to a dataset camera shows that exact pose (roll and intrinsics' FOV included) until the
next interaction.

`Playback` is the one timeline the app uses: play/pause, speed, loop or stop at the end of the time range.

`Resolution` picks the share of the window's pixels the app renders: a fixed scale at rest, and while the view
moves a lower one that keeps frames within a time budget (a software rasterizer pays per pixel).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from splatreel.cameras import UP_AXES, Camera, look_at, orbit_position

from .trajectory import Framing

_MAX_ELEVATION = 89.0


def _direction(elevation: float, azimuth: float, up: str) -> np.ndarray:
    """Unit vector from the target to the eye (`orbit_position` at radius 1)."""
    return orbit_position(elevation, azimuth, 1.0, up)


@dataclass
class CameraController:
    """Orbit / pan / zoom / fly camera (angles in degrees, up axis 'y' or 'z')."""

    target: np.ndarray = field(default_factory=lambda: np.zeros(3))
    distance: float = 3.0
    azimuth: float = 45.0
    elevation: float = 20.0
    fov: float = 40.0
    up: str = "z"
    #: exact camera-to-world pose shown instead of the rig (after snapping to a dataset camera)
    exact_c2w: np.ndarray | None = None
    #: a snapped camera's own vertical fov (degrees) while `exact_c2w` is set
    exact_fov: float | None = None

    @property
    def eye(self) -> np.ndarray:
        if self.exact_c2w is not None:
            return self.exact_c2w[:3, 3].copy()
        return self.target + self.distance * _direction(self.elevation, self.azimuth, self.up)

    def camera(self, width: int, height: int) -> Camera:
        """The current view rendering `width` x `height` pixels."""
        if self.exact_c2w is not None:
            return Camera.from_fov(self.exact_c2w, width, height, fov_y_deg=self.exact_fov or self.fov)
        return look_at(self.eye, self.target, self.up, self.fov, width, height)

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World (right, down, forward) axes of the current view."""
        c2w = self.camera(2, 2).c2w
        return c2w[:3, 0].copy(), c2w[:3, 1].copy(), c2w[:3, 2].copy()

    def _release_exact(self) -> None:
        """Leave a snapped pose: continue from its position and viewing direction with the rig."""
        if self.exact_c2w is None:
            return
        eye, forward = self.exact_c2w[:3, 3].copy(), self.exact_c2w[:3, 2].copy()
        self.exact_c2w, self.exact_fov = None, None
        self.look_from(eye, forward)

    def look_from(self, eye: np.ndarray, forward: np.ndarray) -> None:
        """Place the rig at `eye` looking along `forward`, keeping the current distance to the target."""
        up = np.array(UP_AXES[self.up])
        back = -np.asarray(forward, np.float64) / max(np.linalg.norm(forward), 1e-12)
        self.elevation = float(np.clip(math.degrees(math.asin(np.clip(back @ up, -1, 1))), -_MAX_ELEVATION,
                                       _MAX_ELEVATION))
        # azimuth from the components along the two horizontal axes of orbit_position
        x_axis = _direction(0.0, 0.0, self.up)
        y_axis = _direction(0.0, 90.0, self.up)
        self.azimuth = math.degrees(math.atan2(back @ y_axis, back @ x_axis))
        self.target = np.asarray(eye, np.float64) - self.distance * _direction(self.elevation, self.azimuth, self.up)

    # --- interaction ----------------------------------------------------------------------------------------
    def orbit(self, dx: float, dy: float, degrees_per_pixel: float = 0.3) -> None:
        """Rotate the eye around the target by a mouse drag of (dx, dy) pixels."""
        self._release_exact()
        self.azimuth -= dx * degrees_per_pixel
        self.elevation = float(np.clip(self.elevation + dy * degrees_per_pixel, -_MAX_ELEVATION, _MAX_ELEVATION))

    def look(self, dx: float, dy: float, degrees_per_pixel: float = 0.2) -> None:
        """Turn the view around the eye (fly mode mouse-look)."""
        self._release_exact()
        eye = self.eye
        self.azimuth -= dx * degrees_per_pixel
        self.elevation = float(np.clip(self.elevation + dy * degrees_per_pixel, -_MAX_ELEVATION, _MAX_ELEVATION))
        self.target = eye - self.distance * _direction(self.elevation, self.azimuth, self.up)

    def pan(self, dx: float, dy: float, viewport_height: int) -> None:
        """Slide target and eye so that the scene follows a drag of (dx, dy) pixels."""
        self._release_exact()
        right, down, _ = self.basis()
        scale = 2.0 * self.distance * math.tan(math.radians(0.5 * self.fov)) / max(viewport_height, 1)
        self.target = self.target - scale * (dx * right + dy * down)

    def zoom(self, steps: float) -> None:
        """Dolly towards (steps > 0) or away from the target; 10% per step."""
        self._release_exact()
        self.distance = float(np.clip(self.distance * 0.9 ** steps, 1e-4, 1e6))

    def fly(self, forward: float, right: float, upward: float, dt: float, speed: float) -> None:
        """Move eye and target along the view axes (WASD / QE), `speed` world units per second."""
        if forward == right == upward == 0:
            return
        self._release_exact()
        r, d, f = self.basis()
        self.target = self.target + dt * speed * (forward * f + right * r - upward * d)

    def snap(self, camera: Camera) -> None:
        """Show exactly `camera`'s pose and vertical FOV (until the next interaction)."""
        self.exact_c2w = np.array(camera.c2w)
        self.exact_fov = math.degrees(camera.fov_y)

    def reset(self, framing: Framing, azimuth: float = 45.0, elevation: float = 20.0) -> None:
        """Frame a model: look at its centre from a distance that fits it in the field of view."""
        self.exact_c2w, self.exact_fov = None, None
        self.target = np.array(framing.center, np.float64)
        self.distance = framing.distance(self.fov)
        self.azimuth, self.elevation = azimuth, elevation


#: Without frame times, `Playback.step` moves by one frame of playback at this rate (speed 1).
STEP_FPS = 30


@dataclass
class Playback:
    """Model time of the app: ``time`` in ``time_range``, advancing while ``playing``.

    ``speed`` 1 plays one pass through the time range every `loop_seconds`; ``loop`` wraps at the end, otherwise
    playback stops there. `step` moves by one frame: to the neighbouring time of ``frame_times`` (a keyframed
    model's keys, the training dataset's frame times) or, without them, by one frame of playback at
    `STEP_FPS` frames per second.
    """

    time_range: tuple[float, float] = (0.0, 1.0)
    time: float = 0.0
    playing: bool = True
    speed: float = 1.0
    loop: bool = True
    loop_seconds: float = 2.0
    frame_times: tuple[float, ...] = ()

    def advance(self, dt: float) -> float:
        """Move time on by `dt` wall-clock seconds; returns the new time."""
        if not self.playing:
            return self.time
        t0, t1 = self.time_range
        span = t1 - t0
        t = self.time + dt * self.speed * span / self.loop_seconds
        if self.loop:
            t = t0 + math.fmod(t - t0, span)
            if t < t0:
                t += span
        elif t >= t1 or t <= t0:
            t = min(max(t, t0), t1)
            self.playing = False
        self.time = t
        return t

    def step(self, frames: int) -> float:
        """Pause and move `frames` frames on (negative: back), wrapping round when looping; returns the new time."""
        self.playing = False
        t0, t1 = self.time_range
        times = np.unique(np.clip(self.frame_times, t0, t1)) if len(self.frame_times) else \
            np.linspace(t0, t1, max(2, round(STEP_FPS * self.loop_seconds) + 1))
        eps = 1e-6 * max(t1 - t0, 1e-12)  # a time within rounding of a frame is on it
        if frames >= 0:  # the first frame after the current time is one frame on
            k = int(np.searchsorted(times, self.time + eps, side="right")) + frames - 1
        else:  # the last frame before it is one frame back
            k = int(np.searchsorted(times, self.time - eps, side="left")) + frames
        k = k % len(times) if self.loop else min(max(k, 0), len(times) - 1)
        self.time = float(times[k])
        return self.time

    def set_range(self, time_range: tuple[float, float]) -> None:
        self.time_range = (float(time_range[0]), float(time_range[1]))
        self.time = min(max(self.time, self.time_range[0]), self.time_range[1])


#: The resolutions `Resolution` chooses between, as a share of the window's width and height: steps of 1/8, so that
#: the render targets are re-made only when the step changes.
RESOLUTION_STEPS: tuple[float, ...] = tuple(k / 8 for k in range(2, 9))


@dataclass
class Resolution:
    """Render resolution of the app, as a share of the window's pixels per axis.

    At rest the app draws at `scale` (1 = every window pixel). While the view changes and `adaptive` is on (the
    camera moves, or the animation plays unless `sharp_playback`: `changing`), it draws at the largest of
    `RESOLUTION_STEPS` (at most `scale`) whose predicted draw time fits `budget_ms`, and the image is stretched to
    the window; the first frame at rest (still camera, paused) is sharp again.

    Predictions come from what each step measured lately (a running average, and when the current step gets
    cheaper or dearer the other steps' averages follow in proportion; measurements older than `memory` frames, or
    of another window size, are forgotten); a step not measured yet is predicted from the nearest measured one in
    proportion to pixels. Draw time is not all per pixel (on llvmpipe each splat also costs about
    a microsecond to set up), so when no step fits the budget the app takes the largest step within 25% of the
    fastest rather than the smallest one. It moves up to an unmeasured step only with 20% to spare, so it does not
    flicker between two steps.
    """

    scale: float = 1.0
    adaptive: bool = True
    budget_ms: float = 40.0
    #: keep the full resolution while the animation plays under a still camera (only camera moves lower it)
    sharp_playback: bool = False
    memory: int = 120
    _measured: dict = field(default_factory=dict)  # step -> (running average of draw ms, frame number)
    _frame: int = 0
    _window: tuple = (0, 0)
    _current: float = 1.0

    @staticmethod
    def step_of(scale: float) -> float:
        """The step of `RESOLUTION_STEPS` nearest to `scale`."""
        return min(RESOLUTION_STEPS, key=lambda s: abs(s - scale))

    def observe(self, draw_ms: float, scale: float) -> None:
        """Record what a frame drawn at `scale` of the window cost."""
        if not (math.isfinite(draw_ms) and draw_ms >= 0):
            return
        self._frame += 1
        step = self.step_of(scale)
        previous = self._measured.get(step)
        ms = draw_ms if previous is None else 0.6 * previous[0] + 0.4 * draw_ms
        if previous is not None and previous[0] > 0:
            # the view got cheaper or dearer: assume the other steps did too, in proportion
            change = ms / previous[0]
            self._measured = {k: (v * change, seen) for k, (v, seen) in self._measured.items()}
        self._measured[step] = (ms, self._frame)

    def predicted_ms(self, step: float) -> tuple[float, bool] | None:
        """(predicted draw ms at `step`, whether it was measured there) or None with nothing measured."""
        return self._predictions([step]).get(step)

    def _predictions(self, steps) -> dict[float, tuple[float, bool]]:
        """`predicted_ms` of each of `steps` (empty with nothing measured lately)."""
        fresh = {k: ms for k, (ms, seen) in self._measured.items() if self._frame - seen < self.memory}
        if not fresh:
            return {}
        out = {}
        for step in steps:
            if step in fresh:
                out[step] = (fresh[step], True)
            else:
                nearest = min(fresh, key=lambda k: abs(k - step))
                out[step] = (fresh[nearest] * (step / nearest) ** 2, False)
        return out

    def changing(self, moving: bool, playing: bool) -> bool:
        """Whether a frame whose camera is `moving` and whose model time is `playing` (each: changed since the frame
        before; scrubbing and frame steps change the time too) may be drawn at a lower resolution (`choose`)."""
        return moving or (playing and not self.sharp_playback)

    def choose(self, changing: bool, width: int, height: int) -> float:
        """The scale of the next frame in a window of `width` x `height` pixels; `changing`: the view is changing
        (`changing`)."""
        top = self.step_of(self.scale)
        if (width, height) != self._window:
            if self._window != (0, 0):  # measured in another window size
                self._measured.clear()
            self._window = (width, height)
        if not (changing and self.adaptive):
            self._current = top
            return top
        steps = [s for s in RESOLUTION_STEPS if s <= top]
        predictions = self._predictions(steps)
        if not predictions:
            return min(self._current, top)
        limit = max(self.budget_ms, 1.25 * min(ms for ms, _ in predictions.values()))
        fitting = [s for s, (ms, measured) in predictions.items()
                   if ms <= (limit if (measured or s <= self._current) else 0.8 * limit)]
        self._current = max(fitting) if fitting else steps[0]
        return self._current


def scaled_size(width: int, height: int, scale: float) -> tuple[int, int]:
    """The image size drawn at `scale` of a `width` x `height` window (at least 1 x 1)."""
    return max(1, round(width * scale)), max(1, round(height * scale))
