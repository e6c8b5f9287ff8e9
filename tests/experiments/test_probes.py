"""experiments.probes: the variants of the margin rule do what they say."""

import numpy as np
from iscc_gym.agents import MarginPolicy

from experiments.probes import MarginVariant, markdown
from iscc_gym.envs.vector import ISCCVectorEnv
from iscc_gym.sim.task import action_to_split


def _obs(n=6, steps=7):
    env = ISCCVectorEnv(num_envs=n)
    obs, _ = env.reset(seed=list(range(500_000, 500_000 + n)))
    for _ in range(steps):
        obs, *_ = env.step(np.zeros((n, 3), np.float32))
    return obs


def test_neutral_variant_is_the_rule():
    base = MarginPolicy(3.5, 5.0, 0.03)
    obs = _obs()
    np.testing.assert_array_equal(MarginVariant(base, 5000).predict(obs)[0], base.predict(obs)[0])


def test_burst_sensing_and_lost_command_boost():
    base = MarginPolicy(3.5, 5.0, 0.03)
    obs = _obs()  # after 7 slots: slot 7
    slot = np.rint((1 - obs[:, 22]) * 5000).astype(int)
    assert np.all(slot == 7)
    on = action_to_split(MarginVariant(base, 5000, burst_every=7, burst=0.2, floor=0.01).predict(obs)[0])
    off = action_to_split(MarginVariant(base, 5000, burst_every=3, burst=0.2, floor=0.01).predict(obs)[0])
    assert np.all(on[:, 0] >= 0.2 - 1e-6)
    assert np.all(off[:, 0] >= 0.01 - 1e-6) and np.any(np.abs(off[:, 0] - 0.01) < 1e-5)
    lost = obs.copy()
    lost[:, 20] = 0.0
    a = action_to_split(MarginVariant(base, 5000, lost_boost=2.0).predict(lost)[0])
    b = action_to_split(base.predict(lost)[0])
    fits = a[:, 0] > 0.03 + 1e-6  # where the doubled control share still fits above the floor
    np.testing.assert_allclose(a[fits, 1], 2 * b[fits, 1], rtol=1e-5)


def test_markdown_lists_every_probe():
    rows = [{"probe": "margin (tuned)", "base": "-", "reward": -1.0, "diff": 0.0, "ci95": [0, 0]},
            {"probe": "x", "base": "margin", "reward": -2.0, "diff": -1.0, "ci95": [-1.5, -0.5]}]
    text = markdown(rows, "python -m experiments.probes", [500000, 500001])
    assert "| x | -2.0 | -1.0 [-1.5, -0.5] | margin |" in text
