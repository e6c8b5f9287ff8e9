"""Tests of iscc_gym.physics.sensing: radar link budget, the closed-form FIM (eq:FIM_tau -- eq:FIM_zero)
against the FIM from its definition, the position Jacobian (eq:Jacobian), and the CRLB / PEB / VEB.

Oracles: hand link budget from Table I formulas, central finite differences of the noise-free echo
fed to the FIM definition, finite differences of p(tau, theta, phi), explicit block inverses and
the paper's closed-form scaling laws. The calibrated preset values (offsets, deadlines) are read
from the Scenario object, never hard-coded.
"""

from __future__ import annotations

import math

import numpy as np
import oracle_sensing as so
import pytest
from oracle_sensing import whitened_observation_matrix

from iscc_gym.physics import channel as ch
from iscc_gym.physics import sensing as se
from iscc_gym.physics import signature as sig
from iscc_gym.scenario import SCENARIOS, SPEED_OF_LIGHT_MPS, Scenario

C = 299_792_458.0
assert SPEED_OF_LIGHT_MPS == C


# --------------------------------------------------------------------------------------------------
# hand link budget
# --------------------------------------------------------------------------------------------------
def _hand_path_loss(s, d):
    return 28.0 + 22.0 * math.log10(d) + 20.0 * math.log10(s.carrier_freq_ghz)


def _hand_sensing_path_loss(s, d):
    lam = C / (s.carrier_freq_ghz * 1e9)
    return (2.0 * _hand_path_loss(s, d) - 10.0 * math.log10(s.rcs_m2)
            + 10.0 * math.log10(lam**2 / (4.0 * math.pi)))


def _hand_amp(s, d, shadow_db, fading):
    """P_k beta_S |g_S|^2 with P_k = P_t / K, beta_S = 10^(-(L_S + eps - offset)/10)."""
    p_k = 10.0 ** ((s.tx_power_dbm - 30.0) / 10.0) / s.n_subcarriers
    beta = 10.0 ** (-(_hand_sensing_path_loss(s, d) + shadow_db - s.sensing_snr_offset_db) / 10.0)
    return p_k * beta * fading


def _hand_sigma2(s):
    n0 = 10.0 ** ((s.noise_psd_dbm_hz - 30.0) / 10.0)
    return n0 * (s.bandwidth_hz if s.sensing_noise_convention == "full_band"
                 else s.subcarrier_spacing_hz)


def _dist(s, p):
    return math.sqrt(p[0] ** 2 + p[1] ** 2 + (p[2] - s.gbs_height_m) ** 2)


def _coverage_positions(s, n, seed):
    """Uniform-ish positions in the coverage hemisphere, away from the zenith of the antenna."""
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < n:
        z = rng.uniform(s.altitude_min_m + 1.0, s.altitude_max_m)
        r_max = math.sqrt(s.coverage_radius_m**2 - z**2)
        r = r_max * math.sqrt(rng.uniform())
        if r < 60.0:
            continue
        a = rng.uniform(-math.pi, math.pi)
        out.append([r * math.cos(a), r * math.sin(a), z])
    return np.array(out)


@pytest.mark.parametrize("d", [80.0, 250.0, 537.2, 1000.0])
def test_sensing_path_loss_db_hand(d):
    s = Scenario()
    lam = C / 2.4e9
    expected = (2.0 * (28.0 + 22.0 * math.log10(d) + 20.0 * math.log10(2.4))
                - 10.0 * math.log10(0.01) + 10.0 * math.log10(lam**2 / (4.0 * math.pi)))
    assert se.sensing_path_loss_db(s, d) == pytest.approx(expected, rel=1e-13)
    # two-way: 44 dB per decade
    assert se.sensing_path_loss_db(s, 10 * d) - se.sensing_path_loss_db(s, d) == pytest.approx(44.0)


def test_sensing_path_loss_rcs_dependence():
    s = Scenario()
    big = s.replace(rcs_m2=1.0)
    assert se.sensing_path_loss_db(s, 300.0) - se.sensing_path_loss_db(big, 300.0) == pytest.approx(
        20.0, rel=1e-12)  # 0.01 m^2 -> 1 m^2 is 20 dB less loss


@pytest.mark.parametrize("preset", ["paper", "literal"])
def test_echo_amplitude_and_noise_hand(preset):
    s = SCENARIOS[preset]
    for d, sh, g in [(120.0, 0.0, 1.0), (640.0, -2.5, 0.7), (990.0, 3.1, 1.8)]:
        assert se.echo_amplitude_sq(s, d, sh, g) == pytest.approx(_hand_amp(s, d, sh, g),
                                                                  rel=1e-11)
    for conv in ("full_band", "per_subcarrier"):
        sc = s.replace(sensing_noise_convention=conv)
        assert se.sensing_noise_var_w(sc) == pytest.approx(_hand_sigma2(sc), rel=1e-12)
    assert se.sensing_noise_var_w(s.replace(sensing_noise_convention="full_band")) == \
        pytest.approx(1e-18 * 1e7, rel=1e-12)  # -150 dBm/Hz over 10 MHz


# --------------------------------------------------------------------------------------------------
# closed-form FIM: delay and Doppler entries by hand (eq:FIM_tau, J_nu_nu)
# --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("noise", ["full_band", "per_subcarrier"])
def test_fim_tau_nu_closed_form_hand(noise):
    s = Scenario().replace(sensing_noise_convention=noise, beamforming="matched")
    pos = np.array([[300.0, -420.0, 180.0], [-700.0, 250.0, 260.0]])
    shadow = np.array([1.3, -0.4])
    fading = np.array([0.8, 1.1])
    alpha = 0.2
    j_tau, j_nu, j_ang = se.fim(s, alpha, pos, shadow, fading)
    assert j_tau.shape == j_nu.shape == (2,) and j_ang.shape == (2, 2, 2)
    n = s.n_x * s.n_y
    eta_sq = float(n * n)  # ||a||^2 |a^H w|^2 = N * N for the matched beamformer
    k, m = s.n_subcarriers, s.n_symbols
    for i in range(2):
        pb = _hand_amp(s, _dist(s, pos[i]), shadow[i], fading[i])
        sig2 = _hand_sigma2(s)
        jt = 8 * (math.pi * s.subcarrier_spacing_hz) ** 2 * pb * eta_sq * m * (alpha * k) ** 3 / (
            3 * sig2)
        jn = 8 * (math.pi * s.symbol_duration_s) ** 2 * pb * eta_sq * alpha * k * m**3 / (3 * sig2)
        assert j_tau[i] == pytest.approx(jt, rel=1e-10)
        assert j_nu[i] == pytest.approx(jn, rel=1e-10)


# --------------------------------------------------------------------------------------------------
# closed-form FIM vs the FIM from its definition (finite differences of the echo)
# --------------------------------------------------------------------------------------------------
K_SEN = 20
# step sizes relative to each parameter's scale: the phase moves by ~1e-5 rad per step
STEPS = np.array([1e-12, 1e-6, 1e-6, 1e-3])  # tau [s], theta [rad], phi [rad], nu [Hz]
NU_S = 150.0  # Doppler of ~9.4 m/s radial speed at 2.4 GHz


def _definition_fim(s, pos, shadow_db, fading, steps=STEPS):
    dist, az, el, _ = ch.geometry(s, pos)
    amp = se.echo_amplitude_sq(s, dist, shadow_db, fading)  # the closed form's P_k beta_S |g|^2
    w = ch.beamformer(s, az, el)  # the closed form's beamformer, held fixed
    xi = np.array([2.0 * float(dist) / C, float(az), float(el), NU_S])
    dmu = []
    for i in range(4):
        e = np.zeros(4)
        e[i] = steps[i]
        dmu.append((so.echo_mean(s, xi + e, K_SEN, w, amp)
                    - so.echo_mean(s, xi - e, K_SEN, w, amp)) / (2.0 * steps[i]))
    return so.fim_from_definition(dmu, se.sensing_noise_var_w(s))


def _sum_sq(n):
    """sum_{k=0}^{n-1} k^2 = (n-1) n (2n-1) / 6 (exact), vs the closed form's n^3 / 3."""
    return (n - 1) * n * (2 * n - 1) / 6.0


FIM_CASES = [
    ("horizontal", "matched", [300.0, -420.0, 180.0]),
    ("horizontal", "broadside", [-250.0, 310.0, 260.0]),
    ("vertical", "matched", [520.0, 230.0, 140.0]),
    ("vertical", "broadside", [610.0, -140.0, 220.0]),
    ("printed", "matched", [350.0, 410.0, 290.0]),
]


@pytest.mark.parametrize("orientation, beam, p", FIM_CASES)
def test_fim_closed_form_matches_definition(orientation, beam, p):
    s = Scenario().replace(array_orientation=orientation, beamforming=beam,
                           fim_angle_convention="definition")
    pos = np.array(p)
    shadow, fading = 1.3, 0.8
    jd = _definition_fim(s, pos, shadow, fading)
    # the FD is converged: halving every step changes nothing at the 1e-7 level
    jd_half = _definition_fim(s, pos, shadow, fading, STEPS / 2)
    diag = np.sqrt(np.outer(np.diag(jd), np.diag(jd)))
    assert np.all(np.abs(jd_half - jd) <= 1e-7 * diag)

    alpha = K_SEN / s.n_subcarriers
    j_tau, j_nu, j_ang = se.fim(s, alpha, pos, shadow, fading)
    k, m = K_SEN, s.n_symbols
    # eq:FIM_tau replaces sum_{k<K} k^2 by K^3/3 and J_nu_nu sum_{m<M} m^2 by M^3/3: correct the
    # closed form by the exact ratio before comparing to the definition (exact sums)
    assert jd[0, 0] == pytest.approx(j_tau * _sum_sq(k) / (k**3 / 3.0), rel=1e-6)
    assert jd[3, 3] == pytest.approx(j_nu * _sum_sq(m) / (m**3 / 3.0), rel=1e-6)
    # angle block: no approximation in the closed form
    assert jd[1, 1] == pytest.approx(j_ang[0, 0], rel=1e-6)
    assert jd[2, 2] == pytest.approx(j_ang[1, 1], rel=1e-6)
    assert jd[1, 2] == pytest.approx(j_ang[0, 1], rel=1e-5, abs=1e-6 * diag[1, 2])
    assert j_ang[0, 1] == j_ang[1, 0]
    # eq:FIM_zero: no delay-angle coupling with the centred array (relative to sqrt(J_tt J_aa))
    assert abs(jd[0, 1]) < 1e-7 * diag[0, 1]
    assert abs(jd[0, 2]) < 1e-7 * diag[0, 2]
    # Doppler-angle coupling also vanishes
    assert abs(jd[1, 3]) < 1e-7 * diag[1, 3]
    assert abs(jd[2, 3]) < 1e-7 * diag[2, 3]


def test_fim_definition_delay_doppler_coupling_is_not_zero():
    """Documents a paper simplification: J_{tau nu} != 0 (the paper declares nu decoupled).

    d mu / d tau = -j 2 pi k Df mu and d mu / d nu = j 2 pi m T_S mu, so
    J_{tau nu} = -(8 pi^2 Df T_S P beta ||eta||^2 / sigma^2) sum_k k sum_m m, and the correlation
    coefficient is -sum k sum m / sqrt(M sum k^2 K sum m^2) -> -3/4 for large K, M.
    """
    s = Scenario().replace(fim_angle_convention="definition")
    jd = _definition_fim(s, np.array([300.0, -420.0, 180.0]), 0.0, 1.0)
    k, m = K_SEN, s.n_symbols
    rho_expected = -(k * (k - 1) / 2) * (m * (m - 1) / 2) / math.sqrt(
        m * _sum_sq(k) * k * _sum_sq(m))
    rho = jd[0, 3] / math.sqrt(jd[0, 0] * jd[3, 3])
    assert rho == pytest.approx(rho_expected, rel=1e-6)
    assert abs(rho) > 0.7  # far from the paper's 0 (-0.737 for K = 20, M = 64)
    # the large-K, M limit of the coefficient is -3/4
    kk = mm = 10**6
    assert -(kk * (kk - 1) / 2) * (mm * (mm - 1) / 2) / math.sqrt(
        mm * _sum_sq(kk) * kk * _sum_sq(mm)) == pytest.approx(-0.75, rel=1e-5)


def test_fim_printed_angle_convention_factor():
    s_def = Scenario().replace(fim_angle_convention="definition", beamforming="matched")
    s_pr = s_def.replace(fim_angle_convention="printed")
    pos = _coverage_positions(s_def, 6, seed=5)
    n = s_def.n_x * s_def.n_y
    eta_sq = float(n) ** 2  # ||eta||^2 = ||a||^2 |a^H w|^2 = N^2, matched beamformer
    jt_d, jn_d, ja_d = se.fim(s_def, 0.3, pos, 0.5, 1.2)
    jt_p, jn_p, ja_p = se.fim(s_pr, 0.3, pos, 0.5, 1.2)
    np.testing.assert_allclose(ja_p, ja_d * eta_sq / 4.0, rtol=1e-12)
    np.testing.assert_allclose(jt_p, jt_d, rtol=1e-14)  # only the angle block changes
    np.testing.assert_allclose(jn_p, jn_d, rtol=1e-14)


@pytest.mark.parametrize("preset", ["paper", "literal"])
def test_fim_alpha_scaling(preset):
    s = SCENARIOS[preset]
    pos = _coverage_positions(s, 4, seed=11)
    a1 = np.array([0.05, 0.1, 0.2, 0.3])
    for f in (2.0, 3.0):
        jt1, jn1, ja1 = se.fim(s, a1, pos, 0.0, 1.0)
        jt2, jn2, ja2 = se.fim(s, f * a1, pos, 0.0, 1.0)
        np.testing.assert_allclose(jt2 / jt1, f**3, rtol=1e-12)  # J_tau_tau ~ (alpha K)^3
        np.testing.assert_allclose(jn2 / jn1, f, rtol=1e-12)  # J_nu_nu ~ alpha K
        np.testing.assert_allclose(ja2, f * ja1, rtol=1e-12, atol=0)  # angles ~ alpha K


# --------------------------------------------------------------------------------------------------
# Jacobian and CRLB
# --------------------------------------------------------------------------------------------------
def _p_of_xi(tau, th, ph):
    """p(tau, theta, phi) = (c tau / 2) u(theta, phi), relative to the GBS antenna."""
    return 0.5 * C * tau * np.array([math.cos(ph) * math.cos(th), math.cos(ph) * math.sin(th),
                                     math.sin(ph)])


def _fd_jacobian(s, p):
    rel = np.asarray(p, float) - np.array([0.0, 0.0, s.gbs_height_m])
    d = float(np.linalg.norm(rel))
    xi = np.array([2 * d / C, math.atan2(rel[1], rel[0]), math.asin(rel[2] / d)])
    assert np.allclose(_p_of_xi(*xi), rel, rtol=1e-12)
    steps = np.array([1e-12, 1e-7, 1e-7])
    cols = []
    for i in range(3):
        e = np.zeros(3)
        e[i] = steps[i]
        cols.append((_p_of_xi(*(xi + e)) - _p_of_xi(*(xi - e))) / (2 * steps[i]))
    return np.stack(cols, -1)


def test_position_jacobian_finite_difference():
    s = Scenario()
    pos = _coverage_positions(s, 8, seed=3)
    ups = so.position_jacobian(s, pos)
    assert ups.shape == (8, 3, 3)
    for i in range(8):
        fd = _fd_jacobian(s, pos[i])
        # columns have different units (m/s vs m/rad): compare each column on its own scale
        for c in range(3):
            np.testing.assert_allclose(ups[i][:, c], fd[:, c], rtol=0,
                                       atol=1e-7 * np.linalg.norm(fd[:, c]))
    # first column is (c/2) times the LoS unit vector
    _, _, _, los = ch.geometry(s, pos)
    np.testing.assert_allclose(ups[..., :, 0], 0.5 * C * los, rtol=1e-13)


def _inv_jp(j_tau, j_ang):
    """Inverse of blkdiag(J_tau, 2x2 angle block), written out by hand."""
    a, b, c, d = j_ang[0, 0], j_ang[0, 1], j_ang[1, 0], j_ang[1, 1]
    det = a * d - b * c
    out = np.zeros((3, 3))
    out[0, 0] = 1.0 / j_tau
    out[1:, 1:] = np.array([[d, -b], [-c, a]]) / det
    return out


@pytest.mark.parametrize("orientation", ["horizontal", "vertical"])
def test_crlb_matches_eq_crlb_pos(orientation):
    s = Scenario().replace(array_orientation=orientation, sensing_prior_var_m2=1e12)
    pos = _coverage_positions(s, 10, seed=21)
    shadow = np.linspace(-3.0, 3.0, 10)
    fading = np.linspace(0.5, 1.5, 10)
    alpha = 0.15
    crlb_p, crlb_vr = se.crlb(s, alpha, pos, shadow, fading)
    j_tau, j_nu, j_ang = se.fim(s, alpha, pos, shadow, fading)
    from_jac = so.crlb_position_from_jacobian(s, pos, j_tau, j_ang)
    assert crlb_p.shape == from_jac.shape == (10, 3, 3)
    for i in range(10):
        ups = _fd_jacobian(s, pos[i])
        oracle = ups @ _inv_jp(j_tau[i], j_ang[i]) @ ups.T  # eq:CRLB_pos
        scale = np.abs(oracle).max()
        np.testing.assert_allclose(crlb_p[i], oracle, rtol=1e-5, atol=1e-6 * scale)
        np.testing.assert_allclose(from_jac[i], oracle, rtol=1e-5, atol=1e-6 * scale)
        # symmetric positive definite
        np.testing.assert_allclose(crlb_p[i], crlb_p[i].T, rtol=0, atol=1e-12 * scale)
        assert np.all(np.linalg.eigvalsh(crlb_p[i]) > 0)
    # CRLB_vr = (lambda/2)^2 / J_nu_nu (prior negligible)
    lam = C / (s.carrier_freq_ghz * 1e9)
    np.testing.assert_allclose(crlb_vr, (lam / 2) ** 2 / j_nu, rtol=1e-8)


def test_peb_veb_definitions():
    s = Scenario()
    pos = _coverage_positions(s, 5, seed=8)
    crlb_p, crlb_vr = se.crlb(s, 0.2, pos, 0.0, 1.0)
    for i in range(5):
        tr = crlb_p[i, 0, 0] + crlb_p[i, 1, 1] + crlb_p[i, 2, 2]
        assert se.peb(crlb_p)[i] == pytest.approx(math.sqrt(tr), rel=1e-14)
        assert se.veb(crlb_vr)[i] == pytest.approx(math.sqrt(crlb_vr[i]), rel=1e-14)


def test_crlb_vr_hand():
    s = Scenario().replace(sensing_prior_var_m2=1e12, beamforming="matched")
    p = np.array([-420.0, 510.0, 230.0])
    alpha = 0.25
    _, crlb_vr = se.crlb(s, alpha, p, 0.7, 0.9)
    n = s.n_x * s.n_y
    jn = (8 * (math.pi * s.symbol_duration_s) ** 2 * _hand_amp(s, _dist(s, p), 0.7, 0.9)
          * n**2 * alpha * s.n_subcarriers * s.n_symbols**3 / (3 * _hand_sigma2(s)))
    lam = C / (s.carrier_freq_ghz * 1e9)
    assert crlb_vr == pytest.approx((lam / 2) ** 2 / jn, rel=1e-8)
    assert se.veb(crlb_vr) == pytest.approx(lam / 2 / math.sqrt(jn), rel=1e-8)


def test_crlb_alpha_zero_is_the_prior():
    s = Scenario()
    pos = np.array([[300.0, 200.0, 150.0]])
    crlb_p, crlb_vr = se.crlb(s, 0.0, pos, 0.0, 1.0)
    # computed as U M U^T in the local frame: off-diagonals are rounding of U U^T (1e-16 relative)
    np.testing.assert_allclose(crlb_p[0], s.sensing_prior_var_m2 * np.eye(3), rtol=1e-12,
                               atol=1e-12 * s.sensing_prior_var_m2)
    assert crlb_vr[0] == pytest.approx(s.sensing_prior_var_m2, rel=1e-12)


@pytest.mark.parametrize("preset", ["paper", "literal"])
def test_peb_and_veb_decrease_in_alpha(preset):
    s = SCENARIOS[preset]
    pos = _coverage_positions(s, 5, seed=13)
    alphas = np.linspace(0.01, 1.0, 60)
    for p in pos:
        crlb_p, crlb_vr = se.crlb(s, alphas, np.broadcast_to(p, (60, 3)), 0.0, 1.0)
        peb = se.peb(crlb_p)
        veb = se.veb(crlb_vr)
        assert np.all(np.isfinite(peb)) and np.all(np.isfinite(veb))
        assert np.all(np.diff(peb) < 0.0)
        assert np.all(np.diff(veb) < 0.0)


@pytest.mark.parametrize("preset", ["paper", "literal"])
@pytest.mark.parametrize("p", [[400.0, 0.0, 200.0], [-400.0, 0.0, 150.0], [0.0, 400.0, 200.0],
                               [0.0, -550.0, 280.0]],
                         ids=["theta=0", "theta=pi", "theta=pi/2", "theta=-pi/2"])
def test_crlb_finite_at_printed_endfire(preset, p):
    """The printed response sin(theta)cos(phi), sin(theta)sin(phi) loses one angle at theta = 0, pi
    (d/dphi = 0) and at theta = +-pi/2 (d/dtheta = 0); the weak prior keeps the CRLB finite."""
    s = SCENARIOS[preset].replace(array_orientation="printed")
    pos = np.array(p)
    _, _, j_ang = se.fim(s, 0.2, pos, 0.0, 1.0)
    # the angle information really is singular here (the case under test)
    det = j_ang[0, 0] * j_ang[1, 1] - j_ang[0, 1] ** 2
    assert abs(det) <= 1e-12 * max(j_ang[0, 0], j_ang[1, 1]) ** 2
    crlb_p, crlb_vr = se.crlb(s, 0.2, pos, 0.0, 1.0)
    assert np.all(np.isfinite(crlb_p)) and np.isfinite(crlb_vr)
    np.testing.assert_allclose(crlb_p, crlb_p.T, rtol=0, atol=1e-12 * np.abs(crlb_p).max())
    eig = np.linalg.eigvalsh(crlb_p)
    assert np.all(eig > 0)
    # The lost angle leaves one direction (d u / d phi at theta = 0, pi; d u / d theta at
    # theta = +-pi/2) with the prior alone, orthogonal to the informed ones: its CRLB eigenvalue is
    # exactly sensing_prior_var_m2. The information matrix spans ~1e-6 .. 1e7 m^-2 in the paper
    # preset (condition ~1e13), so floating point only resolves it to ~eps * cond ~ 1e-3.
    assert eig.max() == pytest.approx(s.sensing_prior_var_m2, rel=1e-2)
    assert np.isfinite(se.peb(crlb_p)) and se.peb(crlb_p) > 0


def test_prior_negligible_in_paper_preset():
    """Away from endfire the default weak prior (sensing_prior_var_m2) leaves the paper preset's
    CRLB unchanged (its PEB is centimetres, the prior's std a kilometre). NB: in the "literal"
    preset (PEB ~ 1 km) the same prior dominates the PEB, so it is not negligible there."""
    s = SCENARIOS["paper"]
    pos = _coverage_positions(s, 6, seed=17)
    with_prior, vr_prior = se.crlb(s, 0.2, pos, 0.0, 1.0)
    no_prior, vr_none = se.crlb(s.replace(sensing_prior_var_m2=1e14), 0.2, pos, 0.0, 1.0)
    np.testing.assert_allclose(se.peb(with_prior), se.peb(no_prior), rtol=1e-6)
    np.testing.assert_allclose(vr_prior, vr_none, rtol=1e-6)


@pytest.mark.parametrize("orientation", ["printed", "vertical", "horizontal"])
def test_matched_closed_form_equals_general_signature(orientation):
    """The matched-beamformer closed form vs the explicit array sums with w passed in."""
    s = Scenario(array_orientation=orientation)
    rng = np.random.default_rng(3)
    az, el = rng.uniform(-np.pi, np.pi, 50), rng.uniform(0.05, 1.5, 50)
    closed = sig.signature_derivatives(s, az, el)
    general = sig.signature_derivatives(s, az, el, w=ch.beamformer(s, az, el))
    for c, g in zip(closed, general, strict=True):
        np.testing.assert_allclose(c, g, rtol=1e-10, atol=1e-9 * np.max(np.abs(g)))


@pytest.mark.parametrize("orientation", ["printed", "horizontal"])
def test_crlb_local_frame_equals_inverse_of_position_information(orientation):
    """crlb (local frame, closed-form 2x2 inverse) vs inv(position information + prior)."""
    s = Scenario(array_orientation=orientation)
    rng = np.random.default_rng(4)
    pos = np.column_stack([rng.uniform(-600, 600, 40), rng.uniform(-600, 600, 40),
                           rng.uniform(101, 300, 40)])
    crlb_p, _ = se.crlb(s, 0.15, pos, 0.3, 0.8)
    j_tau, _, j_ang = se.fim(s, 0.15, pos, 0.3, 0.8)
    info = so.position_information(s, pos, j_tau, j_ang) + np.eye(3) / s.sensing_prior_var_m2
    ref = np.linalg.inv(info)
    np.testing.assert_allclose(crlb_p, ref, rtol=1e-7, atol=1e-12 * s.sensing_prior_var_m2)


def test_whitened_observation_carries_the_same_information():
    """(W C)^T (W C) = C^T Sigma_v^{-1} C with Sigma_v = blkdiag(CRLB_p, CRLB_vr) from crlb()."""
    from iscc_gym.physics.kalman import isac_observation_matrix

    s = Scenario()
    rng = np.random.default_rng(5)
    pos = np.column_stack([rng.uniform(-600, 600, 30), rng.uniform(-600, 600, 30),
                           rng.uniform(101, 300, 30)])
    alpha, shadow, fade = 0.2, 0.4, 0.9
    dist, _, _, los = ch.geometry(s, pos)
    trig = ch.direction_trig(los)
    m = se.crlb_local(s, alpha, dist, trig, shadow, fade)
    wc = whitened_observation_matrix(los, trig, *m)
    crlb_p, crlb_vr = se.crlb(s, alpha, pos, shadow, fade)
    sig = np.zeros((30, 4, 4))
    sig[:, :3, :3] = crlb_p
    sig[:, 3, 3] = crlb_vr
    c = isac_observation_matrix(los)
    info = np.swapaxes(c, -1, -2) @ np.linalg.inv(sig) @ c
    got = np.swapaxes(wc, -1, -2) @ wc
    np.testing.assert_allclose(got, info, rtol=1e-6, atol=1e-9 * np.max(np.abs(info)))


@pytest.mark.parametrize("overrides", [{}, {"array_orientation": "printed", "fim_angle_convention": "printed"},
                                       {"array_orientation": "vertical"}, {"beamforming": "broadside"},
                                       {"beamforming": "broadside", "array_orientation": "printed"},
                                       {"beamforming": "broadside", "array_orientation": "vertical"}])
def test_compiled_crlb_local_matches_the_numpy_oracle(overrides):
    """sensing.crlb_local (the env's compiled CRLB) against the numpy oracle (tests/oracle_sensing.py)."""
    s = Scenario(**overrides)
    rng = np.random.default_rng(2)
    pos = rng.uniform([-400, -400, 20], [400, 400, 200], (7, 3))
    dist, _, _, los = ch.geometry(s, pos)
    trig = ch.direction_trig(los)
    alpha = rng.uniform(0, 1, 7)
    shadow, fading = rng.normal(0, 3, 7), rng.exponential(1.0, 7)
    got = se.crlb_local(s, alpha, dist, trig, shadow, fading)
    want = so.crlb_local(s, alpha, dist, trig, shadow, fading)
    for g, w in zip(got, want, strict=True):
        assert g.shape == (7,)
        np.testing.assert_allclose(g, w, rtol=1e-10)
