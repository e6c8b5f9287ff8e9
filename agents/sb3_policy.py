"""A trained SB3 agent behind the policy protocol: the model plus its VecNormalize statistics.

Model files (``.zip``) and ``vecnormalize.pkl`` are pickles: loading one executes code it holds. Load
only files you trust; :meth:`SB3Policy.load` opens only the files the path names (and, for a run
directory, the ones its manifest lists).

A *unit* is a directory holding a model with the statistics it was trained with (``python -m train``
writes one for the final model, for ``best/`` and for every checkpoint): each file is written under a
temporary name and renamed, and ``manifest.yml`` is written last with each file's size and SHA-256,
so a unit whose manifest is missing or does not match its files was interrupted while being written
(:func:`read_manifest` says so; :meth:`SB3Policy.load` refuses it).
"""

from __future__ import annotations

import hashlib
import pickle
import warnings
import zipfile
from pathlib import Path

import numpy as np
import yaml

from iscc_gym import ENV_ID

__all__ = ["SB3Policy", "residual_policy", "MANIFEST", "LAGRANGE_FILE", "write_manifest", "read_manifest", "ALGOS",
           "algo_class"]

MANIFEST = "manifest.yml"
#: The Lagrange multipliers of a constrained run (``python -m train --algo ppo-lag``), beside its model.
LAGRANGE_FILE = "lagrange.yml"
#: The algorithms a run may use: SB3's PPO, SAC and TD3, and sb3-contrib's RecurrentPPO under rl-zoo3's name for it.
ALGOS = ("ppo", "sac", "td3", "ppo_lstm")


def algo_class(algo: str):
    """The SB3 class of ``algo`` (one of :data:`ALGOS`); ``ppo_lstm`` needs sb3-contrib (the ``train`` extra).

    Raises
    ------
    ValueError
        An unknown algorithm, or ``ppo_lstm`` without sb3-contrib installed.
    """
    if algo == "ppo_lstm":
        try:
            from sb3_contrib import RecurrentPPO
        except ImportError:
            raise ValueError("algo = 'ppo_lstm' is sb3-contrib's RecurrentPPO: pip install sb3-contrib (in the "
                             "project's train extra)") from None
        return RecurrentPPO
    from stable_baselines3 import PPO, SAC, TD3

    classes = {"ppo": PPO, "sac": SAC, "td3": TD3}
    if algo not in classes:
        raise ValueError(f"algo = {algo!r}; use one of {ALGOS}")
    return classes[algo]


def _digest(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


#: The fix of a manifest whose file list is damaged (its digests cannot be rebuilt from the files they check).
_RESTORE = "restore it from a copy of the run, or retrain"


def write_manifest(directory: str | Path, files: list[str], **meta) -> Path:
    """Write ``directory/manifest.yml`` (atomically) listing ``files`` (names in ``directory``) with
    their sizes and SHA-256, and ``meta``; call it after every listed file is written.
    """
    from iscc_gym.files import write_atomic

    d = Path(directory)
    listed = {name: {"bytes": (d / name).stat().st_size, "sha256": _digest(d / name)} for name in files}
    return write_atomic(d / MANIFEST, yaml.safe_dump({**meta, "files": listed}, sort_keys=False))


def read_manifest(directory: str | Path) -> dict:
    """The manifest of a unit whose files are all there, whole.

    Raises
    ------
    FileNotFoundError
        No manifest (the unit was never completed, or predates manifests).
    ValueError
        A listed file missing, of another size or content (an interrupted or partial write).
    """
    d = Path(directory)
    path = d / MANIFEST
    if not path.exists():
        raise FileNotFoundError(f"{d}: no {MANIFEST} (incomplete: interrupted while being written)")
    try:
        manifest = yaml.safe_load(path.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as e:
        raise ValueError(f"{path}: not valid YAML ({str(e).splitlines()[0]}): a damaged manifest; {_RESTORE}") from None
    files = manifest.get("files") if isinstance(manifest, dict) else None
    if not isinstance(files, dict) or not files or not all(
            isinstance(v, dict) and isinstance(v.get("bytes"), int) and isinstance(v.get("sha256"), str)
            for v in files.values()):
        raise ValueError(f"{path}: files = {files!r}; not a manifest written by python -m train (empty or "
                         f"damaged: it must list each file of the unit with its bytes and sha256); {_RESTORE}")
    for name, want in files.items():
        p = d / name
        if not p.exists():
            raise ValueError(f"{d}: {name} is missing (an interrupted write); its {MANIFEST} lists it")
        if p.stat().st_size != want["bytes"] or _digest(p) != want["sha256"]:
            raise ValueError(f"{d}: {name} is not the file its {MANIFEST} lists (truncated, or overwritten by an "
                             "interrupted write)")
    return manifest


def _load_model(algo: str, path: Path):
    cls = algo_class(algo)
    try:
        return cls.load(str(path), device="cpu")
    except (zipfile.BadZipFile, EOFError, pickle.UnpicklingError) as e:
        raise ValueError(f"{path}: not a complete SB3 model file (truncated or corrupt: {e})") from None
    except ValueError as e:  # SB3's "wasn't a zip-file" around a BadZipFile
        if isinstance(e.__cause__, zipfile.BadZipFile | EOFError):
            raise ValueError(f"{path}: not a complete SB3 model file (truncated or corrupt: "
                             f"{e.__cause__})") from None
        raise
    except KeyError as e:
        raise ValueError(f"{path}: not an SB3 model file (no {e} in the archive)") from None


class _ZooLoader(yaml.SafeLoader):
    """A safe YAML loader that also reads rl-zoo3's ``config.yml`` (``OrderedDict([[key, value], ...])``)."""


_ZooLoader.add_constructor("tag:yaml.org,2002:python/object/apply:collections.OrderedDict",
                           lambda loader, node: dict(loader.construct_sequence(node, deep=True)[0]))


def find_vecnormalize(model_path: str | Path) -> tuple[Path | None, object]:
    """Where the VecNormalize statistics of a model ``.zip`` outside a ``python -m train`` unit are, and what its
    run's config says of normalisation (``None`` if no config is found).

    Looked for, in order: ``vecnormalize.pkl`` beside the model (SB3's and our own convention), then in a
    sub-folder of the model's folder holding rl-zoo3's run files (``<run>/<env id with / as ->/vecnormalize.pkl``
    beside ``config.yml``; rl-zoo3 names the model ``<env>.zip`` or ``best_model.zip`` in ``<run>/``).

    Raises
    ------
    ValueError
        Two or more candidate statistics files for one model (which one is meant is unknowable).
    """
    model_path = Path(model_path)
    beside = model_path.parent / "vecnormalize.pkl"
    zoo = [d for d in sorted(model_path.parent.iterdir()) if d.is_dir()
           and ((d / "vecnormalize.pkl").exists() or (d / "config.yml").exists())]
    if len(zoo) > 1:  # the folder named after the model (rl-zoo3's <env>.zip beside <env>/), if one is
        named = [d for d in zoo if d.name == model_path.stem]
        if not named and not beside.exists():
            raise ValueError(f"{model_path}: several rl-zoo3 run folders beside it ({', '.join(d.name for d in zoo)}) "
                             "hold statistics; pass the model of a folder that holds one run")
        zoo = named
    normalize = None
    if zoo and (zoo[0] / "config.yml").exists():
        cfg = zoo[0] / "config.yml"
        try:
            normalize = (yaml.load(cfg.read_text(), Loader=_ZooLoader) or {}).get("normalize")
        except (yaml.YAMLError, AttributeError, TypeError, ValueError) as e:
            raise ValueError(f"{cfg}: not an rl-zoo3 config.yml ({e})") from None
    if beside.exists():
        return beside, normalize
    if zoo and (zoo[0] / "vecnormalize.pkl").exists():
        return zoo[0] / "vecnormalize.pkl", normalize
    return None, normalize


def read_vecnormalize(path: Path):
    """SB3's VecNormalize statistics pickled at ``path``; a ``ValueError`` naming the file for one that is
    truncated, corrupt or holds something else.
    """
    from stable_baselines3.common.vec_env import VecNormalize

    try:
        with open(path, "rb") as f:
            obj = pickle.load(f)
    except (EOFError, pickle.UnpicklingError, AttributeError, ModuleNotFoundError, ImportError, IndexError,
            TypeError, ValueError) as e:
        raise ValueError(f"{path}: not a complete VecNormalize file (truncated or corrupt: {e})") from None
    if not isinstance(obj, VecNormalize):
        raise ValueError(f"{path}: holds a {type(obj).__module__}.{type(obj).__name__}, not SB3's VecNormalize "
                         "statistics; a vecnormalize.pkl is written by VecNormalize.save (python -m train writes it)")
    return obj


class SB3Policy:
    """``predict`` of a saved SB3 model on raw env observations (normalised with the training
    run's VecNormalize statistics, if any), so it plugs into the evaluator like a scripted policy.

    Parameters
    ----------
    model : stable_baselines3 BaseAlgorithm
    vecnormalize : stable_baselines3 VecNormalize, optional
        Only its observation statistics are used (``normalize_obs``), never updated.

    Raises
    ------
    ValueError
        The statistics are of another observation size than the model.
    """

    def __init__(self, model, vecnormalize=None):
        self.model = model
        self.vecnormalize = vecnormalize
        self.obs_shape = tuple(model.observation_space.shape)
        # an asymmetric actor-critic's critic was shown the world (agents.world_critic): the deployed agent reads the
        # observation without it, padded with zeros its actor hides
        self.world_entries = int(getattr(model.policy, "world_entries", 0))
        if vecnormalize is not None:
            vecnormalize.training = False
            stats = tuple(np.shape(vecnormalize.obs_rms.mean))
            if stats != self.obs_shape:
                raise ValueError(f"the VecNormalize statistics are of observations of shape {stats}, the model's of "
                                 f"{self.obs_shape}: they come from different runs")
        if self.world_entries:
            self.obs_shape = (self.obs_shape[0] - self.world_entries,)

    @classmethod
    def load(cls, path: str | Path, best: bool = False, check_env: str | None = ENV_ID) -> SB3Policy:
        """Load a run directory written by ``python -m train`` (``model.zip``, or
        ``best/best_model.zip`` with ``best=True``, each with the VecNormalize statistics of its own
        unit), a checkpoint directory, or a model ``.zip`` (with a ``vecnormalize.pkl`` beside it, if
        there is one). Files are pickles: load only files you trust.

        ``check_env``: the env id whose observation size the model must have (None: no check).

        A residual agent's model holds its residual record (:mod:`agents.residual`): it loads as the
        :class:`~agents.residual.ResidualPolicy` it was trained as, its base built from the record, however it is
        loaded; the run's manifest (or config) must agree with the record.

        Raises
        ------
        FileNotFoundError
            No model at the path.
        ValueError
            A truncated or corrupt file, a unit whose files do not match its manifest, a damaged setting of
            the run's manifest or config (naming the file, the field and the fix), a model of another
            observation size.
        """
        p = Path(path)
        if p.is_dir():
            unit = p / "best" if best else p
            model_path = unit / ("best_model.zip" if best else "model.zip")
        else:
            unit, model_path = p.parent, p
        if not model_path.exists():
            raise FileNotFoundError(f"no SB3 model at {model_path}; train one with `python -m train --out DIR`")
        manifest, where, prefix = None, None, "run."
        run = {}
        if (unit / MANIFEST).exists():
            manifest = read_manifest(unit)
            where = unit / MANIFEST
            if model_path.name not in manifest["files"]:
                raise ValueError(f"{model_path}: not listed in {where}; load the unit's own model")
            run = manifest.get("run")
            if run is not None and not isinstance(run, dict):
                raise ValueError(f"{where}: run = {run!r}; expected the mapping of the run's settings python -m "
                                 f"train writes (a damaged manifest; {_RESTORE})")
            run = dict(run or {})
        if not run:
            for cfg in (unit / "config.yml", unit.parent / "config.yml"):
                if cfg.exists():
                    try:
                        args = yaml.safe_load(cfg.read_text())["args"]
                        run = {"algo": args["algo"], "normalize": args.get("normalize")}
                        residual = args.get("residual")
                        run["residual"] = None if residual in (None, "none") else residual
                        if run["residual"] is not None:  # a residual run: its base and reach
                            run.update({k: args.get(k) for k in ("residual_scale", "scenario", "env_overrides")})
                            if args.get("residual_space") not in (None, "action"):
                                run["residual_space"] = args["residual_space"]
                    except (yaml.YAMLError, KeyError, TypeError):
                        raise ValueError(f"{cfg}: not a config.yml written by python -m train") from None
                    where, prefix = cfg, "args."
                    break
        fix = "" if where is None else (
            f"a damaged {where.name}: set it back to what the run was trained with"
            + (" (the same field under args in the run's config.yml)" if where.name == MANIFEST else "")
            + ", or retrain")
        from iscc_gym.agents.residual import RECORD_ENTRY, RECORD_FIX, read_record

        record = read_record(model_path)
        if record is not None:  # the agent's own record of its base: what the run's files say must agree
            for key, value in record.items():
                if where is not None and key in run and run[key] != value:
                    raise ValueError(f"{where}: {prefix}{key} = {run[key]!r}, but {model_path.name} is a residual "
                                     f"agent recorded with {key} = {value!r}: a damaged {where.name}; set it back "
                                     f"to {value!r}")
            run.update(record)
        algo = run.get("algo") or "ppo"
        if algo not in ALGOS:
            raise ValueError(f"{where or unit}: {prefix}algo = {algo!r}; expected one of {', '.join(ALGOS)} ({fix})")
        if run.get("normalize") is not None and not isinstance(run["normalize"], bool):
            raise ValueError(f"{where}: {prefix}normalize = {run['normalize']!r}; expected true or false ({fix})")
        vn_path = unit / "vecnormalize.pkl"
        if manifest is not None:
            has_vn = "vecnormalize.pkl" in manifest["files"]
        else:  # an older run, an rl-zoo3 run or a bare SB3 model: a stale file of a run without normalisation is left
            vn_path, zoo_normalize = find_vecnormalize(model_path)
            if not run and zoo_normalize is not None:
                run = {"normalize": zoo_normalize}
            has_vn = vn_path is not None and run.get("normalize") is not False
            if run.get("normalize") and not has_vn:
                raise ValueError(f"{model_path}: its run was trained with VecNormalize (normalize: "
                                 f"{run['normalize']!r} in its config) but no vecnormalize.pkl was found beside the "
                                 f"model or in {unit}/<env>/ (rl-zoo3's place): copy the run's statistics there")
            if vn_path is None and run.get("normalize") is None:
                warnings.warn(f"{model_path}: no vecnormalize.pkl beside it or in {unit}/<env>/ (rl-zoo3's place) and "
                              "no config saying how it was trained: loaded without observation normalisation; if it "
                              "was trained with VecNormalize its actions are wrong", UserWarning, stacklevel=2)
        if run.get("normalize") and not has_vn:
            raise ValueError(f"{unit}: the run was trained with VecNormalize but {unit} holds no statistics for "
                             f"{model_path.name} (older python -m train runs kept none in best/): load the run's "
                             "final model.zip instead")
        try:
            model = _load_model(algo, model_path)
        except AttributeError as e:  # another algorithm's policy (SB3 looks up the attribute its own one has)
            if where is None:
                raise ValueError(f"{model_path}: does not load as a {algo} model ({e}); a model .zip without its "
                                 "run's manifest.yml or config.yml loads as PPO: load its run directory") from None
            raise ValueError(f"{where}: {prefix}algo = {algo!r} is not the algorithm {model_path.name} was trained "
                             f"with (it does not load as a {algo} model: {e}) ({fix})") from None
        vecnormalize = read_vecnormalize(vn_path) if has_vn else None
        policy = cls(model, vecnormalize)
        if check_env is not None:
            want = _obs_shape(check_env)
            if want is not None and tuple(want) != policy.obs_shape:
                raise ValueError(f"{model_path}: the model takes observations of shape {policy.obs_shape}, "
                                 f"{check_env} gives {tuple(want)}: it was trained on another env")
        if run.get("residual"):  # the record, where the model holds one: it agrees with the run's files (above)
            if record is not None:
                return residual_policy(policy, run, f"{model_path} (its {RECORD_ENTRY})", RECORD_FIX)
            return residual_policy(policy, run, str(where), fix, prefix)
        return policy

    def predict(self, obs, state=None, episode_start=None, deterministic: bool = True):
        """SB3's ``predict`` on raw observations (23,) or (n, 23)."""
        o = np.asarray(obs, dtype=np.float32)
        if o.shape[-len(self.obs_shape):] != self.obs_shape:
            raise ValueError(f"observation of shape {o.shape}; the model takes {self.obs_shape} or (n, "
                             f"{', '.join(map(str, self.obs_shape))})")
        if self.world_entries:
            o = np.concatenate([o, np.zeros(o.shape[:-1] + (self.world_entries,), np.float32)], axis=-1)
        if self.vecnormalize is not None:
            o = self.vecnormalize.normalize_obs(o).astype(np.float32)
        return self.model.predict(o, state=state, episode_start=episode_start, deterministic=deterministic)


def residual_policy(agent: SB3Policy, run: dict, where: str = "the run", fix: str = "retrain", prefix: str = ""):
    """The :class:`agents.residual.ResidualPolicy` of a residual run's trained ``agent``: its base policy
    (``run["residual"]``, with the recorded ``residual_params``) built for the run's scenario, corrected by
    ``agent`` at ``run["residual_scale"]``. ``where``, ``fix``, ``prefix``: what a bad field's error names
    (:func:`agents.residual.base_policy`).
    """
    from iscc_gym.agents.residual import ResidualPolicy, base_policy

    base = base_policy(run, where, fix, prefix, agent.obs_shape)
    return ResidualPolicy(base, agent, run["residual_scale"], run["residual"], run.get("residual_space", "action"))


def _obs_shape(env_id: str):
    """The observation shape of ``env_id`` (a single-drone task's, read from its task file's preset without building
    an env: issue 44, the field agent's env had none), or None for another env (the multi-drone task's, whose shape
    is K drones', or an env id of no task).
    """
    from iscc_gym.tasks import TASKS

    task = TASKS.get(env_id)
    if task is None or task.fleet:
        return None
    from iscc_gym.scenario import make_scenario
    from iscc_gym.sim.schema import obs_size

    return (obs_size(make_scenario(task.preset)),)
