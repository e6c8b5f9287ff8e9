"""The field task's Bayesian rung (issue 45 point 1): its likelihood, dynamics and filter against Monte Carlo, its
posterior-predictive law against the quadrature it replaces, and its limits (no spread in the prior: ``myopic``; a
posterior on the true world: ``aware``)."""

import numpy as np
import pytest
from iscc_gym.agents.bayes import BayesPolicy, MixtureLaw, rician_log_pdf, transition_matrix
from iscc_gym.agents.myopic import MyopicPolicy
from scipy.special import chndtr

from iscc_gym import make_scenario
from iscc_gym.analysis.quadrature import rician_power_nodes
from iscc_gym.physics.channel import rician_gain_one
from iscc_gym.sim.functional import decode_observation
from iscc_gym.units import db_to_lin


def _rician_power(k_lin, rng, size):
    """Samples of the unit-mean Rician power gain by the env's own function (``channel.rician_gain_one``)."""
    los, scat = np.sqrt(k_lin / (k_lin + 1.0)), np.sqrt(0.5 / (k_lin + 1.0))
    z = rng.standard_normal((size, 2))
    return np.array([rician_gain_one(los, scat, a, b) for a, b in z])


@pytest.mark.parametrize("k_db", [-10.0, 0.0, 9.0, 20.0])
def test_the_likelihood_is_the_envs_fading_law(k_db):
    """The exact density integrates to 1, has the unit mean, and its CDF matches the env's own draws (Monte Carlo)."""
    k = db_to_lin(k_db)
    g = np.linspace(1e-9, 40.0, 400_001)
    pdf = np.exp(rician_log_pdf(g, k))
    assert np.trapezoid(pdf, g) == pytest.approx(1.0, abs=2e-4)
    assert np.trapezoid(g * pdf, g) == pytest.approx(1.0, abs=2e-4)
    draws = _rician_power(k, np.random.default_rng(0), 20_000)
    for q in (0.01, 0.1, 0.5, 0.9):
        x = np.quantile(draws, q)
        assert chndtr(x * 2 * (k + 1), 2, 2 * k) == pytest.approx(q, abs=0.01)


def test_the_transition_keeps_the_prior_and_a_short_step_its_mass():
    grid = 9.0 + 5.0 * np.linspace(-4, 4, 41)
    prior = np.exp(-0.5 * ((grid - 9.0) / 5.0) ** 2)
    prior /= prior.sum()
    trans = transition_matrix(grid, 9.0, 5.0, np.array([0.9, 0.0, 1.0]))
    np.testing.assert_allclose(trans.sum(-1), 1.0, atol=1e-12)
    np.testing.assert_allclose(prior @ trans[0], prior, atol=2e-3)  # the stationary law stays
    np.testing.assert_allclose(trans[1], np.broadcast_to(trans[1][0], trans[1].shape))  # rho 0: the prior anew
    np.testing.assert_allclose(trans[2], np.eye(41), atol=1e-12)  # no distance flown: no change


def test_the_filter_is_calibrated_against_monte_carlo():
    """K along a path drawn from the prior's own Gauss-Markov law and gains from the env's Rician law: the posterior
    mean's error is about its posterior standard deviation, and the 90 % credible interval covers the truth about
    90 % of the time (a biased or over-confident filter fails)."""
    s = make_scenario("field", rcs_std_db=1e-9)  # the K-factor alone (the RCS's prior a point)
    pol = BayesPolicy(s, echo_weight=0.0)
    rng = np.random.default_rng(1)
    n, steps, rho = 64, 60, np.exp(-1.0 / s.rician_k_correlation_m)
    k = s.rician_k_db + s.rician_k_std_db * rng.standard_normal(n)
    pol._restart(n)
    errs, sds, cover = [], [], []
    for _ in range(steps):
        g = np.array([_rician_power(db_to_lin(kk), rng, 1)[0] for kk in k])
        post = pol.posterior * np.exp(rician_log_pdf(g[:, None], pol._k_lin[None, :]))[:, :, None]
        pol.posterior = post / post.sum(axis=(1, 2), keepdims=True)
        mean, sd = pol.k_estimate_db()
        w = pol.k_marginal()
        cdf = np.cumsum(w, axis=1)
        lo = pol.k_grid[np.argmax(cdf >= 0.05, axis=1)]
        hi = pol.k_grid[np.argmax(cdf >= 0.95, axis=1)]
        errs.append(mean - k)
        sds.append(sd)
        half = 0.5 * (pol.k_grid[1] - pol.k_grid[0])  # the interval's ends are cells: half a cell either side
        cover.append((k >= lo - half) & (k <= hi + half))
        k = s.rician_k_db + rho * (k - s.rician_k_db) + np.sqrt(1 - rho ** 2) * s.rician_k_std_db * \
            rng.standard_normal(n)
        pol.posterior = np.einsum("nij,nir->njr", transition_matrix(pol.k_grid, s.rician_k_db, s.rician_k_std_db,
                                                                      np.full(n, rho)), pol.posterior)
    errs, sds = np.concatenate(errs[10:]), np.concatenate(sds[10:])
    assert abs(errs.mean()) < 0.5
    assert np.sqrt(np.mean(errs ** 2)) == pytest.approx(np.sqrt(np.mean(sds ** 2)), rel=0.2)
    assert np.mean(np.concatenate(cover[10:])) == pytest.approx(0.9, abs=0.06)


def test_the_posterior_predictive_law_of_one_k_is_the_quadrature_it_replaces():
    k_db = np.array([-5.0, 9.0, 25.0])
    law = MixtureLaw(k_db, np.eye(3))
    for i, kd in enumerate(k_db):
        np.testing.assert_allclose(law.nodes()[i], rician_power_nodes(db_to_lin(kd))[0], rtol=1e-3)
    x = np.array([[1e-6, 0.1, 1.0], [1e-3, 0.5, 2.0], [0.3, 0.9, 1.1]])
    kl = db_to_lin(k_db)[:, None]
    np.testing.assert_allclose(law.cdf(x), chndtr(x * 2 * (kl + 1), 2, 2 * kl), rtol=1e-3, atol=1e-9)
    mix = MixtureLaw(k_db, np.array([[0.5, 0.5, 0.0]] * 2))
    np.testing.assert_allclose(mix.cdf(x[:2]), 0.5 * sum(chndtr(x[:2] * 2 * (k + 1), 2, 2 * k)
                                                         for k in db_to_lin(k_db[:2])), rtol=2e-3, atol=1e-9)


def _field_obs(n=6, seed=3, slots=40, show_world=False):
    import gymnasium as gym

    venv = gym.make_vec("iscc_gym/ISCC-Field-v0", num_envs=n, vectorization_mode="vector_entry_point",
                        show_world=show_world)
    obs, _ = venv.reset(seed=seed)
    pol = MyopicPolicy(make_scenario("field", show_world=show_world))
    for _ in range(slots):
        obs, *_ = venv.step(pol.predict(obs, deterministic=True)[0])
    return obs


def test_no_spread_in_the_prior_is_myopic():
    s = make_scenario("field", rician_k_std_db=1e-6, rcs_std_db=1e-6)
    obs = _field_obs()
    a_bayes = BayesPolicy(s).predict(obs, deterministic=True)[0]
    a_myopic = MyopicPolicy(s).predict(obs, deterministic=True)[0]
    np.testing.assert_allclose(a_bayes, a_myopic, atol=2e-3)


def test_a_posterior_on_the_true_world_is_aware():
    """Shown the world (the aware bound's observation), a posterior that is a point mass on the slot's true K and RCS
    designs the slot as ``aware`` does."""
    obs = _field_obs(show_world=True)
    field = make_scenario("field")
    aware = MyopicPolicy(field.replace(show_world=True))
    want = aware.split_batch(obs)[0]
    pol = BayesPolicy(field)
    from iscc_gym.sim.functional import decode_observation

    d = decode_observation(obs, field.replace(show_world=True))
    ctx_world = aware.slot_context(obs)
    from iscc_gym.agents.bayes import MixtureLaw as Law

    k = np.asarray(d["world_k_db"], dtype=float)
    law = Law(np.unique(k), (k[:, None] == np.unique(k)[None, :]).astype(float))
    ctx = pol.context(d["snr_db"], d["range_m"], d["sin_elevation"], d["cos_azimuth"], d["sin_azimuth"],
                      rcs_offset_db=d["world_rcs_offset_db"], fade=law.nodes(), fade_cdf=law.cdf)
    exact = np.stack([rician_power_nodes(db_to_lin(kk))[0] for kk in k])  # aware's table is within 2-3 % of these
    np.testing.assert_allclose(ctx.fade, exact, rtol=1e-3)
    np.testing.assert_allclose(ctx.fade, ctx_world.fade, rtol=3e-2)
    c0, d0 = pol.search(len(ctx.snr), lambda cc, dd: pol.objective(ctx, cc, dd)[0])
    got = np.stack([1.0 - c0 - d0, c0, d0], -1)
    np.testing.assert_allclose(got, want, atol=5e-3)


def test_bayes_refuses_a_world_it_cannot_filter_and_bad_parameters():
    with pytest.raises(ValueError, match="needs rician_k_std_db or rcs_std_db > 0"):
        BayesPolicy("paper")
    with pytest.raises(ValueError, match="causal"):
        BayesPolicy(make_scenario("field", show_world=True))
    for kw, msg in (({"k_points": 4}, "k_points = 4"), ({"echo_weight": 1.5}, "echo_weight = 1.5"),
                    ({"correlation_scale": 0.0}, "correlation_scale = 0.0"), ({"rcs_points": True}, "rcs_points")):
        with pytest.raises(ValueError, match=msg):
            BayesPolicy("field", **kw)


def test_bayes_is_causal_and_restarts_at_a_new_mission():
    """Its actions on a mission do not depend on the missions played before (a row at slot 0 starts from the
    prior), and it reads the observation only (the field task's 25 entries, no world block)."""
    import gymnasium as gym

    def play(seeds):
        venv = gym.make_vec("iscc_gym/ISCC-Field-v0", num_envs=2, vectorization_mode="vector_entry_point")
        pol = BayesPolicy("field")
        out = []
        for seed in seeds:
            obs, _ = venv.reset(seed=seed)
            acts = []
            for _ in range(15):
                a = pol.predict(obs, deterministic=True)[0]
                acts.append(a)
                obs, *_ = venv.step(a)
            out.append(np.array(acts))
        return out

    fresh = play([[7, 8]])[0]
    after = play([[5, 6], [7, 8]])[1]
    np.testing.assert_array_equal(fresh, after)
    assert BayesPolicy("field").obs_size == 25


def test_make_policy_builds_bayes_from_its_record_tuned_on_training_missions():
    from iscc_gym.agents import make_policy, tuned_record
    from iscc_gym.agents.tuned_records import load_tuned

    record = load_tuned("bayes")
    assert tuned_record("bayes", "field") == "bayes" and record["seeds"].startswith("5000")  # training seeds
    pol = make_policy("bayes", "field")
    assert isinstance(pol, BayesPolicy) and pol.name == "bayes"
    assert (pol.echo_weight, pol.correlation_scale) == (record["params"]["echo_weight"],
                                                        record["params"]["correlation_scale"])


def test_bayes_learn_re_estimates_the_priors_moments_online():
    """On a world whose K-factor's mean is 5 dB below the designer's 9 dB, the empirical-Bayes rung's prior mean
    moves to the world's within a few hundred slots of 16 missions, and its RCS spread stays near the world's."""
    import gymnasium as gym

    from iscc_gym.tasks import variant_scenario

    world = variant_scenario("iscc_gym/ISCC-Field-v0", "K mean 4 dB")
    venv = gym.make_vec("iscc_gym/ISCC-Field-v0", num_envs=16, vectorization_mode="vector_entry_point",
                        rician_k_db=world.rician_k_db)
    pol = BayesPolicy("field", learn_prior=True)
    fixed = BayesPolicy("field")
    assert (pol.name, pol.k_mean) == ("bayes-learn", 9.0)
    obs, _ = venv.reset(seed=11)
    for _ in range(300):
        fixed.update(decode_observation(obs, make_scenario("field")))
        obs, *_ = venv.step(pol.predict(obs, deterministic=True)[0])
    assert abs(pol.k_mean - 4.0) < 1.5 and abs(pol.k_std - 5.0) < 2.0 and abs(pol.rcs_std - 3.74) < 2.0
    assert fixed.k_mean == 9.0  # the designer's prior stays without learn_prior
    with pytest.raises(ValueError, match="learn_prior = 'yes'"):
        BayesPolicy("field", learn_prior="yes")
