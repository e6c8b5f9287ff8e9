"""The urban task (iscc_gym/ISCC-Urban-v0): API checks, bits conserved every slot, the two-way NLoS loss of the
echo, the LoS frequency against TR 36.777 Table B-1, the map's calibration, the preview, the reward."""

from __future__ import annotations

import math
import re

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import iscc_gym
from iscc_gym import SCENARIOS
from iscc_gym.envs.env import ISCCEnv
from iscc_gym.physics.blockage import los_probability
from iscc_gym.sim import functional, loop, schema
from iscc_gym.sim.mission import MC, mission_rows
from iscc_gym.sim.schema import OBS, n_draws, obs_names, obs_size
from iscc_gym.trajectory import sample_reference

U = SCENARIOS["urban"]
SHORT = U.replace(mission_duration_s=20.0)  # 200 slots


def test_registered_env_passes_the_checkers_with_its_observation():
    env = gym.make(iscc_gym.URBAN_ENV_ID)
    assert env.spec.max_episode_steps == U.n_slots == 1200
    assert env.observation_space.shape == (obs_size(U),) == (76,)
    names = obs_names(U)
    assert names[23:26] == ("backlog", "oldest_age", "echo_snr_db") and names[-1] == "echo_nlos_ahead_db_10"
    check_env(env.unwrapped, skip_render_check=True)
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    sb3_check_env(ISCCEnv(SHORT), warn=True)


def test_vector_env_reproduces_single_envs_bit_for_bit():
    venv = gym.make_vec(iscc_gym.URBAN_ENV_ID, num_envs=3, vectorization_mode="vector_entry_point",
                        mission_duration_s=20.0)
    obs_v, _ = venv.reset(seed=[4, 5, 6])
    singles = [ISCCEnv(SHORT) for _ in range(3)]
    obs_s = [e.reset(seed=4 + i)[0] for i, e in enumerate(singles)]
    assert np.array_equal(obs_v, np.stack(obs_s))
    rng = np.random.default_rng(0)
    for _ in range(60):
        a = rng.uniform(-1, 1, (3, 3)).astype(np.float32)
        o, r, te, tr, info = venv.step(a)
        for i, e in enumerate(singles):
            oi, ri, *_ , ii = e.step(a[i])
            assert np.array_equal(o[i], oi) and r[i] == ri and info["bits_dropped"][i] == ii["bits_dropped"]
    venv.close()


def test_seeded_resets_repeat_and_differ():
    e = ISCCEnv(SHORT)
    a, _ = e.reset(seed=3)
    rows = e._state.ref[0].copy()
    b, _ = e.reset(seed=3)
    assert np.array_equal(a, b) and np.array_equal(rows, e._state.ref[0])
    e.reset(seed=4)
    assert not np.array_equal(rows[:, MC["los"]:], e._state.ref[0][:, MC["los"]:])


def test_bits_are_conserved_every_slot_and_the_reward_charges_the_drops():
    s = SHORT
    e = ISCCEnv(s)
    e.reset(seed=1)
    rng = np.random.default_rng(1)
    backlog = 0.0
    mean_bits = s.queue_arrival_bps * s.dt_s
    dropped_any = False
    for t in range(s.n_slots):
        a = rng.uniform(-1, 1, 3).astype(np.float32)
        if 40 <= t < 70:  # no data share for 3 s: the deadline (1 s) passes, bits are dropped
            a[2] = -1.0
        obs, r, term, trunc, info = e.step(a)
        arrived, served, dropped, new = (info[k] for k in ("bits_arrived", "bits_served", "bits_dropped",
                                                             "backlog_bits"))
        assert arrived == pytest.approx(served + dropped + new - backlog, rel=1e-9, abs=1e-6)
        assert served <= info["rate_comm_bps"] * s.dt_s * (1 + 1e-12)
        assert info["cost_rate"] == (1.0 if dropped > 0 else 0.0)
        want = -min(info["tracking_error_m"], s.max_tracking_error_m) - s.w_rate * dropped / mean_bits \
            - s.w_stab * info["cost_stability"]
        if not term:
            assert r == pytest.approx(want, rel=1e-12, abs=1e-9)
        assert obs[OBS["time_left"]] >= 0
        dropped_any |= dropped > 0
        backlog = new
        if term or trunc:
            break
    assert dropped_any  # the starved slots dropped bits: the check above saw both cases


def _table_b2_excess_uma(h, d, fc):
    """UMa-AV NLoS minus LoS path loss, TR 36.777 Table B-2, written out."""
    nlos = -17.5 + (46.0 - 7.0 * math.log10(h)) * math.log10(d) + 20.0 * math.log10(40.0 * math.pi * fc / 3.0)
    return nlos - (28.0 + 22.0 * math.log10(d) + 20.0 * math.log10(fc))


def test_the_echo_pays_the_nlos_excess_twice_the_link_once():
    """Same state, its mission row flipped from LoS to NLoS (unit shadowing 0): the observed link SNR falls by the
    Table B-2 excess, the echo's by twice it."""
    s = SHORT
    e = ISCCEnv(s)
    e.reset(seed=2)
    st = e._state
    n = int(st.n[0])
    ref = st.ref.copy()
    ref[0, n, MC["shadow_unit"]] = 0.0
    ref[0, n, MC["los"]] = 1.0
    los = functional.observe(s, st._replace(ref=ref), 1.0, 0.0)
    ref[0, n, MC["los"]] = 0.0
    nlos = functional.observe(s, st._replace(ref=ref), 1.0, 0.0)
    h = st.x_hat[0, 2]
    d = math.dist(st.x_hat[0, :3], (0.0, 0.0, s.gbs_height_m))
    excess = _table_b2_excess_uma(h, d, s.carrier_freq_ghz)
    assert 10.0 < excess < 40.0
    k_echo = obs_names(s).index("echo_snr_db")
    assert (los[0, OBS["snr_db"]] - nlos[0, OBS["snr_db"]]) * 10.0 == pytest.approx(excess, abs=1e-3)
    assert (los[0, k_echo] - nlos[0, k_echo]) * 10.0 == pytest.approx(2.0 * excess, abs=1e-3)


def test_los_frequency_follows_table_b1_and_the_map_is_calibrated():
    """Over many missions the realised LoS share equals the mean TR 36.777 probability at the reference's
    positions (a binomial test on decorrelated samples), and within bins of the map's LoS probability the
    truth's frequency matches the bin's mean probability."""
    s = U
    rng = np.random.default_rng(7)
    truth, prior, mapped = [], [], []
    for _ in range(60):
        ref = loop.reference_array(sample_reference(s, rng))
        rows = mission_rows(s, ref, rng)[::40]  # 40 slots apart: ~20 m or more, decorrelating
        truth.append(rows[:, MC["los"]])
        prior.append(los_probability(s.blockage, rows[:, 2], np.hypot(rows[:, 0], rows[:, 1])))
        mapped.append(rows[:, MC["p_los_map"]])
    truth, prior, mapped = (np.concatenate(v) for v in (truth, prior, mapped))
    n = len(truth)
    se = math.sqrt(np.mean(prior * (1 - prior)) / n) * 3.0  # correlated neighbours: a generous binomial bound
    assert abs(truth.mean() - prior.mean()) < 4.0 * se
    assert 0.02 < 1.0 - truth.mean() < 0.5  # blockage happens, but not on most of the path
    edges = np.array([0.0, 0.2, 0.5, 0.8, 0.95, 1.0 + 1e-9])
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        sel = (mapped >= lo) & (mapped < hi)
        if sel.sum() < 40:
            continue
        p = mapped[sel].mean()
        assert abs(truth[sel].mean() - p) < 4.0 * math.sqrt(p * (1 - p) / sel.sum()) * 3.0 + 0.02


def test_the_preview_is_the_map_ahead_and_stops_at_the_mission_end():
    s = SHORT
    e = ISCCEnv(s)
    obs, _ = e.reset(seed=5)
    rows = e._state.ref[0]
    k0 = obs_names(s).index("p_los_ahead_1")
    stride = s.preview_stride_slots
    cols = ("p_los_map", "snr_los_map_db", "snr_nlos_map_db", "echo_los_map_db", "echo_nlos_map_db")
    for k in range(s.preview_slots):
        r = min(0 + (k + 1) * stride, s.n_slots)
        for j, col in enumerate(cols):
            assert obs[k0 + 5 * k + j] == np.float32(rows[r, MC[col]] * (1.0 if j == 0 else 0.1))
    # the map's two states: NLoS costs the link the Table B-2 excess once and the echo twice (the shadowing's
    # std also changes with the state, the same for both, so it cancels in the difference of the differences)
    drop_link = rows[:, MC["snr_los_map_db"]] - rows[:, MC["snr_nlos_map_db"]]
    drop_echo = rows[:, MC["echo_los_map_db"]] - rows[:, MC["echo_nlos_map_db"]]
    h, d = rows[:, 2], np.linalg.norm(rows[:, :3] - [0.0, 0.0, s.gbs_height_m], axis=1)
    excess = np.array([_table_b2_excess_uma(hi, di, s.carrier_freq_ghz) for hi, di in zip(h, d, strict=True)])
    np.testing.assert_allclose(drop_echo - drop_link, excess, rtol=0, atol=1e-9)
    for _ in range(s.n_slots - 3):
        obs, *_ = e.step(np.zeros(3, np.float32))
    assert obs[k0 + 5 * (s.preview_slots - 1)] == np.float32(rows[s.n_slots, MC["p_los_map"]])
    d = functional.decode_observation(obs, s)
    assert d["p_los_ahead"].shape == (s.preview_slots,) and d["backlog_bits"] >= 0


def test_the_multi_drone_env_refuses_the_urban_task():
    with pytest.raises(ValueError, match="multi-drone env flies the paper's task only"):
        gym.make(iscc_gym.MULTI_ENV_ID, scenario="urban")


def test_a_longer_mission_warns_of_the_urban_ids_own_time_limit(recwarn):
    """Issue 34 item 12: make(ISCC-Urban-v0, mission_duration_s=300) was cut at its registered 1200 steps without
    a warning (the check compared with the paper env's 5000); the warning names the id's limit and the fix, and
    the fix runs the whole mission."""
    match = r"n_slots = 3000 slots, but iscc_gym/ISCC-Urban-v0 is registered with a TimeLimit of 1200 steps.*" \
            r"max_episode_steps=3000"
    with pytest.warns(UserWarning, match=match):
        env = gym.make(iscc_gym.URBAN_ENV_ID, mission_duration_s=300.0)
    assert env.spec.max_episode_steps == 1200
    with pytest.warns(UserWarning, match=match):
        venv = gym.make_vec(iscc_gym.URBAN_ENV_ID, num_envs=1, vectorization_mode="vector_entry_point",
                            mission_duration_s=300.0)
    assert venv.max_steps == 1200
    recwarn.clear()
    venv = gym.make_vec(iscc_gym.URBAN_ENV_ID, num_envs=1, vectorization_mode="vector_entry_point",
                        mission_duration_s=300.0, max_episode_steps=3000)  # the fix: the vector env knows it
    ISCCEnv("urban", mission_duration_s=300.0)  # no TimeLimit without gymnasium.make
    assert venv.max_steps == 3000 and not [w for w in recwarn if "TimeLimit" in str(w.message)]


@pytest.mark.parametrize("noise", ["stream", "generator"])
def test_loop_step_advances_the_queue_as_the_env_does(noise):
    """loop.step is the whole slot transition: stepped from the env's state with the env's split, it gives the env's
    next state bit for bit, the data queue included (the queue once advanced only inside the env's kernel, so
    loop.step left the backlog as it was), and reports the queue's columns as the env's info does."""
    from iscc_gym.sim.task import action_to_split

    env = ISCCEnv(SHORT)
    env.reset(seed=11)
    state = env._state
    rng = np.random.default_rng(5)
    backlog_seen = 0.0
    for n in range(80):
        a = np.array([rng.uniform(-1, 1), rng.uniform(-1, 1), -0.95 if n < 40 else 1.0], np.float32)
        if noise == "stream":
            state, m = loop.step(SHORT, state, action_to_split(a.astype(float)[None]))
            _, _, _, _, info = env.step(a)
        else:  # the slot's normals from a Generator: as the env step given the same normals
            z = loop.slot_noise(state, np.random.default_rng(1000 + n), n_draws(SHORT))
            state, m = loop.step(SHORT, state, action_to_split(a.astype(float)[None]), np.random.default_rng(1000 + n))
            env._state, out, _ = functional.env_step(SHORT, env._state, a[None].astype(float), normals=z)
            info = functional.step_info(out[0].tolist(), int(env._state.n[0]))
        for field in ("x", "x_hat", "p", "shadow", "n", "queue"):
            assert np.array_equal(getattr(state, field), getattr(env._state, field)), (n, field)
        for key in ("bits_arrived", "bits_served", "bits_dropped", "backlog_bits"):
            assert float(np.asarray(m[key]).reshape(-1)[0]) == info[key], (n, key)
        backlog_seen = max(backlog_seen, info["backlog_bits"])
    assert backlog_seen > U.queue_arrival_bps * U.dt_s  # the data share starved: bits waited


def _docstring_rows(doc: str, s, preset: str = "paper") -> dict[int, tuple[float, float]]:
    """The env docstring's observation tables as {entry: (min, max)} (``26 + 5(k-1)`` expanded for every point): the
    paper's table, then the preset's task's (after its ``**The <preset> task**`` paragraph)."""
    parts = re.split(r"\*\*The (\w+) task\*\*", doc.split("## Rewards")[0])
    text = parts[0] + "".join(body for name, body in zip(parts[1::2], parts[2::2], strict=True) if name == preset)
    rows = {}
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) < 5 or not cells[0][:1].isdigit():
            continue
        lo, hi = float(cells[-2]), float(cells[-1])
        for part in cells[0].split(","):
            part = part.strip()
            if "(k-1)" in part:
                base, step = (int(v) for v in re.fullmatch(r"(\d+) \+ (\d+)\(k-1\)", part).groups())
                rows.update({base + step * k: (lo, hi) for k in range(s.preview_slots)})
            elif "-" in part:
                a, b = (int(v) for v in part.split("-"))
                rows.update({j: (lo, hi) for j in range(a, b + 1)})
            else:
                rows[int(part)] = (lo, hi)
    return rows


@pytest.mark.parametrize("preset", ["paper", "urban", "field"])
def test_the_observation_table_is_the_layout_the_env_writes(preset):
    """schema.observation_table (the docs' per-task table) lists every entry in the env's order, with bounds that the
    entries keep over a mission and that the env's docstring table states; the optional blocks start where
    schema.obs_offsets says, and decode_observation reads them back."""
    s = SCENARIOS[preset].replace(mission_duration_s=30.0)
    table = schema.observation_table(s)
    assert [r["index"] for r in table] == list(range(obs_size(s)))
    assert tuple(r["name"] for r in table) == obs_names(s)
    assert all(set(r) == {"index", "name", "unit", "scaling", "min", "max", "description"} for r in table)
    doc = _docstring_rows(ISCCEnv.__doc__, SCENARIOS[preset], preset)
    assert {j: (r["min"], r["max"]) for j, r in enumerate(schema.observation_table(SCENARIOS[preset]))} == \
        {j: doc[j] for j in range(obs_size(SCENARIOS[preset]))}
    at = schema.obs_offsets(s)
    names = obs_names(s)
    for block, entries in schema.OBS_BLOCKS.items():
        if at[block] >= 0:
            assert names[at[block]].startswith(entries[0].name)
    env = ISCCEnv(s)
    obs, _ = env.reset(seed=2)
    lo, hi = np.array([r["min"] for r in table]), np.array([r["max"] for r in table])
    seen = [obs]
    for n in range(s.n_slots):
        obs, _, term, trunc, info = env.step(np.array([0.0, 0.3, -0.9 if n < 100 else 1.0], np.float32))
        seen.append(obs)
        if term or trunc:
            break
        if n == 150 and s.queue_deadline_slots:
            d = functional.decode_observation(obs, s)
            assert d["backlog_bits"] == pytest.approx(info["backlog_bits"], rel=1e-5)
            assert d["oldest_age_slots"] == pytest.approx(loop_oldest(env._state.queue[0]), abs=1e-4)
            assert d["p_los_ahead"].shape == d["echo_nlos_ahead_db"].shape == (s.preview_slots,)
    seen = np.array(seen)
    assert np.all(seen >= lo) and np.all(seen <= hi)


def loop_oldest(q):
    """Slots the oldest waiting bit has waited."""
    nz = np.flatnonzero(q > 0)
    return float(nz[-1]) if nz.size else 0.0


def test_a_task_composes_its_effects_from_one_record():
    """sim.effects.task_effects decides once what a task adds to the paper's slot; the compiled slot's switches, the
    observation's blocks, the slot's draws, the mission's columns and the loop's buffer all follow it."""
    from iscc_gym.sim.effects import task_effects
    from iscc_gym.sim.mission import mission_columns
    from iscc_gym.sim.params import slot_params

    paper, urban = task_effects(SCENARIOS["paper"]), task_effects(U)
    assert paper.paper_task and not (paper.blockage or paper.queue or paper.preview_points)
    assert (urban.blockage, urban.queue, urban.queue_deadline_slots, urban.preview_points,
            urban.preview_stride_slots, urban.preview_truth) == (True, True, 10, 10, 5, False)
    for s in (SCENARIOS["paper"], U, U.replace(preview_source="truth"), U.replace(queue_deadline_s=0.0),
              SCENARIOS["paper"].replace(observation_source="gnss", reference_feedforward=True)):
        fx, c = task_effects(s), slot_params(s)[0][0]
        assert (c["queue"], c["gnss"], c["feedforward"], c["open_loop"], c["preview_truth"]) == \
            (fx.queue, fx.gnss, fx.feedforward, fx.open_loop, fx.preview_truth)
        assert (c["blockage"] != 0.0) == fx.blockage and c["queue_deadline_slots"] == fx.queue_deadline_slots
        assert n_draws(s) == loop.N_DRAWS + fx.queue
        assert {b for b, _, _ in schema.obs_blocks(s)} == \
            {"base"} | {b for b, on in (("queue", fx.queue), ("blockage", fx.blockage),
                                        ("preview", fx.preview_points)) if on}
        assert mission_columns(s) == (19 if fx.blockage else 9)
        state = loop.init_mission(s, np.random.default_rng(0))
        assert state.queue.shape == (1, fx.queue_deadline_slots)


def test_the_data_deadline_has_one_form():
    """queue_deadline_s is the deadline's only field; Scenario.queue_deadline_slots its one conversion to slots,
    which the slot record, the observation's age scaling and the planners read; no module of the package converts
    the seconds itself."""
    from pathlib import Path

    from iscc_gym.agents import LookaheadPolicy

    from iscc_gym.sim.params import slot_params

    assert _deadline_slots(0.26) == 3 and _deadline_slots(0.0) == 0 and _deadline_slots(0.06) == 1  # >= 1 slot
    s = U.replace(queue_deadline_s=2.0)
    assert s.queue_deadline_slots == 20 and slot_params(s)[0][0]["queue_deadline_slots"] == 20
    row = [r for r in schema.observation_table(s) if r["name"] == "oldest_age"][0]
    assert row["scaling"].startswith("x / 20 ")
    assert LookaheadPolicy(s, deadline_margin=2.0).top == 20 - 1.0 - 2.0
    root = Path(iscc_gym.__file__).parent
    converting = [str(p.relative_to(root)) for p in root.rglob("*.py") if p.name != "scenario.py"
                  and re.search(r"queue_deadline_s\s*[/*]|/\s*s\.dt_s.*queue|queue.*/\s*s\.dt_s", p.read_text())]
    assert converting == []


def _deadline_slots(deadline_s):
    return U.replace(queue_deadline_s=deadline_s).queue_deadline_slots
