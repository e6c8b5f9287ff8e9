"""The figures of :mod:`experiments.paper.fading`: loss of track and error against alpha_ctrl, the trust bound."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from iscc_gym.eval.figures import new_figure, save_figure


# --------------------------------------------------------------------------------------------------
# figures
# --------------------------------------------------------------------------------------------------
def draw(res: dict, figures_dir) -> dict[str, str]:
    """Two PNG figures: ``fading_stability`` (loss rate, loss of track and tracking error vs alpha_ctrl,
    env beside the analysis) and ``evaluator_trust`` (evaluator vs env against the worst position's
    loss rate). Returns {name: path}.
    """
    d = Path(figures_dir)
    rows = res["rows"]
    a = np.array([r["alpha_ctrl"] for r in rows]) * 100
    e = res["edges"]
    n = res["missions"]

    def vlines(ax):
        for key, lab, ls in (("alpha_ctrl_star_mean_snr", "α* (averaged SNR)", ":"),
                             ("alpha_ctrl_trajectory_average", "ε̄ = ε* (slot average)", "-."),
                             ("alpha_ctrl_worst_position", "ε = ε* (worst position)", "--"),
                             ("alpha_ctrl_trusted", "trust edge (ε ≤ 0.4 ε* everywhere)", "-")):
            ax.axvline(100 * e[key], color="0.45", ls=ls, lw=0.9, label=lab)

    fig = new_figure((15, 4.4), dpi=110)
    ax1, ax2, ax3 = fig.subplots(1, 3)
    ax1.semilogy(a, [r["eps_mean_snr"] for r in rows], "k-", label="ε at the averaged SNR (paper)")
    ax1.semilogy(a, [r["evaluator"]["eps_traj"] for r in rows], "C0-", label="ε, slot average (evaluator)")
    ax1.semilogy(a, [r["evaluator"]["eps_worst"] for r in rows], "C3-", label="ε, worst position (evaluator)")
    ax1.semilogy(a, [max(r["env"]["eps_ctrl"], 1e-6) for r in rows], "C0o", ms=4, label="ε, env (slot mean)")
    ax1.axhline(res["eps_star"], color="k", lw=0.8)
    ax1.text(a[-1], res["eps_star"] * 1.15, "ε*", ha="right")
    vlines(ax1)
    ax1.set(xlabel="α_ctrl (%)", ylabel="control loss rate", title="(a) loss rate", ylim=(1e-4, 1.5))
    ax1.legend(fontsize=6.5, loc="lower left")
    p = np.array([r["env"]["lost_fraction"] for r in rows])
    ci = np.array([r["env"]["lost_ci95"] for r in rows])
    ax2.errorbar(a, p, yerr=[np.maximum(p - ci[:, 0], 0), np.maximum(ci[:, 1] - p, 0)], fmt="o-", color="C3", ms=4,
                 capsize=2,
                 label=f"env: missions losing track ({n} per share, 95 % CI)")
    ax2.plot(a, [0.0 if r["rho_m_mean_snr"] < 1 else 1.0 for r in rows], "k:", drawstyle="steps-mid",
             label="averaged-SNR analysis: unstable (ρ(M) ≥ 1)")
    vlines(ax2)
    ax2.set(xlabel="α_ctrl (%)", ylabel="probability", title="(b) loss of track", ylim=(-0.03, 1.03))
    ax2.legend(fontsize=6.5, loc="upper right")

    def series(key):  # shown where at least 10 missions kept track
        keep = [r["env"][f"{key}_error_m"] is not None and r["env"]["missions"] - r["env"]["lost"] >= 10
                for r in rows]
        m = np.array([r["env"][f"{key}_error_m"] if k else np.nan for r, k in zip(rows, keep, strict=True)])
        c = np.array([r["env"][f"{key}_error_ci95"] if k else [np.nan, np.nan]
                      for r, k in zip(rows, keep, strict=True)])
        return m, c

    for key, col, lab in (("mean", "C0", "mean"), ("rms", "C2", "RMS")):
        m, c = series(key)
        ax3.errorbar(a, m, yerr=[np.maximum(m - c[:, 0], 0), np.maximum(c[:, 1] - m, 0)], fmt="o", color=col, ms=4,
                     capsize=2,
                     label=f"env, {lab} (missions keeping track, if >= 10)")
        for reading, ls, name in (("local", "-", "evaluator"), ("mean_snr", ":", "averaged-SNR analysis")):
            y = [np.nan if r["evaluator"][f"{reading}_{key}_m"] is None else r["evaluator"][f"{reading}_{key}_m"]
                 for r in rows]
            ax3.plot(a, y, ls, color=col, lw=1.2, label=f"{name}, {lab}")
    vlines(ax3)
    ax3.set(xlabel="α_ctrl (%)", ylabel="tracking error (m)", title="(c) tracking error (α_sen = 0.2)",
            ylim=(0.35, 1.0))
    ax3.legend(fontsize=6.5, loc="upper right")
    fig.suptitle("Stability rule under fading: the paper's α_ctrl* (averaged SNR) against the env "
                 f"(missions {res['mission_seeds'][0]}–{res['mission_seeds'][1]})", fontsize=10)
    fig.tight_layout()
    out = {"fading_stability": str(save_figure(fig, d / "fading_stability.png"))}

    fig = new_figure((7, 4.4), dpi=110)
    ax = fig.subplots()
    pts = [r for r in rows if r["evaluator"]["local_mean_m"] is not None and r["env"]["mean_error_m"] is not None]
    x = np.array([r["evaluator"]["eps_worst_over_star"] for r in pts])
    for key, col, lab in (("mean", "C0", "mean error"), ("rms", "C2", "RMS error")):
        y = [100 * (r["env"][f"{key}_error_m"] / r["evaluator"][f"local_{key}_m"] - 1) for r in pts]
        ax.plot(x, y, "o-", color=col, ms=4, label=f"env / evaluator − 1, {lab} (α_sen = 0.2)")
    lost = [r for r in pts if r["env"]["lost"]]
    if lost:
        ax.plot([r["evaluator"]["eps_worst_over_star"] for r in lost], [0] * len(lost), "rx", ms=8,
                label="missions lost track")
    for c in res["checks"]:
        ag = c["agreement"]
        if ag["mean_rel"] is not None:
            ax.plot(c["evaluator"]["eps_worst_over_star"], 100 * ag["mean_rel"], "s", color="C1", ms=4)
    ax.plot([], [], "s", color="C1", ms=4, label="checked splits and optimiser picks (mean)")
    ax.axvline(res["trust_loss_fraction"], color="k", lw=1, label="trust bound")
    ax.axhspan(-100 * res["tolerance"]["mean"], 100 * res["tolerance"]["mean"], color="C0", alpha=0.1)
    ax.set(xlabel="worst sampled position's loss rate / ε*", ylabel="env − evaluator (%)",
           title="Where the steady-state evaluator can be trusted")
    ax.legend(fontsize=7)
    fig.tight_layout()
    out["evaluator_trust"] = str(save_figure(fig, d / "evaluator_trust.png"))
    return out
