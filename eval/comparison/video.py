"""Videos of episodes: the robot, its reference path ahead, the platform's path behind, the objects and the conveyors.

:func:`record_episode` runs one seeded episode with :func:`eval.episodes.run_episode` and renders it offscreen
(``mujoco.Renderer``; headless with ``MUJOCO_GL=egl``) to an MP4 file (imageio with its ffmpeg plugin,
``imageio-ffmpeg``) or, where ffmpeg is unavailable, a GIF. The video runs in the episode's time: frame j shows the
state at ``j / fps`` seconds. The paths are drawn into the scene's user geoms, never into the model, so filming
leaves the episode as it is, step for step. :func:`film_first_episodes` films the first episode of each row of a
comparison (``python -m eval --video``).
"""

from __future__ import annotations

import dataclasses
import itertools
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import imageio.v2 as imageio
import mujoco
import numpy as np
from numpy.typing import NDArray
from PIL import Image, ImageDraw, ImageFont

from controllers.base import Controller
from controllers.registry import ControllerSetup, controller_label
from delta_env.config import DEFAULT_PAYLOAD_SIZE, SUCTION_CUP_OFFSET
from delta_env.env import DeltaPickPlaceEnv
from delta_env.scenario import Scenario
from delta_env.scene import PAYLOAD_RGBA, RENDER_SIZE
from eval.episodes import EpisodeRecord, run_episode
from eval.processes import run_jobs
from eval.work import WorkUnit, unit_episode

DEFAULT_FPS = 30.0
"""Frames per second of a video (Hz)."""

VIDEO_SIZE = RENDER_SIZE
"""Width and height of a video (px): the env's render size (:data:`delta_env.scene.RENDER_SIZE`)."""

CAMERA = {"lookat": (0.0, 0.0, -0.62), "distance": 2.15, "azimuth": 120.0, "elevation": -24.0}
"""The free camera of a video: the robot from above its base down to the conveyors, from the pick conveyor's side."""

PATH_SAMPLE = 0.01
"""Spacing in time (s) of the points of the drawn reference and platform paths."""

REFERENCE_RGBA = (0.1, 0.75, 0.95, 1.0)
"""Colour of the reference path still ahead (cyan)."""

PLATFORM_RGBA = (0.95, 0.4, 0.05, 1.0)
"""Colour of the platform's path so far (orange)."""

PATH_WIDTH = 4.0
"""Width (px) of the drawn paths' lines (lines, not capsules: a fraction of the rendering time of a frame)."""

GIF_NOTE = "ffmpeg is unavailable (install imageio-ffmpeg): wrote a GIF instead of an MP4"
"""What a caller is told when a video is a GIF."""


@dataclass(frozen=True)
class Video:
    """A video written by :func:`record_episode`.

    Attributes:
        path: The file (``.mp4``, or ``.gif`` where ffmpeg is unavailable).
        frames: Frames written.
        fps: Frames per second (Hz).
        size: Width and height (px).
        duration: The episode's duration (s): steps times the control period.
    """

    path: Path
    frames: int
    fps: float
    size: tuple[int, int]
    duration: float


def rendering_error() -> str | None:
    """Why MuJoCo cannot render offscreen in this process (no OpenGL context), or None if it can."""
    model = mujoco.MjModel.from_xml_string("<mujoco><worldbody><geom size='0.1'/></worldbody></mujoco>")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # glfw warns before it fails
            mujoco.Renderer(model, 8, 8).close()
    except Exception as error:
        return (
            f"MuJoCo cannot render offscreen ({type(error).__name__}: {str(error).splitlines()[0]}); "
            "set MUJOCO_GL=egl (or osmesa) before starting Python to render without a display"
        )
    return None


def _mp4_available() -> bool:
    try:
        import imageio_ffmpeg  # noqa: F401
    except ImportError:
        return False
    return True


def _writer(path: Path, fps: float) -> tuple[Any, Path]:
    """An imageio writer of an MP4 at ``path`` (H.264), else of a GIF beside it; and the path written."""
    if _mp4_available():
        # yuv420p: the pixel format every player reads; 960 x 720 are multiples of the codec's 16 px blocks.
        writer = imageio.get_writer(path, format="FFMPEG", fps=fps, codec="libx264", pixelformat="yuv420p", quality=7)
        return writer, path
    gif = path.with_suffix(".gif")
    return imageio.get_writer(gif, format="GIF", mode="I", duration=1e3 / fps, loop=0), gif


class _Filmer:
    """Renders the frames of one episode as :func:`eval.episodes.run_episode` steps it (its ``after_step``)."""

    def __init__(self, env: DeltaPickPlaceEnv, writer: Any, fps: float, size: tuple[int, int], title: str) -> None:
        self.env, self.writer, self.fps, self.title = env, writer, fps, title
        width, height = size
        self.renderer = mujoco.Renderer(env.plant.model, height=height, width=width)
        self.camera = mujoco.MjvCamera()
        self.camera.type = mujoco.mjtCamera.mjCAMERA_FREE
        for name, value in CAMERA.items():
            setattr(self.camera, name, value)
        self.path_stride = max(1, round(PATH_SAMPLE / env.dt))
        self.platform_path: list[tuple[float, float, float]] = []
        self.frames = 0
        self.font = ImageFont.load_default(size=max(12, height // 32))

    def __call__(self, step: int) -> None:
        if step % self.path_stride == 0:
            self.platform_path.append(self.env.plant.platform_point())
        # Frame j shows the state at j / fps: the first step that reaches that time (a millisecond-accurate clock).
        while self.frames <= step * self.env.dt * self.fps + 1e-9:
            self.writer.append_data(self._frame(step))
            self.frames += 1

    def _frame(self, step: int) -> NDArray[np.uint8]:
        env = self.env
        self.renderer.update_scene(env.plant.data, camera=self.camera)
        scene = self.renderer.scene
        scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = 0  # the floor's faint mirror image: a third of a frame's time
        trajectory = env.trajectory
        # The reference ahead, the platform's path behind: where both are drawn they would fight for the same pixels.
        _add_path(scene, trajectory.xyz[step :: self.path_stride], REFERENCE_RGBA)
        _add_path(scene, np.array([*self.platform_path, env.plant.platform_point()]), PLATFORM_RGBA)
        below = np.array([0.0, 0.0, SUCTION_CUP_OFFSET + 0.5 * DEFAULT_PAYLOAD_SIZE[2]])
        for place in trajectory.place_indices:
            if place <= step:  # an object placed: drawn where it was released (the model's object moves on)
                _add_geom(
                    scene,
                    mujoco.mjtGeom.mjGEOM_BOX,
                    0.5 * np.asarray(DEFAULT_PAYLOAD_SIZE),
                    trajectory.xyz[place] - below,
                    PAYLOAD_RGBA,
                )
        image = Image.fromarray(self.renderer.render())
        self._caption(image, step)
        return np.asarray(image)

    def _caption(self, image: Image.Image, step: int) -> None:
        """The row, the time and the tracking error at the top; the colours of the paths at the bottom."""
        env, draw = self.env, ImageDraw.Draw(image)
        error = np.linalg.norm(np.array(env.plant.platform_point()) - env.trajectory.xyz[step])
        margin = self.font.size // 2
        draw.text(
            (margin, margin),
            f"{self.title}    t = {step * env.dt:5.2f} s    tracking error {1e3 * error:6.2f} mm",
            fill="white",
            font=self.font,
        )
        bottom = image.height - margin - self.font.size
        draw.text((margin, bottom), "reference path ahead", fill=_rgb(REFERENCE_RGBA), font=self.font)
        offset = margin + draw.textlength("reference path ahead    ", font=self.font)
        draw.text((offset, bottom), "platform path", fill=_rgb(PLATFORM_RGBA), font=self.font)


def _rgb(rgba: Sequence[float]) -> tuple[int, int, int]:
    red, green, blue = (round(255 * channel) for channel in rgba[:3])
    return red, green, blue


def _add_geom(
    scene: mujoco.MjvScene, kind: int, size: NDArray[np.float64], position: NDArray[np.float64], rgba: Sequence[float]
) -> None:
    """A user geom of ``kind`` with half-sizes ``size`` (m) at ``position`` (m), unrotated; none once the scene is
    full."""
    if scene.ngeom >= scene.maxgeom:
        return
    mujoco.mjv_initGeom(
        scene.geoms[scene.ngeom], kind, size, position, np.eye(3).ravel(), np.asarray(rgba, dtype=np.float32)
    )
    scene.ngeom += 1


def _add_path(scene: mujoco.MjvScene, points: NDArray[np.float64], rgba: Sequence[float]) -> None:
    """The polyline through ``points`` (m), ``(n, 3)``, as lines :data:`PATH_WIDTH` wide, as far as the scene has
    room."""
    colour = np.asarray(rgba, dtype=np.float32)
    for start, end in itertools.pairwise(points):
        if scene.ngeom >= scene.maxgeom:
            return
        if not np.all(np.isfinite(start) & np.isfinite(end)):
            continue
        geom = scene.geoms[scene.ngeom]
        mujoco.mjv_initGeom(geom, mujoco.mjtGeom.mjGEOM_LINE, np.zeros(3), np.zeros(3), np.eye(3).ravel(), colour)
        mujoco.mjv_connector(geom, mujoco.mjtGeom.mjGEOM_LINE, PATH_WIDTH, start, end)
        scene.ngeom += 1


def record_episode(
    env: DeltaPickPlaceEnv,
    controller: Controller,
    path: str | Path,
    seed: int,
    *,
    fps: float = DEFAULT_FPS,
    size: tuple[int, int] = VIDEO_SIZE,
    title: str = "",
    payload_masses: Sequence[float] | None = None,
) -> tuple[EpisodeRecord, Video]:
    """Run the episode ``seed`` of ``controller`` on ``env`` (:func:`eval.episodes.run_episode`) and film it.

    Args:
        env: The environment (not wrapped), in the process's OpenGL context (``MUJOCO_GL=egl`` headless).
        controller: As :func:`~eval.episodes.run_episode`'s.
        path: The video's file, ``.mp4``; where ffmpeg is unavailable, a ``.gif`` beside it is written instead
            (:data:`GIF_NOTE`).
        seed: Episode seed.
        fps: Frames per second (Hz), in [1, 1 / env.dt].
        size: Width and height (px), each at least 16 and at most the model's offscreen framebuffer's.
        title: Text at the top of every frame (e.g. the row's label), beside the time and the tracking error.
        payload_masses: As :func:`~eval.episodes.run_episode`'s.

    Returns:
        The episode's record (the same as without filming) and the video written.

    Raises:
        ValueError: on a bad ``path``, ``fps`` or ``size`` (named in the message).
    """
    path = Path(path)
    if path.suffix != ".mp4":
        raise ValueError(f"path must end in .mp4, got {str(path)!r}")
    top_fps = 1.0 / env.dt
    if not (isinstance(fps, int | float) and 1.0 <= fps <= top_fps):
        raise ValueError(
            f"fps must be a number in [1, {top_fps:g}] (one frame per control period at most), got {fps!r}"
        )
    visual = env.plant.model.vis.global_
    for name, value, largest in zip(("width", "height"), size, (visual.offwidth, visual.offheight), strict=True):
        if not (isinstance(value, int) and 16 <= value <= largest):
            raise ValueError(f"video {name} must be an integer in [16, {largest}] px, got {value!r}")
    writer, written = _writer(path, fps)
    filmer = None
    try:
        filmer = _Filmer(env, writer, fps, size, title)
        record = run_episode(env, controller, seed, payload_masses, after_step=filmer)
    finally:
        writer.close()
        if filmer is not None:
            filmer.renderer.close()
    duration = len(record.tracking_error) * env.dt
    return record, Video(written, filmer.frames, float(fps), size, duration)


def _film(job: tuple[WorkUnit, ControllerSetup, Path, float]) -> Video:
    """Film one unit's episode, its controller knowing the setup, into its path (picklable: what
    :func:`eval.processes.run_jobs` maps)."""
    unit, setup, path, fps = job
    env, controller = unit_episode(unit, setup)
    try:
        return record_episode(env, controller, path, unit.seed, fps=fps, title=controller_label(unit.controller))[1]
    finally:
        env.close()


def film_first_episodes(
    scenario: Scenario,
    setup: ControllerSetup,
    keys: Sequence[str],
    seed: int,
    n_cycles: int,
    folder: Path,
    *,
    fps: float = DEFAULT_FPS,
    workers: int = 1,
    progress: Any = None,
) -> list[Video]:
    """Film episode ``seed`` of ``scenario`` (``n_cycles`` cycles) with each controller of ``keys`` (what it knows:
    ``setup``) into ``folder/video_<key>.mp4`` (or ``.gif``), on ``workers`` processes, advancing the tqdm bar
    ``progress`` once per video; the videos in the order of ``keys``."""
    scenario = dataclasses.replace(scenario, task=dataclasses.replace(scenario.task, n_cycles=n_cycles))
    jobs = [(WorkUnit(scenario, key, seed), setup, folder / f"video_{_file_part(key)}.mp4", fps) for key in keys]
    return run_jobs(_film, jobs, workers=workers, progress=progress)


def _file_part(key: str) -> str:
    """A controller key as part of a file name (a user controller's ``module:attr`` has a colon)."""
    return "".join(character if character.isalnum() or character in "-_" else "_" for character in key)


def video_lines(videos: Sequence[Video]) -> list[str]:
    """A summary's lines on ``videos``: one per video, and the note if any is a GIF."""
    lines = [
        f"- {video.path.name}: {video.frames} frames at {video.fps:g} fps, {video.size[0]} x {video.size[1]} px, "
        f"{video.duration:.2f} s of episode"
        for video in videos
    ]
    if any(video.path.suffix == ".gif" for video in videos):
        lines.append(f"Note: {GIF_NOTE}.")
    return lines
