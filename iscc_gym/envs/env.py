"""Gymnasium environment ``iscc_gym/ISCC-v0``: per-slot time-frequency allocation of an ISCC loop."""

from __future__ import annotations

import difflib
import math
import operator
from typing import Any

import gymnasium as gym
import numba
import numpy as np
from gymnasium import spaces
from numpy.typing import ArrayLike

from iscc_gym import threads
from iscc_gym.envs.render import Renderer
from iscc_gym.physics.stability import scenario_eps_star
from iscc_gym.scenario import Scenario, make_scenario
from iscc_gym.sim import kernel, loop
from iscc_gym.sim.schema import (
    COL,
    N_DRAWS,
    OBS_BOUND,
    OBS_NAMES,
    OBS_SCALING,
    STEP_COLUMNS,
)
from iscc_gym.sim.task import (
    action_to_split,
    reward_and_costs,
    split_to_action,
)
from iscc_gym.trajectory import sample_reference

__all__ = ["ISCCEnv", "ENV_ID", "action_to_split", "split_to_action", "observe", "reward_and_costs", "env_step",
           "decode_observation", "OBS_NAMES", "OBS_BOUND",
           "STEP_COLUMNS", "check_seed", "check_keywords", "real_array", "reset_info_arrays", "SLOT_OUTCOME_KEYS"]


def observe(s: Scenario, state: loop.LoopState, last_received: ArrayLike, last_peb_m: ArrayLike):
    """The observation of :class:`ISCCEnv` (table in its docstring), shape (B, 23), float32.

    A pure function of a batch of loop states and the last slot's outcome (arrays of shape (B,)),
    so the single env and any vector env build it the same way (:func:`iscc_gym.sim.kernel.observe_one`;
    an unbatched state gives shape (23,)).
    """
    if state.x.ndim == 1:
        return observe(s, loop.LoopState(*(f[None] for f in state)), last_received, last_peb_m)[0]
    nb = state.x.shape[0]
    obs = np.empty((nb, len(OBS_NAMES)), np.float32)
    kernel.observe_batch(kernel.kernel_constants(s)[0], state.x_hat, state.p, state.shadow, state.n, state.ref,
                         np.broadcast_to(np.asarray(last_received, dtype=float), (nb,)),
                         np.broadcast_to(np.asarray(last_peb_m, dtype=float), (nb,)), obs)
    return obs


def decode_observation(obs: ArrayLike, s: Scenario) -> dict:
    """Named physical values of observations (any leading batch shape), inverting the scalings of
    :data:`iscc_gym.sim.schema.OBS_SCALING` (the table of :class:`ISCCEnv`).

    Entries at the clip bound (+-``OBS_BOUND``) decode to the bound's value, not the true one.

    Returns
    -------
    dict of ndarray
        ``pos_err_m``, ``vel_err_mps`` (predicted estimate minus reference), ``ref_vel_mps``,
        ``ref_acc_mps2`` (shape (..., 3)); ``est_pos_std_m``, ``snr_db`` (predicted large-scale SNR),
        ``range_m``, ``sin_elevation``, ``cos_azimuth``, ``sin_azimuth``, ``alpha_ctrl_min``,
        ``alpha_comm_min``, ``last_packet_received`` (bool), ``last_peb_m``, ``slot`` (the slot index
        n, float) (shape (...)).
    """
    o = np.asarray(obs, dtype=float)
    if o.shape[-1] != len(OBS_NAMES):
        raise ValueError(f"obs must have {len(OBS_NAMES)} entries along the last axis, got shape {o.shape}")
    val = {}
    for j, name in enumerate(OBS_NAMES):
        kind, k = OBS_SCALING[name]
        y = o[..., j]
        if kind == "symlog":
            val[name] = np.sign(y) * k * np.expm1(np.abs(y))
        elif kind == "linear":
            val[name] = y / k
        elif kind == "range":
            val[name] = y * s.coverage_radius_m
        else:  # time_left = 1 - n / n_slots
            val[name] = (1.0 - y) * s.n_slots

    def vec(prefix):
        return np.stack([val[prefix + ax] for ax in "xyz"], -1)

    return {"pos_err_m": vec("pos_err_"), "vel_err_mps": vec("vel_err_"), "ref_vel_mps": vec("ref_vel_"),
            "ref_acc_mps2": vec("ref_acc_"), "est_pos_std_m": val["est_pos_std"], "snr_db": val["snr_db"],
            "range_m": val["range"], "sin_elevation": val["sin_elevation"], "cos_azimuth": val["cos_azimuth"],
            "sin_azimuth": val["sin_azimuth"], "alpha_ctrl_min": val["alpha_ctrl_min"],
            "alpha_comm_min": val["alpha_comm_min"], "last_packet_received": val["last_packet_received"] > 0.5,
            "last_peb_m": val["last_peb"], "slot": val["time_left"]}


#: Smaller batches are always stepped serially; larger ones on all cores only when the parallel kernel
#: is switched on (:mod:`iscc_gym.threads`; the same results bit for bit).
PARALLEL_MIN_BATCH = threads.PARALLEL_MIN_BATCH


#: The columns :meth:`ISCCEnv.step` reads, in the order it unpacks them (one C call per step).
_STEP_FIELDS = ("tracking_error_m", "estimation_error_m", "snr_db", "snr_large_scale_db", "peb_m", "veb_mps",
                "eps_ctrl", "packet_received", "rate_comm_bps", "rate_ctrl_bps", "alpha_sen", "alpha_ctrl",
                "alpha_comm", "cost_rate", "cost_stability", "reward", "terminated", "truncated")
_read_step = operator.itemgetter(*(COL[name] for name in _STEP_FIELDS))


def env_step(s: Scenario, state: loop.LoopState, actions: ArrayLike, normals: ArrayLike = None,
             active: ArrayLike = None, budget: ArrayLike = None):
    """One env step of a batch of loops: action map, slot transition, reward, costs, next observation.

    The single env (a batch of one) and the vector env both call it, so drone i of a batch
    reproduces the single env seeded alike bit for bit.

    Parameters
    ----------
    state : LoopState (batched, B loops)
    actions : ndarray (B, 3), finite
    normals : ndarray (B, N_DRAWS), optional
        The slot's standard normals; default: each loop's episode stream
        (:func:`iscc_gym.sim.noise.slot_normals` of its key and slot, drawn inside the kernel).
    active : ndarray (B,) bool, optional
        Loops to step (default all); the others keep their state, slot index and zero outputs.
    budget : ndarray (B,), optional
        Each loop's share of the band, which scales its split (the multi-drone env,
        :mod:`iscc_gym.envs.multi`); default the whole band.

    Returns
    -------
    state : LoopState
    out : ndarray (B, len(STEP_COLUMNS))
        :data:`STEP_COLUMNS`: the loop metrics, the applied split, ``cost_rate``,
        ``cost_stability``, ``reward``, ``terminated`` and ``truncated`` (0/1).
    obs : ndarray (B, 23) float32
    """
    nb = state.x.shape[0]
    all_active = active is None
    if all_active:
        active = _all_active(nb)
    c, mats = kernel.kernel_constants(s)
    x, x_hat, p, shadow, out, obs = outputs = kernel.new_outputs(nb, len(STEP_COLUMNS))
    z = _NO_NORMALS if normals is None else normals
    b = _WHOLE_BAND if budget is None else budget
    args = (c, mats, state.x, state.x_hat, state.p, state.shadow, state.n, state.ref, state.key, actions, b, z, active)
    # numba.get_num_threads() costs ~0.5 us: asked only for a batch the parallel kernel could take
    if nb >= PARALLEL_MIN_BATCH and threads.use_parallel(nb, numba.get_num_threads()):
        kernel.env_step_batch_parallel(*args, *outputs, kernel.parallel_chunk(nb))
    else:
        kernel.env_step_batch(*args, *outputs)
    n = state.n + 1 if all_active else state.n + active
    return state._replace(x=x, x_hat=x_hat, p=p, shadow=shadow, n=n), out, obs


_ALL_ACTIVE: dict[int, np.ndarray] = {}
_NO_NORMALS = np.empty((0, N_DRAWS))  # the kernel's "draw from the keys" signal
_WHOLE_BAND = np.empty(0)  # the kernel's "every loop has the whole band" signal


def _all_active(nb: int) -> np.ndarray:
    """A read-only all-True mask of length nb (cached: built once per batch size)."""
    mask = _ALL_ACTIVE.get(nb)
    if mask is None:
        mask = np.ones(nb, dtype=bool)
        mask.setflags(write=False)
        _ALL_ACTIVE[nb] = mask
    return mask


def check_seed(seed: ArrayLike, name: str = "seed"):
    """``seed`` as Gymnasium's generator takes it (None or a Python int >= 0), or a clear error.

    Raises
    ------
    TypeError
        Not None and not an integer (a float, a string, a bool).
    ValueError
        A negative integer.
    """
    if seed is None:
        return None
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)):
        raise TypeError(f"{name} = {seed!r} ({type(seed).__name__}): pass an integer >= 0, or None for a fresh "
                        "seed from the operating system")
    if seed < 0:
        raise ValueError(f"{name} = {seed}: pass an integer >= 0, or None for a fresh seed from the operating system")
    return int(seed)


def check_keywords(owner: str, overrides: dict, accepted: tuple[str, ...] = ("scenario", "render_mode")) -> None:
    """Raise Python's own ``TypeError`` wording for a keyword that is not an argument of ``owner`` nor a
    :class:`iscc_gym.Scenario` field: ``<owner>.__init__() got an unexpected keyword argument 'name'``,
    then a hint (the closest valid name, and where the valid names are listed).

    Libraries rely on that wording: TorchRL's ``GymEnv`` passes ``frameskip=1`` and retries without it
    only when the error says ``unexpected keyword argument 'frameskip'``.
    """
    fields = Scenario.__dataclass_fields__
    unknown = [name for name in overrides if name not in fields]
    if not unknown:
        return
    name = unknown[0]
    close = difflib.get_close_matches(name, [*accepted, *fields], n=1)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    raise TypeError(f"{owner}.__init__() got an unexpected keyword argument {name!r}{hint}; it takes "
                    f"{', '.join(accepted)} and the Scenario fields as overrides: "
                    f"{sorted(fields)}" + (f"; unknown: {unknown}" if len(unknown) > 1 else ""))


def real_array(x: ArrayLike, name: str = "action") -> np.ndarray:
    """``x`` as a float64 array, refusing complex numbers (numpy would drop the imaginary part with only
    a warning).

    Raises
    ------
    TypeError
        ``x`` holds complex numbers.
    """
    a = np.asarray(x)
    if a.dtype.kind == "c":
        raise TypeError(f"{name} has complex dtype {a.dtype}; pass real numbers in [-1, 1] (np.real(...) if the "
                        "imaginary parts are meant to be dropped)")
    return a.astype(np.float64, copy=False)


#: Info keys of a step whose values are outcomes of a slot (its fading, measurement and links): NaN in the
#: info of ``reset``, before any slot has run (:func:`reset_info_arrays`).
SLOT_OUTCOME_KEYS = ("snr_db", "snr_large_scale_db", "peb_m", "veb_mps", "eps_ctrl", "rate_comm_bps", "rate_ctrl_bps",
                     "estimation_error_m")


def reset_info_arrays(state: loop.LoopState) -> dict:
    """The values of a step's info keys at reset, per loop of a batch (arrays of shape (B,), ``alpha``
    (B, 3)), so ``reset`` and ``step`` infos carry the same keys (libraries such as TorchRL build their
    specs from the reset info).

    ``tracking_error_m``: the initial state's true error ||p_0 - p_ref,0||; ``cost_rate``,
    ``cost_stability``, ``cost``: 0 (no slot, no violation); ``packet_received``: True and ``alpha``:
    equal thirds (as the observation's entry 20 at reset); ``slot``: 0; the slot outcomes of
    :data:`SLOT_OUTCOME_KEYS` (SNRs, PEB, VEB, loss probability, rates, estimation error): NaN.
    """
    nb = state.x.shape[0]
    zeros = np.zeros(nb)
    info = {"tracking_error_m": np.linalg.norm(state.x[:, :3] - state.ref[np.arange(nb), state.n, :3], axis=1),
            "cost_rate": zeros, "cost_stability": zeros.copy(), "cost": zeros.copy()}
    info.update({key: np.full(nb, np.nan) for key in SLOT_OUTCOME_KEYS})
    info["packet_received"] = np.ones(nb, dtype=bool)
    info["alpha"] = np.full((nb, 3), 1.0 / 3.0)
    info["slot"] = state.n.copy()
    return info


#: The registered id of this env.
ENV_ID = "iscc_gym/ISCC-v0"
#: The registered ``max_episode_steps`` of ``iscc_gym/ISCC-v0`` (the paper's mission: 500 s / 0.1 s).
REGISTERED_MAX_EPISODE_STEPS = 5000


def warn_time_limit(s: Scenario) -> None:
    """Warn when the scenario's mission is longer than the registered TimeLimit: ``gymnasium.make``
    wraps the env in ``TimeLimit(5000)`` unless it is given ``max_episode_steps``, which would cut
    the mission short (a shorter mission ends by itself).
    """
    if s.n_slots > REGISTERED_MAX_EPISODE_STEPS:
        gym.logger.warn(f"this scenario's mission has n_slots = {s.n_slots} slots, but gymnasium.make applies the "
                        f"registered TimeLimit of {REGISTERED_MAX_EPISODE_STEPS} steps: pass "
                        f"max_episode_steps={s.n_slots} to gymnasium.make / make_vec (ignore this if you did)")


class ISCCEnv(gym.Env):
    r"""Allocate each slot's time-frequency resources of an ISCC drone-tracking loop.

    ## Description

    A ground base station (GBS) senses a drone with an OFDM ISAC waveform, estimates its 6-D state
    with a Kalman filter and sends LQG acceleration commands over a finite-blocklength link that
    drops packets (Li et al., *Closed-Loop ISCC for Efficient Drone Flight*; ``docs/model.md``).
    Every slot (dt = 0.1 s) the agent splits the resources into sensing, control and data
    shares: sensing sets the Cramér-Rao bound of the radar measurement, control sets the command's
    loss probability and so mean-square stability, and the data link must carry ``rate_min_bps``.
    Each step calls the pure batched transition :func:`env_step` once on a batch of one (the vector
    env :class:`iscc_gym.envs.vector.ISCCVectorEnv` calls the same function on N loops, so sub-env i
    reproduces this env seeded alike bit for bit). It evaluates the model of ``docs/model.md``
    with a compiled kernel (:mod:`iscc_gym.sim.kernel`, composed of the physics modules' scalar functions;
    ``tests/oracle_loop.py`` holds the same step in numpy as the test oracle).

    ## Action Space

    ``Box(-1, 1, (3,), float32)``, mapped inside the env onto the simplex by
    :func:`action_to_split`: :math:`w_i = (a_i + 1)/2`, :math:`\alpha = w / \sum w` (equal thirds if
    all :math:`w_i = 0`). No minimum share: any split is reachable (:func:`split_to_action` gives its
    action), including zero shares (zero sensing: the radar measurement carries no information; zero
    control: every command is lost; zero data: no rate). ``info["alpha"]`` is the applied split.
    Finite out-of-range actions are clipped; NaN/inf or a wrong shape raise ``ValueError``, complex
    numbers ``TypeError``, and leave the env unchanged.

    | Num | Action | Min | Max |
    |-----|--------|-----|-----|
    | 0   | sensing weight  | -1 | 1 |
    | 1   | control weight  | -1 | 1 |
    | 2   | data weight     | -1 | 1 |

    ## Observation Space

    ``Box(-10, 10, (23,), float32)``: what the GBS knows before it allocates the slot; the slot's
    small-scale fading is drawn after the allocation. symlog(x, c) = sign(x) ln(1 + |x|/c); every
    entry is clipped to [-10, 10].

    | Num | Observation | Unit / scaling | Min | Max |
    |-----|-------------|----------------|-----|-----|
    | 0-2 | predicted position error x_hat_{n|n-1} - p_ref,n | symlog(m, 0.1) | -10 | 10 |
    | 3-5 | predicted velocity error | symlog(m/s, 0.1) | -10 | 10 |
    | 6-8 | reference velocity | m/s / 10 | -10 | 10 |
    | 9-11 | reference acceleration | m/s^2 | -10 | 10 |
    | 12 | estimate's position std sqrt(tr P_pp) | symlog(m, 0.1) | 0 | 10 |
    | 13 | predicted large-scale SNR (path loss, beam gain, shadowing) | dB / 10 | -10 | 10 |
    | 14 | predicted range to the GBS antenna | / coverage radius | 0 | 10 |
    | 15 | sin(predicted elevation) | - | -1 | 1 |
    | 16-17 | cos, sin(predicted azimuth) | - | -1 | 1 |
    | 18 | control share for eps_ctrl = eps* at the predicted SNR | x 10 | 0 | 10 |
    | 19 | data share for R_min at the predicted SNR | - | 0 | 10 |
    | 20 | last slot's command delivered (1 at reset) | 0/1 | 0 | 1 |
    | 21 | last slot's PEB (0 at reset) | symlog(m, 0.05) | 0 | 10 |
    | 22 | mission time left | fraction | 0 | 1 |

    ## Rewards

    .. math::
        r_n = -\|\mathbf p_{n+1} - \mathbf p_{\mathrm{ref},n+1}\| - w_\mathrm{rate}\,
        \frac{(R_\min - \mathcal R_{\mathrm{comm},n})^+}{R_\min}
        - w_\mathrm{stab}\, \mathbb 1[\varepsilon_{\mathrm{ctrl},n} > \varepsilon^\star]

    (tracking error in m, the weights ``w_rate``, ``w_stab`` of the Scenario). The two violations are
    also reported as costs for constrained RL: ``info["cost_rate"]`` (normalised shortfall, in
    [0, 1]), ``info["cost_stability"]`` (0/1) and ``info["cost"]`` (their sum);
    :class:`iscc_gym.envs.wrappers.SafetyCostWrapper` returns Safety-Gymnasium's 6-tuple. Loss of track
    adds a one-off penalty of ``max_tracking_error_m`` per remaining slot (as if the error stayed at
    the bound for the rest of the mission), so ending an episode early never pays.

    ## Starting State

    ``reset`` draws a new reference trajectory (Poisson waypoints, cubic spline) and the drone's
    initial state near its start (``initial_pos_std_m``, ``initial_vel_std_mps``), all from the
    env's generator, and then the episode's noise key: every slot's fading, measurement, drop,
    process and shadowing normals are :func:`iscc_gym.sim.noise.slot_normals` (key, slot), so an
    episode is fixed by the generator's state at reset.

    The reset ``info`` carries every key of a step's ``info``: ``tracking_error_m`` the initial
    error, costs 0, ``packet_received`` True, ``alpha`` equal thirds, ``slot`` 0, ``action`` NaN, and
    the slot outcomes (``snr_db``, ``snr_large_scale_db``, ``peb_m``, ``veb_mps``, ``eps_ctrl``,
    ``rate_comm_bps``, ``rate_ctrl_bps``, ``estimation_error_m``) NaN: no slot has run yet
    (:func:`reset_info_arrays`).

    ## Episode End

    * Termination: loss of track, the tracking error exceeds ``max_tracking_error_m`` (100 m), or
      the state has left the range the model can evaluate (far outside the coverage region, e.g. an
      estimate below ground where the shadowing overflows the SNR, or a non-finite Kalman estimate).
      Observations and rewards stay finite: an observation entry that cannot be evaluated (NaN)
      reads 0, every entry is clipped to [-10, 10], and a NaN rate or loss probability counts as a
      violation (cost 1).
    * Truncation: the mission ends after ``n_slots`` = T_m / dt = 5000 slots (also the registered
      ``max_episode_steps``). A shorter episode on the same mission: ``gymnasium.make(...,
      max_episode_steps=k)`` truncates after k slots and changes nothing else (``mission_duration_s``
      instead sets the length of the flight itself, and so its speed).
    * After either, ``step`` raises ``RuntimeError`` until ``reset`` (the vector env resets ended
      sub-envs itself, per its autoreset mode).

    ## Arguments

    ``gymnasium.make("iscc_gym/ISCC-v0", scenario="paper", render_mode=None, **overrides)``:
    ``scenario`` is a preset name (``"paper"``, ``"literal"``) or a :class:`iscc_gym.Scenario`;
    ``overrides`` are Scenario fields, e.g. ``observation_source="gnss"`` (GNSS feedback, 3 m and
    0.2 m/s), ``control_mode="open_loop"`` (reference acceleration, no feedback),
    ``reference_feedforward=True``. An unknown keyword raises Python's own ``TypeError`` wording,
    ``ISCCEnv.__init__() got an unexpected keyword argument 'frameskip'``, followed by the valid names
    (libraries such as TorchRL's ``GymEnv`` retry without an optional keyword on that wording).
    ``render_mode="rgb_array"`` renders the plan view and altitude of the reference and flown paths,
    and over the last 200 slots the split, the rate and stability violations, the tracking error and
    the PEB (:mod:`iscc_gym.envs.render`). ``render_mode="human"`` prints a status line to stdout (time,
    tracking error, PEB, split, costs) at reset, once per simulated second and when the episode ends,
    and on each call of ``render()``: it needs no display (e.g. ``python -m rl_zoo3.enjoy``).

    ## Version History

    * v0: initial version. Each slot's normals come from a per-episode stream: a key drawn at
      reset from ``np_random``, then :func:`iscc_gym.sim.noise.slot_normals` (key, slot). (Before the
      first release they were drawn from ``np_random`` itself, in blocks of 64 slots, so seeded
      episodes of earlier development versions differ.)
    * v0, issue 23 (no change to dynamics or rewards): the reset ``info`` carries a step's keys,
      ``render_mode="human"`` (a status line on stdout), Python's own ``TypeError`` wording for an
      unknown keyword, complex actions refused.

    ## Example

    >>> import gymnasium as gym, iscc_gym
    >>> env = gym.make("iscc_gym/ISCC-v0", scenario="paper")
    >>> obs, info = env.reset(seed=0)
    >>> obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    """

    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": 10}

    def __init__(self, scenario: str | Scenario = "paper", render_mode: str | None = None,
                 **overrides: Any):
        check_keywords(type(self).__name__, overrides)
        self.scenario = make_scenario(scenario, **overrides)
        warn_time_limit(self.scenario)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode={render_mode!r}; use None or one of "
                             f"{self.metadata['render_modes']}")
        self.render_mode = render_mode
        self.eps_star = scenario_eps_star(self.scenario)
        self.action_space = spaces.Box(-1.0, 1.0, (3,), np.float32)
        self.observation_space = spaces.Box(-OBS_BOUND, OBS_BOUND, (len(OBS_NAMES),), np.float32)
        self._state: loop.LoopState | None = None
        self._ended = False  # the episode terminated: step() needs a reset first
        self._last_received = True
        self._last_peb = 0.0
        self._renderer = (Renderer(self.scenario.dt_s, self.scenario.gbs_height_m) if render_mode == "rgb_array"
                          else None)
        self._human_every = max(1, round(1.0 / self.scenario.dt_s))  # human mode: a line per simulated second
        self._last_info: dict = {}
        self._printed: tuple = ()  # human mode: the (episode, slot) last printed
        self._episodes = 0  # resets so far

    # --- Gymnasium API -------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        seed = check_seed(seed, "seed")  # before anything changes: a rejected seed leaves the env as it was
        super().reset(seed=seed)
        s = self.scenario
        self._state, self._ended = None, False  # a reset that fails (see sample_reference) leaves no episode
        ref = sample_reference(s, self.np_random)
        # a batch of one: bit-identical to the same drone in any batch (the vector env)
        self._state = loop.init_state(s, [ref], [self.np_random])
        self._last_received, self._last_peb = True, 0.0
        self._episodes += 1
        if self._renderer is not None:
            self._renderer.reset(self._state.ref[0], self._state.x[0])
        info = self._reset_info()
        if self.render_mode == "human":
            self._last_info = info
            self.render()
        return self._observation(), info

    def step(self, action):
        if self._state is None:
            raise RuntimeError("step() called before reset(): call env.reset(seed=...) first")
        a = real_array(action, "action")
        if a.shape != (3,):
            raise ValueError(f"action must have shape (3,), got {a.shape}")
        a0, a1, a2 = a.tolist()
        if not (math.isfinite(a0) and math.isfinite(a1) and math.isfinite(a2)):
            raise ValueError(f"action {a.tolist()} contains NaN or inf; pass finite values in [-1, 1]")
        s = self.scenario
        if self._ended:
            raise RuntimeError("the episode has ended (terminated: loss of track); call reset() before step()")
        if self._state.n[0] >= s.n_slots:
            raise RuntimeError("the mission is over (truncated); call reset() before step()")
        self._state, out, obs = env_step(s, self._state, a[None])
        (err, est, snr_db, snr_ls_db, peb, veb, eps, received, rate, rate_ctrl, al_sen, al_ctrl, al_comm,
         cost_rate, cost_stab, reward, terminated, truncated) = _read_step(out[0].tolist())  # _STEP_FIELDS
        self._ended = terminated == 1.0
        self._last_received, self._last_peb = received == 1.0, peb
        n = int(self._state.n[0])
        if self._renderer is not None:
            self._renderer.record(self._state.x[0], err, peb, (al_sen, al_ctrl, al_comm), cost_rate, cost_stab)
        info = {
            "tracking_error_m": err,
            "cost_rate": cost_rate,
            "cost_stability": cost_stab,
            "cost": cost_rate + cost_stab,
            "snr_db": snr_db,
            "snr_large_scale_db": snr_ls_db,
            "peb_m": peb,
            "veb_mps": veb,
            "eps_ctrl": eps,
            "packet_received": self._last_received,
            "rate_comm_bps": rate,
            "rate_ctrl_bps": rate_ctrl,
            "estimation_error_m": est,
            "alpha": np.array((al_sen, al_ctrl, al_comm)),
            "action": a.astype(np.float32),
            "slot": n,
        }
        if self.render_mode == "human":
            self._last_info = info
            if n % self._human_every == 0 or terminated == 1.0 or truncated == 1.0:
                self.render()
        return obs[0], reward, terminated == 1.0, truncated == 1.0, info

    def render(self):
        """``rgb_array``: the frame (:mod:`iscc_gym.envs.render`). ``human``: print the current slot's status
        line to stdout, once per slot (the env also prints it itself at reset, once per simulated second
        and at the episode's end, so it works headless, e.g. under ``python -m rl_zoo3.enjoy``, which
        calls ``render()`` after every step); returns None.
        """
        if self.render_mode is None:
            return None
        if self._state is None:
            raise RuntimeError("render() called before reset()")
        if self.render_mode == "human":
            key = (self._episodes, int(self._state.n[0]))
            if key != self._printed:  # one line per slot, however often render() is called
                self._printed = key
                print(self._status_line(), flush=True)
            return None
        return self._renderer.frame()

    # --- helpers ---------------------------------------------------------------------------------
    def _reset_info(self) -> dict:
        """The step's info keys at reset (:func:`reset_info_arrays`; ``action`` NaN: none applied yet)."""
        arrays = reset_info_arrays(self._state)
        info = {key: (val[0].copy() if key == "alpha" else val[0].item()) for key, val in arrays.items()}
        info["action"] = np.full(3, np.nan, np.float32)
        info["slot"] = 0
        return info

    def _status_line(self) -> str:
        """One line of the episode's state for ``render_mode="human"``."""
        i = self._last_info
        n = int(self._state.n[0])
        al = i.get("alpha", np.full(3, np.nan))
        err = i.get("tracking_error_m", np.nan)
        return (f"ISCC t={n * self.scenario.dt_s:7.1f} s  slot {n:5d}  tracking error {err:8.3f} m"
                f"  PEB {i.get('peb_m', np.nan):8.3f} m  split sen/ctrl/data {al[0]:.2f}/{al[1]:.2f}/{al[2]:.2f}"
                f"  rate cost {i.get('cost_rate', np.nan):.2f}  unstable {i.get('cost_stability', np.nan):.0f}"
                + ("  LOST TRACK" if self._ended else ""))

    def _observation(self) -> np.ndarray:
        return observe(self.scenario, self._state, self._last_received, self._last_peb)[0]
