"""``python -m experiments.paper.sensitivity``: the constants that decide the reproduced split, and the conventions.

Two constants with no value in the paper decide SCA's split (``docs/model.md`` sec. 4): the data-rate
floor ``rate_min_bps`` (R_comm^min of cons:comm_rate; 20 Mbps) and SCA's ``loss_design_fraction``
(the design loss rate as a fraction of eps*, which turns the open constraint alpha_ctrl >
alpha_ctrl* into a threshold; 0.1). This module sweeps each over a range, re-solves SCA (Algorithm 1)
and flies its split in the env (common random numbers): the split, the tracking error (mean and RMS)
and the fraction of slots violating a constraint. It also measures the conventions stated together
in ``docs/model.md`` sec. 4: the communication SNR's per-subcarrier power over full-band noise
against the sensing link's per-subcarrier noise (each flipped, offsets unchanged), the GNSS noise
per axis against the 3-D total, and the PEB calibration against Table II's 0.0635 m at SCA's split.

Missions: seeds ``1_200_000 + 1000 * seed + i`` (:func:`mission_seeds`), held-out evaluation seeds
(``eval.tune.EVAL_SEED_RANGES``), disjoint from training, tuning and ``experiments.paper.fading``'s missions.

Examples::

    python -m experiments.paper.sensitivity                # 64 missions per point, about a minute
    python -m experiments.paper.sensitivity --quick --json /tmp/sens.json --figures /tmp/fig
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import numpy as np
from iscc_gym.agents.sca import sca_allocation
from iscc_gym.commands.protocol import SENSITIVITY_SEED_START as SEED_START
from iscc_gym.commands.protocol import held_out_seeds
from iscc_gym.eval.figures import new_figure, save_figure

from experiments.paper.fading import rollout, summarize_missions
from iscc_gym import SCENARIOS
from iscc_gym.analysis import TRUST_LOSS_FRACTION, static_model
from iscc_gym.analysis.averages import mean_bounds, sample_positions

__all__ = ["run", "draw", "main", "mission_seeds", "RATE_MIN_MBPS", "LOSS_DESIGN_FRACTIONS", "PEB_TABLE2_M",
           "SEED_START"]

#: Sweeps (full, quick).
RATE_MIN_MBPS = (10.0, 15.0, 18.0, 20.0, 22.0, 25.0, 28.0, 30.0)
QUICK_RATE_MIN_MBPS = (15.0, 20.0, 25.0)
LOSS_DESIGN_FRACTIONS = (0.01, 0.02, 0.05, 0.1, 0.2, 0.3, 0.4, 0.6, 1.0)
QUICK_LOSS_DESIGN_FRACTIONS = (0.02, 0.1, 0.4, 1.0)
MISSIONS, QUICK_MISSIONS = 64, 12
#: Table II: PEB (m) at SCA's split (20 / 20 / 60 %), the sensing calibration's target.
PEB_TABLE2_M = 0.0635
#: Table II: SCA's split (sen, ctrl, comm).
SCA_SPLIT_TABLE2 = (0.20, 0.20, 0.60)
#: GNSS reading: the paper's 3 m and 0.2 m/s as per-axis standard deviations (preset) or as the 3-D total.
GNSS_3D_FACTOR = 1.0 / math.sqrt(3.0)


def mission_seeds(n: int, seed: int = 0) -> list[int]:
    """``n`` mission seeds of run ``seed``: ``SEED_START + 1000 * seed + i``, inside the held-out range."""
    return held_out_seeds(SEED_START, n, seed)


def _fin(x):
    x = float(x)
    return x if math.isfinite(x) else None


def _point(model, res, env: dict, **extra) -> dict:
    met = model.evaluate(res.alpha)
    return {**extra, "alpha": [float(a) for a in res.alpha], "sca_feasible": bool(res.feasible),
            "evaluator": {"mean_m": _fin(met.tracking_error_m[0]), "rms_m": _fin(met.tracking_rmse_m[0]),
                          "trusted": bool(met.trusted[0]), "stable": bool(met.stable[0]),
                          "rate_ok": bool(met.rate_ok[0]),
                          "eps_worst_over_star": float(model.eps_ctrl_local(res.alpha[1])[0].max() / model.eps_star)},
            "env": env}


def run(quick: bool = False, seed: int = 0) -> dict:
    """The sweeps of ``rate_min_bps`` and ``loss_design_fraction``, the conventions and the PEB
    calibration (JSON-able; ``claims`` list).
    """
    t0 = time.perf_counter()
    s = SCENARIOS["paper"]
    n = QUICK_MISSIONS if quick else MISSIONS
    seeds = mission_seeds(n, seed)
    base = static_model(s)
    # --- rate_min_bps
    rate_pts = []
    for r_mbps in (QUICK_RATE_MIN_MBPS if quick else RATE_MIN_MBPS):
        sr = s.replace(rate_min_bps=r_mbps * 1e6)
        m = static_model(sr)
        res = sca_allocation(sr, model=m)
        rate_pts.append((m, res, {"rate_min_mbps": r_mbps}))
    rate_rows = []
    for m, res, extra in rate_pts:  # flown with that floor: it sets the env's rate violations
        r_i = rollout([res.alpha], seeds, m.scenario)
        rate_rows.append(_point(m, res, summarize_missions(r_i, 0), **extra))
    # --- loss_design_fraction (with and without the evaluator's trust bound)
    frac_pts = []
    for f in (QUICK_LOSS_DESIGN_FRACTIONS if quick else LOSS_DESIGN_FRACTIONS):
        for trust in (True, False):
            res = sca_allocation(s, model=base, loss_design_fraction=f, enforce_trust=trust)
            frac_pts.append((base, res, {"loss_design_fraction": f, "enforce_trust": trust}))
    env = rollout([p[1].alpha for p in frac_pts], seeds, s)
    frac_rows = [_point(m, res, summarize_missions(env, i), **extra) for i, (m, res, extra) in enumerate(frac_pts)]
    # --- conventions (offsets unchanged; each flipped alone) and the GNSS reading
    variants = {
        "paper preset": {},
        "comm: per-subcarrier noise (P_k / N0 df = P_t / N0 B)": {"snr_convention": "total_power"},
        "sensing: full-band noise (sigma^2 = N0 B)": {"sensing_noise_convention": "full_band"},
    }
    sample = sample_positions(s, 40, seed=0, stride=10)
    conv_rows = []
    for name, ov in variants.items():
        sv = s.replace(**ov)
        m = static_model(sv)
        res = sca_allocation(sv, model=m)
        r = rollout([res.alpha, SCA_SPLIT_TABLE2], seeds, sv)
        row = _point(m, res, summarize_missions(r, 0), variant=name, overrides=ov)
        row["mean_snr_db"] = float(10 * np.log10(m.mean_snr))
        row["rate_per_share_mbps"] = m.rate_comm_per_share_bps * 1e-6
        row["peb_at_0.2_m"] = mean_bounds(sv, sample, 0.2)[0]
        row["env_at_table2_split"] = summarize_missions(r, 1)
        conv_rows.append(row)
    sca = sca_allocation(s, model=base)
    a_ctrl = float(sca.alpha[1])
    gnss_split = [0.0, a_ctrl, 1.0 - a_ctrl]
    gnss_rows = []
    for name, k in (("per axis (preset): 3 m, 0.2 m/s per axis", 1.0),
                    ("3-D total: 3 m, 0.2 m/s over the three axes (1.73 m, 0.115 m/s per axis)", GNSS_3D_FACTOR)):
        sg = s.replace(observation_source="gnss", gnss_pos_std_m=s.gnss_pos_std_m * k,
                       gnss_vel_std_mps=s.gnss_vel_std_mps * k)
        r = rollout([gnss_split], seeds, sg)
        gnss_rows.append({"reading": name, "pos_std_per_axis_m": sg.gnss_pos_std_m,
                          "vel_std_per_axis_mps": sg.gnss_vel_std_mps, "split": gnss_split,
                          "env": summarize_missions(r, 0)})
    iscc_env = conv_rows[0]["env"]
    for g in gnss_rows:
        g["iscc_over_gnss"] = iscc_env["mean_error_m"] / g["env"]["mean_error_m"]
    # --- PEB calibration: Table II's 0.0635 m at SCA's split
    peb_t2 = conv_rows[0]["env_at_table2_split"]["peb_m"]
    shift_db = 20.0 * math.log10(peb_t2 / PEB_TABLE2_M)  # PEB ~ SNR^-1/2 (angle-limited)
    s_cal = s.replace(sensing_snr_offset_db=s.sensing_snr_offset_db + shift_db)
    r = rollout([SCA_SPLIT_TABLE2], seeds, s_cal)
    peb = {"target_m": PEB_TABLE2_M, "target_split": list(SCA_SPLIT_TABLE2), "sca_split": sca.alpha.tolist(),
           "env_peb_at_sca_m": iscc_env["peb_m"], "env_peb_at_table2_split_m": peb_t2,
           "trajectory_average_large_scale_peb_at_0.2_m": conv_rows[0]["peb_at_0.2_m"],
           "preset_offset_db": s.sensing_snr_offset_db, "offset_for_target_db": s.sensing_snr_offset_db + shift_db,
           "env_peb_with_that_offset_m": float(r["peb_m"][0].mean()),
           "env_error_with_that_offset_m": summarize_missions(r, 0)["mean_error_m"]}
    res = {"scenario": "paper", "quick": quick, "seed": seed, "missions": n, "mission_seeds": [seeds[0], seeds[-1]],
           "trust_loss_fraction": TRUST_LOSS_FRACTION, "rate_min": rate_rows, "loss_design_fraction": frac_rows,
           "conventions": conv_rows, "gnss": gnss_rows, "peb_calibration": peb}
    res["claims"] = claims(res)
    res["wall_time_s"] = time.perf_counter() - t0
    return res


def claims(res: dict) -> list[dict]:
    """Claims of the sweeps (Table II's split and its 0.0635 m PEB, the 17.37 % ratio under both GNSS readings)."""
    out = []
    rr = {r["rate_min_mbps"]: r for r in res["rate_min"]}
    r20 = rr.get(20.0)
    if r20 is not None:
        split20 = " / ".join(f"{100 * a:.1f}" for a in r20["alpha"])
        moves = ", ".join(f"{k:g} Mbps: {100 * v['alpha'][2]:.0f} %" for k, v in rr.items())
        out.append({
            "id": "sensitivity-rate-min-split",
            "figure": "Table II",
            "paper": "SCA's split 20 / 20 / 60 % (sen / ctrl / comm)",
            "ours": (f"R_min = 20 Mbps gives {split20} %; the data share moves with R_min ({moves})"),
            "holds": abs(r20["alpha"][2] - 0.60) <= 0.02 and abs(r20["alpha"][1] - 0.20) <= 0.03,
            "why": "the paper gives no R_min; 20 Mbps is chosen so that the data share carries it at alpha_comm "
                   "~0.60 (33.6 Mbps per unit share, slot average)",
        })
    fr = [r for r in res["loss_design_fraction"] if r["enforce_trust"]]
    f01 = next((r for r in fr if r["loss_design_fraction"] == 0.1), None)
    if f01 is not None:
        out.append({
            "id": "sensitivity-loss-design-split",
            "figure": "Table II",
            "paper": "SCA's control share 20 %",
            "ours": (f"loss_design_fraction = 0.1 gives alpha_ctrl = {100 * f01['alpha'][1]:.1f} %; over "
                     f"{fr[0]['loss_design_fraction']:g}-{fr[-1]['loss_design_fraction']:g} it ranges "
                     f"{100 * min(r['alpha'][1] for r in fr):.1f}-{100 * max(r['alpha'][1] for r in fr):.1f} % "
                     f"with the env's mean error {min(r['env']['mean_error_m'] for r in fr):.4f}-"
                     f"{max(r['env']['mean_error_m'] for r in fr):.4f} m"),
            "holds": abs(f01["alpha"][1] - 0.20) <= 0.03,
            "why": "0.1 keeps every sampled position's loss rate at eps*/10 (rho(M) = 0.22 there), well inside the "
                   "evaluator's trust bound; the error is flat in it while the split stays trusted",
        })
    no_trust = [r for r in res["loss_design_fraction"] if not r["enforce_trust"]]
    lost = [r for r in no_trust if r["env"]["lost"]]
    worst = max(no_trust, key=lambda r: r["loss_design_fraction"])
    out.append({
        "id": "sensitivity-design-at-eps-star",
        "figure": "sec. 3.2",
        "paper": "alpha_ctrl > alpha_ctrl* is equivalent to rho(M) < 1 (the threshold itself, design fraction 1)",
        "ours": (f"without the trust bound, design fraction {worst['loss_design_fraction']:g} gives alpha_ctrl = "
                 f"{100 * worst['alpha'][1]:.1f} %: {worst['env']['lost']} of {res['missions']} missions lose track, "
                 f"{sum(r['env']['lost'] for r in lost)} over the {len(no_trust)} fractions"),
        "holds": not lost,
        "why": "at the threshold every stable-on-average split sits where the env's losses come in runs",
    })
    peb = res["peb_calibration"]
    out.append({
        "id": "peb-table2-target",
        "figure": "Table II",
        "paper": f"PEB {PEB_TABLE2_M} m at SCA's split (20 / 20 / 60 %)",
        "ours": (f"held-out env slot-mean PEB {peb['env_peb_at_table2_split_m']:.4f} m at 20 / 20 / 60 %, "
                 f"{peb['env_peb_at_sca_m']:.4f} m at our SCA split; the offset that hits {PEB_TABLE2_M} m on these "
                 f"missions is {peb['offset_for_target_db']:.2f} dB (preset {peb['preset_offset_db']:.2f})"),
        "holds": abs(peb["env_peb_at_table2_split_m"] / PEB_TABLE2_M - 1.0) <= 0.05,
        "why": "the preset's sensing_snr_offset_db is calibrated in the env to this value at 20 / 20 / 60 % on "
               "1024 calibration missions (experiments.paper.reproduce.calibrate_sensing_offset); checked here on "
               "held-out "
               "missions, tolerance 5 %",
    })
    g = res["gnss"]
    out.append({
        "id": "gnss-noise-reading",
        "figure": "Fig. 9",
        "paper": "GNSS noise std 3 m and 0.2 m/s; ISCC error 17.37 % of GNSS's",
        "ours": "; ".join(f"{x['reading'].split(':')[0]}: GNSS {x['env']['mean_error_m']:.3f} m, ISCC/GNSS "
                          f"{100 * x['iscc_over_gnss']:.1f} %" for x in g),
        "holds": abs(g[0]["iscc_over_gnss"] - 0.1737) <= 0.05,
        "why": "per-axis reading (preset) with a 1 Hz fix; the 3-D-total reading lowers GNSS's error by about "
               "1/sqrt(3)",
    })
    return out


# --------------------------------------------------------------------------------------------------
# figures
# --------------------------------------------------------------------------------------------------
def draw(res: dict, figures_dir) -> dict[str, str]:
    """``sensitivity_constants``: SCA's split, its tracking error and the violation fraction over
    ``rate_min_bps`` (top row) and ``loss_design_fraction`` (bottom row). Returns {name: path}.
    """
    fig = new_figure((14, 7.5), dpi=110)
    axes = fig.subplots(2, 3)

    def panel(row_axes, rows, x, xlabel, mark, logx=False, label=""):
        ax_s, ax_e, ax_v = row_axes
        al = np.array([r["alpha"] for r in rows])
        for j, (name, col) in enumerate((("sensing", "C2"), ("control", "C3"), ("data", "C0"))):
            ax_s.plot(x, 100 * al[:, j], "o-", color=col, ms=4, label=f"α_{name}{label}")
        mean = np.array([np.nan if r["env"]["mean_error_m"] is None else r["env"]["mean_error_m"] for r in rows])
        rms = np.array([np.nan if r["env"]["rms_error_m"] is None else r["env"]["rms_error_m"] for r in rows])
        ax_e.plot(x, mean, "o-", color="C0", ms=4, label=f"env, mean{label}")
        ax_e.plot(x, rms, "s-", color="C2", ms=4, label=f"env, RMS{label}")
        ax_e.plot(x, [np.nan if r["evaluator"]["mean_m"] is None else r["evaluator"]["mean_m"] for r in rows],
                  ":", color="C0", label=f"evaluator, mean{label}")
        lost = [(xi, r["env"]["lost"]) for xi, r in zip(x, rows, strict=True) if r["env"]["lost"]]
        for xi, k in lost:
            ax_e.annotate(f"{k} lost", (xi, 0.5), fontsize=7, color="C3", ha="center")
        for key, col, lab in (("violation", "k", "any"), ("rate_violation", "C0", "data rate < R_min"),
                              ("stability_violation", "C3", "ε_ctrl,n > ε*")):
            ax_v.plot(x, [r["env"][key] for r in rows], "o-", color=col, ms=4, label=f"{lab}{label}")
        for ax in row_axes:
            ax.axvline(mark, color="0.5", ls="--", lw=0.9)
            ax.set_xlabel(xlabel)
            if logx:
                ax.set_xscale("log")
        ax_s.set_ylabel("SCA's split (%)")
        ax_e.set_ylabel("tracking error (m)")
        ax_v.set_ylabel("fraction of slots violating")

    rr = res["rate_min"]
    panel(axes[0], rr, [r["rate_min_mbps"] for r in rr], "R_min (Mbps)", 20.0)
    fr = [r for r in res["loss_design_fraction"] if r["enforce_trust"]]
    fn = [r for r in res["loss_design_fraction"] if not r["enforce_trust"]]
    panel(axes[1], fr, [r["loss_design_fraction"] for r in fr], "loss_design_fraction (× ε*)", 0.1, logx=True)
    xs = [r["loss_design_fraction"] for r in fn]
    axes[1][0].plot(xs, [100 * r["alpha"][1] for r in fn], "x--", color="C3", label="α_control, no trust bound")
    axes[1][1].plot(xs, [np.nan if r["env"]["mean_error_m"] is None else r["env"]["mean_error_m"] for r in fn],
                    "x--", color="C0", label="env, mean, no trust bound")
    for xi, r in zip(xs, fn, strict=True):
        if r["env"]["lost"]:
            axes[1][1].annotate(f"{r['env']['lost']}/{res['missions']} lost", (xi, 0.43), fontsize=7, color="C3",
                                ha="center")
    axes[1][0].axvline(res["trust_loss_fraction"], color="k", lw=0.8)
    axes[0][0].set_title("(a) SCA's split vs R_min")
    axes[0][1].set_title("(b) tracking error at SCA's split")
    axes[0][2].set_title("(c) violations at SCA's split")
    axes[1][0].set_title("(d) SCA's split vs loss_design_fraction")
    axes[1][1].set_title("(e) tracking error")
    axes[1][2].set_title("(f) violations")
    for ax in axes.ravel():
        ax.legend(fontsize=6.5)
    axes[0][1].set_ylim(0.38, 0.9)
    axes[1][1].set_ylim(0.38, 0.6)
    fig.suptitle(f"Sensitivity of SCA's split to R_min and the design loss rate (env: {res['missions']} missions "
                 f"per point, seeds {res['mission_seeds'][0]}–{res['mission_seeds'][1]}; dashed: the preset)",
                 fontsize=10)
    fig.tight_layout()
    return {"sensitivity_constants": str(save_figure(fig, Path(figures_dir) / "sensitivity_constants.png"))}


# --------------------------------------------------------------------------------------------------
# command line
# --------------------------------------------------------------------------------------------------
def _report(res: dict) -> None:
    for key in ("rate_min", "loss_design_fraction"):
        for r in res[key]:
            tag = {k: v for k, v in r.items() if k in ("rate_min_mbps", "loss_design_fraction", "enforce_trust")}
            e = r["env"]
            print(f"{tag}: split {np.round(r['alpha'], 4).tolist()}, env mean {e['mean_error_m']}, "
                  f"RMS {e['rms_error_m']}, lost {e['lost']}, violations {e['violation']:.3f}")


def build_parser(prog: str = "python -m experiments.paper.sensitivity"):
    from iscc_gym.commands.options import claims_parser

    return claims_parser(prog, __doc__.splitlines()[0], missions=MISSIONS, quick_missions=QUICK_MISSIONS,
                         seed_base=SEED_START, figures_default="runs/sensitivity/figures")


def main(argv: list[str] | None = None, prog: str = "python -m experiments.paper.sensitivity") -> dict:
    from iscc_gym.commands.options import run_claims_command

    args = build_parser(prog).parse_args(argv)
    return run_claims_command(args, run, draw,
                              lambda a: mission_seeds(QUICK_MISSIONS if a.quick else MISSIONS, a.seed), _report)


if __name__ == "__main__":
    from iscc_gym.commands.cli import run as _run_cli

    sys.exit(_run_cli(main, None, "python -m experiments.paper.sensitivity"))
