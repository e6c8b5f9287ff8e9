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

from iscc_gym.physics.blockage import BLOCKAGE_MODELS
from iscc_gym.physics.channel import matched_gain, rician_constants, snr_constant
from iscc_gym.physics.dynamics import model_matrices
from iscc_gym.physics.fbl import LINK_PARAMS, link_constants, link_params, q_inv
from iscc_gym.physics.queue import arrival_sigma
from iscc_gym.physics.sensing import SENSING_PARAMS, sensing_noise_var_w, sensing_params
from iscc_gym.physics.stability import scenario_eps_star
from iscc_gym.scenario import Scenario, per_scenario
from iscc_gym.sim.effects import task_effects
from iscc_gym.sim.mission import world_column
from iscc_gym.sim.schema import obs_offsets

__all__ = ["SLOT_PARAMS", "slot_params", "MATS"]

#: The slot's own fields (the rest come from the physics modules' records).
_OWN_FIELDS = (
    "gbs_height_m",    # GBS antenna height, m
    "sf_a", "sf_b",    # shadowing std a exp(-b h), dB and 1/m
    "neg_inv_decorr",  # -1 / shadowing decorrelation distance, 1/m
    "ric_los", "ric_scat",  # channel.rician_constants
    "snr_k", "beam_g",      # channel.snr_constant, channel.matched_gain
    "max_tracking_error_m", "rate_min_bps", "coverage_radius_m", "n_slots",
    "gnss", "open_loop", "feedforward", "queue",  # the task's switches (sim.effects.TaskEffects), 0/1
    "eps_star",        # stability.scenario_eps_star
    "q_back",          # Q^-1(eps*) / sqrt(L_ctrl): control-share bound of the observation (fbl.min_shares)
    "w_rate", "w_stab",
    "gnss_every",      # slots between GNSS fixes
    "blockage",        # physics.blockage.BLOCKAGE_MODELS code: 0 none (the paper), 1 UMa-AV, 2 UMi-AV
    "carrier_freq_ghz",
    "queue_deadline_slots",  # the queue's deadline D in slots (Scenario.queue_deadline_slots), 0 without a queue
    "arrival_mean_bits", "arrival_sigma",  # mean arrivals per slot (bits), log-normal sigma (physics.queue)
    "dt_s",
    "preview_slots", "preview_stride_slots",
    "sen_noise_w",     # sensing.sensing_noise_var_w: the echo SNR's noise
    "preview_truth",   # 1.0 with preview_source="truth" (the oracle's preview)
    "obs_queue_at", "obs_echo_at", "obs_preview_at",  # schema.obs_offsets: where the observation's blocks start, -1
    "obs_measured_at", "obs_world_at",
    "world_at",        # mission.world_column: where a mission row's world columns start (the field), -1 without
)
#: The fields of the record (all float64; flags are 0.0/1.0): the slot's own, then those of
#: :data:`iscc_gym.physics.sensing.SENSING_PARAMS` and :data:`iscc_gym.physics.fbl.LINK_PARAMS` (copied from
#: their records). Aligned (``align=True``; all fields float64, so the layout is the packed one): numba types the record
#: as aligned and the device loads each field as one 8-byte word, not byte by byte (issue 46).
SLOT_PARAMS = np.dtype([(name, np.float64) for name in _OWN_FIELDS]
                       + [(name, np.float64) for name in SENSING_PARAMS.names + LINK_PARAMS.names], align=True)

#: Slices of the packed matrices (5, 6, 6): A, B (6 x 3), K (3 x 6), Sigma_w, [chol_w; gnss whitening].
MATS = {"a": 0, "b": 1, "k": 2, "sigma_w": 3, "diags": 4}


@per_scenario
def slot_params(s: Scenario):
    """``(c, mats)``: the :data:`SLOT_PARAMS` record (a read-only structured array of shape (1,)) and
    the packed matrices (5, 6, 6) of :data:`MATS` of one scenario (read-only, cached).
    """
    mm = model_matrices(s)
    eps_star = scenario_eps_star(s)
    c = np.zeros(1, SLOT_PARAMS)
    r = c[0]
    for part in (sensing_params(s)[0], link_params(s)[0]):
        for name in part.dtype.names:
            r[name] = part[name]
    r["gbs_height_m"] = s.gbs_height_m
    r["sf_a"], r["sf_b"] = s.shadowing_a_db, s.shadowing_b_per_m
    r["neg_inv_decorr"] = -1.0 / s.shadowing_decorrelation_m
    r["ric_los"], r["ric_scat"] = rician_constants(s)
    r["snr_k"], r["beam_g"] = snr_constant(s), matched_gain(s)
    r["max_tracking_error_m"], r["rate_min_bps"] = s.max_tracking_error_m, s.rate_min_bps
    r["coverage_radius_m"], r["n_slots"] = s.coverage_radius_m, s.n_slots
    fx = task_effects(s)
    r["gnss"], r["open_loop"], r["feedforward"], r["queue"] = fx.gnss, fx.open_loop, fx.feedforward, fx.queue
    r["eps_star"] = eps_star
    r["q_back"] = float(q_inv(eps_star)) / link_constants(s)[3]
    r["w_rate"], r["w_stab"] = s.w_rate, s.w_stab
    r["gnss_every"] = s.gnss_update_slots
    r["blockage"] = BLOCKAGE_MODELS[s.blockage]
    r["carrier_freq_ghz"] = s.carrier_freq_ghz
    r["queue_deadline_slots"] = fx.queue_deadline_slots
    r["arrival_mean_bits"] = s.queue_arrival_bps * s.dt_s
    r["arrival_sigma"] = arrival_sigma(s.queue_arrival_cv)
    r["dt_s"] = s.dt_s
    r["preview_slots"], r["preview_stride_slots"] = fx.preview_points, fx.preview_stride_slots
    r["sen_noise_w"] = sensing_noise_var_w(s)
    r["preview_truth"] = fx.preview_truth
    at = obs_offsets(s)
    r["obs_queue_at"], r["obs_echo_at"], r["obs_preview_at"] = at["queue"], at["blockage"], at["preview"]
    r["obs_measured_at"], r["obs_world_at"] = at["measured"], at["world"]
    r["world_at"] = world_column(s)
    mats = np.zeros((5, 6, 6))
    mats[MATS["a"]], mats[MATS["b"], :, :3], mats[MATS["k"], :3, :] = mm.a, mm.b, mm.k
    mats[MATS["sigma_w"]] = mm.sigma_w
    mats[MATS["diags"], 0], mats[MATS["diags"], 1] = mm.chol_w, np.diag(mm.gnss_whiten)
    c.setflags(write=False)
    mats.setflags(write=False)
    return c, mats
