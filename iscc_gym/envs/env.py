"""Gymnasium environment ``iscc_gym/ISCC-v0``: per-slot time-frequency allocation of an ISCC loop."""

from __future__ import annotations

import difflib
import math
import operator
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numpy.typing import ArrayLike

from iscc_gym.envs.render import Renderer
from iscc_gym.physics.stability import scenario_eps_star
from iscc_gym.scenario import Scenario, make_scenario
from iscc_gym.sim import loop
from iscc_gym.sim.functional import env_step, observe, reset_info_arrays, step_info
from iscc_gym.sim.schema import COL, OBS_BOUND, obs_size
from iscc_gym.tasks import ENV_ID, TASKS, URBAN_ENV_ID, registered_scenario

__all__ = ["ISCCEnv", "ENV_ID", "URBAN_ENV_ID", "REGISTERED_MAX_EPISODE_STEPS", "check_seed", "check_keywords",
           "real_array", "warn_time_limit", "TimeLimitCheck", "registered_scenario"]

#: Reward, terminated and truncated from a step's output row.
_read_end = operator.itemgetter(COL["reward"], COL["terminated"], COL["truncated"])


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


#: The registered ``max_episode_steps`` of ``iscc_gym/ISCC-v0`` (the paper's mission: 500 s / 0.1 s).
REGISTERED_MAX_EPISODE_STEPS = TASKS[ENV_ID].max_episode_steps


def warn_time_limit(s: Scenario, env_id: str, steps: int | None = None) -> None:
    """Warn when ``gymnasium.make`` / ``make_vec`` of ``env_id`` cut the scenario's mission short: its registered
    TimeLimit (``max_episode_steps``; 5000 for ``iscc_gym/ISCC-v0``, 1200 for ``iscc_gym/ISCC-Urban-v0``) is
    shorter than the mission's ``n_slots`` (a shorter mission ends by itself).

    ``steps``: the limit the env was given (the vector env's ``max_episode_steps``); another value than the
    registered one is the user's, so no warning. Without it (the single env, which cannot see the TimeLimit
    wrapper) the warning says to ignore it if ``max_episode_steps`` was passed.
    """
    try:
        limit = gym.spec(env_id).max_episode_steps
    except gym.error.Error:  # not a registered id (an EnvSpec made by hand)
        return
    if limit is None or s.n_slots <= limit or (steps is not None and steps != limit):
        return
    gym.logger.warn(f"this scenario's mission has n_slots = {s.n_slots} slots, but {env_id} is registered with a "
                    f"TimeLimit of {limit} steps, which cuts it short: pass max_episode_steps={s.n_slots} to "
                    "gymnasium.make / make_vec" + (" (ignore this if you did)" if steps is None else ""))


class TimeLimitCheck:
    """Mixin of the envs: :func:`warn_time_limit` for the env id the env is made as. ``gymnasium.make`` and
    ``make_vec`` set ``env.unwrapped.spec`` right after construction (before wrapping the env in that id's
    TimeLimit): the one moment the env learns its id, so ``spec`` is a property whose setter checks.
    """

    _spec = None
    #: The time limit the env was given (the vector env's ``max_episode_steps``), None if it cannot know it.
    _time_limit_given: int | None = None

    @property
    def spec(self):
        return self._spec

    @spec.setter
    def spec(self, value) -> None:
        self._spec = value
        if value is not None:
            warn_time_limit(self.scenario, value.id, self._time_limit_given)


class ISCCEnv(TimeLimitCheck, gym.Env):
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
    entry is clipped to [-10, 10]. The entries, their scalings, bounds and order are defined once in
    :data:`iscc_gym.sim.schema.OBS_BLOCKS`; :func:`iscc_gym.sim.schema.observation_table` gives a scenario's
    table (the tables below are it, written out; ``tests/env/test_urban.py`` checks they agree) and
    :func:`iscc_gym.sim.functional.decode_observation` the physical values.

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

    **The urban task** (``iscc_gym/ISCC-Urban-v0``, preset ``"urban"``; ``docs/model.md`` Sec. 6) has
    ``Box(-10, 10, (76,), float32)``: the 23 above (entry 13 the slot's measured large-scale SNR,
    blocked line of sight included; entry 19 the data share that would carry the backlog and a slot's mean
    arrivals in the slot), then (:func:`iscc_gym.sim.schema.obs_names`):

    | Num | Observation | Unit / scaling | Min | Max |
    |-----|-------------|----------------|-----|-----|
    | 23 | data backlog B | ln(1 + B / (arrival rate x dt)) | 0 | 10 |
    | 24 | oldest waiting bit's age | / deadline in slots | 0 | 1 |
    | 25 | the slot's measured large-scale echo SNR per element and subcarrier | dB / 10 | -10 | 10 |
    | 26 + 5(k-1) | map's LoS probability k stride slots ahead, k = 1 .. 10 | - | 0 | 1 |
    | 27 + 5(k-1), 28 + 5(k-1) | map's large-scale SNR of the command link there, in LoS, in NLoS | dB / 10 | -10 | 10 |
    | 29 + 5(k-1), 30 + 5(k-1) | map's large-scale echo SNR there, in LoS, in NLoS | dB / 10 | -10 | 10 |

    **The field task** (``iscc_gym/ISCC-Field-v0``, preset ``"field"``; ``docs/model.md`` Sec. 8) plays the paper's
    loop in a world its model does not know (the links' K-factor a field along the path, the drone's RCS drawn per
    mission) and has ``Box(-10, 10, (25,), float32)``: the 23 above, then what the GBS measured in the last slot:

    | Num | Observation | Unit / scaling | Min | Max |
    |-----|-------------|----------------|-----|-----|
    | 23 | last slot's fading gain of the command link (measured over predicted SNR) | dB / 10 | -10 | 10 |
    | 24 | last slot's measured echo SNR per element and subcarrier (fading, RCS) | dB / 10 | -10 | 10 |

    (0 at reset). ``show_world=True`` (the ``aware`` bound's, never a policy's information) adds the slot's hidden
    K-factor and the RCS's offset from ``rcs_m2``, both dB / 10.

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

    With a data queue (the urban task), the data term is :math:`w_\mathrm{rate} X_n / (\lambda\Delta t)`,
    the bits dropped at their deadline in the slot over a slot's mean arrivals, and ``cost_rate`` is 1 in a
    slot that drops bits; ``info`` reports ``bits_arrived``, ``bits_served``, ``bits_dropped`` and
    ``backlog_bits`` (0 without a queue).

    ## Starting State

    ``reset`` draws a new reference trajectory (Poisson waypoints, cubic spline) and the drone's
    initial state near its start (``initial_pos_std_m``, ``initial_vel_std_mps``), all from the
    env's generator, and then the episode's noise key: every slot's fading, measurement, drop,
    process and shadowing normals are :func:`iscc_gym.sim.noise.slot_normals` (key, slot), so an
    episode is fixed by the generator's state at reset.

    The reset ``info`` carries every key of a step's ``info``: ``tracking_error_m`` the initial
    error, costs 0, ``packet_received`` True, ``alpha`` equal thirds, ``slot`` 0, ``action`` NaN, and
    the slot outcomes (``snr_db``, ``snr_large_scale_db``, ``peb_m``, ``veb_mps``, ``eps_ctrl``,
    ``rate_comm_bps``, ``rate_ctrl_bps``, ``estimation_error_m``, ``echo_snr_db``) NaN: no slot has run yet
    (:func:`reset_info_arrays`). ``echo_snr_db`` is the slot's echo SNR per element and subcarrier (fading and RCS
    included), the radar's measurement of its echo.

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
    ``scenario`` is a preset name (``"paper"``, ``"literal"``, ``"urban"``: ``iscc_gym/ISCC-Urban-v0``) or a
    :class:`iscc_gym.Scenario`;
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
    * v0, issue 25 (no change to ``ISCC-v0``'s dynamics, rewards or observations): the queue's four info keys
      (0 without a queue); the urban task ``iscc_gym/ISCC-Urban-v0`` (blocked line of sight, a
      channel-knowledge map, a data queue, a preview of the path), 1,200-slot missions.
    * v0, issue 34 (no change to dynamics, rewards or observations): a mission longer than the registered
      TimeLimit of the id made warns with that id's limit (1,200 for the urban task); the vector env's
      ``SameStep`` top-level info is the reset's, as Gymnasium's ``SyncVectorEnv``.

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
        self.scenario = make_scenario(scenario, **overrides)  # the time limit: TimeLimitCheck, when made by id
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode={render_mode!r}; use None or one of "
                             f"{self.metadata['render_modes']}")
        self.render_mode = render_mode
        self.eps_star = scenario_eps_star(self.scenario)
        self.action_space = spaces.Box(-1.0, 1.0, (3,), np.float32)
        self.observation_space = spaces.Box(-OBS_BOUND, OBS_BOUND, (obs_size(self.scenario),), np.float32)
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
        # a batch of one: bit-identical to the same drone in any batch (the vector env)
        self._state = loop.init_mission(s, self.np_random)
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
        n = int(self._state.n[0])
        row = out[0].tolist()
        info = step_info(row, n)
        info["action"] = a.astype(np.float32)
        reward, terminated, truncated = _read_end(row)
        self._ended = terminated == 1.0
        self._last_received, self._last_peb = info["packet_received"], info["peb_m"]
        if self._renderer is not None:
            self._renderer.record(self._state.x[0], info["tracking_error_m"], info["peb_m"], tuple(info["alpha"]),
                                  info["cost_rate"], info["cost_stability"])
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
