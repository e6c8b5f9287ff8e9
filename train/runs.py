"""Run directories of ``python -m train``: what a run writes (model units with their manifest,
evaluations, learning curve), how an interrupted or finished run is recognised and resumed.
"""

from __future__ import annotations

import csv
import io
import math
import os
import re
import shutil
import sys
import zipfile
from pathlib import Path

import numpy as np
import yaml
from iscc_gym.agents.sb3_policy import LAGRANGE_FILE, MANIFEST, read_manifest, read_vecnormalize, write_manifest

from iscc_gym.files import atomic_dir, atomic_target, write_atomic

from .config import Args, has_residual, randomized

RUN_FILES = ("model.zip", "vecnormalize.pkl", MANIFEST, "config.yml", "summary.yml", "learning_curve.csv",
             "learning_curve.png", "checkpoints", "best", "eval", "tb", LAGRANGE_FILE)
#: What a resumed run must share with the run it continues (SAC/TD3: ``n_envs`` too, the replay buffer's
#: shape), besides the constraints (``cost_limit``, ``lagrange_lr``) and the hyperparameters.
IDENTITY = ("env_id", "algo", "scenario", "env_overrides", "normalize", "norm_reward", "eval_episodes",
            "eval_max_steps")
#: A checkpoint's record of everything else a resume needs (a file of its unit, listed in its manifest):
#: the learning curve and wall time, the evaluations and their schedule, the best score, the multipliers.
RESUME_FILE = "resume.yml"


def run_identity(args: Args, hyperparams: dict | None = None, resumed: dict | None = None) -> dict:
    """The settings of :data:`IDENTITY` of resolved ``args``, as written into every unit's manifest, and
    the constraints (``cost_limit`` as a mapping of limits, ``lagrange_lr``; None for an unconstrained
    run); with ``hyperparams`` (the algorithm's resolved keyword arguments), those too: a resumed model
    keeps the hyperparameters saved in its checkpoint, so a resume that changes them is refused rather
    than silently ignored.

    A residual run's ``residual_params`` are its base's tuned parameters, read once here
    (:func:`agents.residual.residual_record`); a run resumed from checkpoint manifest ``resumed`` keeps the
    ones it recorded.
    """
    from .lagrangian import parse_cost_limits

    ident = {k: getattr(args, k) for k in IDENTITY}
    if args.algo in ("sac", "td3"):
        ident["n_envs"] = args.n_envs
    ident["cost_limit"] = parse_cost_limits(args.cost_limit) if args.cost_limit else None
    ident["lagrange_lr"] = float(args.lagrange_lr) if args.cost_limit else None
    # a residual agent's base policy and reach (agents/residual.py; SB3Policy.load plays them); None otherwise
    # the reward trained on and the critic shown the world (a run of the sampled one, the plain critic: no key)
    if getattr(args, "reward", None) not in (None, "sampled"):
        ident["reward"] = str(args.reward)
    if getattr(args, "critic", None) not in (None, "own"):
        ident["critic"] = str(args.critic)
    ident["residual"] = str(args.residual) if has_residual(args) else None
    ident["residual_scale"] = float(args.residual_scale) if has_residual(args) else None
    if has_residual(args) and args.residual_space not in (None, "action"):  # absent: the default (older runs')
        ident["residual_space"] = str(args.residual_space)
    ident["residual_params"] = None
    if has_residual(args):
        from iscc_gym.agents.residual import residual_record

        was = (resumed or {}).get("run") or {}
        ident["residual_params"] = was["residual_params"] if "residual_params" in was else residual_record(
            args.residual, args.residual_scale, args.scenario, args.env_overrides)["residual_params"]
    ident["randomize"] = str(args.randomize) if randomized(args) else None
    if hyperparams is not None:
        ident["hyperparams"] = hyperparams
    return yaml.safe_load(yaml.safe_dump(ident))


def save_unit(directory: str | os.PathLike, model, vecnormalize=None, *, model_name: str = "model.zip",
              replay_buffer: bool = False, texts: dict[str, str] | None = None, **meta) -> Path:
    """Save ``model`` with its VecNormalize statistics (and replay buffer, and ``texts``: file name ->
    content, e.g. a checkpoint's :data:`RESUME_FILE`) as one unit in ``directory``.

    Every file goes to a temporary name and is renamed (:func:`iscc_gym.files.atomic_target`); the
    manifest (:func:`iscc_gym.agents.sb3_policy.write_manifest`, sizes and SHA-256, plus ``meta``)
    is written last, so a unit interrupted anywhere is recognised as incomplete. A residual run's model
    (``meta["run"]``, :func:`run_identity`, names a ``residual``) holds its residual record
    (:func:`agents.residual.write_record`).
    """
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    files = []
    for name, text in (texts or {}).items():
        write_atomic(d / name, text)
        files.append(name)
    if vecnormalize is not None:
        with atomic_target(d / "vecnormalize.pkl") as tmp:
            vecnormalize.save(str(tmp))
        files.append("vecnormalize.pkl")
    if replay_buffer:
        with atomic_target(d / "replay_buffer.pkl") as tmp:
            model.save_replay_buffer(tmp)
        files.append("replay_buffer.pkl")
    run = meta.get("run") or {}
    with atomic_target(d / model_name) as tmp:
        model.save(tmp)
        if run.get("residual"):
            from iscc_gym.agents.residual import write_record

            write_record(tmp, run)
    files.append(model_name)
    write_manifest(d, files, **meta)
    return d


def replace_unit(directory: str | os.PathLike, model, vecnormalize=None, **kw) -> Path:
    """:func:`save_unit` as one step: the unit is written whole into a temporary directory beside
    ``directory`` (manifest last), then swapped in (:func:`iscc_gym.files.atomic_dir`) and the old one
    deleted. A kill or a full disk while writing leaves the previous unit as it was; where the swap takes
    two renames, a kill between them leaves both whole, and :func:`recover_unit` puts one back.
    """
    with atomic_dir(directory) as tmp:
        save_unit(tmp, model, vecnormalize, **kw)
    return Path(directory)


def recover_unit(directory: str | os.PathLike) -> str | None:
    """Clean up after a :func:`replace_unit` that was killed: if ``directory`` is missing or incomplete,
    the newest complete unit left beside it (``.<name>.*.tmp`` / ``.old``) takes its place; the other
    leftovers are deleted. Returns a note of what was restored, or None.
    """
    d = Path(directory)
    leftovers = sorted([*d.parent.glob(f".{d.name}.*.tmp"), *d.parent.glob(f".{d.name}.*.old")])
    leftovers = [p for p in leftovers if p.is_dir() and not p.is_symlink()]
    note = None
    try:
        read_unit(d)
    except (FileNotFoundError, ValueError):
        complete = []
        for p in leftovers:
            try:
                m = read_unit(p)
            except (FileNotFoundError, ValueError):
                continue
            t = m.get("timesteps")
            complete.append((t if isinstance(t, int) else -1, p.name.endswith(".tmp"), p))
        if complete:
            _, _, keep = max(complete)
            if d.is_dir() and not d.is_symlink():
                shutil.rmtree(d)
            os.rename(keep, d)
            note = f"{d}: restored from {keep.name} (a save interrupted while swapping it in)"
    for p in leftovers:
        if p.exists():
            shutil.rmtree(p, ignore_errors=True)
    return note


def read_unit(directory: str | os.PathLike, need: tuple[str, ...] = ()) -> dict:
    """:func:`iscc_gym.agents.sb3_policy.read_manifest` of a unit, after checking the manifest's own
    layout: valid YAML, ``files`` a non-empty mapping of name -> ``{bytes, sha256}``, listing ``need``.

    Raises
    ------
    FileNotFoundError
        No manifest.
    ValueError
        Naming the manifest: damaged, empty, or not listing a file the unit needs; or a listed file
        missing or not matching it.
    """
    d = Path(directory)
    manifest = read_manifest(d)  # the layout first: valid YAML, files of bytes and sha256
    missing = [n for n in need if n not in manifest["files"]]
    if missing:
        raise ValueError(f"{d / MANIFEST}: lists no {', '.join(missing)} (a damaged manifest)")
    return manifest


def latest_checkpoint(ckpt_dir: str | os.PathLike) -> tuple[Path | None, dict | None, list[str]]:
    """``(directory, manifest, skipped)`` of the newest complete checkpoint ``ckpt_dir/step_<N>``
    (None, None if there is none); ``skipped`` says why each newer one was passed over. A checkpoint is
    complete when its manifest (:func:`read_unit`) lists its model, the statistics and replay buffer its
    run needs, and its step N as ``timesteps``, and every listed file matches it.
    """
    found = []
    for p in Path(ckpt_dir).glob("step_*"):
        m = re.fullmatch(r"step_(\d+)", p.name)
        if m and p.is_dir():
            found.append((int(m.group(1)), p))
    skipped = []
    for step, p in sorted(found, reverse=True):
        try:
            manifest = read_unit(p, need=("model.zip",))
            run = manifest.get("run") if isinstance(manifest.get("run"), dict) else {}
            need = [n for n, on in (("vecnormalize.pkl", run.get("normalize")),
                                    ("replay_buffer.pkl", run.get("algo") in ("sac", "td3"))) if on]
            missing = [n for n in need if n not in manifest["files"]]
            if missing:
                raise ValueError(f"{p / MANIFEST}: lists no {', '.join(missing)} (its run needs it)")
            if manifest.get("timesteps") != step:
                raise ValueError(f"{p / MANIFEST}: timesteps = {manifest.get('timesteps')!r}, not its step {step}")
            return p, manifest, skipped
        except (FileNotFoundError, ValueError) as e:
            skipped.append(str(e))
    return None, None, skipped


#: A temporary file of :func:`iscc_gym.files.atomic_target` (``.NAME.PID.HEX8.tmp``): what a save killed before its
#: rename leaves.
_TEMPORARY = re.compile(r"\.(?P<name>.+)\.\d+\.[0-9a-f]{8}\.tmp")


def _leftovers(out: Path) -> list[str]:
    """The names in ``out`` of temporary files a killed save of a run file (:data:`RUN_FILES`) left, and those a
    killed replace_unit of ``best/`` left (``.best.*.tmp``, ``.best.*.old``).
    """
    names = []
    for q in out.iterdir():
        m = _TEMPORARY.fullmatch(q.name)
        if (m and m.group("name") in RUN_FILES) or (q.name.startswith(".best.") and q.name.endswith((".tmp", ".old"))):
            names.append(q.name)
    return names


def _is_run_dir(out: Path) -> bool:
    """Whether ``out`` holds a run of python -m train (its config.yml or manifest), so ``overwrite`` may delete; or
    only the run files and temporary files of a first save killed before its config.yml was in place (issue 43.8:
    no command could recover such a folder).
    """
    leftovers = _leftovers(out)
    if leftovers and all(q.name in RUN_FILES or q.name in leftovers for q in out.iterdir()):
        return True
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


def prepare_out(args: Args, hyperparams: dict | None = None) -> tuple[Path | None, dict | None]:
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
            print(f"train: warning: resume skipped an incomplete checkpoint: {why}", file=sys.stderr, flush=True)
        if ckpt is None:
            older = " (model_<N>_steps.zip files of an older python -m train carry no manifest: retrain)" if list(
                (out / "checkpoints").glob("model_*_steps.zip")) else ""
            raise FileNotFoundError(f"resume: no complete checkpoint in {out / 'checkpoints'}"
                                    + (f" ({len(skipped)} incomplete)" if skipped else "") + older
                                    + "; train without --resume first (with --checkpoint-freq > 0)")
        was = manifest.get("run") or {}
        if not isinstance(was, dict):
            raise ValueError(f"{ckpt / MANIFEST}: run = {was!r}; not a manifest written by python -m train")
        # a checkpoint of an older python -m train records no hyperparameters (or constraints): nothing to
        # compare them with (its multipliers then come from lagrange.yml, which must be there)
        now = run_identity(args, hyperparams if "hyperparams" in was else None, manifest)
        if "cost_limit" not in was:
            now = {k: v for k, v in now.items() if k not in ("cost_limit", "lagrange_lr")}
        if "residual_params" not in was:  # an older checkpoint: its base reads its tuning record, as it did
            now.pop("residual_params")
        if "norm_reward" not in was:  # an older checkpoint recorded no reward scaling (issue 43.15: now it does)
            now.pop("norm_reward")
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
        # and what a killed save left beside them (temporary files; a killed replace_unit of best/)
        for name in (*RUN_FILES, *_leftovers(out)):
            p = out / name
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p)
            elif p.exists() or p.is_symlink():
                p.unlink()
    return None, None


def load_vecnormalize(path: str | os.PathLike, venv):
    """A checkpoint's VecNormalize statistics around ``venv`` (SB3's ``VecNormalize.load``), with a
    ``ValueError`` naming the file for one that is not a VecNormalize, or of another observation space.
    """
    vn = read_vecnormalize(Path(path))
    try:
        vn.set_venv(venv)
    except (ValueError, AssertionError, AttributeError) as e:
        raise ValueError(f"{path}: statistics that do not fit the training env ({e})") from None
    return vn


def save_evaluations(path: str | os.PathLike, timesteps, results, ep_lengths) -> None:
    """``evaluations.npz`` as SB3's EvalCallback writes it (``timesteps``, ``results``, ``ep_lengths``), atomically."""
    with atomic_target(path) as tmp, open(tmp, "wb") as f:
        np.savez(f, timesteps=np.asarray(timesteps, dtype=np.int64), results=np.asarray(results, dtype=np.float64),
                 ep_lengths=np.asarray(ep_lengths, dtype=np.int64))


def read_history(out: Path, upto: int) -> tuple[dict, list[dict]]:
    """What a resumed run continues when its checkpoint has no :data:`RESUME_FILE` (an older python -m
    train): the evaluations and learning-curve rows of ``out`` up to step ``upto`` (later ones belong to
    the continuation that was cut off, replayed now). A damaged file is a ``ValueError`` naming it.
    """
    history = {"timesteps": [], "results": [], "ep_lengths": []}
    npz = out / "eval" / "evaluations.npz"
    if npz.exists():
        try:
            with np.load(npz) as d:
                keep = d["timesteps"] <= upto
                history = {k: d[k][keep].tolist() for k in history}
        except (OSError, ValueError, KeyError, IndexError, EOFError, zipfile.BadZipFile) as e:
            raise ValueError(f"{npz}: not an evaluations.npz of python -m train ({e}); move it away to resume "
                             "without the earlier evaluations") from None
    rows = []
    curve = out / "learning_curve.csv"
    if curve.exists():
        try:
            with open(curve, newline="") as f:
                for r in csv.DictReader(f):
                    if r["wall_s"] and int(r["timesteps"]) <= upto:
                        rows.append({"timesteps": int(r["timesteps"]), "wall_s": float(r["wall_s"]),
                                     "train_ep_reward_mean": float(r["train_ep_reward_mean"]),
                                     "train_ep_length_mean": float(r["train_ep_length_mean"])})
        except (OSError, ValueError, KeyError, TypeError, csv.Error, UnicodeDecodeError) as e:
            raise ValueError(f"{curve}: not a learning_curve.csv of python -m train ({type(e).__name__}: {e}); move "
                             "it away to resume without the earlier rows") from None
    return history, rows


def best_score(out: Path) -> tuple[float, int | None, str | None]:
    """``(mean reward, timesteps, note)`` of the best model kept in ``out/best`` (after
    :func:`recover_unit`), or ``(-inf, None, why)`` if there is none or it is incomplete.
    """
    try:
        manifest = read_unit(out / "best", need=("best_model.zip",))
        mean, t = manifest.get("mean_reward"), manifest.get("timesteps")
        if isinstance(mean, bool) or not isinstance(mean, int | float) or math.isnan(mean):
            raise ValueError(f"{out / 'best' / MANIFEST}: mean_reward = {mean!r}; not a number")
        return float(mean), (t if isinstance(t, int) else None), None
    except FileNotFoundError as e:
        return -np.inf, None, str(e) if (out / "best").exists() else None
    except ValueError as e:
        return -np.inf, None, str(e)


def _fail(path: Path, field: str, value, want: str):
    raise ValueError(f"{path}: {field} = {value!r}; {want} (a damaged checkpoint: resume from an older one by "
                     "moving this one away)")


def _is_num(v) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def resume_state(*, timesteps: int, wall_s: float, curve: list[dict], evaluations: dict, schedule: dict,
                 best: dict | None, lagrange: dict | None) -> str:
    """The text of a checkpoint's :data:`RESUME_FILE`."""
    doc = {"timesteps": int(timesteps), "wall_s": float(wall_s), "schedule": schedule, "best": best,
           "lagrange": lagrange, "evaluations": evaluations, "curve": curve}
    return yaml.dump(doc, Dumper=getattr(yaml, "CSafeDumper", yaml.SafeDumper), sort_keys=False,
                     default_flow_style=None, width=120)


def read_resume(ckpt: Path, manifest: dict) -> dict | None:
    """A checkpoint's :data:`RESUME_FILE`, checked field by field (None for a checkpoint of an older
    python -m train that has none). The multipliers (``lagrange``) are checked by the caller
    (:func:`train.lagrangian.check_lagrange`).

    Raises
    ------
    ValueError
        Naming the file and the field that is damaged.
    """
    if RESUME_FILE not in manifest["files"]:
        return None
    path = ckpt / RESUME_FILE
    try:
        doc = yaml.load(path.read_text(), Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))
    except (yaml.YAMLError, UnicodeDecodeError) as e:
        raise ValueError(f"{path}: not valid YAML ({str(e).splitlines()[0]})") from None
    if not isinstance(doc, dict):
        _fail(path, "the document", doc, "expected a mapping")
    if doc.get("timesteps") != manifest["timesteps"]:
        _fail(path, "timesteps", doc.get("timesteps"), f"expected the checkpoint's {manifest['timesteps']}")
    wall = doc.get("wall_s")
    if not (_is_num(wall) and math.isfinite(wall) and wall >= 0):
        _fail(path, "wall_s", wall, "expected seconds >= 0")
    curve = doc.get("curve")
    keys = ("timesteps", "wall_s", "train_ep_reward_mean", "train_ep_length_mean")
    if not isinstance(curve, list):
        _fail(path, "curve", curve, "expected a list of rows")
    for i, r in enumerate(curve):
        if not (isinstance(r, dict) and set(r) == set(keys) and isinstance(r["timesteps"], int)
                and all(_is_num(r[k]) for k in keys)):
            _fail(path, f"curve[{i}]", r, f"expected a row of {', '.join(keys)}")
    ev = doc.get("evaluations")
    if not (isinstance(ev, dict) and all(isinstance(ev.get(k), list) for k in ("timesteps", "results", "ep_lengths"))
            and len(ev["timesteps"]) == len(ev["results"]) == len(ev["ep_lengths"])
            and all(isinstance(t, int) for t in ev["timesteps"])
            and all(isinstance(r, list) and all(_is_num(x) for x in r) for r in ev["results"])):
        _fail(path, "evaluations", ev, "expected timesteps, results and ep_lengths of equal length")
    sched = doc.get("schedule")
    if not (isinstance(sched, dict) and all(sched.get(k) is None or isinstance(sched.get(k), int)
                                            for k in ("every", "last", "next"))):
        _fail(path, "schedule", sched, "expected every, last and next (steps, or null)")
    best = doc.get("best")
    if best is not None and not (isinstance(best, dict) and _is_num(best.get("mean_reward"))
                                 and not math.isnan(best["mean_reward"]) and isinstance(best.get("timesteps"), int)):
        _fail(path, "best", best, "expected null or mean_reward and timesteps")
    lag = doc.get("lagrange")
    if lag is not None and not isinstance(lag, dict):
        _fail(path, "lagrange", lag, "expected null or the multipliers' record")
    return doc


def write_curve(out: Path, rows: list[dict], evals: list[tuple[int, float]], png: bool = True) -> None:
    """``learning_curve.csv`` (atomically; at every evaluation and checkpoint, and at the end) and, with
    ``png``, ``learning_curve.png``.
    """
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
    if not png:
        return
    lines = []
    if rows:
        lines.append(([r["timesteps"] for r in rows], [r["train_ep_reward_mean"] for r in rows], "-", "train episodes"))
    if evals:
        lines.append((*zip(*evals, strict=True), "o-", "held-out eval"))
    plot_curve(out, lines, "episode reward")


def plot_curve(out: Path, lines: list[tuple], ylabel: str, seconds: list | None = None) -> None:
    """``learning_curve.png`` in ``out`` (atomically): each of ``lines`` ``(steps, values, style, label)`` against env
    steps; with ``seconds`` (the wall time of each point of the first line), that line against seconds beside it.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10 if seconds is not None else 6, 3.5), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 2 if seconds is not None else 1, 1)
    for x, y, style, label in lines:
        ax.plot(x, y, style, label=label)
    ax.set_xlabel("env steps")
    ax.set_ylabel(ylabel)
    ax.legend()
    if seconds is not None:
        right = fig.add_subplot(1, 2, 2, sharey=ax)
        right.plot(seconds, lines[0][1], lines[0][2], label=lines[0][3])
        right.set_xlabel("wall time, s")
    fig.tight_layout()
    with atomic_target(out / "learning_curve.png") as tmp:
        fig.savefig(tmp, format="png")
