"""PNG figures of ``python -m eval.reproduce`` (matplotlib, Agg canvas; no display needed).

* ``schemes_trajectories_3d.png``: 3-D flight of the four schemes of Fig. 9 on one mission;
* ``schemes_tracking_error.png``: their tracking error over time (Fig. 9's error panel);
* ``alloc_tracking_error.png``, ``alloc_lqg_cost.png``: steady-state tracking error and LQG cost over
  (alpha_sen, alpha_ctrl), alpha_comm = 1 - the others (the paper's Figs. 6-7, analytic evaluator);
* ``peb_veb_vs_alpha_sen.png``: trajectory-averaged PEB and VEB versus alpha_sen (Fig. 4);
* ``rho_vs_eps_ctrl.png``: rho(M) versus eps_ctrl, and eps_ctrl versus alpha_ctrl (Fig. 5).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from iscc_gym.analysis import StaticModel, local_crlb
from iscc_gym.dynamics import model_matrices
from iscc_gym.fbl import ctrl_bler
from iscc_gym.scenario import Scenario
from iscc_gym.stability import scenario_eps_star, spectral_radius, stability_matrix

__all__ = ["write_all", "save_figure", "new_figure", "FIGURES"]

#: File name -> title of every figure :func:`write_all` writes.
FIGURES = {
    "schemes_trajectories_3d.png": "3-D trajectories of the four schemes (Fig. 9a analog)",
    "schemes_tracking_error.png": "tracking error over time of the four schemes (Fig. 9b analog)",
    "alloc_tracking_error.png": "tracking error over (alpha_sen, alpha_ctrl) (Fig. 7 analog)",
    "alloc_lqg_cost.png": "LQG cost over (alpha_sen, alpha_ctrl) (Fig. 6 analog)",
    "peb_veb_vs_alpha_sen.png": "PEB and VEB versus alpha_sen (Fig. 4 analog)",
    "rho_vs_eps_ctrl.png": "rho(M) versus eps_ctrl and eps_ctrl versus alpha_ctrl (Fig. 5 analog)",
}

_SCHEME_STYLE = {
    "open_loop": ("open loop", "tab:orange"),
    "gnss": ("GNSS feedback", "tab:green"),
    "ignore_loss": ("ISCC ignoring loss", "tab:red"),
    "iscc": ("proposed ISCC", "tab:blue"),
}
_ALLOC_MARK = {"sca": ("SCA", "o"), "grid": ("grid", "s"), "evolutionary": ("evolutionary", "^")}


def new_figure(size, dpi: int = 100):
    """A matplotlib Figure on the Agg canvas (no display needed)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, dpi=dpi)
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig, path: str | Path) -> Path:
    """Save ``fig`` as a PNG at ``path`` atomically (a temporary name, then a rename): an interrupted run
    never leaves a truncated figure."""
    from iscc_gym.files import atomic_target

    with atomic_target(path) as tmp:
        fig.savefig(tmp, format="png")
    return Path(path)


def _alive(tr):
    """Slots of the first recorded episode up to its end (the trace is NaN after it)."""
    err = np.asarray(tr["tracking_error_m"])[:, 0]
    return np.isfinite(err)


def trajectories_3d(path: Path, traces: dict, dt_s: float) -> None:
    """(a) the whole mission of every scheme; (b) a 30 s window of GNSS feedback and ISCC, whose
    errors (metres, decimetres) do not show at the mission's scale."""
    fig = new_figure((13, 6))
    first = traces["iscc"]
    ok = _alive(first)
    ref = np.asarray(first["ref_pos"])[ok, 0]
    n0 = max(0, min(1000, len(ref) - 300))
    window = slice(n0, min(n0 + 300, len(ref)))
    for panel, (names, sl, title) in enumerate((
            (tuple(_SCHEME_STYLE), slice(None), "(a) one mission, same seed for every scheme"),
            (("gnss", "iscc"), window, f"(b) {window.start * dt_s:g}-{window.stop * dt_s:g} s of the same mission"))):
        ax = fig.add_subplot(1, 2, panel + 1, projection="3d")
        for name in names:
            if name not in traces:
                continue
            label, color = _SCHEME_STYLE[name]
            ok = _alive(traces[name])
            pos = np.asarray(traces[name]["pos"])[ok, 0][sl]
            ax.plot(pos[:, 0], pos[:, 1], pos[:, 2], color=color, lw=0.9, label=label)
        r = ref[sl]
        ax.plot(r[:, 0], r[:, 1], r[:, 2], "k--", lw=1.0, label="reference")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_zlabel("z (m)")
        ax.set_title(title, fontsize=9)
        ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    save_figure(fig, path)


def tracking_error_vs_time(path: Path, traces: dict, dt_s: float, bound_m: float) -> None:
    fig = new_figure((9, 4))
    ax = fig.add_subplot(1, 1, 1)
    for name, (label, color) in _SCHEME_STYLE.items():
        if name not in traces:
            continue
        err = np.asarray(traces[name]["tracking_error_m"])[:, 0]
        ok = np.isfinite(err)
        t = np.arange(len(err))[ok] * dt_s
        ax.plot(t, err[ok], color=color, lw=0.8, label=f"{label} (mean {np.mean(err[ok]):.3g} m)")
    ax.axhline(bound_m, color="grey", ls=":", lw=1, label=f"env's loss-of-track bound ({bound_m:g} m)")
    ax.set_yscale("log")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("tracking error (m)")
    ax.set_title("One mission, loss-of-track bound lifted so every scheme flies the whole mission", fontsize=9)
    ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    save_figure(fig, path)


def allocation_maps(out: Path, model: StaticModel, splits: dict, n: int) -> None:
    """Figs. 6-7 analog: steady-state tracking error and LQG cost over (alpha_sen, alpha_ctrl)."""
    a_sen = np.geomspace(0.005, 0.6, n)
    a_ctrl = np.linspace(0.02, 0.3, n)
    ss, cc = np.meshgrid(a_sen, a_ctrl, indexing="ij")
    grid = np.stack([ss.ravel(), cc.ravel(), 1.0 - ss.ravel() - cc.ravel()], -1)
    met = model.evaluate(grid)
    fine_c = np.linspace(0.02, 0.3, 2 * n)
    fine_s = np.geomspace(0.005, 0.6, 2 * n)
    cuts_s = (0.02, 0.05, 0.1, 0.2, 0.4)
    cuts_c = (0.1, 0.12, 0.15, 0.2, 0.3)
    by_ctrl = {a_s: model.evaluate(np.stack([np.full_like(fine_c, a_s), fine_c, 1.0 - a_s - fine_c], -1))
               for a_s in cuts_s}
    by_sen = {}
    for a_c in cuts_c:
        fs = fine_s[fine_s < 1.0 - a_c - 0.01]
        by_sen[a_c] = (fs, model.evaluate(np.stack([fs, np.full_like(fs, a_c), 1.0 - a_c - fs], -1)))
    for key, fname, label in (("tracking_error_m", "alloc_tracking_error.png", "mean tracking error (m)"),
                              ("lqg_cost", "alloc_lqg_cost.png", "LQG cost b")):
        z = getattr(met, key).reshape(n, n)
        z = np.where(met.stable.reshape(n, n) & np.isfinite(z), z, np.nan)
        fig = new_figure((14, 4.2))
        ax = fig.add_subplot(1, 3, 1)
        ax.set_facecolor("0.85")
        im = ax.pcolormesh(100 * a_sen, 100 * a_ctrl, z.T, shading="auto", cmap="viridis",
                           vmax=float(np.nanpercentile(z, 97)))
        cb = fig.colorbar(im, ax=ax, extend="max")
        cb.set_label(label)
        ax.set_xscale("log")
        for method, (lab, marker) in _ALLOC_MARK.items():
            a = splits[method]
            ax.plot(100 * a[0], 100 * a[1], marker, color="w", mec="k", ms=7, label=lab)
        ax.set_xlabel("alpha_sen (%)")
        ax.set_ylabel("alpha_ctrl (%)")
        ax.set_title("(a) grey: not mean-square stable at some position", fontsize=8)
        ax.legend(fontsize=7)
        ax = fig.add_subplot(1, 3, 2)
        for a_s, cut in by_ctrl.items():
            v = getattr(cut, key)
            ax.plot(100 * fine_c, np.where(np.isfinite(v), v, np.nan), lw=1, label=f"alpha_sen = {100 * a_s:g} %")
        ax.set_yscale("log")
        ax.set_xlabel("alpha_ctrl (%)")
        ax.set_ylabel(label)
        ax.set_title("(b) versus alpha_ctrl", fontsize=8)
        ax.legend(fontsize=7)
        ax = fig.add_subplot(1, 3, 3)
        for a_c, (fs, cut) in by_sen.items():
            v = getattr(cut, key)
            ax.plot(100 * fs, np.where(np.isfinite(v), v, np.nan), lw=1, label=f"alpha_ctrl = {100 * a_c:g} %")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("alpha_sen (%)")
        ax.set_ylabel(label)
        ax.set_title("(c) versus alpha_sen", fontsize=8)
        ax.legend(fontsize=7)
        fig.suptitle(f"{label}, steady-state evaluator (alpha_comm = 1 - alpha_sen - alpha_ctrl)", fontsize=9)
        fig.tight_layout()
        save_figure(fig, out / fname)


def peb_veb(path: Path, model: StaticModel) -> None:
    a = np.geomspace(1e-3, 1.0, 80)
    m_r, m_tt, _, m_pp, vr = local_crlb(model.sensing, a[:, None])
    pe = np.sqrt(m_r + m_tt + m_pp).mean(axis=1)
    ve = np.sqrt(vr).mean(axis=1)
    fig = new_figure((9, 3.8))
    ax = fig.add_subplot(1, 2, 1)
    ax.loglog(100 * a, pe, lw=1.2)
    ax.axhspan(0.03, 0.07, xmin=0, xmax=1, color="tab:orange", alpha=0.15, label="paper at 20 %: 0.03-0.07 m")
    ax.axvline(20, color="grey", ls=":", lw=1)
    ax.set_xlabel("alpha_sen (%)")
    ax.set_ylabel("PEB (m), trajectory average")
    ax.legend(fontsize=7)
    ax = fig.add_subplot(1, 2, 2)
    ax.loglog(100 * a, ve, lw=1.2, color="tab:green")
    ax.axvline(20, color="grey", ls=":", lw=1)
    ax.set_xlabel("alpha_sen (%)")
    ax.set_ylabel("VEB (m/s), trajectory average")
    fig.tight_layout()
    save_figure(fig, path)


def rho_vs_eps(path: Path, s: Scenario, model: StaticModel) -> None:
    mm = model_matrices(s)
    e_star = scenario_eps_star(s)
    eps = np.linspace(0.0, 1.0, 401)
    rho = [spectral_radius(stability_matrix(mm.a, mm.b, mm.k, e)) for e in eps]
    fig = new_figure((10, 3.8))
    ax = fig.add_subplot(1, 2, 1)
    ax.plot(eps, rho, lw=1.2)
    ax.axhline(1.0, color="grey", ls=":", lw=1)
    ax.axvline(e_star, color="tab:red", ls="--", lw=1, label=f"eps* = {e_star:.4f} (paper 0.5055)")
    ax.set_xlabel("control packet-loss rate eps_ctrl")
    ax.set_ylabel("rho(M)")
    ax.legend(fontsize=7)
    ax = fig.add_subplot(1, 2, 2)
    a = np.linspace(0.02, 0.2, 400)
    ax.semilogy(100 * a, np.maximum(ctrl_bler(s, a, model.mean_snr), 1e-12), lw=1.2,
                label="at the trajectory-averaged SNR (paper)")
    ax.semilogy(100 * a, np.maximum(model.eps_ctrl(a), 1e-12), lw=1.2,
                label="averaged over slots (shadowing, fading)")
    ax.axhline(e_star, color="tab:red", ls="--", lw=1, label="eps*")
    ax.set_ylim(1e-12, 2.0)
    ax.set_xlabel("alpha_ctrl (%)")
    ax.set_ylabel("eps_ctrl")
    ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path)


def write_all(out_dir: str | Path, s: Scenario, model: StaticModel, traces: dict, splits: dict,
              quick: bool = False, bound_m: float = 100.0) -> dict[str, str]:
    """Write every figure of :data:`FIGURES` into ``out_dir``; returns {file name: path}.

    ``traces``: per scheme (``open_loop``, ``gnss``, ``ignore_loss``, ``iscc``) the ``traces`` of
    :func:`iscc_gym.eval.evaluate.evaluate` with ``record=1``; ``splits``: the Table II allocations.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    trajectories_3d(out / "schemes_trajectories_3d.png", traces, s.dt_s)
    tracking_error_vs_time(out / "schemes_tracking_error.png", traces, s.dt_s, bound_m)
    allocation_maps(out, model, splits, 20 if quick else 60)
    peb_veb(out / "peb_veb_vs_alpha_sen.png", model)
    rho_vs_eps(out / "rho_vs_eps_ctrl.png", s, model)
    return {name: str(out / name) for name in FIGURES}
