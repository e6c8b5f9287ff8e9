"""The paper's Figs. 3-8 redrawn from our model, and its statements about them tested as claims.

Part of ``python -m experiments.paper.reproduce`` (:func:`run` computes, :func:`draw` writes the PNGs). Figure
numbers are the paper's (LaTeX order; Figs. 1-2 are illustrations). Where each figure's numbers come
from:

* **Fig. 3** (VEB, PEB vs alpha_sen at several SNRs) and **Fig. 4** (rho(M) vs eps_ctrl, eps_ctrl vs
  alpha_ctrl, rho(M) vs alpha_ctrl): closed forms (the CRLB of :mod:`iscc_gym.physics.sensing` on the
  trajectory sample, eq:M and eq:ctrl_bler of :mod:`iscc_gym.physics.stability` / :mod:`iscc_gym.physics.fbl`), as in
  the paper. The SNR levels of Fig. 3 are shifts of the sensing link's echo SNR around the ``paper``
  preset (the paper does not give its levels).
* **Figs. 5-8** (LQG cost and tracking error over (alpha_sen, alpha_ctrl), error vs PEB, the coupling
  of PEB, data rate and LQG cost): a closed-loop Monte Carlo of the env's transition
  (:func:`experiments.paper.paper_mc.fly_splits`: every split on the same seeded missions, the LQG stage
  cost recovered exactly from the transition). The steady-state evaluator
  (:mod:`iscc_gym.analysis`) is drawn beside it as dashed lines where it calls a split stable: it has
  no loss-of-track and is optimistic near the stability edge (issue 13), which is exactly where the
  paper's statements about alpha_ctrl = 5-7 % live, so it is not the source of any claim here.

Every claim is a dict ``{id, figure, paper, ours, holds, why}``; :func:`claims` derives them from
the measured numbers only (the paper's words and numbers are quoted in :data:`PAPER`).
"""

from __future__ import annotations

import numpy as np

from experiments.paper.paper_figures_draw import FIGURES, PAPER, draw
from experiments.paper.paper_mc import fly_splits
from iscc_gym.analysis import static_model
from iscc_gym.analysis.averages import mean_bounds, mean_snr, sample_positions
from iscc_gym.physics.dynamics import model_matrices
from iscc_gym.physics.fbl import ctrl_bler
from iscc_gym.physics.sensing import echo_amplitude_sq, sensing_noise_var_w
from iscc_gym.physics.stability import alpha_ctrl_star, eps_star, spectral_radius, stability_matrix
from iscc_gym.scenario import Scenario
from iscc_gym.units import w_to_dbm

__all__ = ["PAPER", "FIGURES", "run", "draw", "claims", "fit_line"]

#: Where each figure's numbers come from (docs/results.md).
SOURCES = {
    "Fig. 3": "closed form: the CRLB on the trajectory sample (large-scale echo, no fading)",
    "Fig. 4": "closed form: eq:M and eq:ctrl_bler at the trajectory-averaged SNR (plus the fading-averaged "
              "loss rate, dashed)",
    "Fig. 5": "Monte Carlo of the env's transition (LQG stage cost recovered from the transition); "
              "steady-state evaluator dashed",
    "Fig. 6": "Monte Carlo of the env's transition; steady-state evaluator dashed",
    "Fig. 7": "Monte Carlo of the env's transition (env PEB, with echo fading); evaluator dashed",
    "Fig. 8": "Monte Carlo of the env's transition (the Fig. 5-6 grid)",
}

ALPHA_SEN = (0.01, 0.02, 0.03, 0.05, 0.07, 0.10, 0.15, 0.20, 0.25, 0.30)
ALPHA_CTRL = (0.04, 0.05, 0.06, 0.07, 0.08, 0.09, 0.10, 0.12, 0.15, 0.20)
QUICK_ALPHA_SEN = (0.01, 0.05, 0.10, 0.30)
QUICK_ALPHA_CTRL = (0.05, 0.07, 0.10, 0.20)
#: The paper's Fig. 7 curves go up to 9 % and 10 %; ours add the stable 12-20 %.
FIG7_CTRL = (0.06, 0.07, 0.08, 0.09, 0.10, 0.12, 0.15, 0.20)
#: Shifts (dB) of the echo SNR around the ``paper`` preset: the SNR levels of Fig. 3.
SNR_SHIFTS_DB = (-10.0, -5.0, 0.0, 5.0, 10.0)
MISSIONS, QUICK_MISSIONS, QUICK_SLOTS = 24, 2, 200
N_BOOT = 300


def fit_line(x, y):
    """Least-squares line y = k x + c: returns (k, c, R^2) (R^2 = nan with fewer than 3 points)."""
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    if len(x) < 2:
        return float("nan"), float("nan"), float("nan")
    k, c = np.polyfit(x, y, 1)
    ss_res = float(np.sum((y - (k * x + c)) ** 2))
    ss_tot = float(np.sum((y - y.mean()) ** 2))
    r2 = 1.0 - ss_res / ss_tot if len(x) >= 3 and ss_tot > 0 else float("nan")
    return float(k), float(c), r2


# --------------------------------------------------------------------------------------------------
# data
# --------------------------------------------------------------------------------------------------
def fig3_data(s: Scenario, sample, quick: bool) -> dict:
    a = np.geomspace(0.005, 1.0, 10 if quick else 40)
    s0 = s.replace(sensing_snr_offset_db=0.0)
    mean_range = float(np.mean(np.linalg.norm(sample.pos_m - np.array([0.0, 0.0, s.gbs_height_m]), axis=1)))
    echo_dbm = float(w_to_dbm(echo_amplitude_sq(s0, mean_range, 0.0, 1.0)))
    noise_dbm = float(w_to_dbm(sensing_noise_var_w(s0)))
    curves = []
    for d in SNR_SHIFTS_DB:
        sd = s.replace(sensing_snr_offset_db=s.sensing_snr_offset_db + d)
        b = np.array([mean_bounds(sd, sample, float(x)) for x in a])
        curves.append({"shift_db": d, "echo_snr_db": echo_dbm + s.sensing_snr_offset_db + d - noise_dbm,
                       "peb_m": b[:, 0].tolist(), "veb_mps": b[:, 1].tolist()})
    return {"alpha_sen": a.tolist(), "curves": curves, "mean_range_m": mean_range,
            "peb_m_at_0_2": mean_bounds(s, sample, 0.2)[0]}


def fig4_data(s: Scenario, sample, model) -> dict:
    mm = model_matrices(s)
    e_star = eps_star(mm.a, mm.b, mm.k)
    eps = np.linspace(0.0, 1.0, 201)
    rho_eps = [spectral_radius(stability_matrix(mm.a, mm.b, mm.k, e)) for e in eps]
    snr = mean_snr(s, sample)
    a = np.linspace(0.02, 0.2, 181)
    eps_a = np.asarray(ctrl_bler(s, a, snr), dtype=float)
    rho_a = [spectral_radius(stability_matrix(mm.a, mm.b, mm.k, e)) for e in eps_a]
    return {
        "eps": eps.tolist(), "rho_vs_eps": rho_eps, "eps_star": e_star,
        "alpha_ctrl": a.tolist(), "eps_vs_alpha": eps_a.tolist(), "rho_vs_alpha": rho_a,
        "eps_faded_vs_alpha": model.eps_ctrl(a).tolist(),
        "eps_worst_vs_alpha": model.eps_ctrl_local(a).max(axis=1).tolist(),
        "alpha_ctrl_star": alpha_ctrl_star(s, snr, e_star),
        "alpha_ctrl_star_faded_mean": model.alpha_ctrl_for_loss(e_star, local=False),
        "alpha_ctrl_star_faded_worst": model.alpha_ctrl_for_loss(e_star, local=True),
        "mean_snr_db": float(10.0 * np.log10(snr)),
    }


def grid_data(s: Scenario, model, quick: bool, seed: int, extra_splits: dict) -> dict:
    sen = QUICK_ALPHA_SEN if quick else ALPHA_SEN
    ctrl = QUICK_ALPHA_CTRL if quick else ALPHA_CTRL
    grid = [(a, c, 1.0 - a - c) for c in ctrl for a in sen]
    names = list(extra_splits)
    splits = np.array(grid + [tuple(extra_splits[n]) for n in names], dtype=float)
    mc = fly_splits(s, splits, QUICK_MISSIONS if quick else MISSIONS, seed=seed,
                    n_slots=QUICK_SLOTS if quick else None)
    n = len(grid)
    shape = (len(ctrl), len(sen))
    keys = ("tracking_error_m", "tracking_rmse_m", "lqg_cost", "peb_m", "rate_mbps", "eps_ctrl", "lost")
    out = {"alpha_sen": list(sen), "alpha_ctrl": list(ctrl), "n_missions": mc["n_missions"],
           "n_slots": mc["n_slots"], "seed": seed}
    for k in keys:
        out[k] = mc[k][:n].reshape(shape).tolist()
    per = mc["per_mission"]
    out["per_mission"] = {k: per[k][:n].reshape(shape + (-1,)).tolist()
                          for k in ("tracking_error_m", "peb_m", "lost")}
    out["splits"] = {name: {"alpha": [float(x) for x in splits[n + i]], **{k: float(mc[k][n + i]) for k in keys}}
                     for i, name in enumerate(names)}
    # the steady-state evaluator on the same grid (inf where it calls the split unstable)
    met = model.evaluate(np.array(grid))
    out["analytic"] = {k: np.where(np.isfinite(v := getattr(met, k)), v, np.nan).reshape(shape).tolist()
                       for k in ("tracking_error_m", "tracking_rmse_m", "lqg_cost", "peb_m")}
    # the evaluator's lines for Figs. 5(b)-6(b) and 7 (fine alpha_ctrl)
    fine = np.linspace(min(ctrl), max(ctrl), 12 if quick else 60)
    lines = {}
    for a in sen:
        m = model.evaluate(np.stack([np.full_like(fine, a), fine, 1.0 - a - fine], -1))
        lines[str(a)] = {k: np.where(np.isfinite(v := getattr(m, k)), v, np.nan).tolist()
                         for k in ("tracking_error_m", "lqg_cost")}
    out["analytic_vs_ctrl"] = {"alpha_ctrl": fine.tolist(), "by_alpha_sen": lines}
    return out


def run(s: Scenario, quick: bool = False, seed: int = 0, sample=None, extra_splits: dict | None = None) -> dict:
    """Compute Figs. 3-8 for scenario ``s`` (JSON-able), with their ``claims``.

    ``sample``: the trajectory sample of the closed forms (default: 40 trajectories, 4 with
    ``quick``); ``extra_splits``: named splits flown beside the grid (e.g. SCA's), reported under
    ``grid.splits``. ``quick``: a 4 x 4 grid, 2 missions of 200 slots (for tests).
    """
    if sample is None:
        sample = sample_positions(s, 4 if quick else 40, seed=seed, stride=50 if quick else 10)
    model = static_model(s)
    extra = {"paper_sca": (0.2, 0.2, 0.6), **(extra_splits or {})}
    res = {
        "fig3": fig3_data(s, sample, quick),
        "fig4": fig4_data(s, sample, model),
        "grid": grid_data(s, model, quick, seed, extra),
        "sources": dict(SOURCES),
        "paper": dict(PAPER),
    }
    res["fig7"] = fig7_fits(res["grid"])
    res["fig8"] = fig8_stats(res["grid"], model)
    res["claims"] = claims(res)
    return res


def _stable_rows(g) -> np.ndarray:
    """Rows (alpha_ctrl) of the grid where no mission of any alpha_sen lost track."""
    return ~np.any(np.asarray(g["lost"]) > 0, axis=1)


def fig7_fits(g: dict) -> dict:
    """Per alpha_ctrl row of :data:`FIG7_CTRL` in the grid: the line error = k PEB + c over the
    alpha_sen points where no mission lost track (env PEB), its R^2, a bootstrap 90 % interval of k
    over missions, and the evaluator's k on the same splits.
    """
    ctrl = list(g["alpha_ctrl"])
    err_pm = np.asarray(g["per_mission"]["tracking_error_m"])
    peb_pm = np.asarray(g["per_mission"]["peb_m"])
    lost = np.asarray(g["lost"])
    an_err, an_peb = np.asarray(g["analytic"]["tracking_error_m"]), np.asarray(g["analytic"]["peb_m"])
    rng = np.random.default_rng(0)
    m = err_pm.shape[-1]
    boots = rng.integers(0, m, size=(N_BOOT, m))
    out = []
    for c in FIG7_CTRL:
        if c not in ctrl:
            continue
        i = ctrl.index(c)
        ok = lost[i] == 0
        row = {"alpha_ctrl": c, "n_points": int(ok.sum()), "peb_m": peb_pm[i].mean(-1).tolist(),
               "tracking_error_m": err_pm[i].mean(-1).tolist(), "ok": ok.tolist()}
        if ok.sum() >= 3:
            k, c0, r2 = fit_line(peb_pm[i][ok].mean(-1), err_pm[i][ok].mean(-1))
            ks = [np.polyfit(peb_pm[i][ok][:, b].mean(-1), err_pm[i][ok][:, b].mean(-1), 1)[0] for b in boots]
            row.update(k=k, c=c0, r2=r2, k_ci90=[float(np.percentile(ks, 5)), float(np.percentile(ks, 95))])
        fin = np.isfinite(an_err[i])
        if fin.sum() >= 3:
            ka, ca, r2a = fit_line(an_peb[i][fin], an_err[i][fin])
            row.update(k_analytic=ka, c_analytic=ca, r2_analytic=r2a)
        out.append(row)
    return {"rows": out}


def fig8_stats(g: dict, model) -> dict:
    """Fig. 8: the LQG cost against the PEB (a line per alpha_ctrl row where no mission lost track, the
    PEB varied by alpha_sen), and the data rate above which the best achievable tracking error rises
    (the knee: the smallest rate R such that every split with a rate >= R has an error above 1.25 x
    the best of all splits, or loses track).
    """
    peb, lqg = np.asarray(g["peb_m"]), np.asarray(g["lqg_cost"])
    err, rate = np.asarray(g["tracking_error_m"]).ravel(), np.asarray(g["rate_mbps"]).ravel()
    lost = np.asarray(g["lost"])
    rows = []
    for i, c in enumerate(g["alpha_ctrl"]):
        if np.any(lost[i] > 0) or len(g["alpha_sen"]) < 3:
            continue
        k, c0, r2 = fit_line(peb[i], lqg[i])
        rows.append({"alpha_ctrl": c, "k": k, "c": c0, "r2": r2})
    e = np.where(lost.ravel() > 0, np.inf, err)
    best = float(np.min(e))
    order = np.argsort(rate)
    knee = float("nan")
    for j in range(len(order)):
        if np.all(e[order[j:]] > 1.25 * best):
            knee = float(rate[order[j]])
            break
    return {"lqg_vs_peb": rows, "rate_knee_mbps": knee, "best_error_m": best,
            "max_rate_mbps": float(model.rate_comm_per_share_bps * 1e-6)}


# --------------------------------------------------------------------------------------------------
# claims
# --------------------------------------------------------------------------------------------------
def _pct(x: float) -> str:
    return f"{100 * x:.3g} %"


def _first_saturated(values, ref: float, ok, tol: float):
    """Index of the first entry from which every later entry with ``ok`` stays within ``tol`` (relative)
    of ``ref`` (None if none).
    """
    v = np.asarray(values, dtype=float)
    okv = np.asarray(ok, dtype=bool)
    for j in range(len(v)):
        tail = v[j:]
        if okv[j:].all() and np.all(np.abs(tail / ref - 1.0) <= tol):
            return j
    return None


def claims(res: dict) -> list[dict]:
    """The paper's statements about Figs. 3-8 (and the Table II PEB and error readings), each tested
    on the measured numbers of ``res``.
    """
    out = []

    def add(cid, figure, paper, ours, holds, why):
        out.append({"id": cid, "figure": figure, "paper": paper, "ours": ours, "holds": bool(holds), "why": why})

    # --- Fig. 3
    f3 = res["fig3"]
    a = np.asarray(f3["alpha_sen"])
    mono = all(np.all(np.diff(c[k]) < 0) for c in f3["curves"] for k in ("peb_m", "veb_mps"))
    conc = all(np.all(np.diff(-np.diff(c[k]) / np.diff(a)) < 0) for c in f3["curves"] for k in ("peb_m", "veb_mps"))
    mid = next(c for c in f3["curves"] if c["shift_db"] == 0.0)
    p = np.asarray(mid["peb_m"])
    i05, i20, i80 = (int(np.argmin(np.abs(a - x))) for x in (0.05, 0.2, 0.8))
    add("fig3-monotone", "Fig. 3(a)-(b)", "VEB and PEB decrease monotonically with alpha_sen, at every SNR level",
        f"{len(f3['curves'])} echo SNRs ({f3['curves'][0]['echo_snr_db']:.0f} to {f3['curves'][-1]['echo_snr_db']:.0f} "
        f"dB per element and subcarrier): every curve strictly decreasing: {mono}", mono,
        "the Fisher information grows with the number of sensing subcarriers (alpha_sen^3 in range, alpha_sen in "
        "angle and Doppler)")
    add("fig3-saturation", "Fig. 3(a)-(b)",
        "the gain saturates as alpha_sen grows (insufficient sensing limits accuracy, excess gives marginal gains)",
        f"gain per unit alpha_sen decreasing on every curve: {conc}; PEB {p[i05]:.3g} m at {_pct(a[i05])}, "
        f"{p[i20]:.3g} m at {_pct(a[i20])}, {p[i80]:.3g} m at {_pct(a[i80])} (preset SNR)", conc,
        "angle-limited: PEB ~ alpha_sen^-1/2, a convex decreasing curve")
    g = res["grid"]
    sca = g["splits"].get("sca", g["splits"]["paper_sca"])
    add("table2-peb", "Table II / Fig. 3(b)", f"PEB {PAPER['table2_peb_m']} m at SCA's split (20/20/60 %)",
        f"{sca['peb_m']:.4f} m in the env at SCA's split {_split(sca['alpha'])} ({g['n_missions']} missions; "
        f"{f3['peb_m_at_0_2']:.4f} m without echo fading at alpha_sen = 20 %)",
        abs(sca["peb_m"] / PAPER["table2_peb_m"] - 1.0) <= 0.10,
        "the preset's sensing_snr_offset_db is calibrated in the env to 0.0635 m at 20/20/60 % (docs/model.md "
        "Sec. 2.4); these are other missions and our SCA split; tolerance 10 %")
    # --- Fig. 4
    f4 = res["fig4"]
    e_star = f4["eps_star"]
    add("fig4a-eps-star", "Fig. 4(a)", f"eps_ctrl* = {PAPER['eps_ctrl_star']}", f"{e_star:.4f}",
        abs(e_star / PAPER["eps_ctrl_star"] - 1.0) <= 0.01,
        "first root of rho(M(eps)) = 1 with the paper's A, B and LQ gain; tolerance 1 %")
    eps, rho = np.asarray(f4["eps"]), np.asarray(f4["rho_vs_eps"])
    region = rho <= 1.0
    inc = bool(np.all(np.diff(rho[region]) >= -1e-12))
    add("fig4a-monotone", "Fig. 4(a)", "within rho(M) <= 1, rho(M) increases monotonically with eps_ctrl",
        f"non-decreasing on eps in [0, {eps[region].max():.3f}]: {inc}; rho(0) = {rho[0]:.4f}", inc,
        "rho(M(eps)) of eq:M")
    a_star = f4["alpha_ctrl_star"]
    add("fig4b-alpha-star", "Fig. 4(b)", f"alpha_ctrl* = {_pct(PAPER['alpha_ctrl_star'])} (trajectory-averaged SNR)",
        f"{_pct(a_star)} at the trajectory-averaged SNR {f4['mean_snr_db']:.2f} dB; with fading and shadowing the mean "
        f"loss rate reaches eps* at {_pct(f4['alpha_ctrl_star_faded_mean'])}, the worst position's at "
        f"{_pct(f4['alpha_ctrl_star_faded_worst'])}", abs(a_star / PAPER["alpha_ctrl_star"] - 1.0) <= 0.05,
        "ctrl_deadline_s is calibrated to it (docs/model.md); tolerance 5 %")
    al, ea = np.asarray(f4["alpha_ctrl"]), np.asarray(f4["eps_vs_alpha"])
    hi, lo = al[ea >= 0.9].max(initial=al[0]), al[ea <= 1e-3].min(initial=al[-1])
    add("fig4b-sharp", "Fig. 4(b)", "eps_ctrl shows a sharp transition at alpha_ctrl*",
        f"eps_ctrl falls from 0.9 to 1e-3 between alpha_ctrl = {_pct(hi)} and {_pct(lo)}", lo - hi <= 0.015,
        "the FBL error probability is a Q-function of the rate gap; 'sharp' read as three decades within 1.5 "
        "points of alpha_ctrl")
    ra = np.asarray(f4["rho_vs_alpha"])
    beyond = al >= 0.05
    spread = float(ra[beyond].max() - ra[beyond].min())
    add("fig4c-saturation", "Fig. 4(c)", "beyond alpha_ctrl ~5 %, rho(M) saturates around 0.1",
        f"rho(M) = {ra[beyond][0]:.4f} at 5 %, {ra[-1]:.4f} at {_pct(al[-1])} (spread {spread:.4f} beyond 5 %)",
        abs(ra[-1] - PAPER["rho_m_saturated"]) <= 0.02 and spread <= 0.02,
        "rho(M) tends to rho((A-BK)x(A-BK)) = rho(A-BK)^2 as eps_ctrl -> 0; tolerance 0.02")
    # --- the stability rule of Fig. 4 in the env (the grid's loss-of-track fraction)
    ctrl, sen = list(g["alpha_ctrl"]), list(g["alpha_sen"])
    lost = np.asarray(g["lost"])
    first_ok = next((c for i, c in enumerate(ctrl) if not np.any(lost[i] > 0)), None)
    above = [(c, float(lost[i].mean())) for i, c in enumerate(ctrl) if c > PAPER["alpha_ctrl_star"]]
    add("fig4-rule-in-env", "Fig. 4 / Sec. IV-C.1",
        "alpha_ctrl > alpha_ctrl* (4.03 %) is equivalent to mean-square stability",
        "missions losing track in the env: " + ", ".join(f"{_pct(c)}: {_pct(f)}" for c, f in above[:5])
        + (f"; none from {_pct(first_ok)}" if first_ok else "; some at every alpha_ctrl of the grid"),
        bool(above) and above[0][1] == 0.0,
        "alpha_ctrl* uses the trajectory-averaged SNR; per-slot fading and shadowing push the loss rate above eps* "
        "at the far, shadowed part of a trajectory, where losses come in runs (docs/model.md Sec. 2.6)")
    # --- Fig. 5 and Fig. 6
    cost, err, rms = (np.asarray(g[k]) for k in ("lqg_cost", "tracking_error_m", "tracking_rmse_m"))
    rows_ok = _stable_rows(g)
    top = len(ctrl) - 1
    j_lo, j_hi = 0, len(sen) - 1
    floor_cost = float(cost[top, j_hi])
    add("fig5-floor", "Fig. 5(c)", f"the LQG cost stabilises at about {PAPER['lqg_cost_floor']:.3g}",
        f"{floor_cost:.4g} at alpha_sen = {_pct(sen[j_hi])}, alpha_ctrl = {_pct(ctrl[top])}",
        abs(floor_cost / PAPER["lqg_cost_floor"] - 1.0) <= 0.15,
        "our process noise is read as variances and our LQG gain is the paper's; the paper's larger cost would need "
        "a larger steady-state error or control effort than its own 0.41 m implies; tolerance 15 %")
    mono_rows = [c for i, c in enumerate(ctrl) if rows_ok[i] and np.all(np.diff(cost[i]) <= 0.01 * cost[i, :-1])]
    stable_list = [c for i, c in enumerate(ctrl) if rows_ok[i]]
    add("fig5-sen-monotone", "Fig. 5(a), (c)", "the LQG cost decreases monotonically as alpha_sen increases",
        f"decreasing (within 1 % noise) on {len(mono_rows)} of {len(stable_list)} alpha_ctrl rows where every mission "
        f"kept track ({', '.join(_pct(c) for c in stable_list)})",
        bool(stable_list) and len(mono_rows) == len(stable_list),
        "more sensing shrinks the Kalman error covariance; the Monte Carlo mean carries noise from rare excursions")
    j_flat = _first_saturated(cost[top], floor_cost, np.ones(len(sen), bool), 0.05)
    flat_sen = sen[j_flat] if j_flat is not None else float("nan")
    add("fig5-flat-15", "Fig. 5(c)", "the LQG cost flattens once alpha_sen exceeds ~15 %",
        f"within 5 % of its alpha_sen = {_pct(sen[j_hi])} value from alpha_sen = {_pct(flat_sen)} "
        f"(alpha_ctrl = {_pct(ctrl[top])})", 0.10 <= flat_sen <= 0.20,
        "read as: within 5 % of the floor from 10-20 % on")
    for key, fig, name, arr, paper_sat, tol in (
            ("fig5", "Fig. 5(b)", "LQG cost", cost, "no significant improvement", 0.05),
            ("fig6", "Fig. 6(b)", "tracking error", err, "improvement saturates", 0.02)):
        sats = []
        for j in (j_lo, sen.index(0.2) if 0.2 in sen else j_hi):
            jj = _first_saturated(arr[:, j], float(arr[top, j]), lost[:, j] == 0, tol)
            sats.append((sen[j], ctrl[jj] if jj is not None else float("nan")))
        ours_sat = max(x for _, x in sats)
        add(f"{key}-ctrl-saturation-7", fig,
            f"beyond alpha_ctrl ~7 % the {name}: {paper_sat}",
            "; ".join(f"at alpha_sen = {_pct(a_)}: within {100 * tol:g} % of its alpha_ctrl = {_pct(ctrl[top])} "
                      f"value and no mission losing track from alpha_ctrl = {_pct(c_)}" for a_, c_ in sats),
            abs(ours_sat - PAPER["ctrl_saturation"]) <= 0.01,
            "the alpha_ctrl where the loop stops losing commands in runs is set by the worst positions' loss rate "
            f"(eps* reached at {_pct(f4['alpha_ctrl_star_faded_worst'])}), not by alpha_ctrl*; tolerance 1 point "
            "(5 % on the cost, ~quadratic in the error; 2 % on the error)")
    i5 = ctrl.index(0.05) if 0.05 in ctrl else None
    i6 = ctrl.index(0.06) if 0.06 in ctrl else None
    if i5 is not None:
        l5 = float(lost[i5].mean())
        l6 = float(lost[i6].mean()) if i6 is not None else float("nan")
        holds = l5 == 0.0 and (i6 is None or l6 == 0.0) and (i6 is None or np.all(err[i5] > err[i6]))
        add("fig6-5-to-6", "Fig. 6(b)", "as alpha_ctrl rises from 5 % to 6 %, the tracking error decreases rapidly "
            "(both stable)",
            f"missions losing track: {_pct(l5)} at 5 %" + (f", {_pct(l6)} at 6 %" if i6 is not None else "")
            + f"; mean error up to loss of track {np.nanmean(err[i5]):.3g} m at 5 %", holds,
            "at 5-6 % the far, shadowed part of a trajectory loses commands faster than eps* (per-slot fading), so the "
            "loop diverges: the paper's 5-6 % region is not stable in the env")
    e_floor, r_floor = float(err[top, j_hi]), float(rms[top, j_hi])
    add("fig6-floor-0.4", "Fig. 6(c)", f"the tracking error stabilises at around {PAPER['error_floor_m']} m",
        f"mean ||e|| {e_floor:.4f} m, RMS {r_floor:.4f} m at alpha_sen = {_pct(sen[j_hi])}, "
        f"alpha_ctrl = {_pct(ctrl[top])}", abs(e_floor / PAPER["error_floor_m"] - 1.0) <= 0.10,
        "the mean error norm is what the paper's 'average tracking error' plots (its RMS would be ~8.5 % higher for "
        "a Gaussian 3-D error); tolerance 10 %")
    j10 = _first_saturated(err[top], e_floor, np.ones(len(sen), bool), 0.02)
    sat_sen = sen[j10] if j10 is not None else float("nan")
    add("fig6-flat-10", "Fig. 6(c)", "the marginal gain of alpha_sen fades beyond ~10 %",
        f"error within 2 % of its alpha_sen = {_pct(sen[j_hi])} value from alpha_sen = {_pct(sat_sen)} "
        f"(alpha_ctrl = {_pct(ctrl[top])}): {err[top, 0]:.4f} m at {_pct(sen[0])}, {e_floor:.4f} m at "
        f"{_pct(sen[j_hi])}", 0.05 <= sat_sen <= 0.15, "read as: within 2 % of the floor from 5-15 % on")
    corner_hi = float(np.where(lost[0, 0] > 0, np.inf, err[0, 0]))
    add("fig6-peaks", "Fig. 6(a)", "the error is large when either share is insufficient, and peaks when both are low",
        f"at ({_pct(sen[0])}, {_pct(ctrl[0])}): {_pct(float(lost[0, 0]))} of missions lose track "
        f"(mean {err[0, 0]:.3g} m up to then); at ({_pct(sen[0])}, {_pct(ctrl[top])}): {err[top, 0]:.3f} m; "
        f"at ({_pct(sen[j_hi])}, {_pct(ctrl[top])}): {e_floor:.3f} m",
        corner_hi > err[top, 0] > e_floor,
        "low alpha_ctrl diverges (loss of track), low alpha_sen raises the Kalman error")
    # --- Fig. 7
    rows = [r for r in res["fig7"]["rows"] if "k" in r]
    ks = [(r["alpha_ctrl"], r["k"]) for r in rows]
    txt = "; ".join(f"{_pct(r['alpha_ctrl'])}: k = {r['k']:.3f} [{r['k_ci90'][0]:.3f}, {r['k_ci90'][1]:.3f}], "
                    f"R2 = {r['r2']:.2f}" for r in rows)
    an = "; ".join(f"{_pct(r['alpha_ctrl'])}: {r['k_analytic']:.3f}" for r in res["fig7"]["rows"] if "k_analytic" in r)
    lin = bool(rows) and all(r["r2"] >= 0.9 for r in rows)
    add("fig7-linear", "Fig. 7", "the tracking error depends approximately linearly on the PEB, for every alpha_ctrl",
        txt + (f" (rows without loss of track; evaluator's k: {an})" if an else ""), lin,
        "read as R2 >= 0.9 on every row; near the stability edge rare long runs of lost commands add noise that is "
        "not a function of the PEB")
    add("fig7-k-below-1", "Fig. 7", "the fitted slopes satisfy k < 1 for every alpha_ctrl",
        ", ".join(f"{_pct(c)}: {k:.3f}" for c, k in ks), bool(ks) and all(k < 1.0 for _, k in ks),
        "the Kalman filter and the loop's low-pass attenuate the measurement noise")
    if len(ks) >= 3:
        ranks = [np.argsort(np.argsort(v)) for v in zip(*ks, strict=True)]
        rho_s = float(np.corrcoef(ranks[0], ranks[1])[0, 1])
    else:
        rho_s = float("nan")
    add("fig7-k-falls", "Fig. 7", "k falls as alpha_ctrl rises",
        f"Spearman rank correlation of k with alpha_ctrl: {rho_s:+.2f} "
        f"({', '.join(f'{_pct(c)}: {k:.3f}' for c, k in ks)})",
        rho_s < -0.5,
        "with fewer lost commands the loop follows its estimate more closely, so estimation error (which the PEB "
        "drives) passes to the tracking error more directly: the steady-state evaluator also gives k rising with "
        "alpha_ctrl")
    k9 = next((r for r in rows if abs(r["alpha_ctrl"] - 0.09) < 1e-9), None)
    k10 = next((r for r in rows if abs(r["alpha_ctrl"] - 0.10) < 1e-9), None)
    if k9 and k10:
        rel = abs(k9["k"] / k10["k"] - 1.0)
        add("fig7-k-9-10", "Fig. 7", "k is nearly identical at alpha_ctrl = 9 % and 10 %",
            f"k = {k9['k']:.3f} at 9 %, {k10['k']:.3f} at 10 % ({100 * rel:.0f} % apart)", rel <= 0.10,
            "read as within 10 %")
    # --- Fig. 8
    f8 = res["fig8"]
    lv = f8["lqg_vs_peb"]
    add("fig8-lqg-linear-peb", "Fig. 8", "the LQG cost increases linearly with the PEB",
        "line per alpha_ctrl row without loss of track (PEB varied by alpha_sen): "
        + "; ".join(f"{_pct(r['alpha_ctrl'])}: slope {r['k']:.4g}, R2 = {r['r2']:.2f}" for r in lv),
        bool(lv) and all(r["k"] > 0 and r["r2"] >= 0.9 for r in lv),
        "read as a positive slope with R2 >= 0.9 on every row; far from the stability edge the cost is linear in the "
        "PEB, near it (alpha_ctrl up to ~12 %) rare runs of lost commands dominate the mean cost")
    add("fig8-rate-knee-35", "Fig. 8", f"above ~{PAPER['rate_knee_mbps']:g} Mbps, errors rise sharply",
        f"every split with a data rate above {f8['rate_knee_mbps']:.1f} Mbps has an error above 1.25 x the best "
        f"({f8['best_error_m']:.3f} m) or loses track; the data link's mean rate at alpha_comm = 1 is "
        f"{f8['max_rate_mbps']:.1f} Mbps", abs(f8["rate_knee_mbps"] / PAPER["rate_knee_mbps"] - 1.0) <= 0.15,
        "the knee sits where the data share squeezes alpha_ctrl below the stable region; our link's maximum is below "
        "35 Mbps once fading is averaged; tolerance 15 %")
    # --- the 0.41 m: mean norm and RMS at SCA's split
    add("table2-error-rms", "Table II / Fig. 9(b)",
        f"SCA tracking error {PAPER['table2_error_m']} m (0.41 m in Fig. 9); the objective prob:obj is the mean "
        "squared error",
        f"mean ||e|| {sca['tracking_error_m']:.4f} m, RMS {sca['tracking_rmse_m']:.4f} m at SCA's split "
        f"{_split(sca['alpha'])} ({g['n_missions']} missions x {g['n_slots']} slots)",
        abs(sca["tracking_error_m"] / PAPER["table2_error_m"] - 1.0) <= 0.15
        and abs(sca["tracking_rmse_m"] / PAPER["table2_error_m"] - 1.0) <= 0.15,
        "both within 15 %; the paper's number is most plausibly the mean error norm: Fig. 9(b) plots ||e_p,n|| "
        "over time and the text calls 0.41 m its average over the horizon")
    return out


def _split(a) -> str:
    return "/".join(f"{100 * x:.1f}" for x in a) + " %"
