"""PNG figures of the scheme level of ``python -m experiments.paper.reproduce`` (matplotlib, Agg canvas; no display
needed), and the helpers every reproduce figure uses (:func:`new_figure`, :func:`save_figure`).

* ``fig9a_schemes_trajectories_3d.png``: 3-D flight of the four schemes of the paper's Fig. 9 on one mission;
* ``fig9b_schemes_tracking_error.png``: their tracking error over time (Fig. 9(b)).

The paper's Figs. 3-8 are drawn by :mod:`experiments.paper.paper_figures`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from iscc_gym.analysis import StaticModel
from iscc_gym.scenario import Scenario

__all__ = ["write_all", "save_figure", "new_figure", "FIGURES"]

#: File name -> title of every figure :func:`write_all` writes (the paper's figure numbers).
FIGURES = {
    "fig9a_schemes_trajectories_3d.png": "Fig. 9(a): 3-D trajectories of the four schemes",
    "fig9b_schemes_tracking_error.png": "Fig. 9(b): tracking error over time of the four schemes",
}

_SCHEME_STYLE = {
    "open_loop": ("open loop", "tab:orange"),
    "gnss": ("GNSS feedback", "tab:green"),
    "ignore_loss": ("ISCC ignoring loss", "tab:red"),
    "iscc": ("proposed ISCC", "tab:blue"),
}


def new_figure(size, dpi: int = 100):
    """A matplotlib Figure on the Agg canvas (no display needed)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, dpi=dpi)
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig, path: str | Path) -> Path:
    """Save ``fig`` as a PNG at ``path`` atomically (a temporary name, then a rename): an interrupted run
    never leaves a truncated figure.
    """
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
    errors (metres, decimetres) do not show at the mission's scale.
    """
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


def write_all(out_dir: str | Path, s: Scenario, model: StaticModel, traces: dict, splits: dict,
              quick: bool = False, bound_m: float = 100.0) -> dict[str, str]:
    """Write every figure of :data:`FIGURES` into ``out_dir``; returns {file name: path}.

    ``traces``: per scheme (``open_loop``, ``gnss``, ``ignore_loss``, ``iscc``) the ``traces`` of
    :func:`iscc_gym.eval.engine.evaluate` with ``record=1``. ``model``, ``splits`` (the Table II
    allocations) and ``quick`` are accepted for :mod:`experiments.paper.schemes`' call and not used: the
    allocation maps are the paper's Figs. 5-6 in :mod:`experiments.paper.paper_figures`.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    trajectories_3d(out / "fig9a_schemes_trajectories_3d.png", traces, s.dt_s)
    tracking_error_vs_time(out / "fig9b_schemes_tracking_error.png", traces, s.dt_s, bound_m)
    return {name: str(out / name) for name in FIGURES}
