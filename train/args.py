"""The settings of a training run, each written once: :class:`Args`, one field per ``python -m train`` flag, its
name, type, default and ``--help`` text in the field (:func:`flag`, :func:`run_setting`); :data:`FIELD_HELP`,
:data:`RUN_KEYS`, :data:`RUN_DEFAULTS` and :data:`RUN_TYPES` are read from them. Beside them, what a run's
settings say about it (a warm start, a residual base, randomised missions; the settings a study exports).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from iscc_gym import ENV_ID
from iscc_gym.tasks import TASKS, registered_scenario

__all__ = ["Args", "flag", "run_setting", "FIELD_HELP", "RUN_KEYS", "RUN_DEFAULTS", "RUN_TYPES", "HYPERPARAMS",
           "PPO_LAG_LIMITS", "randomize_sets", "expand_algo", "has_warm_start", "has_residual", "randomized",
           "randomized_overrides", "run_settings", "run_flags", "flag_type"]

HYPERPARAMS = Path(__file__).with_name("hyperparams.yml")
#: ``--algo ppo-lag``: PPO with the Lagrangian of train/lagrangian.py, at these limits unless
#: ``--cost-limit`` gives others.
PPO_LAG_LIMITS = "rate=0.05,stability=0.0"


def flag(default, help: str, kind: type | None = None):  # noqa: A002 (argparse's name)
    """A field of :class:`Args`: its default, its ``--help`` (the default is appended by the parser) and, for a
    field whose default is None, the type of its value (``kind``).
    """
    meta = {"help": help, "kind": kind or type(default)}
    return field(default_factory=dict, metadata=meta) if isinstance(default, dict) else field(default=default,
                                                                                               metadata=meta)


def run_setting(help: str, yaml: str, fallback, kind: type, fallback_text: str | None = None):  # noqa: A002
    """A run setting: None as a flag's default, filled from the YAML entry's key ``yaml`` (rl-zoo3's name where
    it has one), else ``fallback``; ``{default}`` in ``help`` says so (``fallback_text``: how the help names it).
    """
    shown = fallback_text if fallback_text is not None else (
        "on" if fallback is True else "off" if fallback is False else f"{fallback:,}" if isinstance(fallback, int)
        else fallback)
    where = "YAML entry's " + yaml if yaml in ("n_timesteps", "n_envs", "normalize") else "YAML's"
    default = f"default: the {where}" + ("" if shown is None else f", else {shown}")
    return field(default=None, metadata={"help": help.format(default=default), "kind": kind, "yaml": yaml,
                                         "fallback": fallback})


def _scenario_help() -> str:
    return ("Scenario preset of the env (default: the env id's own: "
            + ", ".join(f"{t.preset} for {e}" for e, t in TASKS.items()) + ")")


@dataclass
class Args:
    """Everything a training run depends on, one field per ``python -m train`` flag (``--help`` lists them)."""

    env_id: str = flag(ENV_ID, "Gymnasium env id to train on (an entry of --hyperparams, or of the task's "
                               "train_like)")
    algo: str = flag("ppo", "SB3 algorithm: ppo | sac | td3 | ppo_lstm (sb3-contrib's RecurrentPPO) | ppo-lag (PPO "
                            f"with --cost-limit, by default {PPO_LAG_LIMITS})")
    total_timesteps: int | None = run_setting(
        "env steps to train ({default}); PPO trains whole rollouts (n_envs x n_steps), so it rounds up to the next "
        "one, and says so", "n_timesteps", 200_000, int)
    n_envs: int | None = run_setting("parallel envs ({default})", "n_envs", 4, int)
    vec_env: str = flag("batched", "dummy | subproc | batched (the ISCC env's own batched env, fastest)")
    seed: int = flag(0, "training seed (envs, networks, sampling)")
    # None: the preset the env id is registered with (urban for ISCC-Urban-v0)
    scenario: str | None = flag(None, "Scenario preset of the env (default: the preset the env id is registered "
                                      "with, e.g. urban for iscc_gym/ISCC-Urban-v0)", str)
    # Scenario field overrides, e.g. {"observation_source": "gnss"} (--env-set)
    env_overrides: dict = flag({}, "Scenario fields of the env (--env-set FIELD=VALUE)")
    out: str = flag("runs/ppo", "run directory; must be empty or new unless --resume or --overwrite")
    hyperparams: str = flag(str(HYPERPARAMS), "hyperparameter YAML in rl-zoo3's layout (env id -> "
                                              "hyperparameters; see train/hyperparams.yml)")
    overrides: dict = flag({}, "hyperparameters of the YAML entry overridden (--set KEY=VALUE)")
    normalize: bool | None = run_setting("VecNormalize observations and rewards ({default})", "normalize", True,
                                         bool)
    # VecNormalize's reward scaling with normalize on; off where a rare huge penalty (a lost drone) inflates the
    # return statistics until every slot's reward vanishes
    norm_reward: bool | None = run_setting(
        "with --normalize, scale the rewards too (VecNormalize's norm_reward; {default}); --no-norm-reward where "
        "rare huge penalties (a lost drone) swamp the return statistics", "norm_reward", True, bool)
    # warm start by behaviour cloning of a scripted policy (agents.make_policy spec; train/pretrain.py)
    init_policy: str | None = run_setting(
        "warm start: behaviour-clone this scripted policy (agents.make_policy spec, e.g. myopic; none: no warm "
        "start; {default})", "init_policy", None, str)
    init_envs: int | None = run_setting("envs the scripted policy plays during the warm start ({default})",
                                        "init_envs", 16, int)
    init_steps: int | None = run_setting("steps per env of the warm start ({default})", "init_steps", 5000, int)
    init_log_std: float | None = run_setting(
        "log standard deviation of the actions after the warm start ({default})", "init_log_std", None, float,
        "kept")
    # residual learning (agents/residual.py): the agent corrects a scripted policy's action
    residual: str | None = run_setting(
        "residual learning: the agent corrects this scripted policy's action (agents.make_policy spec, e.g. "
        "myopic; none: no residual; {default})", "residual", None, str)
    residual_scale: float | None = run_setting(
        "reach of the residual agent's correction in action units, in (0, 2] ({default})", "residual_scale", 0.5,
        float)
    residual_space: str | None = run_setting(
        "where the residual agent's correction acts: action (added to the base's action) or split (the base's "
        "shares' logits, no action bound clips it) ({default})", "residual_space", "action", str)
    # training over randomised missions (iscc_gym.tasks: a task's shifts)
    randomize: str | None = run_setting(
        "train over randomised missions: <preset>-shifts, e.g. urban-shifts (the task's preset and each of its "
        "shifted statistics, its shifts in iscc_gym.tasks, on equal shares of the envs: n_envs >= 5), or "
        "field-worlds (the field preset and 16 worlds drawn from iscc_gym.tasks.field.FIELD_WORLD_RANGES: n_envs >= "
        "17); none: the env's own ({default})", "randomize", None, str)
    # issue 45: what only the simulator knows, at training time only (train/privileged.py)
    reward: str | None = run_setting(
        "the reward the learner is paid: sampled (the env's) or expected (the field task's expected one-slot reward "
        "over the slot's fading at its true K, the simulator's knowledge: unbiased, a tenth of the variance; "
        "evaluation always plays the sampled one; the batched env only; {default})", "reward", "sampled", str)
    critic: str | None = run_setting(
        "what the critic reads: own (the agent's observation) or world (PPO on the field task: the critic is also "
        "shown the slot's true K-factor and RCS, the actor never; asymmetric actor-critic, agents/world_critic.py; "
        "the batched env only; {default})", "critic", "own", str)
    eval_freq: int = flag(500_000, "env steps between held-out evaluations (0: none); the best model goes to OUT/best/")
    eval_episodes: int = flag(8, "held-out missions per evaluation (seeds from 1,000,000)")
    eval_max_steps: int = flag(5000, "slots per held-out episode at most (the full mission by default)")
    checkpoint_freq: int = flag(1_000_000, "env steps between checkpoints in OUT/checkpoints/ (0: none)")
    resume: bool = flag(False, "continue the run in OUT from its newest complete checkpoint (same algo, env, "
                               "scenario, normalisation)")
    overwrite: bool = flag(False, "start afresh in a non-empty OUT: its previous run's files are deleted first")
    tensorboard: bool = flag(True, "write TensorBoard logs to OUT/tb (tensorboard --logdir OUT/tb)")
    progress_bar: bool | None = flag(None, "show a progress bar (default: on a terminal unless --quiet)", bool)
    quiet: bool = flag(False, "no progress lines on stderr, no progress bar and no closing line")
    torch_threads: int = flag(1, "torch threads (1 is fastest here: python -m eval.bench)")
    numba_threads: int | None = flag(None, "threads of the env's compiled kernel (default: all cores)", int)
    verbose: int = flag(0, "SB3 verbosity: 0 quiet, 1 training logs, 2 debug")
    # constrained training (train/lagrangian.py): outage-fraction limits
    cost_limit: str | None = flag(None, "constrained training (Lagrangian, train/lagrangian.py): the fraction of "
                                        "slots allowed to violate each constraint, e.g. rate=0.05,stability=0.0 "
                                        "(default: none, the fixed-weight reward)", str)
    lagrange_lr: float = flag(0.05, "step of the Lagrange multipliers' dual ascent, once per rollout")


_FIELDS = dataclasses.fields(Args)
#: The ``--help`` text of every :class:`Args` field.
FIELD_HELP = {f.name: f.metadata["help"] for f in _FIELDS}
#: Run settings a YAML entry may hold beside the algorithm's hyperparameters (rl-zoo3's names), mapped
#: to the :class:`Args` field they fill. ``init_*`` are python -m train's own: in a file rl-zoo3 reads too, they go
#: under ``iscc_gym.train.settings``.
RUN_KEYS = {f.metadata["yaml"]: f.name for f in _FIELDS if "yaml" in f.metadata}
#: The value of each run setting when neither the flag nor the YAML sets it.
RUN_DEFAULTS = {f.name: f.metadata["fallback"] for f in _FIELDS if "yaml" in f.metadata}


def flag_type(name: str) -> type:
    """The type of the value of :class:`Args` field ``name``."""
    return next(f.metadata["kind"] for f in _FIELDS if f.name == name)


def _to_int(v):
    f = float(v)
    if not f.is_integer():
        raise ValueError
    return int(f)


def _to_bool(v):
    if not isinstance(v, bool):
        raise ValueError
    return v


#: How a run setting's YAML value is read (an integer written 4.0e+6 too; a boolean only as one).
RUN_TYPES = {name: {int: _to_int, bool: _to_bool}.get(flag_type(name), flag_type(name)) for name in RUN_DEFAULTS}


#: Worlds a ``--randomize field-worlds`` run trains over beside the field preset's own (issue 45, point 3).
FIELD_RANDOM_WORLDS = 16


def randomize_sets() -> dict[str, tuple[str, dict[str, dict]]]:
    """``--randomize NAME`` -> ``(env id, {shift: overrides})``: the shifted statistics a randomised run trains over
    beside the env's own (``<preset>-shifts``: the shifts of the task of that preset), read from the task table
    when asked, so a task registered at run time counts too; and ``field-worlds``: :data:`FIELD_RANDOM_WORLDS` laws of
    the field task's world drawn from :data:`iscc_gym.tasks.field.FIELD_WORLD_RANGES`
    (:func:`iscc_gym.tasks.field.draw_worlds`, seed 0: the randomised learned estimator's draw), ranges that cover its
    test worlds but none of them as such.
    """
    from iscc_gym.tasks.field import FIELD_ENV_ID, draw_worlds

    sets = {f"{t.preset}-shifts": (e, t.shift_overrides()) for e, t in TASKS.items() if t.shifts}
    sets["field-worlds"] = (FIELD_ENV_ID, {f"world {k}": w
                                           for k, w in enumerate(draw_worlds(FIELD_RANDOM_WORLDS, 0), 1)})
    return sets


def expand_algo(args: Args) -> Args:
    """``algo = "ppo-lag"`` -> PPO with ``cost_limit`` (:data:`PPO_LAG_LIMITS` unless given); any
    other algo unchanged.
    """
    if args.algo == "ppo-lag":
        return dataclasses.replace(args, algo="ppo", cost_limit=args.cost_limit or PPO_LAG_LIMITS)
    return args


def _in_use(setting) -> bool:
    """Whether a run setting naming something (a policy spec, a set of missions) is in use: set, and not ``none``."""
    return bool(setting) and str(setting).lower() != "none"


def has_warm_start(args: Args) -> bool:
    """Whether ``args`` clones a scripted policy before training (``init_policy`` in use)."""
    return _in_use(args.init_policy)


def randomized(args: Args) -> bool:
    """Whether ``args`` trains over randomised missions (``randomize`` in use)."""
    return _in_use(args.randomize)


def randomized_overrides(args: Args) -> list[dict]:
    """The Scenario overrides of each share of the envs of a randomised run: the run's own (``env_overrides``),
    then each of :func:`randomize_sets`'s sets on top of them.
    """
    shifts = randomize_sets()[args.randomize][1]
    return [dict(args.env_overrides)] + [{**args.env_overrides, **o} for o in shifts.values()]


def run_settings(args: Args) -> dict:
    """The run settings of resolved ``args`` that shape what is trained beside the hyperparameters (a warm
    start, a residual base, randomised missions), as a hyperparameter file's ``settings`` entry holds them;
    only those in use.
    """
    out: dict[str, Any] = {}
    if has_warm_start(args):
        out.update(init_policy=args.init_policy, init_envs=args.init_envs, init_steps=args.init_steps)
        if args.init_log_std is not None:
            out["init_log_std"] = float(args.init_log_std)
    if has_residual(args):
        out.update(residual=str(args.residual), residual_scale=float(args.residual_scale))
        if args.residual_space not in (None, "action"):
            out["residual_space"] = str(args.residual_space)
    if randomized(args):
        out["randomize"] = str(args.randomize)
    if args.normalize and args.norm_reward is False:
        out["norm_reward"] = False
    return out


def run_flags(args: Args) -> dict:
    """What a run of resolved ``args`` plays beside its hyperparameters and :func:`run_settings`, as a study's
    export must say it: a scenario preset that is not the env id's own, the env overrides (Scenario fields) and the
    constraints (``cost_limit``, ``lagrange_lr``); only those in use.
    """
    out: dict[str, Any] = {}
    if args.scenario is not None and args.scenario != registered_scenario(args.env_id):
        out["scenario"] = str(args.scenario)
    if args.env_overrides:
        out["env_overrides"] = dict(args.env_overrides)
    if args.cost_limit:
        out.update(cost_limit=str(args.cost_limit), lagrange_lr=float(args.lagrange_lr))
    return out


def has_residual(args: Args) -> bool:
    """Whether ``args`` trains a residual agent (``residual`` in use)."""
    return _in_use(args.residual)
