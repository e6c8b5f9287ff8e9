"""iscc_gym.envs.render: the frames show the split the agent chose and the violations, and follow the episode."""

import gymnasium as gym
import numpy as np
import pytest

import iscc_gym
from iscc_gym.envs import render
from iscc_gym.sim.task import split_to_action

SEN, CTRL, COMM, RATE = (np.array([int(render._COLORS[k][i:i + 2], 16) for i in (1, 3, 5)])
                         for k in ("sen", "ctrl", "comm", "rate"))


def _mask(img, color, tol=12):
    return np.all(np.abs(img.astype(int) - color) <= tol, axis=-1)


def _play(split, steps=60, seed=0):
    env = gym.make(iscc_gym.ENV_ID, render_mode="rgb_array")
    env.reset(seed=seed)
    a = split_to_action(np.asarray(split, float))
    for _ in range(steps):
        env.step(a)
    return env, env.render()


def _split_panel(img, env):
    """The inside of the split axes (right, top), legend excluded."""
    ax = env.unwrapped._renderer._axes[2]
    x0, y0, x1, y1 = ax.bbox.extents
    h = img.shape[0]
    return img[int(h - y1) + 2:int(h - y0) - 2, int(x0) + 2:int(x1) - 2]


def _row_of(mask):
    rows = np.flatnonzero(mask.sum(axis=1) > 20)
    assert rows.size, "line not drawn"
    return rows.mean()


def test_frame_shape_and_type():
    _, img = _play((0.1, 0.2, 0.7), steps=3)
    assert img.shape == (400, 800, 3) and img.dtype == np.uint8


def test_split_lines_sit_at_the_played_shares():
    """A constant split draws each share as a horizontal line, higher on screen for a larger share."""
    env, img = _play((0.1, 0.3, 0.6))
    panel = _split_panel(img, env)
    y_sen, y_ctrl, y_comm = (_row_of(_mask(panel, c)) for c in (SEN, CTRL, COMM))
    assert y_comm < y_ctrl < y_sen  # image rows grow downwards
    # equal share steps map to equal pixel steps (a linear axis): 0.1 -> 0.3 -> 0.6
    assert (y_sen - y_ctrl) / (y_ctrl - y_comm) == pytest.approx(0.2 / 0.3, rel=0.15)


def _ticks(split, seed, steps=40):
    """Rate-violation tick pixels drawn, and the rate violations the env reported."""
    env = gym.make(iscc_gym.ENV_ID, render_mode="rgb_array")
    env.reset(seed=seed)
    a = split_to_action(np.asarray(split, float))
    violations = sum(env.step(a)[4]["cost_rate"] > 0 for _ in range(steps))
    return _mask(_split_panel(env.render(), env), RATE).sum(), violations


def test_rate_violations_are_marked_only_when_they_happen():
    starved, v_starved = _ticks((0.5, 0.5, 0.0), seed=0)
    some, v_some = _ticks((0.02, 0.08, 0.9), seed=1)
    none, v_none = _ticks((0.02, 0.08, 0.9), seed=2)
    assert (v_starved, v_none) == (40, 0) and 0 < v_some < 40
    assert none == 0 < some < starved


def test_frames_follow_steps_and_a_new_episode():
    env, first = _play((0.2, 0.2, 0.6), steps=5)
    env.step(split_to_action(np.array((0.6, 0.2, 0.2))))
    assert not np.array_equal(first, env.render())
    env.reset(seed=5)
    fresh = env.render()
    assert _mask(_split_panel(fresh, env), SEN).sum() == 0  # no slot played yet in this episode


def test_copies_and_pickles_draw_the_same_frame():
    import copy
    import pickle

    env, img = _play((0.2, 0.3, 0.5), steps=10)
    np.testing.assert_array_equal(copy.deepcopy(env.unwrapped).render(), img)
    np.testing.assert_array_equal(pickle.loads(pickle.dumps(env.unwrapped)).render(), img)
