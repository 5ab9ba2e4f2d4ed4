"""Videos of episodes (eval.comparison.video): read back, their frames counted against the episode's duration and frame
rate; the conveyors they show are drawn only."""

from __future__ import annotations

import math
from pathlib import Path

import imageio.v2 as imageio
import mujoco
import numpy as np
import pytest

from controllers.registry import ControllerSetup, build_controller
from delta_env.config import PlantConfig
from delta_env.env import DeltaPickPlaceEnv
from delta_env.scene import build_model
from eval.comparison import video
from eval.comparison.__main__ import parse_args
from eval.comparison.video import record_episode
from eval.episodes import run_episode


@pytest.fixture(scope="module")
def filmed(
    tmp_path_factory: pytest.TempPathFactory, controller_setup: ControllerSetup, opengl_context: None
) -> tuple[Path, object, object, object]:
    """One cycle of PD on seed 3 filmed at 40 fps, 320 x 240 px, and the same episode unfilmed."""
    path = tmp_path_factory.mktemp("video") / "pd.mp4"
    env = DeltaPickPlaceEnv(n_cycles=1)
    record, video = record_episode(
        env, build_controller("pd", controller_setup, env), path, 3, fps=40.0, size=(320, 240), title="PD"
    )
    plain = run_episode(env, build_controller("pd", controller_setup, env), 3)
    return path, record, video, plain


def test_a_video_has_a_frame_every_one_over_fps_seconds_of_the_episode(filmed: tuple) -> None:
    path, record, video, _ = filmed
    duration = len(record.tracking_error) * 1e-3
    assert video.path == path and video.duration == pytest.approx(duration)
    assert duration > 1.0  # a whole cycle: the count below is a real one
    with imageio.get_reader(path) as reader:
        frames = reader.count_frames()
        meta = reader.get_meta_data()
        first = reader.get_data(0)
    assert frames == video.frames == math.floor(duration * 40.0 + 1e-9) + 1
    assert meta["fps"] == pytest.approx(40.0)
    assert meta["size"] == (320, 240) and first.shape == (240, 320, 3)
    assert first.std() > 10.0  # a picture, not a blank frame


def test_filming_leaves_the_episode_as_it_is(filmed: tuple) -> None:
    _, record, _, plain = filmed
    np.testing.assert_array_equal(record.tracking_error, plain.tracking_error)
    np.testing.assert_array_equal(record.torque, plain.torque)


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        ({"path": "a.avi"}, "path must end in .mp4"),
        ({"fps": 0.5}, r"fps must be a number in \[1, 1000\]"),
        ({"fps": 2000}, r"fps must be a number in \[1, 1000\]"),
        ({"size": (2000, 720)}, r"video width must be an integer in \[16, 1280\] px"),
        ({"size": (960, 8)}, r"video height must be an integer in \[16, 720\] px"),
    ],
)
def test_bad_video_settings_are_refused(
    arguments: dict, message: str, controller_setup: ControllerSetup, tmp_path: Path
) -> None:
    env = DeltaPickPlaceEnv(n_cycles=1)
    settings = {"path": tmp_path / "a.mp4", **arguments}
    with pytest.raises(ValueError, match=message):
        record_episode(env, build_controller("pd", controller_setup, env), seed=0, **settings)
    assert not any(tmp_path.iterdir())


def test_the_conveyors_are_drawn_only() -> None:
    model = build_model(PlantConfig())
    conveyor = [n for n in range(model.ngeom) if "conveyor" in mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, n)]
    assert len(conveyor) == 2 * (1 + 2 + 4)  # two conveyors: a belt, two rails, four legs
    assert all(model.geom_bodyid[n] == 0 for n in conveyor)
    assert not model.geom_contype[conveyor].any() and not model.geom_conaffinity[conveyor].any()
    assert (model.vis.global_.offwidth, model.vis.global_.offheight) == (1280, 720)


def test_without_ffmpeg_a_video_is_a_gif(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, controller_setup: ControllerSetup, opengl_context: None
) -> None:
    monkeypatch.setattr(video, "_mp4_available", lambda: False)
    env = DeltaPickPlaceEnv(n_cycles=1)
    record, written = record_episode(
        env, build_controller("pd", controller_setup, env), tmp_path / "pd.mp4", 3, fps=10.0, size=(64, 48)
    )
    assert written.path == tmp_path / "pd.gif" and not (tmp_path / "pd.mp4").exists()
    frames = imageio.mimread(written.path)
    assert len(frames) == written.frames == math.floor(len(record.tracking_error) * 1e-3 * 10.0 + 1e-9) + 1
    assert frames[0].shape[:2] == (48, 64)
    with imageio.get_reader(written.path) as reader:
        assert reader.get_meta_data()["duration"] == pytest.approx(100.0)  # ms a frame: 10 fps
    assert video.GIF_NOTE in "\n".join(video.video_lines([written]))


def test_video_without_an_opengl_context_is_a_usage_error(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture, opengl_context: None
) -> None:
    assert video.rendering_error() is None  # this machine renders
    monkeypatch.setattr(video, "rendering_error", lambda: "MuJoCo cannot render offscreen (test); set MUJOCO_GL=egl")
    with pytest.raises(SystemExit) as exit_info:
        parse_args(["--video", "--controllers", "pd"])
    assert exit_info.value.code == 2
    assert "--video: MuJoCo cannot render offscreen (test); set MUJOCO_GL=egl" in capsys.readouterr().err
