"""Tests of iscc_gym.physics.channel against independent oracles.

Every expected value below is written out from the paper's equations (Sec. II-B, "Communication
Signal Model under FBL"), from Table I, from physical array geometry, from finite differences, or
from Monte Carlo with a fixed seed -- never from the library's own output.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from oracle_loop import rician_power_gain, shadowing_step
from scipy import stats

from iscc_gym.physics import channel as ch
from iscc_gym.scenario import SCENARIOS, Scenario

S = Scenario()
GBS = np.array([0.0, 0.0, S.gbs_height_m])
ORIENTATIONS = ("printed", "vertical", "horizontal")


# --------------------------------------------------------------------------------------------------
# path loss
# --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("dist", [1.0, 10.0, 87.3, 250.0, 1000.0, 1234.5])
def test_path_loss_db_hand_formula(dist):
    # 3GPP UMa-AV LoS, l in m, f_c in GHz: 28 + 22 log10(l) + 20 log10(f_c).
    expected = 28.0 + 22.0 * math.log10(dist) + 20.0 * math.log10(2.4)
    assert ch.path_loss_db(S, dist) == pytest.approx(expected, rel=1e-13)


def test_path_loss_db_other_carrier_and_vectorised():
    s = S.replace(carrier_freq_ghz=3.5)
    d = np.array([50.0, 300.0, 900.0])
    expected = [28.0 + 22.0 * math.log10(x) + 20.0 * math.log10(3.5) for x in d]
    np.testing.assert_allclose(ch.path_loss_db(s, d), expected, rtol=1e-13)
    # 1 m at 1 GHz leaves only the constant.
    assert ch.path_loss_db(S.replace(carrier_freq_ghz=1.0), 1.0) == pytest.approx(28.0, abs=1e-12)


def test_path_loss_22_db_per_decade():
    d = np.array([1.0, 10.0, 100.0, 1000.0, 10000.0])
    np.testing.assert_allclose(np.diff(ch.path_loss_db(S, d)), 22.0, rtol=1e-12)
    # doubling the distance adds 22 log10(2) = 6.6227 dB
    assert ch.path_loss_db(S, 400.0) - ch.path_loss_db(S, 200.0) == pytest.approx(
        22.0 * math.log10(2.0), rel=1e-12)


# --------------------------------------------------------------------------------------------------
# geometry
# --------------------------------------------------------------------------------------------------
def _hand_geometry(p):
    """Range, azimuth, elevation, unit vector of one position, element by element with math."""
    rx, ry, rz = p[0] - 0.0, p[1] - 0.0, p[2] - S.gbs_height_m
    dist = math.sqrt(rx * rx + ry * ry + rz * rz)
    az = math.atan2(ry, rx)
    el = math.asin(rz / dist)
    return dist, az, el, np.array([rx, ry, rz]) / dist


def test_geometry_simple_points():
    # straight up from the antenna: 100 m, elevation 90 deg
    d, az, el, g = ch.geometry(S, [0.0, 0.0, S.gbs_height_m + 100.0])
    assert d == pytest.approx(100.0)
    assert el == pytest.approx(math.pi / 2)
    np.testing.assert_allclose(g, [0.0, 0.0, 1.0], atol=1e-15)
    # horizontal at antenna height along +x: azimuth 0, elevation 0
    d, az, el, g = ch.geometry(S, [100.0, 0.0, S.gbs_height_m])
    assert (d, az, el) == (pytest.approx(100.0), pytest.approx(0.0), pytest.approx(0.0))
    # 3-4-5 triangle relative to the antenna (not the ground origin)
    d, az, el, g = ch.geometry(S, [0.0, 3.0, S.gbs_height_m + 4.0])
    assert d == pytest.approx(5.0)
    assert az == pytest.approx(math.pi / 2)
    assert el == pytest.approx(math.asin(0.8))
    # the paper's theta = arctan(p_y / p_x) in the first quadrant
    d, az, el, g = ch.geometry(S, [300.0, 200.0, 150.0])
    assert az == pytest.approx(math.atan(200.0 / 300.0), rel=1e-14)


@pytest.mark.parametrize("shape", [(5,), (2, 4)])
def test_geometry_batch_matches_hand(shape):
    rng = np.random.default_rng(1)
    pos = rng.uniform([-900.0, -900.0, 100.0], [900.0, 900.0, 300.0], size=shape + (3,))
    dist, az, el, los = ch.geometry(S, pos)
    assert dist.shape == shape and az.shape == shape and el.shape == shape
    assert los.shape == shape + (3,)
    for idx in np.ndindex(*shape):
        d, a, e, g = _hand_geometry(pos[idx])
        assert dist[idx] == pytest.approx(d, rel=1e-13)
        assert az[idx] == pytest.approx(a, rel=1e-12, abs=1e-14)
        assert el[idx] == pytest.approx(e, rel=1e-12, abs=1e-14)
        np.testing.assert_allclose(los[idx], g, rtol=1e-12, atol=1e-15)
    # round trip: l [cos(el)cos(az), cos(el)sin(az), sin(el)] + antenna = p
    recon = dist[..., None] * np.stack(
        [np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1) + GBS
    np.testing.assert_allclose(recon, pos, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(los, axis=-1), 1.0, rtol=1e-14)


def test_geometry_uses_antenna_height():
    s = S.replace(gbs_height_m=0.0)
    d0, _, el0, _ = ch.geometry(s, [400.0, 0.0, 300.0])
    d1, _, el1, _ = ch.geometry(S, [400.0, 0.0, 300.0])
    assert d0 == pytest.approx(500.0)
    assert d1 == pytest.approx(math.hypot(400.0, 275.0))
    assert el1 == pytest.approx(math.atan2(275.0, 400.0))


# --------------------------------------------------------------------------------------------------
# shadowing
# --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("h", [0.0, 100.0, 150.0, 300.0])
def test_shadowing_std_db_table_i(h):
    assert ch.shadowing_std_db(S, h) == pytest.approx(4.64 * math.exp(-0.0066 * h), rel=1e-13)


def test_shadowing_std_db_vectorised():
    h = np.array([[100.0, 200.0], [250.0, 300.0]])
    np.testing.assert_allclose(ch.shadowing_std_db(S, h), 4.64 * np.exp(-0.0066 * h), rtol=1e-13)


def test_shadowing_step_limits():
    s_prev = np.array([1.5, -0.3, 0.0])
    z = np.array([0.2, -1.1, 0.7])
    # no movement: the state is unchanged; huge movement: the state is the fresh innovation
    np.testing.assert_allclose(shadowing_step(S, s_prev, 0.0, z), s_prev, atol=1e-15)
    np.testing.assert_allclose(shadowing_step(S, s_prev, 1e6, z), z, atol=1e-15)
    # one decorrelation distance: rho = 1/e
    rho = math.exp(-1.0)
    np.testing.assert_allclose(shadowing_step(S, s_prev, S.shadowing_decorrelation_m, z),
                               rho * s_prev + math.sqrt(1 - rho * rho) * z, rtol=1e-13)
    # the env's compiled step is this AR(1) (the numpy form above is the test oracle)
    for x, d, zz in zip([1.5, -0.3, 0.0, 2.0], [0.0, 10.0, 37.0, 1e6], [0.2, -1.1, 0.7, -0.4], strict=True):
        got = ch.shadowing_step_one(-1.0 / S.shadowing_decorrelation_m, x, d, zz)
        assert got == pytest.approx(float(shadowing_step(S, x, d, zz)), rel=1e-14, abs=1e-15)


@pytest.mark.parametrize("moved", [5.0, 37.0, 80.0])
def test_shadowing_step_monte_carlo(moved):
    n = 200_000
    rng = np.random.default_rng(12345)
    s0 = rng.standard_normal(n)  # stationary N(0, 1) state
    s1 = shadowing_step(S, s0, np.full(n, moved), rng.standard_normal(n))
    rho = math.exp(-moved / S.shadowing_decorrelation_m)  # Gudmundson AR(1) correlation
    # std error of a sample variance of N(0,1): sqrt(2/n) = 0.0032 -> 0.015 is > 4.5 sigma
    assert np.var(s1) == pytest.approx(1.0, abs=0.015)
    assert np.mean(s1) == pytest.approx(0.0, abs=0.012)  # 5.4 sigma of 1/sqrt(n)
    # std error of a sample correlation: (1 - rho^2)/sqrt(n) <= 0.0023 -> 0.01
    assert np.corrcoef(s0, s1)[0, 1] == pytest.approx(rho, abs=0.01)


def test_shadowing_chain_stays_stationary():
    # start from zero and iterate: the variance converges to 1, not to something else
    rng = np.random.default_rng(7)
    x = np.zeros(50_000)
    for _ in range(60):
        x = shadowing_step(S, x, 10.0, rng.standard_normal(x.size))
    assert np.var(x) == pytest.approx(1.0, abs=0.03)


# --------------------------------------------------------------------------------------------------
# Rician fading
# --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("k_db", [9.0, 0.0, 3.0])
def test_rician_power_gain_monte_carlo(k_db):
    s = S.replace(rician_k_db=k_db)
    k = 10.0 ** (k_db / 10.0)
    n = 200_000
    rng = np.random.default_rng(2024)
    p = rician_power_gain(s, rng.standard_normal(n), rng.standard_normal(n))
    assert np.all(p >= 0.0)
    # unit mean power; std of |g|^2 is sqrt(1+2K)/(K+1) <= 0.87, std error <= 0.002
    assert np.mean(p) == pytest.approx(1.0, abs=0.01)
    # the LoS component alone (zero scattering draw) is |mu|^2 = K/(K+1)
    # the env's compiled draw is this formula (the numpy form is the test oracle)
    los, scat = ch.rician_constants(s)
    for zr, zi in ((0.0, 0.0), (1.3, -0.4), (-2.0, 0.7)):
        assert ch.rician_gain_one(los, scat, zr, zi) == float(rician_power_gain(s, zr, zi))
    mu_sq = rician_power_gain(s, 0.0, 0.0)
    assert mu_sq == pytest.approx(k / (k + 1.0), rel=1e-13)
    # K-factor = |E g|^2 / Var g, with Var g = E|g|^2 - |E g|^2
    var_g = np.mean(p) - mu_sq
    assert mu_sq / var_g == pytest.approx(k, rel=0.05)
    # Var |g|^2 = sigma^4 + 2 |mu|^2 sigma^2 = (1 + 2K) / (K + 1)^2
    assert np.var(p) == pytest.approx((1 + 2 * k) / (k + 1) ** 2, rel=0.03)
    # 2(K+1)|g|^2 ~ noncentral chi-square, 2 dof, noncentrality 2K: KS distance
    ks = stats.kstest(2.0 * (k + 1.0) * p, stats.ncx2(df=2, nc=2.0 * k).cdf)
    # P(D_n > 1.95/sqrt(n)) ~ 1e-3; 0.006 = 2.7/sqrt(n) is a ~1e-6 false-alarm level
    assert ks.statistic < 0.006


# --------------------------------------------------------------------------------------------------
# UPA array response
# --------------------------------------------------------------------------------------------------
def _explicit_a(s, th, ph):
    """a = a_x kron a_y with the paper's phase terms, centred indices and spacing d/lambda."""
    if s.array_orientation == "printed":
        ux, uy = math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph)
    elif s.array_orientation == "vertical":
        ux, uy = math.cos(ph) * math.sin(th), math.sin(ph)
    else:
        ux, uy = math.cos(ph) * math.cos(th), math.cos(ph) * math.sin(th)
    d = s.antenna_spacing_wavelengths
    ix = np.arange(s.n_x) - (s.n_x - 1) / 2.0
    iy = np.arange(s.n_y) - (s.n_y - 1) / 2.0
    a_x = np.exp(1j * 2.0 * math.pi * d * ix * ux)
    a_y = np.exp(1j * 2.0 * math.pi * d * iy * uy)
    return np.kron(a_x, a_y)


def _geometric_a(s, th, ph):
    """Steering vector from physical element positions: exp(j 2 pi r_i . u / lambda)."""
    u = np.array([math.cos(ph) * math.cos(th), math.cos(ph) * math.sin(th), math.sin(ph)])
    e1, e2 = {"horizontal": (np.eye(3)[0], np.eye(3)[1]),  # up-facing, in the x-y plane
              "vertical": (np.eye(3)[1], np.eye(3)[2])}[s.array_orientation]  # y-z plane
    d = s.antenna_spacing_wavelengths
    out = []
    for i in range(s.n_x):  # kron order: first-axis index is the slow one
        for j in range(s.n_y):
            r = d * ((i - (s.n_x - 1) / 2.0) * e1 + (j - (s.n_y - 1) / 2.0) * e2)
            out.append(np.exp(1j * 2.0 * math.pi * float(r @ u)))
    return np.array(out)


ANGLES = [(0.3, 0.2), (-2.1, 0.45), (1.2, 1.1), (3.0, 0.05), (-0.7, 0.9)]


@pytest.mark.parametrize("orientation", ORIENTATIONS)
@pytest.mark.parametrize("nxy", [(2, 4), (3, 5), (4, 1)])
def test_array_response_kron(orientation, nxy):
    s = S.replace(array_orientation=orientation, n_x=nxy[0], n_y=nxy[1])
    for th, ph in ANGLES:
        a, _, _ = ch.array_response(s, th, ph)
        assert a.shape == (s.n_x * s.n_y,)
        np.testing.assert_allclose(a, _explicit_a(s, th, ph), rtol=0, atol=1e-13)
        if orientation != "printed":
            np.testing.assert_allclose(a, _geometric_a(s, th, ph), rtol=0, atol=1e-13)
        # phase reference at the array centre: mirrored elements have opposite phases
        np.testing.assert_allclose(a * a[::-1], 1.0, atol=1e-13)


def test_array_response_batch_shape():
    s = S.replace(array_orientation="vertical")
    th = np.array([[0.3, -2.1, 1.2], [3.0, -0.7, 0.0]])
    ph = np.array([[0.2, 0.45, 1.1], [0.05, 0.9, 0.3]])
    a, da_t, da_p = ch.array_response(s, th, ph)
    assert a.shape == da_t.shape == da_p.shape == (2, 3, 8)
    for idx in np.ndindex(2, 3):
        np.testing.assert_allclose(a[idx], _explicit_a(s, th[idx], ph[idx]), atol=1e-13)


@pytest.mark.parametrize("orientation", ORIENTATIONS)
def test_array_response_derivatives_finite_difference(orientation):
    s = S.replace(array_orientation=orientation)
    h = 1e-6  # central FD error ~ (pi h)^2 / 6 relative ~ 1e-12, roundoff ~ 1e-10
    for th, ph in ANGLES:
        _, da_t, da_p = ch.array_response(s, th, ph)
        fd_t = (_explicit_a(s, th + h, ph) - _explicit_a(s, th - h, ph)) / (2 * h)
        fd_p = (_explicit_a(s, th, ph + h) - _explicit_a(s, th, ph - h)) / (2 * h)
        np.testing.assert_allclose(da_t, fd_t, rtol=1e-7, atol=1e-8)
        np.testing.assert_allclose(da_p, fd_p, rtol=1e-7, atol=1e-8)


# --------------------------------------------------------------------------------------------------
# beamforming
# --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("orientation", ORIENTATIONS)
@pytest.mark.parametrize("nxy", [(2, 4), (3, 3)])
def test_matched_beamformer_gain_is_n(orientation, nxy):
    s = S.replace(array_orientation=orientation, beamforming="matched", n_x=nxy[0], n_y=nxy[1])
    th = np.array([a for a, _ in ANGLES])
    ph = np.array([b for _, b in ANGLES])
    a, _, _ = ch.array_response(s, th, ph)
    w = ch.beamformer(s, th, ph)
    assert w.shape == (len(ANGLES), nxy[0] * nxy[1])
    np.testing.assert_allclose(np.linalg.norm(w, axis=-1), 1.0, rtol=1e-13)
    np.testing.assert_allclose(ch.beamforming_gain(a, w), nxy[0] * nxy[1], rtol=1e-12)


@pytest.mark.parametrize("orientation", ORIENTATIONS)
def test_broadside_beamformer_gain(orientation):
    s = S.replace(array_orientation=orientation, beamforming="broadside")
    n = s.n_x * s.n_y
    for th, ph in ANGLES:
        a_explicit = _explicit_a(s, th, ph)
        w = ch.beamformer(s, th, ph)
        np.testing.assert_allclose(w, np.full(n, 1 / math.sqrt(n)), atol=1e-15)
        gain = ch.beamforming_gain(ch.array_response(s, th, ph)[0], w)
        assert gain == pytest.approx(abs(np.sum(a_explicit)) ** 2 / n, rel=1e-10, abs=1e-12)
        assert gain <= n * (1 + 1e-12)


def test_broadside_gain_full_along_array_normal():
    # horizontal array faces +z (zenith), vertical array faces +x, printed has u = 0 at theta = 0
    for orientation, (th, ph) in [("horizontal", (0.4, math.pi / 2)), ("vertical", (0.0, 0.0)),
                                  ("printed", (0.0, 0.7))]:
        s = S.replace(array_orientation=orientation, beamforming="broadside")
        a, _, _ = ch.array_response(s, th, ph)
        gain = ch.beamforming_gain(a, ch.beamformer(s, th, ph))
        assert gain == pytest.approx(s.n_x * s.n_y, rel=1e-12)


def test_beamforming_gain_definition():
    rng = np.random.default_rng(3)
    a = rng.standard_normal((4, 6)) + 1j * rng.standard_normal((4, 6))
    w = rng.standard_normal((4, 6)) + 1j * rng.standard_normal((4, 6))
    expected = [abs(np.vdot(a[i], w[i])) ** 2 for i in range(4)]  # |a^H w|^2
    np.testing.assert_allclose(ch.beamforming_gain(a, w), expected, rtol=1e-13)


# --------------------------------------------------------------------------------------------------
# link budget
# --------------------------------------------------------------------------------------------------
def _hand_snr(s, pos, shadow_db, gain):
    d = math.sqrt(pos[0] ** 2 + pos[1] ** 2 + (pos[2] - s.gbs_height_m) ** 2)
    p_w = 10.0 ** ((s.tx_power_dbm - 30.0) / 10.0)  # dBm -> W
    if s.snr_convention == "per_subcarrier_power":
        p_w /= s.n_subcarriers  # P_k = P_t / K
    loss_db = 28.0 + 22.0 * math.log10(d) + 20.0 * math.log10(s.carrier_freq_ghz) + shadow_db
    beta = 10.0 ** (-(loss_db - s.comm_snr_offset_db) / 10.0)
    noise_w = 10.0 ** ((s.noise_psd_dbm_hz - 30.0) / 10.0) * s.bandwidth_hz  # N_0 B
    return p_w * beta * gain / noise_w


@pytest.mark.parametrize("convention", ["total_power", "per_subcarrier_power"])
@pytest.mark.parametrize("offset", [0.0, -3.5, 6.0])
def test_large_scale_snr_hand_link_budget(convention, offset):
    s = S.replace(snr_convention=convention, comm_snr_offset_db=offset)
    pos = np.array([[300.0, -420.0, 180.0], [-650.0, 120.0, 290.0], [20.0, 15.0, 110.0]])
    shadow = np.array([1.7, -2.3, 0.0])
    snr = ch.large_scale_snr(s, pos, shadow)  # matched beamformer: G = N = 8
    assert snr.shape == (3,)
    for i in range(3):
        assert snr[i] == pytest.approx(_hand_snr(s, pos[i], shadow[i], 8.0), rel=1e-11)
    # explicit gain argument replaces G
    snr_g = ch.large_scale_snr(s, pos, shadow, gain=np.array([1.0, 2.5, 8.0]))
    for i, g in enumerate([1.0, 2.5, 8.0]):
        assert snr_g[i] == pytest.approx(_hand_snr(s, pos[i], shadow[i], g), rel=1e-11)


def test_large_scale_snr_conventions_differ_by_k():
    pos = np.array([400.0, 100.0, 200.0])
    tot = ch.large_scale_snr(S.replace(snr_convention="total_power"), pos, 0.0)
    per = ch.large_scale_snr(S.replace(snr_convention="per_subcarrier_power"), pos, 0.0)
    assert tot / per == pytest.approx(100.0, rel=1e-12)


def test_large_scale_snr_literal_preset_value():
    # Table I as printed: 42 dBm total power, N_0 B = -150 dBm/Hz * 10 MHz = -80 dBm, G = 8
    s = SCENARIOS["literal"]
    pos = np.array([0.0, 500.0, S.gbs_height_m])  # 500 m away at antenna height
    pl = 28.0 + 22.0 * math.log10(500.0) + 20.0 * math.log10(2.4)
    snr_db = 42.0 - pl + 10.0 * math.log10(8.0) - (-150.0 + 70.0)
    assert 10 * math.log10(ch.large_scale_snr(s, pos, 0.0)) == pytest.approx(snr_db, abs=1e-9)


def test_noise_power_w():
    assert ch.noise_power_w(S) == pytest.approx(1e-18 * 1e7, rel=1e-12)  # -150 dBm/Hz * 10 MHz


# --------------------------------------------------------------------------------------------------
# the numpy API is the array form of the compiled scalar functions
# --------------------------------------------------------------------------------------------------
def test_direction_trig_angles_and_zenith():
    rng = np.random.default_rng(3)
    g = rng.normal(size=(2, 5, 3))
    g /= np.linalg.norm(g, axis=-1, keepdims=True)
    ct, st, cp, sp = ch.direction_trig(g)
    assert ct.shape == st.shape == cp.shape == sp.shape == (2, 5)
    az = np.arctan2(g[..., 1], g[..., 0])  # oracle: the angles, then their cosines and sines
    el = np.arcsin(g[..., 2])
    for got, want in ((ct, np.cos(az)), (st, np.sin(az)), (cp, np.cos(el)), (sp, np.sin(el))):
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-14)
    assert ch.direction_trig([0.0, 0.0, 1.0]) == (1.0, 0.0, 0.0, 1.0)  # zenith: azimuth taken as 0
    assert all(np.ndim(v) == 0 for v in ch.direction_trig(g[0, 0]))


def test_array_forms_equal_the_compiled_scalars_bit_for_bit():
    rng = np.random.default_rng(4)
    dist = rng.uniform(50.0, 900.0, 7)
    shadow = rng.normal(0.0, 4.0, 7)
    gain = rng.uniform(0.5, 8.0, 7)
    snr = ch.link_snr(S, dist, shadow, gain)
    k = ch.snr_constant(S)
    assert snr.tolist() == [ch.link_snr_one(k, g, d, e) for g, d, e in zip(gain, dist, shadow, strict=True)]
    g = rng.normal(size=(7, 3))
    g /= np.linalg.norm(g, axis=-1, keepdims=True)
    trig = np.stack(ch.direction_trig(g), -1)
    assert trig.tolist() == [list(ch.trig_one(*row)) for row in g]
    for orientation in ORIENTATIONS:
        s = S.replace(array_orientation=orientation)
        (ux, uy), (tx, ty), (qx, qy) = ch.direction_cosines_trig(s, *trig.T)
        want = [list(ch.upa_terms_one(ch.ORIENTATIONS[orientation], *row)) for row in trig]
        assert np.stack([ux, uy, tx, ty, qx, qy], -1).tolist() == want
