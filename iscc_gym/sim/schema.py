"""One schema for a slot's inputs and outputs: metric and env columns, observation entries, noise draws.

Everything that names or positions a number crossing the step boundary is defined here once and
read by the compiled kernel (:mod:`iscc_gym.sim.kernel`), the numpy transition (:mod:`iscc_gym.sim.loop`),
the single env, the vector env and the agents. Plain Python: the module imports nothing from the
package, so every layer can use it (the integer positions are module constants numba freezes at
compile time).
"""

from __future__ import annotations

__all__ = ["obs_names", "obs_size", "QUEUE_OBS_NAMES", "PREVIEW_OBS_NAMES", "BLOCKAGE_OBS_NAMES",
           "METRIC_NAMES", "ENV_COLUMNS", "STEP_COLUMNS", "COL", "N_METRICS", "N_STEP_COLUMNS", "OBS_NAMES",
           "OBS", "N_OBS", "OBS_BOUND", "OBS_SCALING", "N_DRAWS", "DRAWS", "n_draws", "Z_ARRIVAL", "ERR_SCALE",
           "REF_VEL_SCALE",
           "REF_ACC_SCALE", "SNR_SCALE", "CTRL_SHARE_SCALE", "PEB_SCALE"]

#: Columns of a slot's metrics (:func:`iscc_gym.sim.loop.step`), in order: the closed loop's, then the data
#: queue's (:mod:`iscc_gym.physics.queue`: the slot's arrivals, the bits served and dropped, the backlog after the
#: slot; 0 without a queue).
METRIC_NAMES = ("tracking_error_m", "estimation_error_m", "snr_db", "snr_large_scale_db", "peb_m",
                "veb_mps", "eps_ctrl", "packet_received", "rate_comm_bps", "rate_ctrl_bps", "diverged",
                "bits_arrived", "bits_served", "bits_dropped", "backlog_bits")
#: Columns an env step adds after :data:`METRIC_NAMES`: the applied split, costs, reward, episode end (0/1).
ENV_COLUMNS = ("alpha_sen", "alpha_ctrl", "alpha_comm", "cost_rate", "cost_stability", "reward",
               "terminated", "truncated")
#: Columns of the per-loop output array of an env step (:func:`iscc_gym.sim.functional.env_step`).
STEP_COLUMNS = METRIC_NAMES + ENV_COLUMNS
#: Position of each column of :data:`STEP_COLUMNS` by name.
COL = {name: j for j, name in enumerate(STEP_COLUMNS)}
N_METRICS = len(METRIC_NAMES)
N_STEP_COLUMNS = len(STEP_COLUMNS)

#: Names of the observation entries, in order (table in :class:`iscc_gym.envs.env.ISCCEnv`).
OBS_NAMES = (
    "pos_err_x", "pos_err_y", "pos_err_z", "vel_err_x", "vel_err_y", "vel_err_z",
    "ref_vel_x", "ref_vel_y", "ref_vel_z", "ref_acc_x", "ref_acc_y", "ref_acc_z",
    "est_pos_std", "snr_db", "range", "sin_elevation", "cos_azimuth", "sin_azimuth",
    "alpha_ctrl_min", "alpha_comm_min", "last_packet_received", "last_peb", "time_left",
)
#: Position of each observation entry by name.
OBS = {name: j for j, name in enumerate(OBS_NAMES)}
N_OBS = len(OBS_NAMES)
#: Every observation entry is clipped to [-OBS_BOUND, OBS_BOUND].
OBS_BOUND = 10.0
#: Scales of the observation entries (module constants: the compiled observation reads them too).
ERR_SCALE = 0.1          # symlog scale of the predicted errors (m, m/s) and of the estimate's std (m)
REF_VEL_SCALE = 0.1      # reference velocity, per m/s
REF_ACC_SCALE = 1.0      # reference acceleration, per m/s^2
SNR_SCALE = 0.1          # predicted SNR, per dB
CTRL_SHARE_SCALE = 10.0  # control share at eps*
PEB_SCALE = 0.05         # symlog scale of the last PEB, m
#: How each entry is scaled from its physical value: ``("symlog", c)`` is sign(x) ln(1 + |x|/c),
#: ``("linear", k)`` is k x; ``"range"`` divides by the coverage radius, ``"time_left"`` is
#: 1 - n / n_slots (both scenario-dependent). :func:`iscc_gym.sim.functional.decode_observation` inverts them.
OBS_SCALING = {
    **{name: ("symlog", ERR_SCALE) for name in OBS_NAMES[0:6]},
    **{name: ("linear", REF_VEL_SCALE) for name in OBS_NAMES[6:9]},
    **{name: ("linear", REF_ACC_SCALE) for name in OBS_NAMES[9:12]},
    "est_pos_std": ("symlog", ERR_SCALE),
    "snr_db": ("linear", SNR_SCALE),
    "range": ("range", None),
    "sin_elevation": ("linear", 1.0),
    "cos_azimuth": ("linear", 1.0),
    "sin_azimuth": ("linear", 1.0),
    "alpha_ctrl_min": ("linear", CTRL_SHARE_SCALE),
    "alpha_comm_min": ("linear", 1.0),
    "last_packet_received": ("linear", 1.0),
    "last_peb": ("symlog", PEB_SCALE),
    "time_left": ("time_left", None),
}

#: Observation entries of the data queue (after :data:`OBS_NAMES`, with a queue): the backlog, as
#: ln(1 + B / A) with A the mean arrivals of a slot, and the oldest waiting bit's age over the deadline D.
QUEUE_OBS_NAMES = ("backlog", "oldest_age")
#: Observation entries of one preview point (after the others, with a preview), at the reference's slot
#: n + k stride, k = 1 .. preview_slots (the last slot where that is past the mission's end): the map's LoS
#: probability, and the large-scale SNRs it predicts there with its mean shadowing (dB, times SNR_SCALE) of the
#: command link in LoS and in NLoS and of the echo in LoS and in NLoS.
PREVIEW_OBS_NAMES = ("p_los_ahead", "snr_los_ahead_db", "snr_nlos_ahead_db", "echo_los_ahead_db",
                     "echo_nlos_ahead_db")
#: Observation entries with blockage (after the queue's, before the preview's): the slot's measured large-scale
#: SNR of the echo per element and subcarrier (dB, times SNR_SCALE), as ``snr_db`` is the command link's.
BLOCKAGE_OBS_NAMES = ("echo_snr_db",)


def obs_names(s) -> tuple[str, ...]:
    """The observation's entries for a scenario: :data:`OBS_NAMES`, then :data:`QUEUE_OBS_NAMES` with a queue
    (``queue_slots`` > 0), then :data:`PREVIEW_OBS_NAMES` suffixed ``_1`` .. ``_H`` for each preview point.
    """
    names = OBS_NAMES
    if s.queue_slots > 0:
        names += QUEUE_OBS_NAMES
    if s.blockage != "none":
        names += BLOCKAGE_OBS_NAMES
    for k in range(1, s.preview_slots + 1):
        names += tuple(f"{name}_{k}" for name in PREVIEW_OBS_NAMES)
    return names


def obs_size(s) -> int:
    """Length of :func:`obs_names`."""
    return len(obs_names(s))


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
    return N_DRAWS + (1 if s.queue_slots > 0 else 0)
