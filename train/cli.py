"""``python -m train`` / ``iscc-train``: the command line above :func:`iscc_gym.train.train.main`.

Every :class:`~iscc_gym.train.config.Args` field is a flag; ``--set`` / ``--env-set`` override hyperparameters /
Scenario fields; ``--optimize`` and ``--seeds`` run a study or several seeds (:mod:`iscc_gym.train.study`).
"""

from __future__ import annotations

import argparse
import dataclasses
from typing import Any

import yaml
from iscc_gym.commands.cli import invoked_prog, run
from iscc_gym.commands.options import PICKLE_WARNING, Parser
from iscc_gym.train.args import FIELD_HELP, Args, expand_algo, flag_type
from iscc_gym.train.study import add_study_arguments, run_cli

__all__ = ["build_parser", "args_from_namespace", "parse_value", "parse_args", "cli", "console", "PICKLE_WARNING"]


#: Where ``python -m train`` trains (``--device``).
DEVICES = ("cpu", "cuda", "standin")



def build_parser(prog: str = "python -m train") -> argparse.ArgumentParser:
    """The parser of ``python -m train``: every :class:`Args` field is a flag (help: :data:`FIELD_HELP`),
    ``--set`` / ``--env-set`` override hyperparameters / Scenario fields, and :mod:`train.study` adds
    ``--optimize``, ``--seeds``.
    """
    ap = Parser(
        prog=prog, gym_packages=True,
        description="Train an SB3 agent (PPO by default; SAC, TD3) on ``iscc_gym/ISCC-v0``.",
        epilog="Writes into OUT: model.zip and vecnormalize.pkl (the final model and its statistics), best/ "
               "(the best model on the held-out missions, with its own statistics), checkpoints/step_<N>/ "
               "(for --resume), eval/evaluations.npz, learning_curve.csv/.png, config.yml, summary.yml, tb/ "
               "(--device: model.zip, vecnormalize.pkl, config.yml, summary.yml and learning_curve.csv/.png, the "
               "mean reward per step of each rollout). "
               + PICKLE_WARNING + " --resume only runs of your own.")
    defaults = Args()
    for f in dataclasses.fields(Args):
        if f.name in ("overrides", "env_overrides"):  # --set, --env-set below
            continue
        flag = "--" + f.name.replace("_", "-")
        flags = (flag, "--env") if f.name == "env_id" else (flag,)  # --env: python -m eval's name of it
        default, kind = getattr(defaults, f.name), flag_type(f.name)
        help_ = FIELD_HELP[f.name]
        if kind is bool:
            ap.add_argument(*flags, action=argparse.BooleanOptionalAction, default=default, help=help_)
        elif default is None:  # a run setting the YAML fills (RUN_KEYS), or numba's default: said in its help
            ap.add_argument(*flags, type=kind, default=None, help=help_)
        else:
            ap.add_argument(*flags, type=kind, default=default, help=help_ + f" (default: {default})")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="override a hyperparameter of the YAML, e.g. --set n_steps=256 (value read as YAML)")
    ap.add_argument("--env-set", action="append", default=[], metavar="FIELD=VALUE",
                    help="override a Scenario field of the env, e.g. --env-set observation_source=gnss")
    ap.add_argument("--device", choices=DEVICES, default="cpu",
                    help="cpu: SB3 on the CPU (the default, every option); cuda: PPO on the device env on a GPU "
                         "(iscc_gym.train.device_ppo, the gpu extra; saves an SB3 model python -m eval loads); "
                         "standin: that trainer on the device env's CPU stand-in (no GPU needed)")
    ap.add_argument("--learner", choices=("ppo", "estimator", "dagger"), default="ppo",
                    help="what to train: ppo (an SB3 agent, --algo; the default), estimator (the field task's world "
                         "learned from the simulator, RMA-style: a GRU over the measurements regressed on the true "
                         "K-factor and RCS; bayes's design plays on it as --policies estimator:OUT; "
                         "train/estimator.py), dagger (a student of aware under DAgger; train/dagger.py). "
                         "--total-timesteps counts slots played, --n-envs the missions at once, --set the "
                         "learner's settings")
    add_study_arguments(ap)
    return ap


def args_from_namespace(ap: argparse.ArgumentParser, ns: argparse.Namespace) -> Args:
    """The :class:`Args` of flags parsed by :func:`build_parser` (``--set`` values parsed as YAML)."""

    def pairs(items, flag):
        out: dict[str, Any] = {}
        for item in items:
            if "=" not in item or not item.split("=", 1)[0]:
                ap.error(f"{flag} {item!r}: use KEY=VALUE")
            k, v = item.split("=", 1)
            try:
                out[k] = parse_value(v)
            except yaml.YAMLError:
                ap.error(f"{flag} {item!r}: the value is not valid YAML")
        return out

    kw = {f.name: getattr(ns, f.name) for f in dataclasses.fields(Args) if f.name not in ("overrides", "env_overrides")}
    return expand_algo(Args(overrides=pairs(ns.set, "--set"), env_overrides=pairs(ns.env_set, "--env-set"), **kw))


def parse_value(text: str):
    """A ``--set`` / ``--env-set`` value: YAML, with numbers YAML 1.1 leaves as strings (``5e-5``,
    ``1e6``) read as numbers.
    """
    value = yaml.safe_load(text)
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            pass
    return value


def parse_args(argv: list[str] | None = None) -> Args:
    """``Args`` from the command line (every field is a flag; ``--set key=value`` overrides a
    hyperparameter, the value parsed as YAML).
    """
    ap = build_parser()
    return args_from_namespace(ap, ap.parse_args(argv))


def cli(argv: list[str] | None = None, prog: str = "python -m train") -> dict:
    """``python -m train``: train once, or run a study (``--optimize``) or several seeds (``--seeds``);
    returns the summary (for Python callers; the console commands end through :func:`console`).
    """
    ap = build_parser(prog)
    ns = ap.parse_args(argv)
    args = args_from_namespace(ap, ns)
    if ns.learner != "ppo":
        if ns.device != "cpu" or ns.optimize or ns.seeds is not None:
            ap.error(f"--learner {ns.learner} trains one run on the CPU: drop --device, --optimize and --seeds")
        import importlib

        summary = importlib.import_module(f"iscc_gym.train.{ns.learner}").main(args)
    elif ns.device != "cpu":
        if ns.optimize or ns.seeds is not None:
            ap.error(f"--device {ns.device} trains one run: --optimize and --seeds run SB3 on the CPU")
        from iscc_gym.train.device import main as device_main

        summary = device_main(args, ns.device)
    elif ns.optimize or ns.seeds is not None:
        return run_cli(ap, ns, args)
    else:
        from iscc_gym.train.config import check_args

        check_args(args)  # before the training loop loads torch and SB3 (issue 43.12)
        from iscc_gym.train import train as loop

        summary = loop.main(args)
    if not args.quiet:
        print(f"trained {summary['timesteps']} steps in {summary['wall_time_s']:.1f} s -> {summary['out']}")
    return summary


def console(argv: list[str] | None = None, prog: str = "iscc-train") -> int:
    """The ``iscc-train`` / ``python -m train`` entry point: exit code 0 on success, 2 with one line
    for a user's mistake (:func:`iscc_gym.commands.cli.run`); ``python -m train`` is named as invoked
    (:func:`iscc_gym.commands.cli.invoked_prog`: ``python -m iscc_gym.train`` under the installed name).
    """
    prog = invoked_prog(prog)
    return run(lambda a: cli(a, prog=prog), argv, prog)
