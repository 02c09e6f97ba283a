"""Rendering: rgb_array frames that show the episode, real-time frame rate, human mode under Agg."""

import warnings

import gymnasium as gym
import numpy as np
import pytest
from helpers import ENV_IDS, GAIN_SCHEDULE, PID_TUNE, SERVO

import gripper_env  # noqa: F401

POSITION_RGB = (31, 119, 180)  # matplotlib's C0: the position line


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_rgb_array(env_id):
    env = gym.make(env_id, render_mode="rgb_array")
    env.reset(seed=0)
    first = env.render()
    for _ in range(3):
        *_, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            break
    image = env.render()
    for img in (first, image):
        assert isinstance(img, np.ndarray)
        assert img.dtype == np.uint8
        assert img.ndim == 3 and img.shape[2] == 3
        assert img.shape[0] > 100 and img.shape[1] > 100
    assert img.std() > 0  # something was drawn
    env.close()


def position_pixels(env, image):
    """(time s, angle deg) of every pixel drawn in the position colour inside the axes."""
    ax = env.unwrapped._renderer.plot.ax
    height = image.shape[0]
    rows, cols = np.nonzero(np.all(image == POSITION_RGB, axis=2))
    x, y = cols + 0.5, height - rows - 0.5  # pixel centres, display coordinates
    box = ax.bbox
    inside = (x > box.x0) & (x < box.x1) & (y > box.y0) & (y < box.y1)
    data = ax.transData.inverted().transform(np.column_stack([x[inside], y[inside]]))
    return data[:, 0], data[:, 1]


def test_frame_shows_the_episode_so_far():
    """The position line is drawn where the measured angle was, up to the current time only,
    and a reset clears it (the content of the frame, checked through the axes' transform)."""
    env = gym.make(SERVO, render_mode="rgb_array", residual="reference")
    env.reset(seed=0)
    t, _ = position_pixels(env, env.render())
    assert len(t) == 0  # nothing has happened yet
    measured = []
    for _ in range(300):  # 6 s: grip at 1 s, then held at 21 deg
        obs, *_ = env.step(np.zeros(1, np.float32))
        measured.append(obs[0] * 35.5 + 56.5)
        if len(measured) % 100 == 0:
            image = env.render()  # frames every 2 s: only the new segments are drawn each time
    t, angle = position_pixels(env, image)
    assert t.max() == pytest.approx(6.0, abs=0.1) and t.min() == pytest.approx(0.0, abs=0.1)
    px_deg = np.diff(env.unwrapped._renderer.plot.ax.get_ylim())[0] / 200  # about a pixel
    for t0, expected in ((0.5, measured[24]), (4.0, measured[199]), (5.9, measured[294])):
        near = np.abs(t - t0) < 0.05
        assert near.any()
        assert np.median(angle[near]) == pytest.approx(expected, abs=2 + 2 * px_deg)
    env.reset(seed=1)
    t, _ = position_pixels(env, env.render())
    assert len(t) == 0


@pytest.mark.parametrize(("period", "fps"), [(0.020, 50.0), (0.040, 25.0)])
def test_render_fps_is_real_time(period, fps):
    env = gym.make(GAIN_SCHEDULE, render_mode="rgb_array", control_period_s=period)
    assert env.metadata["render_fps"] == fps


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_human_under_agg(env_id):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        env = gym.make(env_id, render_mode="human")
        env.reset(seed=0)
        env.step(env.action_space.sample())
        assert env.render() is None
        env.close()


def test_the_command_has_its_own_axis_that_holds_every_command():
    """Below the angle, the controller's output on its own axis, the servo's range dotted; a
    command beyond the axis widens it and the frame is drawn again whole (nothing cut at the
    edge, nothing lost)."""
    env = gym.make(GAIN_SCHEDULE, render_mode="rgb_array")
    env.reset(seed=0)
    env.action_space.seed(0)
    first = None
    for i in range(400):
        env.step(env.action_space.sample())
        if i % 50 == 49:
            image = env.render()
            first = first or env.unwrapped._renderer.plot.cax.get_ylim()
    plot = env.unwrapped._renderer.plot
    _, series = env.unwrapped._renderer.recorder.series()
    lo, hi = plot.cax.get_ylim()
    command = series["command"]
    assert command.max() > 180.0 or command.min() < 0.0  # gains that push the PID's output out
    assert lo < min(0.0, command.min()) and hi > max(180.0, command.max())
    assert (lo, hi) != first  # widened on the way
    levels = sorted(line.get_ydata()[0] for line in plot.cax.lines if line.get_linestyle() == ":")
    assert levels == [0.0, 180.0]
    t, _ = position_pixels(env, image)
    assert t.min() == pytest.approx(0.0, abs=0.1)  # the redraw kept the episode's start
    env.close()


def test_a_pid_tune_frame_holds_the_whole_runs_command():
    env = gym.make(PID_TUNE, render_mode="rgb_array")
    env.reset(seed=0)
    env.step(np.ones(env.action_space.shape, np.float32))  # the largest gains
    env.render()
    renderer = env.unwrapped._renderer
    lo, hi = renderer.plot.cax.get_ylim()
    u = renderer.run[2]
    assert lo < min(0.0, u.min()) and hi > max(180.0, u.max())
    env.close()
