"""Reproduce the paper's model-level operating point and print it beside the paper's figures.

Usage::

    python -m eval.reproduce [--scenario paper|literal] [--json PATH] [--quick]

Every number is computed here from the Scenario; the paper's numbers are quoted from its text.
The ``calibration`` block shows the values of the ``paper`` preset's calibration fields that hit
the paper's reported figures on the same trajectory sample, beside the preset's own values.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq

from iscc_gym import SCENARIOS, Scenario, make_scenario
from iscc_gym.channel import geometry, large_scale_snr
from iscc_gym.dynamics import model_matrices
from iscc_gym.fbl import comm_rate_bps, ctrl_bler, dispersion, q_inv
from iscc_gym.sensing import crlb, peb, veb
from iscc_gym.stability import alpha_ctrl_star, eps_star, spectral_radius, stability_matrix
from iscc_gym.trajectory import sample_reference

#: The paper's reported model-level figures (its Sec. II-C Fig. 4, Sec. IV-C, Sec. V Table II text).
PAPER = {
    "eps_ctrl_star": 0.5055,
    "rho_m_large_alpha_ctrl": 0.1,
    "alpha_ctrl_star": 0.0403,
    "max_comm_rate_mbps": 35.0,
    "peb_m_at_alpha_sen_0_2": [0.03, 0.07],
}

ALPHA_SEN_GRID = (0.01, 0.02, 0.05, 0.1, 0.15, 0.2, 0.3, 0.5, 0.8)
ALPHA_CTRL_GRID = (0.02, 0.03, 0.035, 0.04, 0.045, 0.05, 0.06, 0.08, 0.1)
LARGE_ALPHA_CTRL = 0.2


@dataclass(frozen=True)
class TrajectorySample:
    """Drone positions along sampled reference trajectories (every ``stride``-th slot)."""

    pos_m: np.ndarray  # (n, 3)
    n_trajectories: int


def sample_positions(s: Scenario, n_trajectories: int, seed: int = 0, stride: int = 10):
    """Reference positions of ``n_trajectories`` seeded trajectories, one every ``stride`` slots."""
    rng = np.random.default_rng(seed)
    pos = [sample_reference(s, rng).pos_m[::stride] for _ in range(n_trajectories)]
    return TrajectorySample(np.concatenate(pos), n_trajectories)


def mean_snr(s: Scenario, sample: TrajectorySample) -> float:
    """Trajectory-averaged SNR (linear mean of the large-scale SNR, shadowing at its 0 dB median,
    E|g|^2 = 1)."""
    return float(np.mean(large_scale_snr(s, sample.pos_m, 0.0)))


def mean_comm_rate_bps(s: Scenario, sample: TrajectorySample, alpha_comm: float = 1.0) -> float:
    """Trajectory average of the data link's FBL rate (eq:rate_equation) at ``alpha_comm``."""
    return float(np.mean(comm_rate_bps(s, alpha_comm, large_scale_snr(s, sample.pos_m, 0.0))))


def mean_bounds(s: Scenario, sample: TrajectorySample, alpha_sen: float):
    """Trajectory-averaged PEB (m) and VEB (m/s) at ``alpha_sen`` (large-scale echo, no fading)."""
    cp, cv = crlb(s, alpha_sen, sample.pos_m, 0.0)
    return float(np.mean(peb(cp))), float(np.mean(veb(cv)))


def calibrate(s: Scenario, sample: TrajectorySample, eps_max: float) -> dict[str, float]:
    """Calibration values that put this scenario on the paper's figures for this sample.

    * ``comm_snr_offset_db``: mean FBL rate at alpha_comm = 1 equals 35 Mbps;
    * ``ctrl_deadline_s``: alpha_ctrl* at the trajectory-averaged SNR equals 4.03 %
      (closed form: eps_ctrl(alpha*) = eps* solved for T_d);
    * ``sensing_snr_offset_db``: trajectory-averaged PEB at alpha_sen = 0.2 equals 0.05 m (the
      middle of the paper's 0.03-0.07 m).
    """
    target_rate = PAPER["max_comm_rate_mbps"] * 1e6

    def rate_gap(off):
        return mean_comm_rate_bps(s.replace(comm_snr_offset_db=off), sample) - target_rate

    comm_off = float(brentq(rate_gap, -80.0, 80.0, xtol=1e-6))
    snr = mean_snr(s.replace(comm_snr_offset_db=comm_off), sample)
    c = np.log2(1.0 + snr) - q_inv(eps_max) * np.sqrt(dispersion(snr) / s.ctrl_blocklength)
    deadline = s.ctrl_packet_bits / (PAPER["alpha_ctrl_star"] * s.bandwidth_hz * c)

    def peb_gap(off):
        return np.log(mean_bounds(s.replace(sensing_snr_offset_db=off), sample, 0.2)[0] / 0.05)

    sen_off = float(brentq(peb_gap, -50.0, 250.0, xtol=1e-6))
    return {"comm_snr_offset_db": comm_off, "ctrl_deadline_s": float(deadline),
            "sensing_snr_offset_db": sen_off}


def model_level(s: Scenario, sample: TrajectorySample) -> dict:
    """The model-level figures of the paper's Secs. II-C and IV-C for scenario ``s``."""
    mm = model_matrices(s)
    e_star = eps_star(mm.a, mm.b, mm.k)
    snr = mean_snr(s, sample)
    a_star = alpha_ctrl_star(s, snr, e_star)
    eps_at = [float(ctrl_bler(s, a, snr)) for a in ALPHA_CTRL_GRID]
    rho_at = [spectral_radius(stability_matrix(mm.a, mm.b, mm.k, e)) for e in eps_at]
    eps_large = float(ctrl_bler(s, LARGE_ALPHA_CTRL, snr))
    bounds = [mean_bounds(s, sample, a) for a in ALPHA_SEN_GRID]
    p02, v02 = mean_bounds(s, sample, 0.2)
    dist = geometry(s, sample.pos_m)[0]
    return {
        "eps_ctrl_star": e_star,
        "rho_m_large_alpha_ctrl": spectral_radius(stability_matrix(mm.a, mm.b, mm.k, eps_large)),
        "rho_a_minus_bk_squared": float(np.max(np.abs(np.linalg.eigvals(mm.a_cl)))) ** 2,
        "mean_snr_db": float(10.0 * np.log10(snr)),
        "alpha_ctrl_star": a_star,
        "eps_ctrl_vs_alpha_ctrl": {"alpha_ctrl": list(ALPHA_CTRL_GRID), "eps_ctrl": eps_at,
                                   "rho_m": rho_at},
        "max_comm_rate_mbps": mean_comm_rate_bps(s, sample) / 1e6,
        "alpha_sen": list(ALPHA_SEN_GRID),
        "peb_m": [b[0] for b in bounds],
        "veb_mps": [b[1] for b in bounds],
        "peb_m_at_alpha_sen_0_2": p02,
        "veb_mps_at_alpha_sen_0_2": v02,
        "mean_range_m": float(np.mean(dist)),
    }


def run(scenario: str = "paper", quick: bool = False, seed: int = 0) -> dict:
    """Compute the reproduction for a preset; returns the JSON-able result."""
    s = make_scenario(scenario)
    t0 = time.perf_counter()
    sample = sample_positions(s, 4 if quick else 40, seed=seed, stride=50 if quick else 10)
    ours = model_level(s, sample)
    mm = model_matrices(s)
    cal = calibrate(SCENARIOS["paper"], sample, eps_star(mm.a, mm.b, mm.k))
    preset = SCENARIOS["paper"]
    return {
        "scenario": scenario,
        "quick": quick,
        "n_trajectories": sample.n_trajectories,
        **ours,
        "calibration": {
            "solved": cal,
            "paper_preset": {k: getattr(preset, k) for k in cal},
        },
        "paper": dict(PAPER),
        "wall_time_s": time.perf_counter() - t0,
    }


def format_table(res: dict) -> str:
    """Plain-text table: quantity, ours, the paper's."""
    p = res["paper"]
    lo, hi = p["peb_m_at_alpha_sen_0_2"]
    rows = [
        ("eps_ctrl* (max loss rate for MS stability)", f"{res['eps_ctrl_star']:.4f}",
         f"{p['eps_ctrl_star']:.4f}"),
        (f"rho(M) at alpha_ctrl = {LARGE_ALPHA_CTRL:g}", f"{res['rho_m_large_alpha_ctrl']:.4f}",
         f"~{p['rho_m_large_alpha_ctrl']:g}"),
        ("alpha_ctrl* (trajectory-averaged SNR)", f"{100 * res['alpha_ctrl_star']:.3f} %",
         f"{100 * p['alpha_ctrl_star']:.2f} %"),
        ("trajectory-averaged SNR", f"{res['mean_snr_db']:.2f} dB", "(not given)"),
        ("max data rate (alpha_comm = 1)", f"{res['max_comm_rate_mbps']:.2f} Mbps",
         f"~{p['max_comm_rate_mbps']:g} Mbps"),
        ("PEB at alpha_sen = 0.2", f"{res['peb_m_at_alpha_sen_0_2']:.4g} m",
         f"{lo:g}-{hi:g} m"),
        ("VEB at alpha_sen = 0.2", f"{res['veb_mps_at_alpha_sen_0_2']:.4g} m/s", "(Fig. 4a)"),
    ]
    w0 = max(len(r[0]) for r in rows)
    w1 = max(len(r[1]) for r in rows + [("", "ours")])
    lines = [f"Model-level reproduction, scenario '{res['scenario']}' "
             f"({res['n_trajectories']} trajectories{', quick' if res['quick'] else ''})",
             f"{'quantity':<{w0}}  {'ours':>{w1}}  paper", "-" * (w0 + w1 + 12)]
    lines += [f"{a:<{w0}}  {b:>{w1}}  {c}" for a, b, c in rows]
    lines.append("")
    lines.append("eps_ctrl vs alpha_ctrl (sharp transition at alpha_ctrl*):")
    tr = res["eps_ctrl_vs_alpha_ctrl"]
    for a, e, r in zip(tr["alpha_ctrl"], tr["eps_ctrl"], tr["rho_m"], strict=True):
        lines.append(f"  alpha_ctrl = {100 * a:5.1f} %   eps_ctrl = {e:9.3e}   rho(M) = {r:8.4f}")
    lines.append("PEB / VEB vs alpha_sen (trajectory average):")
    for a, pe, ve in zip(res["alpha_sen"], res["peb_m"], res["veb_mps"], strict=True):
        lines.append(f"  alpha_sen = {100 * a:5.1f} %   PEB = {pe:10.4g} m   VEB = {ve:10.4g} m/s")
    cal = res["calibration"]
    lines.append("Calibration of the 'paper' preset on this trajectory sample (solved vs preset):")
    for k, v in cal["solved"].items():
        lines.append(f"  {k:<24} solved {v:12.5g}   preset {cal['paper_preset'][k]:12.5g}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(prog="python -m eval.reproduce", description=__doc__.split("\n")[0])
    ap.add_argument("--scenario", default="paper", choices=sorted(SCENARIOS))
    ap.add_argument("--json", metavar="PATH", help="write the result as JSON to PATH")
    ap.add_argument("--quick", action="store_true", help="reduced trajectory sample (for tests)")
    ap.add_argument("--seed", type=int, default=0, help="trajectory sample seed")
    args = ap.parse_args(argv)
    res = run(args.scenario, quick=args.quick, seed=args.seed)
    print(format_table(res))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(res, f, indent=2)
        print(f"wrote {args.json}")
    return res


if __name__ == "__main__":
    main(sys.argv[1:])
