"""Run directories of ``python -m train``: what a run writes (model units with their manifest,
evaluations, learning curve), how an interrupted or finished run is recognised and resumed.
"""

from __future__ import annotations

import csv
import io
import os
import re
import shutil
from pathlib import Path

import numpy as np
import yaml
from iscc_gym.agents.sb3_policy import LAGRANGE_FILE, MANIFEST, read_manifest, write_manifest

from iscc_gym.files import atomic_target, write_atomic

from .config import Args

RUN_FILES = ("model.zip", "vecnormalize.pkl", MANIFEST, "config.yml", "summary.yml", "learning_curve.csv",
             "learning_curve.png", "checkpoints", "best", "eval", "tb", LAGRANGE_FILE)
#: What a resumed run must share with the run it continues (SAC/TD3: ``n_envs`` too, the replay buffer's shape).
IDENTITY = ("env_id", "algo", "scenario", "env_overrides", "normalize", "eval_episodes", "eval_max_steps")


def run_identity(args: Args, hyperparams: dict | None = None) -> dict:
    """The settings of :data:`IDENTITY` of resolved ``args``, as written into every unit's manifest;
    with ``hyperparams`` (the algorithm's resolved keyword arguments), those too: a resumed model keeps
    the hyperparameters saved in its checkpoint, so a resume that changes them is refused rather than
    silently ignored.
    """
    ident = {k: getattr(args, k) for k in IDENTITY}
    if args.algo in ("sac", "td3"):
        ident["n_envs"] = args.n_envs
    if hyperparams is not None:
        ident["hyperparams"] = hyperparams
    return yaml.safe_load(yaml.safe_dump(ident))


def save_unit(directory: str | os.PathLike, model, vecnormalize=None, *, model_name: str = "model.zip",
              replay_buffer: bool = False, **meta) -> Path:
    """Save ``model`` with its VecNormalize statistics (and replay buffer) as one unit in ``directory``.

    Every file goes to a temporary name and is renamed (:func:`iscc_gym.files.atomic_target`); the
    manifest (:func:`iscc_gym.agents.sb3_policy.write_manifest`, sizes and SHA-256, plus ``meta``)
    is written last, so a unit interrupted anywhere is recognised as incomplete.
    """
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    files = []
    if vecnormalize is not None:
        with atomic_target(d / "vecnormalize.pkl") as tmp:
            vecnormalize.save(str(tmp))
        files.append("vecnormalize.pkl")
    if replay_buffer:
        with atomic_target(d / "replay_buffer.pkl") as tmp:
            model.save_replay_buffer(tmp)
        files.append("replay_buffer.pkl")
    with atomic_target(d / model_name) as tmp:
        model.save(tmp)
    files.append(model_name)
    write_manifest(d, files, **meta)
    return d


def latest_checkpoint(ckpt_dir: str | os.PathLike) -> tuple[Path | None, dict | None, list[str]]:
    """``(directory, manifest, skipped)`` of the newest complete checkpoint ``ckpt_dir/step_<N>``
    (None, None if there is none); ``skipped`` says why each newer one was passed over.
    """
    found = []
    for p in Path(ckpt_dir).glob("step_*"):
        m = re.fullmatch(r"step_(\d+)", p.name)
        if m and p.is_dir():
            found.append((int(m.group(1)), p))
    skipped = []
    for _, p in sorted(found, reverse=True):
        try:
            return p, read_manifest(p), skipped
        except (FileNotFoundError, ValueError) as e:
            skipped.append(str(e))
    return None, None, skipped


def _is_run_dir(out: Path) -> bool:
    """Whether ``out`` holds a run of python -m train (its config.yml or manifest), so ``overwrite`` may delete."""
    for name, key in (("config.yml", "args"), (MANIFEST, "files")):
        try:
            if key in yaml.safe_load((out / name).read_text()):
                return True
        except (OSError, yaml.YAMLError, TypeError):
            continue
    return False


def _flat_identity(ident: dict) -> dict:
    """A run identity with its hyperparameters as top-level entries (compared, and named, one by one)."""
    ident = dict(ident)
    hyperparams = ident.pop("hyperparams", None) or {}
    return {**ident, **hyperparams}


def _prepare_out(args: Args, hyperparams: dict | None = None) -> tuple[Path | None, dict | None]:
    """Check ``args.out`` for the run: new or empty, or ``overwrite`` (its run files deleted), or
    ``resume`` from its newest complete checkpoint with the same :data:`IDENTITY`. Returns the
    checkpoint's directory and manifest (None, None without ``resume``).
    """
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise FileExistsError(f"out {out} is a file; name a directory")
    if args.resume and args.overwrite:
        raise ValueError("--resume and --overwrite: use one (continue the run in OUT, or start afresh)")
    if args.resume:
        ckpt, manifest, skipped = latest_checkpoint(out / "checkpoints")
        for why in skipped:
            print(f"resume: skipped an incomplete checkpoint: {why}")
        if ckpt is None:
            older = " (model_<N>_steps.zip files of an older python -m train carry no manifest: retrain)" if list(
                (out / "checkpoints").glob("model_*_steps.zip")) else ""
            raise FileNotFoundError(f"resume: no complete checkpoint in {out / 'checkpoints'}"
                                    + (f" ({len(skipped)} incomplete)" if skipped else "") + older
                                    + "; train without --resume first (with --checkpoint-freq > 0)")
        was = manifest.get("run") or {}
        # a checkpoint of an older python -m train records no hyperparameters: nothing to compare them with
        now = run_identity(args, hyperparams if "hyperparams" in was else None)
        was, now = _flat_identity(was), _flat_identity(now)
        diff = [f"{k} {was.get(k)!r} -> {now.get(k)!r}" for k in dict.fromkeys([*now, *was])
                if was.get(k) != now.get(k)]
        if diff:
            raise ValueError(f"resume: {out} was trained with other settings ({'; '.join(diff)}); a resumed run "
                             "keeps its checkpoint's settings and hyperparameters: resume with the same ones "
                             "(drop the --set/--env-set that change them), or train into another --out")
        return ckpt, manifest
    if out.exists() and any(out.iterdir()):
        if not args.overwrite:
            raise FileExistsError(f"out {out} is not empty (a previous run?); pass --resume to continue it, "
                                  "--overwrite to start afresh (deletes its run files), or another --out")
        if not _is_run_dir(out):
            raise FileExistsError(f"--overwrite: {out} holds no run of python -m train (no config.yml or "
                                  f"{MANIFEST} of one); nothing deleted: choose another --out")
        for name in RUN_FILES:
            p = out / name
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p)
            elif p.exists() or p.is_symlink():
                p.unlink()
    return None, None


def save_evaluations(path: str | os.PathLike, timesteps, results, ep_lengths) -> None:
    """``evaluations.npz`` as SB3's EvalCallback writes it (``timesteps``, ``results``, ``ep_lengths``), atomically."""
    with atomic_target(path) as tmp, open(tmp, "wb") as f:
        np.savez(f, timesteps=np.asarray(timesteps, dtype=np.int64), results=np.asarray(results, dtype=np.float64),
                 ep_lengths=np.asarray(ep_lengths, dtype=np.int64))


def _read_history(out: Path, upto: int) -> tuple[dict, list[dict], float]:
    """What a resumed run continues: the evaluations and learning-curve rows of ``out`` up to step
    ``upto`` (later ones belong to the continuation that was cut off, replayed now), and the reward
    of the best model kept in ``out/best`` (-inf if there is none, or it is incomplete).
    """
    history = {"timesteps": [], "results": [], "ep_lengths": []}
    npz = out / "eval" / "evaluations.npz"
    if npz.exists():
        with np.load(npz) as d:
            keep = d["timesteps"] <= upto
            history = {k: d[k][keep].tolist() for k in history}
    rows = []
    curve = out / "learning_curve.csv"
    if curve.exists():
        with open(curve, newline="") as f:
            for r in csv.DictReader(f):
                if r["wall_s"] and int(r["timesteps"]) <= upto:
                    rows.append({"timesteps": int(r["timesteps"]), "wall_s": float(r["wall_s"]),
                                 "train_ep_reward_mean": float(r["train_ep_reward_mean"]),
                                 "train_ep_length_mean": float(r["train_ep_length_mean"])})
    best = -np.inf
    try:
        best = float(read_manifest(out / "best")["mean_reward"])
    except (FileNotFoundError, ValueError, KeyError, TypeError):
        pass
    return history, rows, best


def _write_curve(out: Path, rows: list[dict], evals: list[tuple[int, float]]) -> None:
    buf = io.StringIO(newline="")
    w = csv.writer(buf)
    w.writerow(["timesteps", "wall_s", "train_ep_reward_mean", "train_ep_length_mean", "eval_reward_mean"])
    ev = dict(evals)
    for r in rows:
        w.writerow([r["timesteps"], f"{r['wall_s']:.3f}", r["train_ep_reward_mean"], r["train_ep_length_mean"],
                    ev.get(r["timesteps"], "")])
    for t, v in evals:
        if t not in {r["timesteps"] for r in rows}:
            w.writerow([t, "", "", "", v])
    write_atomic(out / "learning_curve.csv", buf.getvalue())
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6, 3.5), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    if rows:
        ax.plot([r["timesteps"] for r in rows], [r["train_ep_reward_mean"] for r in rows], label="train episodes")
    if evals:
        ax.plot(*zip(*evals, strict=True), "o-", label="held-out eval")
    ax.set_xlabel("env steps")
    ax.set_ylabel("episode reward")
    ax.legend()
    fig.tight_layout()
    with atomic_target(out / "learning_curve.png") as tmp:
        fig.savefig(tmp, format="png")
