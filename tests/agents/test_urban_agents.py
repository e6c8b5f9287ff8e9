"""The urban task's baselines: drift-plus-penalty's queue price, the planner's fluid queue and its look-ahead, the
oracle's view, tuning and the comparison command (tiny budgets)."""

from __future__ import annotations

import numpy as np
import pytest
from iscc_gym.agents import DriftPlusPenaltyPolicy, LookaheadPolicy, MyopicPolicy, make_policy

from iscc_gym import SCENARIOS
from iscc_gym.envs.env import ISCCEnv
from iscc_gym.physics.queue import queue_step
from iscc_gym.sim.schema import obs_names

U = SCENARIOS["urban"]


@pytest.fixture(scope="module")
def observations():
    """Observations of a urban mission under a fixed split (seed 500003, a tuning seed)."""
    env = ISCCEnv(U)
    obs, _ = env.reset(seed=500_003)
    out = [obs]
    for _ in range(40):
        obs, *_ = env.step(np.array([0.0, -0.5, 0.3], np.float32))
        out.append(obs)
    return np.array(out)


def _with_backlog(obs, backlog_bits):
    o = obs.copy()
    k = obs_names(U).index("backlog")
    o[:, k] = np.log1p(backlog_bits / (U.queue_arrival_bps * U.dt_s))
    return o


def test_dpp_prices_data_by_the_backlog(observations):
    """An empty buffer gets less data share than a full one; a larger V gives data less (tracking first)."""
    pol = DriftPlusPenaltyPolicy(U, v=1.0)
    empty, _ = pol.split_batch(_with_backlog(observations, 0.0))
    full, _ = pol.split_batch(_with_backlog(observations, 8 * U.queue_arrival_bps * U.dt_s))
    assert np.all(full[:, 2] >= empty[:, 2] - 1e-12) and full[:, 2].mean() > empty[:, 2].mean() + 0.02
    patient, _ = DriftPlusPenaltyPolicy(U, v=50.0).split_batch(_with_backlog(observations, 8 * 5e5))
    assert patient[:, 2].mean() < full[:, 2].mean()
    with pytest.raises(ValueError, match="needs a data queue"):
        DriftPlusPenaltyPolicy("paper")
    with pytest.raises(ValueError, match="v = "):
        DriftPlusPenaltyPolicy(U, v=0.0)


def test_the_planners_fluid_queue_matches_the_queue_at_constant_rates():
    """Constant arrivals and service: the fluid model's backlog and drops equal the FIFO queue's (physics.queue)."""
    pol = LookaheadPolicy(U)
    d, a = U.queue_deadline_slots, U.queue_arrival_bps * U.dt_s
    for served in (0.0, 0.3, 0.9, 1.0, 1.7):
        q = np.zeros((1, d))
        dropped_q = 0.0
        for _ in range(25):
            q, _, x = queue_step(q, a, served * a)
            dropped_q += x[0]
        b, dropped_f, _ = pol._fluid(np.zeros(1), np.array([served]), 25)
        assert q.sum() / a == pytest.approx(b[0], abs=1e-9)
        assert dropped_q / a == pytest.approx(dropped_f[0], abs=1e-9)


def test_the_planner_sends_data_ahead_of_a_blocked_stretch(observations):
    """Same slot, a backlog waiting: with the path ahead blocked (map LoS probability 0, the link 30 dB weaker) the
    planner gives data more now than with it clear; myopic cannot tell the two apart."""
    s = U
    names = obs_names(s)
    o = _with_backlog(observations[5:6], 4 * s.queue_arrival_bps * s.dt_s)
    clear, blocked = o.copy(), o.copy()
    for k in range(1, s.preview_slots + 1):
        p, snr_l, snr_n = (names.index(f"{n}_{k}") for n in ("p_los_ahead", "snr_los_ahead_db", "snr_nlos_ahead_db"))
        clear[0, p] = 1.0
        blocked[0, p] = 0.0
        blocked[0, snr_n] = clear[0, snr_l] - 3.0  # 30 dB below the LoS link
    pol = LookaheadPolicy(s)
    now_clear, now_blocked = pol.split_batch(clear)[0][0], pol.split_batch(blocked)[0][0]
    assert now_blocked[2] > now_clear[2] + 0.02
    my = MyopicPolicy(s)
    assert np.array_equal(my.split_batch(clear)[0], my.split_batch(blocked)[0])
    assert abs(now_clear.sum() - 1.0) < 1e-12 and np.all(now_blocked >= 0)
    hold = LookaheadPolicy(s, preview="hold")  # blind to the preview: the two paths look the same to it
    assert np.array_equal(hold.split_batch(clear)[0], hold.split_batch(blocked)[0])
    with pytest.raises(ValueError, match="preview = "):
        LookaheadPolicy(s, preview="peek")


def test_a_holding_cost_serves_a_backlog_sooner(observations):
    """A backlog of 4 slots' arrivals with the deadline far: without a holding cost the fluid sees no reason to serve it
    now rather than later; with one the planner gives data more now (never less), and a negative cost is refused."""
    o = _with_backlog(observations[5:25], 4 * U.queue_arrival_bps * U.dt_s)
    free, _ = LookaheadPolicy(U, holding_cost=0.0).split_batch(o)
    held, _ = LookaheadPolicy(U, holding_cost=0.2).split_batch(o)
    assert np.all(held[:, 2] >= free[:, 2] - 1e-9) and held[:, 2].mean() > free[:, 2].mean() + 0.01
    with pytest.raises(ValueError, match="holding_cost = "):
        LookaheadPolicy(U, holding_cost=-0.1)



def test_the_planners_data_weight_is_the_rewards_unless_given(observations):
    """``rate_weight`` prices the planner's dropped data: by default the scenario's ``w_rate``; a lower one gives a
    backlog at its deadline less data share (never more), and 0 none: it is the weight of the fluid's cost."""
    o = _with_backlog(observations[5:25], 8.5 * U.queue_arrival_bps * U.dt_s)
    default, _ = LookaheadPolicy(U, holding_cost=0.2).split_batch(o)
    same, _ = LookaheadPolicy(U, holding_cost=0.2, rate_weight=U.w_rate).split_batch(o)
    assert np.array_equal(default, same)
    cheap, _ = LookaheadPolicy(U, holding_cost=0.2, rate_weight=0.05 * U.w_rate).split_batch(o)
    assert np.all(cheap[:, 2] <= default[:, 2] + 1e-9) and cheap[:, 2].mean() < default[:, 2].mean() - 0.01
    assert np.all(LookaheadPolicy(U, rate_weight=0.0).split_batch(o)[0][:, 2] == 0.0)
    for bad in (-1.0, float("nan"), True):
        with pytest.raises(ValueError, match="rate_weight = "):
            LookaheadPolicy(U, rate_weight=bad)

def test_the_oracle_sees_the_truth_on_the_same_missions():
    oracle = make_policy("oracle", U) if _has_record("mpc") else None
    if oracle is None:
        pytest.skip("no mpc-urban record yet")
    assert oracle.scenario_overrides == {"preview_source": "truth"}
    a = ISCCEnv(U)
    b = ISCCEnv(U.replace(preview_source="truth"))
    oa, _ = a.reset(seed=7)
    ob, _ = b.reset(seed=7)
    k = obs_names(U).index("p_los_ahead_1")
    assert np.array_equal(oa[:k], ob[:k]) and set(np.unique(ob[k::5][:U.preview_slots])) <= {0.0, 1.0}
    assert np.array_equal(a._state.ref, b._state.ref)


def _has_record(name):
    from iscc_gym.agents.tuned_records import TUNED_DIR

    return (TUNED_DIR / f"{name}-urban.yml").exists()


def test_urban_specs_need_the_urban_task():
    with pytest.raises(ValueError, match="urban task"):
        make_policy("mpc", "paper")
    with pytest.raises(ValueError, match="'dpp:' takes one number"):
        make_policy("dpp:x", U)
    assert make_policy("dpp:2", U).v == 2.0


def test_tune_and_compare_on_the_urban_task(tmp_path):
    from iscc_gym.eval.__main__ import main as eval_main
    from iscc_gym.eval.tune import main as tune_main

    rec = tune_main(["dpp", "--scenario", "urban", "--episodes", "1", "--max-steps", "5", "--quiet",
                     "--out", str(tmp_path / "dpp.yml")])
    assert rec["policy"] == "dpp" and rec["params"]["v"] in [g for g, _ in rec["grid"]] and len(rec["grid"]) == 7
    assert (tmp_path / "dpp.yml").exists()
    res = eval_main(["--env", "iscc_gym/ISCC-Urban-v0", "--policies", "dpp:1,dpp:5", "--reference", "dpp:1",
                     "--episodes", "2", "--max-steps", "12", "--workers", "1", "--quiet"])
    assert set(res["policies"]) == {"dpp:1", "dpp:5"}
    assert "dropped_mbit_mean" in res["policies"]["dpp:1"]


def test_task_description_and_the_mission_figure(tmp_path):
    from experiments.urban_figure import main as figure_main
    from experiments.urban_task import main as task_main

    st = task_main(["--missions", "3"])
    assert st["n"] == 3 and 0.0 <= st["share_with_blockage"] <= 1.0 and 0.5 < st["los_share_mean"] <= 1.0
    assert all(sum(m["stretches"]) == round((1.0 - m["los_share"]) * (U.n_slots + 1)) for m in st["missions"])
    for state in ("los", "nlos"):  # the FBL rate at the whole band: below Shannon's B log2(1 + SNR), above half of it
        shannon = U.bandwidth_hz * np.log2(1.0 + 10.0 ** (st[f"snr_{state}_db_median"] / 10.0)) * 1e-6
        assert 0.5 * shannon < st[f"capacity_{state}_mbps"] < shannon or st[f"capacity_{state}_mbps"] == 0.0
    assert st["capacity_los_mbps"] > st["arrival_mbps"] == U.queue_arrival_bps * 1e-6
    out = tmp_path / "mission.png"
    assert figure_main(["--seed", "1500024", "--policies", "fixed:0.2,0.3,0.5,margin", "--out", str(out)]) == out
    assert out.stat().st_size > 10_000


def test_the_comparison_shows_dropped_data_only_where_a_queue_dropped_some():
    from iscc_gym.eval.report import DETAIL_COLUMNS, DROPPED_COLUMN, detail_columns

    assert detail_columns({"policies": {"a": {"dropped_mbit_mean": 0.0}}}) == DETAIL_COLUMNS
    assert detail_columns({"policies": {"a": {"dropped_mbit_mean": 0.0}, "b": {"dropped_mbit_mean": 2.5}}})[-1] \
        == DROPPED_COLUMN


LEVERS_TINY = ["--variants", "smooth,urban", "--missions", "1", "--tune-missions", "1", "--max-steps", "5", "--skip",
               "3"]


def test_the_levers_table_splits_myopics_reward_and_pairs_the_planners():
    """``experiments.urban_levers`` on a tiny budget: myopic's reward is the sum of its tracking, stability and
    dropped-data terms (no loss of track in 25 slots), the planners are paired on the same missions, and an unknown
    variant is refused by name."""
    from experiments import urban_levers

    (row,) = urban_levers.main(["--variants", "smooth", "--missions", "2", "--tune-missions", "2", "--max-steps",
                                "25"])
    rows = urban_levers.main(LEVERS_TINY)
    assert rows[0]["seeds"] == [500004, 500004] and rows[1]["name"] == "urban"  # 3 missions after the tuning one
    assert row["overrides"] == {"los_field_kernel": "gaussian"}
    assert row["parts"]["lost_track"] == pytest.approx(0.0, abs=1e-6)
    assert row["parts"]["tracking"] > 0.0 and row["myopic"] < 0.0
    assert row["seeds"] == [500002, 500003] and row["tune_seeds"] == [500000, 500001]
    for k in ("mpc", "oracle", "preview", "knowledge"):
        mean, (lo, hi) = row[k]
        assert lo <= mean <= hi
    with pytest.raises(ValueError, match="unknown"):
        urban_levers.main(["--variants", "smooth,nope"])


@pytest.mark.slow
def test_the_levers_table_is_the_same_from_two_processes():
    """``--jobs 2`` (a pool of worker processes, each importing the planners) gives the serial run's rows."""
    from experiments import urban_levers

    assert urban_levers.main(LEVERS_TINY + ["--jobs", "2"]) == urban_levers.main(LEVERS_TINY)


def test_shifted_missions_change_the_env_and_leave_the_policies_as_tuned(monkeypatch):
    """``experiments.urban_shift``: every policy is built for the urban preset, only the env's missions are shifted; the
    table pairs the focus with every other policy on each shift.
    """
    from iscc_gym.eval import evaluate

    from experiments import urban_shift

    seen = []
    real = evaluate.run_episodes

    def spy(policy, seeds, scenario, *args, **kw):
        seen.append((getattr(policy, "scenario", U), scenario))
        return real(policy, seeds, scenario, *args, **kw)

    monkeypatch.setattr(evaluate, "run_episodes", spy)  # the engine's one rollout loop (iscc_gym.eval.engine)
    res = urban_shift.main(["--shifts", "none,umi_av", "--policies", "myopic,margin", "--focus", "myopic",
                            "--episodes", "2", "--max-steps", "5"])
    assert list(res) == ["none", "umi_av"] and set(res["umi_av"]["focus_paired"]) == {"myopic_vs_margin"}
    assert seen[0][0] == U and all(built == U for built, _ in seen)  # myopic designed for the preset
    assert sorted(env.blockage for _, env in seen) == ["uma_av", "uma_av", "umi_av", "umi_av"]
    for bad, match in ((["--shifts", "nope"], "unknown"),
                       (["--policies", "myopic,margin", "--focus", "dpp"], "--focus")):
        with pytest.raises(ValueError, match=match):
            urban_shift.main(bad)


def test_the_phases_of_a_mission_against_its_blocked_stretches():
    from experiments.urban_learned import PHASES, phases

    los = np.array([1, 1, 1, 0, 0, 1, 1, 1, 1, 1], dtype=bool)
    # by hand, window 2: slots 1-2 see the stretch ahead, 3-4 are in it, 5-6 follow it
    assert [PHASES[k] for k in phases(los, 2)] == ["clear", "ahead", "ahead", "blocked", "blocked", "after",
                                                   "after", "clear", "clear", "clear"]
    assert list(phases(np.array([1, 0, 1], dtype=bool), 5)) == [1, 2, 3]  # ahead wins over after only where both
    assert list(phases(np.array([0, 1, 0], dtype=bool), 1)) == [2, 1, 2]


class _Recurrent:
    """A policy with memory: its split follows the slots it has counted since its episode started (its state)."""

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        n = len(np.atleast_2d(obs))
        count = np.zeros(n) if state is None else np.asarray(state, dtype=float)
        if episode_start is not None:
            count = np.where(np.broadcast_to(np.asarray(episode_start, dtype=bool), (n,)), 0.0, count)
        action = np.stack([np.cos(count / 7.0), np.sin(count / 5.0), np.full(n, -0.2)], axis=1).astype(np.float32)
        return (action[0] if np.ndim(obs) == 1 else action), count + 1.0


def test_a_mission_is_played_as_python_m_eval_plays_it_memory_included():
    """Issue 34.5: play_mission (experiments.urban_figure, experiments.urban_learned) carries a recurrent policy's
    state and episode start as the evaluator's rollout does, so it plays the policy python -m eval scores."""
    from iscc_gym.eval.evaluate import run_episodes

    from experiments.urban_figure import play_mission

    seed, short = 1_500_024, U.replace(mission_duration_s=U.mission_duration_s / 10)  # 120 slots
    run = play_mission(_Recurrent(), seed, short)
    assert np.ptp(run["alpha"][:20, 0]) > 0.1  # its memory moves the split
    scored = run_episodes(_Recurrent(), [seed], short)["episodes"]
    assert run["reward"] == pytest.approx(scored["reward"][0], rel=1e-12)
    assert len(run["alpha"]) == scored["length"][0]


def test_the_urban_commands_build_every_policy_before_playing_any(tmp_path, monkeypatch):
    """Issue 34.16: experiments.urban_learned and experiments.urban_figure refuse a bad policy before playing the ones
    before it, and tell an agent of another env to change --policies (they have no --env)."""
    from iscc_gym.agents.shipped import PPO_AGENT

    from experiments import urban_figure, urban_learned

    played = []
    for module in (urban_figure, urban_learned):
        monkeypatch.setattr(module, "play_mission", lambda *a, **k: played.append(a))
    with pytest.raises(ValueError, match="unknown policy spec 'nope'"):
        urban_learned.main(["--policies", "myopic,nope", "--missions", "1"])
    with pytest.raises(ValueError, match="trained on another env; .* give --policies an agent trained on it") as e:
        urban_figure.main(["--policies", f"myopic,paper={PPO_AGENT}", "--seed", "1500024",
                           "--out", str(tmp_path / "m.png")])
    assert "--env" not in str(e.value) and not played


def _ctrl_c_then_sleep(i):
    """A variant played for 30 s; the first one presses Ctrl-C (SIGINT to the command) as it starts."""
    import os
    import signal
    import time

    if i == 0:
        time.sleep(0.1)  # the other call started too
        os.kill(os.getppid(), signal.SIGINT)
    time.sleep(30.0)


def _run_item_ctrl_c_then_sleep(index, *args):
    """The engine's worker call (:func:`iscc_gym.eval.policies._run_item`), each run played for 30 s."""
    _ctrl_c_then_sleep(index)


@pytest.mark.parametrize("command, argv", [
    pytest.param("urban_shift", ["--shifts", "umi_av,map error 0.8", "--policies", "myopic", "--focus", "myopic",
                                 "--episodes", "1"], marks=pytest.mark.slow),  # spawned workers import the engine
    ("urban_levers", ["--variants", "urban,smooth", "--missions", "1"]),
])
def test_ctrl_c_stops_the_urban_commands_jobs_at_once(command, argv, monkeypatch):
    """Issue 34.16: Ctrl-C (SIGINT) while ``--jobs 2`` plays two variants: the command stops within a couple of
    seconds, its worker processes ended, instead of waiting for the variants still being played (up to 90 s).
    urban_shift plays through the engine's pool (:func:`iscc_gym.eval.policies.play`, spawned workers), urban_levers
    through :func:`iscc_gym.eval.policies.pool_map`."""
    import importlib
    import multiprocessing
    import signal
    import time

    from iscc_gym.eval import policies

    module = importlib.import_module(f"experiments.{command}")
    if command == "urban_shift":
        monkeypatch.setattr(policies, "_run_item", _run_item_ctrl_c_then_sleep)
    else:
        def sleeping(fn, *iterables, workers):  # the command's pool, each variant played for 30 s
            return policies.pool_map(_ctrl_c_then_sleep, range(len(iterables[0])), workers=workers)

        monkeypatch.setattr(module, "pool_map", sleeping)
    pressed = []

    def on_sigint(signum, frame):  # Python's own handler, noting when Ctrl-C came
        pressed.append(time.perf_counter())
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGINT, on_sigint)
    try:
        with pytest.raises(KeyboardInterrupt):  # Ctrl-C once the pool's calls run (not while it starts its workers)
            module.main(argv + ["--jobs", "2"])
    finally:
        signal.signal(signal.SIGINT, previous)
    # ended (SIGTERM), not left playing; the executor's manager thread may reap a terminated worker a moment later
    deadline = time.perf_counter() + 2.0
    while multiprocessing.active_children() and time.perf_counter() < deadline:
        time.sleep(0.02)
    assert pressed and time.perf_counter() - pressed[0] < 3.0 and not multiprocessing.active_children()
