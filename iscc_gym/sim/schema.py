"""One schema for a slot's inputs and outputs: metric and env columns, observation entries, noise draws.

Everything that names or positions a number crossing the step boundary is defined here once and
read by the compiled kernel (:mod:`iscc_gym.sim.kernel`), the numpy transition (:mod:`iscc_gym.sim.loop`),
the single env, the vector env and the agents. Plain Python: the module imports only the task's effects
(:mod:`iscc_gym.sim.effects`, which decide the observation's blocks and the slot's draws), so every layer can
use it (the integer positions are module constants numba freezes at compile time).
"""

from __future__ import annotations

from typing import NamedTuple

from iscc_gym.sim.effects import task_effects

__all__ = ["obs_names", "obs_size", "obs_entries", "obs_blocks", "obs_offsets", "observation_table", "ObsEntry",
           "OBS_BLOCKS", "BASE_OBS", "QUEUE_OBS", "BLOCKAGE_OBS", "PREVIEW_OBS", "MEASURED_OBS", "WORLD_OBS",
           "N_PREVIEW_OBS", "O_BACKLOG",
           "O_OLDEST_AGE", "O_P_LOS_AHEAD", "O_SNR_LOS_AHEAD", "O_SNR_NLOS_AHEAD", "O_ECHO_LOS_AHEAD",
           "O_ECHO_NLOS_AHEAD",
           "QUEUE_OBS_NAMES", "PREVIEW_OBS_NAMES", "BLOCKAGE_OBS_NAMES",
           "METRIC_NAMES", "ENV_COLUMNS", "STEP_COLUMNS", "COL", "N_METRICS", "N_STEP_COLUMNS", "OBS_NAMES",
           "OBS", "N_OBS", "OBS_BOUND", "OBS_SCALING", "N_DRAWS", "DRAWS", "n_draws", "Z_ARRIVAL", "ERR_SCALE",
           "REF_VEL_SCALE",
           "REF_ACC_SCALE", "SNR_SCALE", "CTRL_SHARE_SCALE", "PEB_SCALE"]

#: Columns of a slot's metrics (:func:`iscc_gym.sim.loop.step`), in order: the closed loop's, then the data
#: queue's (:mod:`iscc_gym.physics.queue`: the slot's arrivals, the bits served and dropped, the backlog after the
#: slot; 0 without a queue), then the echo's SNR per element and subcarrier in the slot, its fading and the drone's
#: RCS included (dB: what the radar measures of its echo).
METRIC_NAMES = ("tracking_error_m", "estimation_error_m", "snr_db", "snr_large_scale_db", "peb_m",
                "veb_mps", "eps_ctrl", "packet_received", "rate_comm_bps", "rate_ctrl_bps", "diverged",
                "bits_arrived", "bits_served", "bits_dropped", "backlog_bits", "echo_snr_db")
#: Columns an env step adds after :data:`METRIC_NAMES`: the applied split, costs, reward, episode end (0/1).
ENV_COLUMNS = ("alpha_sen", "alpha_ctrl", "alpha_comm", "cost_rate", "cost_stability", "reward",
               "terminated", "truncated")
#: Columns of the per-loop output array of an env step (:func:`iscc_gym.sim.functional.env_step`).
STEP_COLUMNS = METRIC_NAMES + ENV_COLUMNS
#: Position of each column of :data:`STEP_COLUMNS` by name.
COL = {name: j for j, name in enumerate(STEP_COLUMNS)}
N_METRICS = len(METRIC_NAMES)
N_STEP_COLUMNS = len(STEP_COLUMNS)

#: Every observation entry is clipped to [-OBS_BOUND, OBS_BOUND].
OBS_BOUND = 10.0
#: Scales of the observation entries (module constants: the compiled observation reads them too).
ERR_SCALE = 0.1          # symlog scale of the predicted errors (m, m/s) and of the estimate's std (m)
REF_VEL_SCALE = 0.1      # reference velocity, per m/s
REF_ACC_SCALE = 1.0      # reference acceleration, per m/s^2
SNR_SCALE = 0.1          # predicted SNR, per dB
CTRL_SHARE_SCALE = 10.0  # control share at eps*
PEB_SCALE = 0.05         # symlog scale of the last PEB, m


class ObsEntry(NamedTuple):
    """One observation entry: what the GBS knows of it, how it is scaled, its bounds.

    ``scaling`` and ``scale`` say how the entry is computed from its physical value x: ``"symlog"``
    sign(x) ln(1 + |x| / scale), ``"linear"`` scale x, ``"flag"`` x (0 or 1), and with the scenario's constants
    ``"range"`` x / coverage radius, ``"time_left"`` 1 - n / n_slots (x the slot index n), ``"log_arrivals"``
    ln(1 + x / A) (A a slot's mean arrivals in bits), ``"per_deadline"`` x / D (D the queue's deadline in slots);
    :func:`iscc_gym.sim.functional.decode_observation` inverts them, :func:`observation_table` writes them out.
    ``decoded`` is the key of the physical value in :func:`iscc_gym.sim.functional.decode_observation`'s dict
    (entries sharing a key are stacked along a last axis: the x, y, z of a vector, the points of the preview).
    ``low``, ``high``: the range the entry takes (inside the clip bound +-:data:`OBS_BOUND`).
    """

    name: str
    unit: str
    scaling: str
    scale: float | None
    low: float
    high: float
    decoded: str
    description: str


def _vec(prefix, unit, scaling, scale, low, high, decoded, what):
    return tuple(ObsEntry(f"{prefix}_{ax}", unit, scaling, scale, low, high, decoded, f"{what}, {ax}")
                 for ax in "xyz")


#: The entries every observation has, in order (the table of :class:`iscc_gym.envs.env.ISCCEnv`): what the GBS
#: knows before it allocates the slot, from its predicted estimate x_hat_{n|n-1}.
BASE_OBS = (
    *_vec("pos_err", "m", "symlog", ERR_SCALE, -OBS_BOUND, OBS_BOUND, "pos_err_m",
          "predicted position error x_hat_{n|n-1} - p_ref,n"),
    *_vec("vel_err", "m/s", "symlog", ERR_SCALE, -OBS_BOUND, OBS_BOUND, "vel_err_mps", "predicted velocity error"),
    *_vec("ref_vel", "m/s", "linear", REF_VEL_SCALE, -OBS_BOUND, OBS_BOUND, "ref_vel_mps", "reference velocity"),
    *_vec("ref_acc", "m/s^2", "linear", REF_ACC_SCALE, -OBS_BOUND, OBS_BOUND, "ref_acc_mps2",
          "reference acceleration"),
    ObsEntry("est_pos_std", "m", "symlog", ERR_SCALE, 0.0, OBS_BOUND, "est_pos_std_m",
             "estimate's position std sqrt(tr P_pp)"),
    ObsEntry("snr_db", "dB", "linear", SNR_SCALE, -OBS_BOUND, OBS_BOUND, "snr_db",
             "predicted large-scale SNR of the command link (path loss, beam gain, shadowing; with blockage the "
             "slot's measured one, blocked line of sight included)"),
    ObsEntry("range", "m", "range", None, 0.0, OBS_BOUND, "range_m", "predicted range to the GBS antenna"),
    ObsEntry("sin_elevation", "-", "linear", 1.0, -1.0, 1.0, "sin_elevation", "sin(predicted elevation)"),
    ObsEntry("cos_azimuth", "-", "linear", 1.0, -1.0, 1.0, "cos_azimuth", "cos(predicted azimuth)"),
    ObsEntry("sin_azimuth", "-", "linear", 1.0, -1.0, 1.0, "sin_azimuth", "sin(predicted azimuth)"),
    ObsEntry("alpha_ctrl_min", "-", "linear", CTRL_SHARE_SCALE, 0.0, OBS_BOUND, "alpha_ctrl_min",
             "control share for eps_ctrl = eps* at the predicted SNR"),
    ObsEntry("alpha_comm_min", "-", "linear", 1.0, 0.0, OBS_BOUND, "alpha_comm_min",
             "data share for R_min at the predicted SNR (with a queue: that would carry the backlog and a slot's "
             "mean arrivals in the slot)"),
    ObsEntry("last_packet_received", "0/1", "flag", None, 0.0, 1.0, "last_packet_received",
             "last slot's command delivered (1 at reset)"),
    ObsEntry("last_peb", "m", "symlog", PEB_SCALE, 0.0, OBS_BOUND, "last_peb_m", "last slot's PEB (0 at reset)"),
    ObsEntry("time_left", "slot", "time_left", None, 0.0, 1.0, "slot", "mission time left (decodes to the slot n)"),
)
#: The data queue's entries (with a queue, after :data:`BASE_OBS`).
QUEUE_OBS = (
    ObsEntry("backlog", "bit", "log_arrivals", None, 0.0, OBS_BOUND, "backlog_bits", "data backlog B"),
    ObsEntry("oldest_age", "slot", "per_deadline", None, 0.0, 1.0, "oldest_age_slots",
             "oldest waiting bit's age (slots it has waited)"),
)
#: The entries with blockage (after the queue's, before the preview's): the slot's measured large-scale SNR of
#: the echo per element and subcarrier, as ``snr_db`` is the command link's.
BLOCKAGE_OBS = (
    ObsEntry("echo_snr_db", "dB", "linear", SNR_SCALE, -OBS_BOUND, OBS_BOUND, "echo_snr_db",
             "the slot's measured large-scale echo SNR per element and subcarrier"),
)
#: The entries with the field (after the blockage's): what the GBS measured in the last slot (0 at reset), from which
#: an adaptive policy infers the world its model does not know: the command link's small-scale fading gain (the
#: acknowledgement's pilots: the slot's SNR over its predicted large-scale SNR) and the echo's SNR.
MEASURED_OBS = (
    ObsEntry("last_fade_db", "dB", "linear", SNR_SCALE, -OBS_BOUND, OBS_BOUND, "last_fade_db",
             "last slot's small-scale fading gain of the command link (measured SNR over the large-scale SNR)"),
    ObsEntry("last_echo_snr_db", "dB", "linear", SNR_SCALE, -OBS_BOUND, OBS_BOUND, "last_echo_snr_db",
             "last slot's measured echo SNR per element and subcarrier (fading and the drone's RCS included)"),
)
#: The entries with ``show_world`` (after the measured ones): the world's hidden values of the slot about to be
#: allocated, for the model-knowledge bound ``aware``; never a policy's information.
WORLD_OBS = (
    ObsEntry("world_k_db", "dB", "linear", SNR_SCALE, -OBS_BOUND, OBS_BOUND, "world_k_db",
             "the slot's Rician K-factor (hidden: the aware bound's)"),
    ObsEntry("world_rcs_offset_db", "dB", "linear", SNR_SCALE, -OBS_BOUND, OBS_BOUND, "world_rcs_offset_db",
             "the drone's RCS over the model's rcs_m2 (hidden: the aware bound's)"),
)
#: The entries of one preview point (after the others, one group per point k = 1 .. preview_slots, names suffixed
#: ``_k``), at the reference's slot n + k stride (the last slot where that is past the mission's end): the map's
#: LoS probability, and the large-scale SNRs it predicts there with its mean shadowing, of the command link in LoS
#: and in NLoS and of the echo in LoS and in NLoS. With ``preview_source="truth"`` (the oracle) the realised LoS
#: state, and the realised SNRs in both states' entries.
PREVIEW_OBS = (
    ObsEntry("p_los_ahead", "-", "linear", 1.0, 0.0, 1.0, "p_los_ahead", "map's LoS probability"),
    ObsEntry("snr_los_ahead_db", "dB", "linear", SNR_SCALE, -OBS_BOUND, OBS_BOUND, "snr_los_ahead_db",
             "map's large-scale SNR of the command link, in LoS"),
    ObsEntry("snr_nlos_ahead_db", "dB", "linear", SNR_SCALE, -OBS_BOUND, OBS_BOUND, "snr_nlos_ahead_db",
             "map's large-scale SNR of the command link, in NLoS"),
    ObsEntry("echo_los_ahead_db", "dB", "linear", SNR_SCALE, -OBS_BOUND, OBS_BOUND, "echo_los_ahead_db",
             "map's large-scale echo SNR, in LoS"),
    ObsEntry("echo_nlos_ahead_db", "dB", "linear", SNR_SCALE, -OBS_BOUND, OBS_BOUND, "echo_nlos_ahead_db",
             "map's large-scale echo SNR, in NLoS"),
)
#: The observation's blocks in their order; which a scenario has, and how often: :func:`obs_blocks`.
OBS_BLOCKS = {"base": BASE_OBS, "queue": QUEUE_OBS, "blockage": BLOCKAGE_OBS, "measured": MEASURED_OBS,
              "world": WORLD_OBS, "preview": PREVIEW_OBS}

#: Names of the entries every observation has, in order, and their positions.
OBS_NAMES = tuple(e.name for e in BASE_OBS)
OBS = {name: j for j, name in enumerate(OBS_NAMES)}
N_OBS = len(OBS_NAMES)
#: Each base entry's ``(scaling, scale)`` (:class:`ObsEntry`).
OBS_SCALING = {e.name: (e.scaling, e.scale) for e in BASE_OBS}
QUEUE_OBS_NAMES = tuple(e.name for e in QUEUE_OBS)
BLOCKAGE_OBS_NAMES = tuple(e.name for e in BLOCKAGE_OBS)
PREVIEW_OBS_NAMES = tuple(e.name for e in PREVIEW_OBS)
#: Positions inside a block (the compiled observation writes them: block offset + position).
O_BACKLOG, O_OLDEST_AGE = (QUEUE_OBS_NAMES.index(k) for k in ("backlog", "oldest_age"))
O_P_LOS_AHEAD, O_SNR_LOS_AHEAD, O_SNR_NLOS_AHEAD, O_ECHO_LOS_AHEAD, O_ECHO_NLOS_AHEAD = range(len(PREVIEW_OBS))
N_PREVIEW_OBS = len(PREVIEW_OBS)


def obs_blocks(s) -> tuple[tuple[str, int, int], ...]:
    """The observation's blocks for a scenario, in order: ``(block, offset, repeats)`` for each block it has
    (:data:`OBS_BLOCKS`): the base entries; the queue's with a queue (``queue_deadline_s`` > 0); the echo's with
    blockage; the measured ones with the field; the world's with ``show_world``; the preview's, once per point
    (``preview_slots`` > 0). The one place the layout is decided.
    """
    fx = task_effects(s)
    counts = {"base": 1, "queue": int(fx.queue), "blockage": int(fx.blockage), "measured": int(fx.field),
              "world": int(fx.show_world), "preview": fx.preview_points}
    blocks, at = [], 0
    for name, entries in OBS_BLOCKS.items():
        if counts[name] > 0:
            blocks.append((name, at, counts[name]))
            at += len(entries) * counts[name]
    return tuple(blocks)


def obs_offsets(s) -> dict[str, int]:
    """Where each block of :data:`OBS_BLOCKS` starts in a scenario's observation; -1 for a block it lacks."""
    at = {name: -1 for name in OBS_BLOCKS}
    at.update({name: offset for name, offset, _ in obs_blocks(s)})
    return at


def obs_entries(s) -> tuple[tuple[str, ObsEntry, int], ...]:
    """The scenario's observation entries in order: ``(name, entry, k)``, k the preview point (1 .. H; its names
    suffixed ``_k``), 0 outside the preview.
    """
    out = []
    for block, _, repeats in obs_blocks(s):
        for k in range(1, repeats + 1):
            k = k if block == "preview" else 0
            out += [(f"{e.name}_{k}" if k else e.name, e, k) for e in OBS_BLOCKS[block]]
    return tuple(out)


def obs_names(s) -> tuple[str, ...]:
    """The observation's entry names for a scenario (:func:`obs_entries`): :data:`OBS_NAMES`, then
    :data:`QUEUE_OBS_NAMES` with a queue, :data:`BLOCKAGE_OBS_NAMES` with blockage, then
    :data:`PREVIEW_OBS_NAMES` suffixed ``_1`` .. ``_H`` for each preview point.
    """
    return tuple(name for name, _, _ in obs_entries(s))


def obs_size(s) -> int:
    """Length of :func:`obs_names`."""
    return sum(len(OBS_BLOCKS[block]) * repeats for block, _, repeats in obs_blocks(s))


def _scaling_text(e: ObsEntry, s) -> str:
    if e.scaling == "symlog":
        return f"sign(x) ln(1 + |x| / {e.scale:g})"
    if e.scaling == "linear":
        return "x" if e.scale == 1.0 else f"{e.scale:g} x"
    if e.scaling == "flag":
        return "x (0 or 1)"
    if e.scaling == "range":
        return f"x / {s.coverage_radius_m:g} m (the coverage radius)"
    if e.scaling == "time_left":
        return f"1 - n / {s.n_slots} (n the slot index)"
    if e.scaling == "log_arrivals":
        return f"ln(1 + x / {s.queue_arrival_bps * s.dt_s:g} bit) (a slot's mean arrivals)"
    if e.scaling == "per_deadline":
        return f"x / {s.queue_deadline_slots} (the deadline in slots)"
    raise ValueError(f"unknown scaling {e.scaling!r}")


def observation_table(s) -> list[dict]:
    """The observation's table for a scenario, one row per entry, in order (the docs site's per-task table).

    Parameters
    ----------
    s : Scenario

    Returns
    -------
    list of dict
        One dict per entry with ``index`` (its position), ``name`` (:func:`obs_names`), ``unit`` (of the
        physical value x), ``scaling`` (how the entry is computed from x, with this scenario's constants:
        :class:`ObsEntry`), ``min`` and ``max`` (the range of the entry itself, inside +-:data:`OBS_BOUND`) and
        ``description``. Written from :data:`OBS_BLOCKS`, the one definition the compiled observation
        (:func:`iscc_gym.sim.kernel.observe_one`), the decoder (:func:`iscc_gym.sim.functional.decode_observation`)
        and the env's space read.
    """
    return [{"index": j, "name": name, "unit": e.unit, "scaling": _scaling_text(e, s), "min": e.low, "max": e.high,
             "description": e.description + (f", {k * s.preview_stride_slots} slots ahead" if k else "")}
            for j, (name, e, k) in enumerate(obs_entries(s))]


#: Standard normals per loop per slot (one more, :data:`Z_ARRIVAL`, with a queue: the slot's arrivals).
N_DRAWS = 18
#: The layout of a slot's :data:`N_DRAWS` normals: first index and count of each group. Fading:
#: (re, im) of the communication link, then of the sensing echo; measurement: 4 whitened ISAC rows
#: or 6 GNSS entries; drop: the control packet's Bernoulli draw (delivered iff Phi(z) >= eps);
#: process: the 6 process-noise entries; shadowing: the AR(1) innovation.
DRAWS = {"fading_comm": (0, 2), "fading_sensing": (2, 2), "measurement": (4, 6), "drop": (10, 1),
         "process": (11, 6), "shadowing": (17, 1)}
Z_FADE_COMM = DRAWS["fading_comm"][0]
Z_FADE_SEN = DRAWS["fading_sensing"][0]
Z_MEAS = DRAWS["measurement"][0]
Z_DROP = DRAWS["drop"][0]
Z_PROC = DRAWS["process"][0]
Z_SHADOW = DRAWS["shadowing"][0]
#: The queue's arrival draw, after the slot's :data:`N_DRAWS` (drawn only with a queue: the stream's first
#: N_DRAWS normals are the same with and without).
Z_ARRIVAL = N_DRAWS
assert sum(n for _, n in DRAWS.values()) == N_DRAWS


def n_draws(s) -> int:
    """Standard normals per loop per slot for a scenario: :data:`N_DRAWS`, and :data:`Z_ARRIVAL` with a queue."""
    return N_DRAWS + (1 if task_effects(s).queue else 0)
