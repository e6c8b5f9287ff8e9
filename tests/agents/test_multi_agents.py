"""The multi-drone baselines, training and evaluation commands (issue 16 items 4-6)."""

import gymnasium as gym
import numpy as np
import pytest
from iscc_gym.agents.margin import MarginPolicy
from iscc_gym.agents.multi import EqualShareSCA, JointSCA, MultiMarginPolicy, ScaledSensing, make_multi_policy
from iscc_gym.agents.sca_slot import SCAPolicy

import iscc_gym
from iscc_gym.analysis.sensing_share import crlb_trace
from iscc_gym.envs.multi import ISCCMultiEnv
from iscc_gym.sim.fleet import multi_split, shares_to_action


def _observations(k, n_steps=40, seed=0):
    env = ISCCMultiEnv(n_drones=k)
    obs, _ = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    out = [obs]
    for _ in range(n_steps):
        obs, *_ = env.step(rng.uniform(-1, 1, 3 * k).astype(np.float32))
        out.append(obs)
    return env.scenario, np.array(out)


def test_shares_to_action_inverts_the_action_map():
    rng = np.random.default_rng(0)
    alpha = rng.dirichlet(np.ones(12), size=20).reshape(20, 4, 3)
    np.testing.assert_allclose(multi_split(shares_to_action(alpha), 4), alpha, rtol=1e-6, atol=1e-7)
    with pytest.raises(ValueError, match="sum to 1"):
        shares_to_action(np.full((2, 3), 0.2))


def test_joint_sca_of_one_drone_is_algorithm_1_per_slot():
    """Bounds plus water-filling against the SCA iterations of SCAPolicy (an independent solver)."""
    s, obs = _observations(1)
    joint = JointSCA(s, 1).shares_batch(obs.reshape(-1, 1, 23))[:, 0]
    sca, _ = SCAPolicy(s, mode="per_slot").split_batch(obs)
    np.testing.assert_allclose(joint, sca, atol=1e-6)


def test_joint_sca_meets_the_bounds_and_equalises_the_marginal_crlb():
    s, obs = _observations(3)
    pol = JointSCA(s, 3)
    o = obs.reshape(-1, 3, 23)
    alpha = pol.shares_batch(o)
    np.testing.assert_allclose(alpha.sum((1, 2)), 1.0, atol=1e-9)
    coef, ctrl, comm = pol.terms(o)
    fits = ctrl.sum(-1) + comm.sum(-1) <= 1 - 3e-3
    assert fits.any()
    a = alpha[fits]
    np.testing.assert_allclose(a[..., 1], ctrl[fits], rtol=1e-12)
    np.testing.assert_allclose(a[..., 2], comm[fits], rtol=1e-12)
    # KKT: moving sensing between two drones never lowers the summed trace (finite differences)
    from iscc_gym.analysis.sensing_share import SensingCoefficients

    sub = SensingCoefficients(*(np.asarray(getattr(coef, f))[fits] if np.ndim(getattr(coef, f)) else getattr(coef, f)
                                for f in ("info_range", "info_az", "info_cross", "info_el", "info_vr", "prior")))
    base = crlb_trace(sub, a[..., 0])[0].sum(-1)
    for i, j in ((0, 1), (1, 2), (0, 2)):
        for d in (1e-4, -1e-4):
            moved = a[..., 0].copy()
            moved[:, i] += d
            moved[:, j] -= d
            ok = (moved > 0).all(-1)
            assert np.all(crlb_trace(sub, moved)[0].sum(-1)[ok] >= base[ok] * (1 - 1e-9))


def test_level_cap_meets_the_small_demands_and_cuts_the_large_to_one_level():
    """Against a bisection on the level (an independent solver)."""
    from iscc_gym.agents.multi import level_cap

    rng = np.random.default_rng(3)
    x = rng.uniform(0.0, 0.25, (50, 8))
    total = 0.9
    y = level_cap(x, total)
    for xi, yi in zip(x, y, strict=True):
        if xi.sum() <= total:
            np.testing.assert_array_equal(yi, xi)
            continue
        lo, hi = 0.0, xi.max()
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if np.minimum(xi, mid).sum() < total else (lo, mid)
        np.testing.assert_allclose(yi, np.minimum(xi, lo), atol=1e-12)
    assert (x.sum(-1) > total).any() and (x.sum(-1) <= total).any()


def test_equal_share_sca_gives_every_drone_a_kth_of_the_band():
    s, obs = _observations(4, 20)
    alpha = EqualShareSCA(s, 4).shares_batch(obs.reshape(-1, 4, 23))
    np.testing.assert_allclose(alpha.sum(-1), 0.25, atol=1e-12)
    assert (alpha >= -1e-15).all()


def test_the_margin_rule_of_one_drone_is_the_single_drone_rule():
    s, obs = _observations(1)
    multi = MultiMarginPolicy.tuned(1).shares_batch(obs.reshape(-1, 1, 23))[:, 0]
    single, _ = MarginPolicy.tuned().split_batch(obs)
    np.testing.assert_allclose(multi, single, rtol=1e-12, atol=1e-15)
    four = MultiMarginPolicy.tuned(4).shares_batch(_observations(4, 5)[1].reshape(-1, 4, 23))
    np.testing.assert_allclose(four.sum((1, 2)), 1.0, atol=1e-12)


def test_bad_specs_and_shapes_are_refused():
    with pytest.raises(ValueError, match="unknown"):
        make_multi_policy("nope", ISCCMultiEnv(n_drones=2).scenario, 2)
    with pytest.raises(ValueError, match="shape"):
        MultiMarginPolicy.tuned(2).predict(np.zeros(23))


def test_the_commands_train_and_compare_on_tiny_budgets(tmp_path, monkeypatch, capsys):
    from iscc_gym.eval import multi as EM
    from iscc_gym.eval.__main__ import main as eval_main

    from experiments import multi_agents as TM

    monkeypatch.chdir(tmp_path)
    TM.train_all([2], total_timesteps=256, dest=tmp_path / "ship", out_root=str(tmp_path / "runs"), n_envs=4,
                 overrides={"n_steps": 32, "batch_size": 64}, eval_freq=0, init_envs=2, init_steps=20,
                 norm_reward=False)
    agent = tmp_path / "ship" / "k2"
    assert (agent / "model.zip").is_file()
    # issue 34: --no-norm-reward trains with VecNormalize's reward scaling off (K = 8's setting, TM.K_SETTINGS)
    import pickle

    assert pickle.loads((agent / "vecnormalize.pkl").read_bytes()).norm_reward is False
    assert TM.run_args(8).norm_reward is False and TM.run_args(4).norm_reward is None
    summary = __import__("yaml").safe_load((agent / "summary.yml").read_text())
    assert summary["warm_start"]["policy"] == "margin"  # the multi-drone margin rule cloned first
    res = EM.main(["--n-drones", "2", "--episodes", "2", "--max-steps", "40", "--agent", str(agent)])
    r = res["results"]["2"]
    assert set(r["policies"]) == {"ppo", "equal-sca", "joint-sca", "margin", "margin-starved"}
    assert "ppo_vs_margin" in r["focus_paired"] and "margin_vs_joint-sca" in r["paired"]
    out = eval_main(["--env", "iscc_gym/ISCC-Multi-v0", "--n-drones", "2", "--episodes", "2", "--max-steps", "20",
                     "--agent", "none", "--policies", "margin"])
    assert list(out["results"]["2"]["policies"]) == ["margin"]
    with pytest.raises(ValueError, match="n_drones"):
        EM.main(["--n-drones", "2", "--agent", str(agent), "--episodes", "1", "--max-steps", "5", "--k-scan", "3"])
    with pytest.raises(ValueError, match="unknown"):
        EM.main(["--policies", "nope"])
    capsys.readouterr()
    scan = EM.main(["--k-scan", "1,2", "--episodes", "2", "--max-steps", "5", "--agent", "none",
                    "--policies", "margin"])
    captured = capsys.readouterr()
    text = captured.out
    # issue 23: progress without a terminal; issue 34: every slot counted once (two missions played side by side
    # are one run's 5 slots: the bar stopped at half its total)
    assert "[python -m eval.multi] done: 10/10 slot" in captured.err
    # issue 34: a terminal gets plain tables, as python -m eval prints them, not the docs' markdown
    assert "| K |" not in text and "|---" not in text
    header = next(line for line in text.splitlines() if line.startswith("K  policy"))
    assert "median PEB (m) ↓" in header  # issue 34: the median PEB beside the mean
    for k in ("1", "2"):  # one row per K and policy, with the comparison's own figures
        p = scan["results"][k]["policies"]["margin"]
        row = next(line for line in text.splitlines() if line.startswith(f"{k}  margin"))
        assert f"{p['reward_mean']:.1f} " in row and f" {p['peb_m_mean']:.4f} " in row
        assert f" {p['peb_median_m_mean']:.4f} " in row
    assert "| K | policy | episode reward ↑ | tracking error (m) ↓ | PEB (m) ↓ | median PEB (m) ↓ |" in EM.scan_table(
        {int(k): v for k, v in scan["results"].items()})


def test_joint_sca_keeps_every_drones_control_where_the_bounds_do_not_fit():
    """Issue 34: at K = 8 the drones' control and data bounds exceed the band; joint-sca's fallback kept the static
    design's sensing share (0.54) and scaled the control links into the rest, which lost every drone (-491,909 per
    mission). Control first now: every drone's bound, data scaled above the total sensing floor."""
    for k in (4, 8):
        s, obs = _observations(k, n_steps=6)
        pol = make_multi_policy("joint-sca", s, k)
        o = obs.reshape(-1, k, 23)
        alpha = pol.shares_batch(o)
        _, ctrl, comm = pol.terms(o)
        fallback = ctrl.sum(-1) + comm.sum(-1) > 1 - k * 1e-3
        room = ctrl.sum(-1) <= 1.0 - pol.sensing_floor
        assert fallback.any() and (fallback & room).any() == (k == 4) and (fallback & ~room).any() == (k == 8)
        np.testing.assert_allclose(alpha.sum((1, 2)), 1.0, atol=1e-9)
        np.testing.assert_allclose(alpha[room][..., 1], ctrl[room], rtol=1e-12)  # every control bound met
        sen = alpha[fallback][..., 0].sum(-1)  # the floor (data took the rest, up to its bounds)
        np.testing.assert_allclose(sen, np.maximum(pol.sensing_floor, 1.0 - (ctrl + comm)[fallback].sum(-1)))
        np.testing.assert_allclose(alpha[fallback & ~room][..., 1].sum(-1), 1.0 - pol.sensing_floor)
        # above the band the largest bounds are cut to one level, the smaller met in full (scaled together, the near
        # drones' bounds fell below their need and 3 of 20 missions lost a drone at K = 8)
        c, a8 = ctrl[fallback & ~room], alpha[fallback & ~room][..., 1]
        level = a8.max(-1, keepdims=True)
        np.testing.assert_allclose(a8, np.minimum(c, level), rtol=1e-12)
        assert (c < level).any() == (k == 8)
        assert (alpha[..., 0] > 0).all()
    with pytest.raises(ValueError, match="sensing_floor"):
        JointSCA(s, 8, sensing_floor=0.001)


def _rewards(policy, k, n_envs=2, steps=200, seed=500000):
    """Mean per-slot reward of ``policy`` on the env's reward and on the old one (mean error, summed penalties)."""
    s = iscc_gym.SCENARIOS["paper"]
    v = gym.make_vec(iscc_gym.MULTI_ENV_ID, num_envs=n_envs, vectorization_mode="vector_entry_point", n_drones=k)
    obs, _ = v.reset(seed=seed)
    new = old = 0.0
    for _ in range(steps):
        obs, r, term, _, info = v.step(policy.predict(obs)[0])
        assert not term.any()
        err = np.minimum(info["tracking_error_m"], s.max_tracking_error_m)
        new += r.sum()
        old += (-err.mean(-1) - (s.w_rate * info["cost_rate"] + s.w_stab * info["cost_stability"]).sum(-1)).sum()
    return new / (n_envs * steps), old / (n_envs * steps)


def test_the_reward_no_longer_pays_for_starving_sensing():
    """Issue 23: at K = 4, taking sensing from ``margin`` and giving it to the data links (sensing x 0.3) earned
    more of the old reward (mean error, penalties summed over drones: the direction its maximiser took, to a PEB
    above 1 km) and earns less of the per-drone mean reward than ``margin`` itself (2 missions x 200 slots,
    training seeds; per slot, margin vs scaled: -1.14 vs -1.20 on the new reward, -3.17 vs -3.11 on the old)."""
    margin = MultiMarginPolicy.tuned(4)
    new_m, old_m = _rewards(margin, 4)
    new_s, old_s = _rewards(ScaledSensing(margin, 4, 0.3), 4)
    assert old_s > old_m + 0.02  # the old reward's maximiser direction: less sensing
    assert new_s < new_m - 0.02  # the env's reward: sensing pays again
    starved = make_multi_policy("margin-starved", ISCCMultiEnv(n_drones=4).scenario, 4)
    assert _rewards(starved, 4, steps=100)[0] < _rewards(margin, 4, steps=100)[0]


def test_scaled_sensing_moves_only_sensing_to_data():
    s, obs = _observations(3, 10)
    base = MultiMarginPolicy.tuned(3)
    a = base.shares_batch(obs.reshape(-1, 3, 23))
    b = ScaledSensing(base, 3, 0.25).shares_batch(obs.reshape(-1, 3, 23))
    np.testing.assert_allclose(b[..., 0], 0.25 * a[..., 0], rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(b[..., 1], a[..., 1], rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(b.sum(-1), a.sum(-1), rtol=1e-5, atol=1e-7)
    with pytest.raises(ValueError, match="scale"):
        ScaledSensing(base, 3, -1.0)


def test_the_shipped_agent_keeps_its_radar():
    """Issue 23: the K = 4 agent trained on the per-drone mean reward scores more than the same agent with a tenth of
    its sensing given to the data links (2 missions x 100 slots, training seeds; per slot -0.90 vs -0.99). The agent
    of the old reward, which had starved its sensing already, gained only 0.014 per slot from its own sensing."""
    from iscc_gym.agents.sb3_policy import SB3Policy
    from iscc_gym.eval.multi import agent_dir

    agent = SB3Policy.load(agent_dir(4), check_env=None)
    assert _rewards(agent, 4, steps=100)[0] > _rewards(ScaledSensing(agent, 4, 0.1), 4, steps=100)[0] + 0.03


def test_the_shipped_k8_agent_was_trained_to_keep_every_drone():
    """Issue 34: the K = 8 agent shipped before lost track in training (evaluations -40,748 to -274,188 per mission)
    and on 4 of 20 held-out missions: VecNormalize's reward scaling, inflated by the lost drones, hid every slot's
    reward from PPO. Retrained without it (experiments.multi_agents.K_SETTINGS), no evaluation of its run lost a drone
    (a loss half-way costs the 8-mission mean about 31,000; margin scores about -8,100 at K = 8)."""
    import pickle

    import yaml
    from iscc_gym.eval.multi import agent_dir

    d = agent_dir(8)
    assert pickle.loads((d / "vecnormalize.pkl").read_bytes()).norm_reward is False
    evaluations = yaml.safe_load((d / "summary.yml").read_text())["evaluations"]
    assert len(evaluations) == 8 and all(mean > -10_000 for _, mean in evaluations)

