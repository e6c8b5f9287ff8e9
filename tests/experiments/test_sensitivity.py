"""Tests of experiments.paper.sensitivity: the constants that decide SCA's split and the conventions.

Oracles: env rollouts (data rate carried at SCA's split, PEB scaling with the echo SNR), the closed
form of the GNSS loop (iscc_gym.analysis.kalman_steady.gnss_steady_error_m) and the project's seed ranges."""

from __future__ import annotations

import math

import numpy as np
import pytest
from iscc_gym.agents.sca import sca_allocation
from iscc_gym.eval.tune import check_tuning_seeds

from experiments.paper import fading, sensitivity
from iscc_gym import SCENARIOS, analysis
from iscc_gym.analysis import averages
from iscc_gym.analysis.kalman_steady import gnss_steady_error_m

S = SCENARIOS["paper"]


def test_mission_seeds_held_out_and_disjoint_from_fading():
    seeds = sensitivity.mission_seeds(64, 0)
    with pytest.raises(ValueError, match="evaluation range"):
        check_tuning_seeds(seeds[:1])
    assert not set(seeds) & set(fading.mission_seeds(1000, 0))


def test_rate_floor_sets_the_data_share_the_env_carries():
    """SCA's data share carries R_min on average: flown in the env (8 missions) the mean data rate is
    within 12 % of R_min for two floors (the trajectory sample differs: 2 % below on 64 missions),
    and the data share scales with the floor."""
    shares, rates = [], []
    for r_min in (15e6, 25e6):
        s = S.replace(rate_min_bps=r_min)
        res = sca_allocation(s, model=analysis.static_model(s))
        out = fading.rollout([res.alpha], sensitivity.mission_seeds(8, 0), s)
        shares.append(res.alpha[2])
        rates.append(out["rate_comm_mbps"][0].mean() * 1e6)
        assert rates[-1] == pytest.approx(r_min, rel=0.12)
    assert shares[1] / shares[0] == pytest.approx(25 / 15, rel=1e-6)


def test_peb_scales_as_the_inverse_root_of_the_echo_snr():
    """The calibration step to Table II's 0.0635 m assumes PEB ~ SNR^-1/2 (angle-limited): +6 dB of
    echo SNR divides the trajectory-averaged PEB by 10^(6/20) within 2 %."""
    sample = averages.sample_positions(S, 4, seed=0, stride=50)
    p0 = averages.mean_bounds(S, sample, 0.2)[0]
    p6 = averages.mean_bounds(S.replace(sensing_snr_offset_db=S.sensing_snr_offset_db + 6.0), sample, 0.2)[0]
    assert p0 / p6 == pytest.approx(10 ** (6 / 20), rel=0.02)


def test_gnss_3d_reading_lowers_the_gnss_error():
    """Reading 3 m / 0.2 m/s as the 3-D total (per axis / sqrt 3) lowers the GNSS loop's steady error,
    by less than sqrt 3 (the process noise does not scale)."""
    k = sensitivity.GNSS_3D_FACTOR
    per_axis = gnss_steady_error_m(S, 0.0065, period_slots=10)
    total = gnss_steady_error_m(S.replace(gnss_pos_std_m=3 * k, gnss_vel_std_mps=0.2 * k), 0.0065, period_slots=10)
    assert 1.0 < per_axis / total < math.sqrt(3)
    assert k == pytest.approx(1 / math.sqrt(3))


def test_claims_flip_with_the_measurements():
    def res(alpha20, lost_at_1, peb):
        row = {"alpha": alpha20, "env": {"mean_error_m": 0.4, "lost": 0}, "rate_min_mbps": 20.0}
        fr = [{"loss_design_fraction": 0.1, "enforce_trust": True, "alpha": alpha20, "env": {"mean_error_m": 0.4,
                                                                                             "lost": 0}},
              {"loss_design_fraction": 1.0, "enforce_trust": False, "alpha": [0.3, 0.081, 0.619],
               "env": {"mean_error_m": 0.5, "lost": lost_at_1}}]
        return {"rate_min": [row], "loss_design_fraction": fr, "missions": 64,
                "peb_calibration": {"env_peb_at_sca_m": peb, "env_peb_at_table2_split_m": peb,
                                    "offset_for_target_db": 103.0, "preset_offset_db": 103.8},
                "gnss": [{"reading": "per axis: x", "env": {"mean_error_m": 2.2}, "iscc_over_gnss": 0.18}]}

    good = {c["id"]: c["holds"] for c in sensitivity.claims(res([0.216, 0.188, 0.596], 0, 0.0630))}
    bad = {c["id"]: c["holds"] for c in sensitivity.claims(res([0.5, 0.1, 0.4], 3, 0.050))}
    assert all(good.values())
    assert not any(bad[k] for k in ("sensitivity-rate-min-split", "sensitivity-loss-design-split",
                                    "sensitivity-design-at-eps-star", "peb-table2-target"))
    assert np.isfinite(sensitivity.PEB_TABLE2_M)
