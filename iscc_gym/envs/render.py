"""``rgb_array`` frames of the ISCC env: what the agent decides, beside where the drone flies.

One figure per env, built at the first frame; its static parts (axes, ticks, the reference) are drawn
once into a saved background, and each frame restores it and draws only the moving artists (Agg
blitting); the background is redrawn only when an axis must grow. A frame shows

* left: the plan view (x, y) of the reference, the flown path and the GBS, and the altitude profile
  (reference and drone) underneath;
* right, top: the split ``(alpha_sen, alpha_ctrl, alpha_comm)`` of the last :data:`WINDOW` slots, one
  line per share, with ticks under them for slots with a rate violation (R < R_min) and a stability
  violation (eps_ctrl > eps*);
* right, bottom: the tracking error and the PEB (position error bound: the Cramér-Rao bound of the
  position measurement) over the same window.

Matplotlib is imported at the first frame only.
"""

from __future__ import annotations

import numpy as np

__all__ = ["WINDOW", "Renderer"]

#: Slots shown in the time panels (the most recent ones).
WINDOW = 200

_COLORS = {"sen": "#4c72b0", "ctrl": "#dd8452", "comm": "#55a868", "rate": "#c44e52", "stab": "#8172b3"}


class Renderer:
    """Keeps an episode's history and draws frames of it.

    Parameters
    ----------
    dt_s : float
        Slot length (the time axis).
    gbs_height_m : float
        Height of the GBS (drawn at the origin of the plan view).
    """

    def __init__(self, dt_s: float, gbs_height_m: float, size_px: tuple[int, int] = (800, 400)):
        self.dt_s = float(dt_s)
        self.gbs_height_m = float(gbs_height_m)
        self.size_px = size_px
        self._fig = None
        self.reset(np.zeros((1, 3)), np.zeros(3))

    # --- history ---------------------------------------------------------------------------------
    def reset(self, reference: np.ndarray, position: np.ndarray) -> None:
        """A new episode: the reference path (slots, >= 3 columns x, y, z) and the start position."""
        self._ref = np.asarray(reference, dtype=float)[:, :3]
        self._pos = [np.asarray(position, dtype=float)[:3].copy()]
        self._rows: list[tuple] = []  # (err, peb, a_sen, a_ctrl, a_comm, rate violation, stability violation)
        self._new_episode = True

    def record(self, position, tracking_error_m: float, peb_m: float, alpha, cost_rate: float,
               cost_stability: float) -> None:
        """One slot's outcome (the values of the env's ``info``)."""
        self._pos.append(np.asarray(position, dtype=float)[:3].copy())
        a = np.asarray(alpha, dtype=float)
        self._rows.append((tracking_error_m, peb_m, a[0], a[1], a[2], cost_rate > 0, cost_stability > 0))

    # --- drawing ---------------------------------------------------------------------------------
    def _build(self):
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure

        w, h = self.size_px
        fig = Figure(figsize=(w / 100, h / 100), dpi=100)
        self._canvas = FigureCanvasAgg(fig)
        gs = fig.add_gridspec(2, 2, width_ratios=(1, 1.3), height_ratios=(2, 1), left=0.08, right=0.98,
                              bottom=0.12, top=0.9, wspace=0.25, hspace=0.5)
        ax_xy, ax_z = fig.add_subplot(gs[0, 0]), fig.add_subplot(gs[1, 0])
        ax_a, ax_e = fig.add_subplot(gs[0, 1]), fig.add_subplot(gs[1, 1])
        small = {"fontsize": 8}
        moving = []

        def line(ax, *args, **kw):
            (artist,) = ax.plot([], [], *args, animated=True, **kw)
            moving.append(artist)
            return artist

        ax_xy.set_title("plan view: reference (dashed), drone (blue), GBS (red)", **small)
        ax_xy.set_xlabel("x (m)", **small)
        ax_xy.set_ylabel("y (m)", **small)
        self._ref_xy, = ax_xy.plot([], [], "k--", lw=0.8)
        ax_xy.plot([0], [0], "^", color=_COLORS["rate"], ms=6)
        self._pos_xy = line(ax_xy, color=_COLORS["sen"], lw=1.2)
        self._now_xy = line(ax_xy, "o", color=_COLORS["sen"], ms=4)
        ax_z.set_xlabel("time (s)", **small)
        ax_z.set_ylabel("z (m)", **small)
        self._ref_z, = ax_z.plot([], [], "k--", lw=0.8)
        self._pos_z = line(ax_z, color=_COLORS["sen"], lw=1.0)
        ax_a.set_ylabel(f"split, last {WINDOW} slots", **small)
        ax_a.set_ylim(-0.13, 1.0)
        ax_a.set_yticks([0, 0.5, 1])
        span = (-WINDOW * self.dt_s, 0.0)
        ax_a.set_xlim(*span)
        self._bands = {name: line(ax_a, color=_COLORS[name], lw=1.0, drawstyle="steps-post", label=label)
                       for name, label in (("sen", "sensing"), ("ctrl", "control"), ("comm", "data"))}
        self._viol_rate = line(ax_a, "|", color=_COLORS["rate"], ms=5, label="R < R_min")
        self._viol_stab = line(ax_a, "|", color=_COLORS["stab"], ms=5, label="eps > eps*")
        ax_a.legend(loc="lower left", fontsize=6, ncol=5, frameon=False, bbox_to_anchor=(0, 1.0))
        ax_e.set_xlabel("time relative to now (s)", **small)
        ax_e.set_ylabel("m", **small)
        ax_e.set_xlim(*span)
        self._err = line(ax_e, color=_COLORS["ctrl"], lw=1.0, label="tracking error")
        self._peb = line(ax_e, color=_COLORS["comm"], lw=1.0, label="PEB")
        ax_e.legend(loc="upper left", fontsize=6, ncol=2, frameon=False)
        for ax in (ax_xy, ax_z, ax_a, ax_e):
            ax.tick_params(labelsize=7)
        self._axes = (ax_xy, ax_z, ax_a, ax_e)
        self._moving = moving
        self._fig = fig
        self._background = None

    def _limits(self, pos: np.ndarray, rows: np.ndarray) -> bool:
        """Fix the axes' limits for the data; True when they changed (the background is drawn anew)."""
        ax_xy, ax_z, _, ax_e = self._axes
        changed = False
        if self._new_episode:
            self._ref_xy.set_data(self._ref[:, 0], self._ref[:, 1])
            t_ref = np.arange(len(self._ref)) * self.dt_s
            self._ref_z.set_data(t_ref, self._ref[:, 2])
            ax_z.set_xlim(0.0, max(t_ref[-1], self.dt_s))
            self._xy_box = _box(np.concatenate([self._ref[:, :2], [[0.0, 0.0]]]))
            self._z_box = _box(self._ref[:, 2:3])
            self._err_top = 0.5
            self._new_episode, changed = False, True
        for attr, data in (("_xy_box", pos[:, :2]), ("_z_box", pos[:, 2:3])):
            box = getattr(self, attr)
            if np.any(data < box[0]) or np.any(data > box[1]):
                setattr(self, attr, _box(np.concatenate([data, box])))
                changed = True
        top = float(np.max(rows[:, :2])) if len(rows) else 0.0
        if np.isfinite(top) and top > self._err_top:
            self._err_top = 2.0 * top
            changed = True
        if changed:
            (x0, y0), (x1, y1) = self._xy_box
            ax_xy.set_xlim(x0, x1)
            ax_xy.set_ylim(y0, y1)
            ax_z.set_ylim(*self._z_box[:, 0])
            ax_e.set_ylim(0.0, self._err_top)
        return changed

    def frame(self) -> np.ndarray:
        """The current frame, (height, width, 3) uint8."""
        if self._fig is None:
            self._build()
        pos = np.asarray(self._pos)
        n = len(self._rows)
        lo = max(0, n - WINDOW)
        rows = np.asarray(self._rows[lo:], dtype=float).reshape(-1, 7)
        if self._limits(pos, rows) or self._background is None:
            self._canvas.draw()  # everything but the moving artists
            self._background = self._canvas.copy_from_bbox(self._fig.bbox)
        t = (np.arange(lo, n) + 1 - n) * self.dt_s
        self._pos_xy.set_data(pos[:, 0], pos[:, 1])
        self._now_xy.set_data(pos[-1:, 0], pos[-1:, 1])
        self._pos_z.set_data(np.arange(len(pos)) * self.dt_s, pos[:, 2])
        for i, name in enumerate(("sen", "ctrl", "comm")):
            self._bands[name].set_data(t, rows[:, 2 + i])
        rate, stab = rows[:, 5] > 0, rows[:, 6] > 0
        self._viol_rate.set_data(t[rate], np.full(int(rate.sum()), -0.05))
        self._viol_stab.set_data(t[stab], np.full(int(stab.sum()), -0.1))
        self._err.set_data(t, rows[:, 0])
        self._peb.set_data(t, rows[:, 1])
        self._canvas.restore_region(self._background)
        for artist in self._moving:
            artist.axes.draw_artist(artist)
        return np.asarray(self._canvas.buffer_rgba())[..., :3].copy()

    def __getstate__(self):
        """Copies and pickles keep the history; the figure is rebuilt at the next frame."""
        keep = ("dt_s", "gbs_height_m", "size_px", "_ref", "_pos", "_rows")
        return {**{k: self.__dict__[k] for k in keep}, "_fig": None, "_new_episode": True}

    def close(self) -> None:
        """Release the figure."""
        self._fig = None


def _box(points: np.ndarray) -> np.ndarray:
    """Limits (2, d) around ``points`` (n, d) with a 5 % margin (at least 1 unit)."""
    finite = points[np.all(np.isfinite(points), axis=1)]
    if not len(finite):
        finite = np.zeros((1, points.shape[1]))
    lo, hi = finite.min(axis=0), finite.max(axis=0)
    pad = 0.05 * np.maximum(hi - lo, 20.0)
    return np.stack([lo - pad, hi + pad])
