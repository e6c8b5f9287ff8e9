"""Residual learning (agents/residual.py) and training on the urban task (python -m train --env ISCC-Urban-v0)."""

import shutil
import zipfile

import numpy as np
import pytest
import yaml
from iscc_gym.agents import make_policy
from iscc_gym.agents.residual import ResidualPolicy, ResidualVecEnv, read_record, residual_action
from iscc_gym.agents.sb3_policy import SB3Policy
from iscc_gym.agents.sb3_vec_env import ISCCBatchedVecEnv
from iscc_gym.agents.shipped import URBAN_AGENT
from iscc_gym.agents.tuned_records import load_tuned
from iscc_gym.train import Args
from iscc_gym.train.cli import parse_args
from iscc_gym.train.config import resolve_args
from iscc_gym.train.train import main
from tiny_runs import tiny_args

from iscc_gym import URBAN_ENV_ID

BASE = "fixed:0.2,0.3,0.5"


def test_the_residual_action_is_the_clipped_sum():
    base = np.array([[1.0, -0.5, 0.2], [-1.0, 0.0, 0.9]])
    agent = np.array([[0.4, -0.4, 3.0], [-0.2, 0.6, 0.5]])  # 3.0: clipped to 1 first, as SB3 clips to the box
    got = residual_action(base, agent, 0.5)
    want = [[1.0, -0.7, 0.7], [-1.0, 0.3, 1.0]]  # by hand
    np.testing.assert_allclose(got, want, atol=1e-7)
    assert got.dtype == np.float32
    np.testing.assert_array_equal(residual_action(base, np.zeros_like(base), 2.0), base.astype(np.float32))
    with pytest.raises(ValueError, match="NaN or inf"):
        residual_action(base, np.full_like(base, np.nan), 0.5)
    with pytest.raises(ValueError, match="shape"):
        residual_action(base, agent[:1], 0.5)
    for bad in (0.0, -1.0, 2.5, float("nan"), "x"):
        with pytest.raises(ValueError, match="residual_scale"):
            ResidualPolicy(make_policy(BASE), None, bad)


def test_a_zero_correction_plays_the_base_policy_exactly():
    base = make_policy("margin")
    plain, res = ISCCBatchedVecEnv(3), ResidualVecEnv(ISCCBatchedVecEnv(3), base, 0.5)
    plain.seed(7)
    res.seed(7)
    obs, obs_r = plain.reset(), res.reset()
    state, start = None, np.ones(3, dtype=bool)
    for _ in range(30):
        np.testing.assert_array_equal(obs, obs_r)
        action, state = base.predict(obs, state=state, episode_start=start)
        obs, rew, done, _ = plain.step(action)
        obs_r, rew_r, done_r, _ = res.step(np.zeros((3, 3), dtype=np.float32))
        np.testing.assert_array_equal(rew, rew_r)
        start = done
    # a correction moves the env's action: the env plays clip(base + 0.5 correction) (recorded below it)
    played = []
    res.venv.step_async = lambda a: (played.append(np.array(a)), ISCCBatchedVecEnv.step_async(res.venv, a))
    o = res.reset()
    res.step(np.tile([-1.0, 0.4, 0.0], (3, 1)).astype(np.float32))
    a, _ = base.predict(o)
    np.testing.assert_allclose(played[0], np.clip(a + 0.5 * np.array([-1.0, 0.4, 0.0]), -1, 1), atol=1e-6)
    assert not np.allclose(played[0], a)


def test_a_residual_run_saves_what_loads_as_base_plus_correction(tmp_path):
    out = tmp_path / "res"
    main(tiny_args(out, residual=BASE, residual_scale=0.4, total_timesteps=128, eval_freq=0, checkpoint_freq=0,
                   quiet=True))
    policy = SB3Policy.load(out)
    assert isinstance(policy, ResidualPolicy) and policy.spec == BASE and policy.scale == 0.4
    assert read_record(out / "model.zip") == {"residual": BASE, "residual_scale": 0.4, "scenario": "paper",
                                              "env_overrides": {}, "residual_params": None}  # the model's own
    agent = SB3Policy.load(out, check_env=None)
    assert not isinstance(agent, ResidualPolicy) or agent.agent is not None
    obs = ISCCBatchedVecEnv(4).reset()
    correction, _ = policy.agent.predict(obs)
    base, _ = make_policy(BASE).predict(obs)
    want = np.clip(base + 0.4 * np.clip(correction, -1, 1), -1, 1)  # the definition, written out
    np.testing.assert_allclose(policy.predict(obs)[0], want, atol=1e-6)


def test_residual_settings_are_checked_before_any_work(tmp_path):
    with pytest.raises(ValueError, match="residual_scale"):
        main(tiny_args(tmp_path / "a", residual="myopic", residual_scale=3.0))
    with pytest.raises(ValueError, match="use one"):
        main(tiny_args(tmp_path / "b", residual="myopic", init_policy="myopic"))
    with pytest.raises(ValueError, match="not iscc_gym/ISCC-Multi-v0"):
        main(tiny_args(tmp_path / "c", env_id="iscc_gym/ISCC-Multi-v0", residual="myopic"))
    assert not any(tmp_path.iterdir())


def test_the_urban_env_trains_on_the_batched_env_with_its_own_scenario_and_entry():
    args, hp = resolve_args(parse_args(["--env", URBAN_ENV_ID]))
    assert args.env_id == URBAN_ENV_ID and args.scenario == "urban" and args.vec_env == "batched"
    assert hp["gamma"] == 0.9  # the urban entry of train/hyperparams.yml, not the paper env's
    assert resolve_args(Args())[0].scenario == "paper"
    assert resolve_args(parse_args(["--env", URBAN_ENV_ID, "--scenario", "paper"]))[0].scenario == "paper"


def test_the_shipped_urban_agent_is_the_urban_entrys_residual_on_myopic():
    import gymnasium as gym
    import yaml
    from iscc_gym.agents.shipped import URBAN_AGENT
    from iscc_gym.eval.policies import resolve_specs

    from experiments.ship import ship_args

    policy = SB3Policy.load(URBAN_AGENT, check_env=URBAN_ENV_ID)
    assert isinstance(policy, ResidualPolicy) and policy.spec == "myopic"
    with pytest.raises(ValueError, match="trained on another env"):
        SB3Policy.load(URBAN_AGENT)  # the paper env's observations are another size
    cfg = yaml.safe_load((URBAN_AGENT / "config.yml").read_text())["args"]
    shipped, _ = resolve_args(ship_args(URBAN_ENV_ID))
    for key in ("env_id", "scenario", "seed", "total_timesteps", "n_envs", "residual", "residual_scale"):
        assert cfg[key] == getattr(shipped, key), key
    assert resolve_specs("ppo", URBAN_AGENT) == [f"ppo={URBAN_AGENT}"]
    env = gym.make(URBAN_ENV_ID)
    obs, _ = env.reset(seed=10_000)
    for _ in range(5):
        action, _ = policy.predict(obs)
        assert env.action_space.contains(action)
        obs, *_ = env.step(action)


def test_each_env_ships_its_own_agent():
    from iscc_gym.agents.shipped import FIELD_AGENT, PPO_AGENT, URBAN_AGENT
    from iscc_gym.agents.tasks import SHIPPED_AGENTS

    from experiments.ship import SHIP_ARGS, ship_args
    from iscc_gym import ENV_ID, FIELD_ENV_ID

    assert ship_args(ENV_ID) is SHIP_ARGS and SHIPPED_AGENTS == {ENV_ID: PPO_AGENT, URBAN_ENV_ID: URBAN_AGENT,
                                                                 FIELD_ENV_ID: FIELD_AGENT}
    urban = ship_args(URBAN_ENV_ID)
    assert (urban.env_id, urban.seed, urban.out) == (URBAN_ENV_ID, 0, "runs/ship_ppo_urban")
    with pytest.raises(ValueError, match="an agent is shipped for"):
        ship_args("iscc_gym/ISCC-Multi-v0")


def test_recurrent_ppo_trains_a_residual_agent_that_carries_its_memory(tmp_path):
    """``--algo ppo_lstm`` (sb3-contrib's RecurrentPPO, the urban entry's section): a run saves, loads as a
    residual policy whose state holds the LSTM's, and a new episode's start resets that memory.
    """
    pytest.importorskip("sb3_contrib")
    out = tmp_path / "lstm"
    main(tiny_args(out, env_id=URBAN_ENV_ID, algo="ppo_lstm", n_envs=2, eval_freq=0, checkpoint_freq=0,
                   overrides={"n_steps": 16, "batch_size": 16, "n_epochs": 1}, residual="margin", quiet=True))
    policy = SB3Policy.load(out, check_env=URBAN_ENV_ID)
    assert isinstance(policy, ResidualPolicy) and type(policy.model).__name__ == "RecurrentPPO"
    recorded = load_tuned("margin-urban")["params"]  # the base's parameters as trained, in the model and manifest
    assert read_record(out / "model.zip")["residual_params"] == recorded
    assert yaml.safe_load((out / "manifest.yml").read_text())["run"]["residual_params"] == recorded
    venv = ISCCBatchedVecEnv(2, scenario="urban")
    venv.seed(3)
    obs = venv.reset()
    a0, state = policy.predict(obs, episode_start=np.ones(2, dtype=bool))
    h = state[0][0]
    assert h.shape[-1] == 64  # the LSTM's hidden state, carried between calls
    obs, *_ = venv.step(a0)
    a1, _ = policy.predict(obs, state=state, episode_start=np.zeros(2, dtype=bool))
    fresh, _ = policy.predict(obs, state=None, episode_start=np.ones(2, dtype=bool))
    carried = policy.agent.predict(obs, state=state[0], episode_start=np.zeros(2, dtype=bool))[0]
    reset = policy.agent.predict(obs, state=state[0], episode_start=np.ones(2, dtype=bool))[0]
    np.testing.assert_array_equal(reset, policy.agent.predict(obs, episode_start=np.ones(2, dtype=bool))[0])
    assert not np.array_equal(carried, reset)  # the memory changes the correction
    np.testing.assert_array_equal(a1, residual_action(make_policy("margin", "urban").predict(obs)[0], carried, 0.5))
    np.testing.assert_array_equal(fresh, residual_action(make_policy("margin", "urban").predict(obs)[0], reset, 0.5))


def test_concatenated_envs_play_each_part_as_it_would_alone():
    from iscc_gym.agents.sb3_vec_env import ConcatVecEnv

    both = ConcatVecEnv([ISCCBatchedVecEnv(2, scenario="urban"), ISCCBatchedVecEnv(3, scenario="urban",
                                                                                   blockage="umi_av")])
    alone = [ISCCBatchedVecEnv(2, scenario="urban"), ISCCBatchedVecEnv(3, scenario="urban", blockage="umi_av")]
    assert both.num_envs == 5 and both.seed(11) == [11, 12, 13, 14, 15]
    alone[0].seed(11)
    alone[1].seed(13)  # sub-env i of the whole is seeded 11 + i
    np.testing.assert_array_equal(both.reset(), np.concatenate([v.reset() for v in alone]))
    rng = np.random.default_rng(0)
    for _ in range(5):
        a = rng.uniform(-1, 1, (5, 3)).astype(np.float32)
        got = both.step(a)
        want = [alone[0].step(a[:2]), alone[1].step(a[2:])]
        np.testing.assert_array_equal(got[0], np.concatenate([w[0] for w in want]))
        np.testing.assert_array_equal(got[1], np.concatenate([w[1] for w in want]))
    with pytest.raises(ValueError, match="spaces differ"):
        ConcatVecEnv([ISCCBatchedVecEnv(1), ISCCBatchedVecEnv(1, scenario="urban")])


def test_randomised_training_splits_the_envs_between_the_preset_and_its_shifts(tmp_path):
    from iscc_gym.train.train import make_train_env

    from iscc_gym.tasks import TASKS, URBAN_ENV_ID

    args, _ = resolve_args(parse_args(["--env", URBAN_ENV_ID, "--randomize", "urban-shifts", "--n-envs", "7"]))
    venv = make_train_env(args)
    parts = venv.venv.venv.venvs  # VecMonitor(ResidualVecEnv(ConcatVecEnv))
    assert [p.num_envs for p in parts] == [2, 2, 1, 1, 1]
    assert parts[0].venv.scenario.blockage == "uma_av" and parts[1].venv.scenario.blockage == "umi_av"
    for part, shift in zip(parts[1:], TASKS[URBAN_ENV_ID].shift_overrides().values(), strict=True):
        assert all(getattr(part.venv.scenario, k) == v for k, v in shift.items())
    out = tmp_path / "rand"
    main(tiny_args(out, env_id=URBAN_ENV_ID, randomize="urban-shifts", n_envs=5, residual="margin", eval_freq=0,
                   checkpoint_freq=0, overrides={"n_steps": 16, "batch_size": 16, "n_epochs": 1}, quiet=True))
    import yaml

    assert yaml.safe_load((out / "manifest.yml").read_text())["run"]["randomize"] == "urban-shifts"
    for bad, match in (({"randomize": "nope"}, "use one of"), ({"randomize": "urban-shifts"}, "draws urban")):
        with pytest.raises(ValueError, match=match):
            main(tiny_args(tmp_path / "bad", **bad))


def test_field_worlds_randomise_the_field_task_over_drawn_worlds_not_its_test_worlds():
    from iscc_gym.train.args import FIELD_RANDOM_WORLDS, randomize_sets
    from iscc_gym.train.train import make_train_env

    from iscc_gym.tasks import FIELD_ENV_ID
    from iscc_gym.tasks.field import FIELD_VARIANTS, draw_worlds

    env, worlds = randomize_sets()["field-worlds"]
    assert env == FIELD_ENV_ID and list(worlds.values()) == draw_worlds(FIELD_RANDOM_WORLDS, 0)
    assert not any(w == v.overrides for w in worlds.values() for v in FIELD_VARIANTS.values())
    args, _ = resolve_args(parse_args(["--env", FIELD_ENV_ID, "--randomize", "field-worlds", "--n-envs", "17",
                                       "--critic", "own", "--reward", "sampled"]))
    parts = make_train_env(args).venv.venv.venvs  # VecMonitor(ResidualVecEnv(ConcatVecEnv))
    assert [p.num_envs for p in parts] == [1] * 17 and parts[0].venv.scenario.rician_k_db == 9.0
    assert all(getattr(parts[k].venv.scenario, key) == v for k, w in enumerate(worlds.values(), 1)
               for key, v in w.items())
    from iscc_gym.train.config import check_resolved

    check_resolved(*resolve_args(parse_args(["--env", FIELD_ENV_ID, "--randomize", "field-worlds", "--n-envs", "17",
                                             "--critic", "own", "--reward", "sampled"])))
    with pytest.raises(ValueError, match="reward = 'expected'.*no --randomize"):  # the shipped entry's privileges
        check_resolved(*resolve_args(parse_args(["--env", FIELD_ENV_ID, "--randomize", "field-worlds",
                                                 "--n-envs", "17"])))


def test_randomised_training_refuses_fewer_envs_than_mission_sets(tmp_path):
    # 4 envs over the preset and its 4 shifts would never train on the last shift
    with pytest.raises(ValueError, match="n_envs = 4.*--n-envs 5 or more"):
        main(tiny_args(tmp_path / "few", env_id=URBAN_ENV_ID, randomize="urban-shifts", n_envs=4))
    assert not (tmp_path / "few").exists()


def _obs_urban(n=6, seed=5):
    venv = ISCCBatchedVecEnv(n, scenario="urban")
    venv.seed(seed)
    return venv.reset()


@pytest.fixture(scope="module")
def shipped_urban():
    """The shipped urban agent (a residual agent on myopic) and its actions on a few urban observations."""
    policy = SB3Policy.load(URBAN_AGENT, check_env=URBAN_ENV_ID)
    obs = _obs_urban()
    return policy, obs, policy.predict(obs)[0]


def test_a_residual_model_loads_as_the_residual_agent_without_its_run_files(tmp_path, shipped_urban):
    """Issue 34.6: model.zip with vecnormalize.pkl beside it (SB3's convention), no manifest or config: the model's
    own record makes it the residual agent, not a plain one whose actions are off by up to 1.
    """
    policy, obs, actions = shipped_urban
    for name in ("model.zip", "vecnormalize.pkl"):
        shutil.copy(URBAN_AGENT / name, tmp_path / name)
    bare = SB3Policy.load(tmp_path / "model.zip", check_env=URBAN_ENV_ID)
    assert isinstance(bare, ResidualPolicy) and (bare.spec, bare.scale) == ("myopic", 0.5)
    np.testing.assert_array_equal(bare.predict(obs)[0], actions)
    # a run whose manifest lost its residual entries: the same agent
    d = tmp_path / "unit"
    shutil.copytree(URBAN_AGENT, d)
    m = yaml.safe_load((d / "manifest.yml").read_text())
    m["run"] = {k: v for k, v in m["run"].items() if not k.startswith("residual")}
    (d / "manifest.yml").write_text(yaml.safe_dump(m))
    np.testing.assert_array_equal(SB3Policy.load(d, check_env=URBAN_ENV_ID).predict(obs)[0], actions)


def test_the_shipped_urban_agent_plays_the_base_parameters_it_was_trained_with(tmp_path, monkeypatch, shipped_urban):
    """Issue 34.7: re-tuning myopic on the urban task (another agents/tuned/myopic-urban.yml) leaves the shipped
    agent's base as trained (rate_weight 0.3, myopic-urban.yml at its ship commit 6de79c4), with a warning.
    """
    import iscc_gym.agents.tuned_records as records
    from iscc_gym.train.runs import run_identity

    policy, obs, actions = shipped_urban
    assert read_record(URBAN_AGENT / "model.zip")["residual_params"] == {"rate_weight": 0.3}
    retuned = tmp_path / "tuned"
    shutil.copytree(records.TUNED_DIR, retuned)
    record = yaml.safe_load((retuned / "myopic-urban.yml").read_text())
    record["params"]["rate_weight"] = 2.0
    (retuned / "myopic-urban.yml").write_text(yaml.safe_dump(record))
    monkeypatch.setattr(records, "TUNED_DIR", retuned)
    assert make_policy("myopic", "urban").rate_weight == 2.0  # what the spec plays now
    with pytest.warns(UserWarning, match=r"trained with \(\{'rate_weight': 0.3\}\), not .*myopic-urban.yml's "
                                         r"\{'rate_weight': 2.0\}"):
        again = SB3Policy.load(URBAN_AGENT, check_env=URBAN_ENV_ID)
    assert again.base.rate_weight == 0.3
    np.testing.assert_array_equal(again.predict(obs)[0], actions)
    # a run resumed from a checkpoint keeps the parameters its checkpoint recorded
    args, _ = resolve_args(parse_args(["--env", URBAN_ENV_ID]))
    assert run_identity(args)["residual_params"] == {"rate_weight": 2.0}
    assert run_identity(args, None, {"run": {"residual_params": {"rate_weight": 0.3}}})["residual_params"] == {
        "rate_weight": 0.3}


def _unit(tmp_path, name, record=True):
    """A copy of the shipped urban agent's unit in ``tmp_path/name``; ``record=False``: its model without the
    residual record (a residual run saved before models held one), its manifest rewritten to match.
    """
    from iscc_gym.agents.sb3_policy import read_manifest, write_manifest

    d = tmp_path / name
    shutil.copytree(URBAN_AGENT, d)
    if not record:
        with zipfile.ZipFile(URBAN_AGENT / "model.zip") as src, zipfile.ZipFile(d / "model.zip", "w") as dst:
            for item in src.infolist():
                if item.filename != "residual.yml":
                    dst.writestr(item, src.read(item.filename))
        m = read_manifest(URBAN_AGENT)
        m["run"].pop("residual_params")
        write_manifest(d, list(m.pop("files")), **m)
    return d


#: Damaged manifests (issue 34.16): (the damage, the field the error names, the unit has the model's record).
DAMAGED = [
    (lambda m: m.update(run=3), "run = 3", True),
    (lambda m: m.update(files=["model.zip"]), "files = ", True),
    (lambda m: m["run"].update(residual_scale=0.25), "run.residual_scale = 0.25, .*set it back to 0.5", True),
    (lambda m: m["run"].update(scenario="paper"), "run.scenario = 'paper', .*set it back to 'urban'", True),
    (lambda m: m["run"].update(residual=None), "run.residual = None, .*set it back to 'myopic'", True),
    (lambda m: m["run"].update(algo="ppox"), "run.algo = 'ppox'; expected one of", True),
    (lambda m: m["run"].update(algo="sac"), "run.algo = 'sac' is not the algorithm", True),
    (lambda m: m["run"].update(normalize="yes"), "run.normalize = 'yes'; expected true or false", True),
    (lambda m: m["run"].pop("residual_scale"), "run.residual_scale = None; expected a number", False),
    (lambda m: m["run"].update(residual_scale="x"), "run.residual_scale = 'x'; expected a number", False),
    (lambda m: m["run"].update(scenario="paper"), "run.scenario = 'paper' .*gives observations of size", False),
    (lambda m: m["run"].update(residual="myopix"), "run.residual = 'myopix' does not build", False),
    (lambda m: m["run"].update(env_overrides=[1]), "run.env_overrides = \\[1\\]; expected a mapping", False),
]


@pytest.mark.parametrize("damage,field,record", DAMAGED)
def test_a_damaged_manifest_is_named_with_its_field_and_the_fix(tmp_path, damage, field, record):
    """Issue 34.16: each damage of a residual unit's manifest.yml is a ValueError naming the file, the field and
    the fix, never a KeyError, an AttributeError, a plain agent or a shape error at the first step.
    """
    d = _unit(tmp_path, "unit", record)
    m = yaml.safe_load((d / "manifest.yml").read_text())
    damage(m)
    (d / "manifest.yml").write_text(yaml.safe_dump(m))
    with pytest.raises(ValueError, match=f"manifest\\.yml: {field}") as e:
        SB3Policy.load(d, check_env=None)
    assert any(fix in str(e.value) for fix in ("set it back", "restore it", "retrain"))


def test_a_split_space_correction_scales_the_base_shares_and_never_clips():
    """residual_space="split": shares times e^(s a), renormalised; zero plays the base split; a base at a corner of
    the action box (one share at +1, a small one near -1) moves symmetrically, where the additive form clips."""
    from iscc_gym.sim.task import action_to_split, split_to_action

    base_split = np.array([[0.04, 0.25, 0.71], [0.2, 0.3, 0.5]])
    base = split_to_action(base_split)
    np.testing.assert_allclose(action_to_split(residual_action(base, np.zeros_like(base), 0.3, "split")), base_split,
                               rtol=1e-6)
    up = action_to_split(residual_action(base, np.array([[1.0, 0.0, 0.0]] * 2), 0.3, "split"))
    down = action_to_split(residual_action(base, np.array([[-1.0, 0.0, 0.0]] * 2), 0.3, "split"))
    ratio = lambda a: np.log(a[:, 0] / a[:, 2])  # noqa: E731
    np.testing.assert_allclose(ratio(up) - ratio(base_split), 0.3, atol=1e-6)
    np.testing.assert_allclose(ratio(down) - ratio(base_split), -0.3, atol=1e-6)
    # the data share sits at +1: the additive form clips a positive correction there, the split form does not
    add_up = action_to_split(residual_action(base, np.array([[0.0, 0.0, 1.0]] * 2), 0.3))
    np.testing.assert_allclose(add_up[0], base_split[0], rtol=1e-6)  # clipped: nothing moved
    split_up = action_to_split(residual_action(base, np.array([[0.0, 0.0, 1.0]] * 2), 0.3, "split"))
    assert split_up[0, 2] > base_split[0, 2]


def test_a_split_space_record_round_trips_and_older_records_read_as_action(tmp_path):
    from iscc_gym.agents.residual import check_space, residual_record, write_record

    rec = residual_record("adaptive", 0.3, "field", space="split")
    assert rec["residual_space"] == "split"
    assert "residual_space" not in residual_record("adaptive", 0.3, "field")  # the default left out, as before
    for record, name in ((rec, "split.zip"), (residual_record("margin", 0.5), "old.zip")):
        path = tmp_path / name
        with zipfile.ZipFile(path, "w") as z:
            z.writestr("data", "{}")
        write_record(path, record)
        assert read_record(path) == record
    with pytest.raises(ValueError, match="residual_space"):
        check_space("logits")
    with pytest.raises(ValueError, match="residual_space"):
        ResidualPolicy(make_policy(BASE), None, 0.5, space="logits")


def test_the_field_entry_trains_a_split_residual_on_bayes_with_the_world_shown_and_ships_it(tmp_path):
    """python -m train --env iscc_gym/ISCC-Field-v0 reads its entry's settings (a residual on bayes that scales its
    shares, PPO's critic shown the world, the expected reward: issue 45's best learner); a tiny run of it and the
    shipped agent both load as that residual policy reading the task's observation alone; a flag overrides the
    YAML's setting, and the device trainer refuses the settings it lacks, naming the flag."""
    import yaml
    from iscc_gym.agents.shipped import FIELD_AGENT
    from iscc_gym.train.device import config_from_args

    from iscc_gym import FIELD_ENV_ID

    args, hp = resolve_args(parse_args(["--env", FIELD_ENV_ID]))
    assert (args.scenario, args.residual, args.residual_space, args.residual_scale, args.critic, args.reward) == (
        "field", "bayes", "split", 0.3, "world", "expected")
    plain, _ = resolve_args(parse_args(["--env", FIELD_ENV_ID, "--critic", "own", "--reward", "sampled"]))
    assert (plain.critic, plain.reward) == ("own", "sampled")
    assert (resolve_args(parse_args([]))[0].critic, resolve_args(parse_args([]))[0].reward) == ("own", "sampled")
    main(tiny_args(tmp_path / "f", env_id=FIELD_ENV_ID, scenario="field"))
    for path in (tmp_path / "f", FIELD_AGENT):
        policy = SB3Policy.load(path, check_env=FIELD_ENV_ID)
        assert isinstance(policy, ResidualPolicy) and (policy.spec, policy.space) == ("bayes", "split")
        cfg = yaml.safe_load((path / "config.yml").read_text())["args"]
        assert (cfg["residual"], cfg["residual_space"], cfg["critic"], cfg["reward"]) == ("bayes", "split", "world",
                                                                                            "expected")
    with pytest.raises(ValueError, match="--residual 'bayes' .*drop --device"):
        config_from_args(parse_args(["--env", FIELD_ENV_ID]), "standin")
    with pytest.raises(ValueError, match="--reward 'expected' .*drop --device"):
        config_from_args(parse_args(["--env", FIELD_ENV_ID, "--residual", "none"]), "standin")
    with pytest.raises(ValueError, match="--critic 'world' .*drop --device"):
        config_from_args(parse_args(["--env", FIELD_ENV_ID, "--residual", "none", "--reward", "sampled"]), "standin")
