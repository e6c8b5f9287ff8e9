"""Per-scenario constants of the compiled slot, as one typed record.

:func:`slot_params` evaluates, once per scenario, every constant the compiled scalar functions of
the physics modules need (``channel.*_one``, ``fbl.*_one``, ``sensing.*_one``, ``kalman.*_one``,
``dynamics.*_one``), from the same helpers as the numpy functions (``channel.rician_constants``,
``fbl.link_constants``, ``sensing.fim_constants``, ...). The record is a numpy structured array of
one element with the named float fields of :data:`SLOT_PARAMS`; numba reads its fields by name
(``c.snr_k``), at the cost of a load, as it read the slots of the former constants vector.
"""

from __future__ import annotations

import numpy as np

from .channel import matched_gain, rician_constants, snr_constant
from .dynamics import model_matrices
from .fbl import link_constants, q_inv
from .scenario import SPEED_OF_LIGHT_MPS, Scenario, per_scenario
from .sensing import echo_constant, fim_constants, index_moments
from .stability import scenario_eps_star

__all__ = ["SLOT_PARAMS", "slot_params", "MATS", "ORIENTATIONS"]

#: The fields of the record (all float64; flags are 0.0/1.0).
SLOT_PARAMS = np.dtype([(name, np.float64) for name in (
    "h_gbs",           # GBS antenna height, m
    "sf_a", "sf_b",    # shadowing std a exp(-b h), dB and 1/m
    "neg_inv_decorr",  # -1 / shadowing decorrelation distance, 1/m
    "ric_los", "ric_scat",  # channel.rician_constants
    "snr_k", "beam_g",      # channel.snr_constant, channel.matched_gain
    "echo_k", "m_over_sig2", "c_tau", "c_nu",  # sensing.echo_constant, sensing.fim_constants
    "n_sub", "eta_sq", "sxx", "syy",           # subcarriers, sensing.index_moments
    "prior",           # 1 / sensing_prior_var_m2
    "two_over_c_sq",   # (2 / c)^2
    "lam_half_sq",     # (lambda / 2)^2
    "k_comm", "k_ctrl", "bits_per_hz", "sqrt_l",  # fbl.link_constants
    "bw", "max_err", "rate_min", "coverage_r", "n_slots",
    "orient",          # ORIENTATIONS[array_orientation]
    "fim_printed", "gnss", "open_loop", "feedforward",  # flags
    "eps_star",        # stability.scenario_eps_star
    "q_back",          # Q^-1(eps*) / sqrt(L_ctrl): control-share bound of the observation (fbl.min_shares)
    "w_rate", "w_stab",
    "gnss_every",      # slots between GNSS fixes
)])

#: Codes of ``Scenario.array_orientation`` in the record.
ORIENTATIONS = {"horizontal": 0.0, "printed": 1.0, "vertical": 2.0}

#: Slices of the packed matrices (5, 6, 6): A, B (6 x 3), K (3 x 6), Sigma_w, [chol_w; gnss whitening].
MATS = {"a": 0, "b": 1, "k": 2, "sigma_w": 3, "diags": 4}


@per_scenario
def slot_params(s: Scenario):
    """``(c, mats)``: the :data:`SLOT_PARAMS` record (a read-only structured array of shape (1,)) and
    the packed matrices (5, 6, 6) of :data:`MATS` of one scenario (read-only, cached)."""
    mm = model_matrices(s)
    eps_star = scenario_eps_star(s)
    c = np.zeros(1, SLOT_PARAMS)
    r = c[0]
    r["h_gbs"] = s.gbs_height_m
    r["sf_a"], r["sf_b"] = s.shadowing_a_db, s.shadowing_b_per_m
    r["neg_inv_decorr"] = -1.0 / s.shadowing_decorrelation_m
    r["ric_los"], r["ric_scat"] = rician_constants(s)
    r["snr_k"], r["beam_g"] = snr_constant(s), matched_gain(s)
    r["echo_k"] = echo_constant(s)
    r["m_over_sig2"], r["c_tau"], r["c_nu"] = fim_constants(s)
    r["sxx"], r["syy"], r["eta_sq"] = index_moments(s)
    r["n_sub"] = s.n_subcarriers
    r["prior"] = 1.0 / s.sensing_prior_var_m2
    r["two_over_c_sq"] = (2.0 / SPEED_OF_LIGHT_MPS) ** 2
    r["lam_half_sq"] = (0.5 * s.wavelength_m) ** 2
    k_comm, k_ctrl, bits_per_hz, sqrt_l = link_constants(s)
    r["k_comm"], r["k_ctrl"], r["bits_per_hz"], r["sqrt_l"] = k_comm, k_ctrl, bits_per_hz, sqrt_l
    r["bw"], r["max_err"], r["rate_min"] = s.bandwidth_hz, s.max_tracking_error_m, s.rate_min_bps
    r["coverage_r"], r["n_slots"] = s.coverage_radius_m, s.n_slots
    r["orient"] = ORIENTATIONS[s.array_orientation]
    r["fim_printed"] = float(s.fim_angle_convention == "printed")
    r["gnss"] = float(s.observation_source == "gnss")
    r["open_loop"] = float(s.control_mode == "open_loop")
    r["feedforward"] = float(s.reference_feedforward)
    r["eps_star"] = eps_star
    r["q_back"] = float(q_inv(eps_star)) / sqrt_l
    r["w_rate"], r["w_stab"] = s.w_rate, s.w_stab
    r["gnss_every"] = s.gnss_update_slots
    mats = np.zeros((5, 6, 6))
    mats[MATS["a"]], mats[MATS["b"], :, :3], mats[MATS["k"], :3, :] = mm.a, mm.b, mm.k
    mats[MATS["sigma_w"]] = mm.sigma_w
    mats[MATS["diags"], 0], mats[MATS["diags"], 1] = mm.chol_w, np.diag(mm.gnss_whiten)
    c.setflags(write=False)
    mats.setflags(write=False)
    return c, mats
