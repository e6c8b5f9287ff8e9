r"""``python -m train --learner estimator``: an RMA-style estimator of the field task's world, learned in simulation.

The field task hides its world (the K-factor along the path, the RCS offset) from the policy; the simulator knows
it. This trainer plays ``bayes`` (:class:`agents.bayes.BayesPolicy`: the design the estimator will feed) on the
training missions of a world-shown batched env, records each slot's measurements as the filter reads them
(:func:`agents.bayes.estimator_inputs`) beside the slot's true K and RCS from the world block, and fits
:func:`agents.estimator.WorldEstimator` by cross-entropy against the truths' two-hot bins on the filter's grids
(truncated back-propagation through time over the missions in order, Adam, the rate annealed to a tenth). A part
of the missions is held out of
the fit: the epoch whose held-out K cross-entropy is lowest is kept, and the summary compares it with ``bayes``'s
posterior on the same held-out slots (cross-entropy and the absolute error of the mean).

``--set worlds=N`` (N > 1): the missions are split over N worlds whose laws are drawn from
:data:`iscc_gym.tasks.field.FIELD_WORLD_RANGES` (domain randomisation; ``bayes`` on the preset's prior plays them
all, as the deployed estimator is fed by the preset's model).

Writes into OUT: ``estimator.pt`` (weights, grids, hidden size, scenario: ``--policies estimator:OUT``),
``config.yml`` (the settings) and ``summary.yml``.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import yaml
from iscc_gym.agents.bayes import ESTIMATOR_INPUTS

from iscc_gym.files import write_atomic
from iscc_gym.tasks.field import draw_worlds

from .callbacks import printer

__all__ = ["main", "collect", "fit", "tbptt_pass", "two_hot", "settings_of", "check_out", "learner_scenario",
           "SETTINGS"]

#: The estimator's own settings (``--set KEY=VALUE``) and defaults.
SETTINGS = {"hidden": 64, "epochs": 40, "chunk": 100, "learning_rate": 3e-3, "held_out": 0.125, "worlds": 1}


def two_hot(y, grid) -> tuple[np.ndarray, np.ndarray]:
    """``y`` on the uniform ``grid`` as the lower bin's index and the upper bin's weight (``y`` clipped to the
    grid): the target whose cross-entropy is minimised by the law that puts the right mass on each cell.
    """
    grid = np.asarray(grid, dtype=float)
    if grid.size == 1:
        return np.zeros(np.shape(y), dtype=np.int64), np.zeros(np.shape(y))
    u = (np.clip(np.asarray(y, dtype=float), grid[0], grid[-1]) - grid[0]) / (grid[1] - grid[0])
    i = np.clip(np.floor(u).astype(np.int64), 0, grid.size - 2)
    return i, np.clip(u - i, 0.0, 1.0)


def _cross_entropy(logp, index, weight):
    r"""Mean of :math:`-(1-w)\log p_i - w \log p_{i+1}` (numpy or torch alike)."""
    lo = np.take_along_axis(logp, index[..., None], -1)[..., 0] if isinstance(logp, np.ndarray) else \
        logp.gather(-1, index.unsqueeze(-1)).squeeze(-1)
    hi = np.take_along_axis(logp, np.minimum(index + 1, logp.shape[-1] - 1)[..., None], -1)[..., 0] \
        if isinstance(logp, np.ndarray) else \
        logp.gather(-1, (index + 1).clamp(max=logp.shape[-1] - 1).unsqueeze(-1)).squeeze(-1)
    return -((1.0 - weight) * lo + weight * hi)


def collect(scenario, n_envs: int, n_slots: int, seed: int, say=None, worlds=({},)) -> dict:
    """Play ``bayes`` on ``n_envs`` world-shown missions from ``seed`` for ``n_slots`` slots (missions restart as the
    env does): the estimator's inputs (T, N, 7), the true K and RCS offset (T, N), and ``bayes``'s K posterior's
    cross-entropy and mean on the same slots (T, N), for the comparison.
    """
    from iscc_gym.agents import make_policy
    from iscc_gym.agents.sb3_vec_env import ConcatVecEnv, ISCCBatchedVecEnv
    from iscc_gym.train.privileged import world_entries

    from iscc_gym.sim.functional import decode_observation

    shown = scenario.replace(show_world=True)
    worlds = list(worlds)
    sizes = [n_envs // len(worlds) + (k < n_envs % len(worlds)) for k in range(len(worlds))]
    groups = [ISCCBatchedVecEnv(m, scenario=shown.replace(**w)) for m, w in zip(sizes, worlds, strict=True) if m > 0]
    venv = groups[0] if len(groups) == 1 else ConcatVecEnv(groups)
    venv.seed(seed)
    nw = world_entries(scenario)
    policy = make_policy("bayes", scenario)
    out = {"x": np.empty((n_slots, n_envs, len(ESTIMATOR_INPUTS)), np.float32), "k": np.empty((n_slots, n_envs)),
           "rcs": np.empty((n_slots, n_envs)), "bayes_ce": np.empty((n_slots, n_envs)),
           "bayes_mean": np.empty((n_slots, n_envs))}
    obs = venv.reset()
    t0 = time.perf_counter()
    for t in range(n_slots):
        action, _ = policy.predict(obs[:, :-nw])
        world = decode_observation(np.asarray(obs, dtype=float), shown)
        out["x"][t] = policy.measured_inputs()
        out["k"][t], out["rcs"][t] = world["world_k_db"], world["world_rcs_offset_db"]
        wk = policy.k_marginal()
        i, w = two_hot(out["k"][t], policy.k_grid)
        out["bayes_ce"][t] = _cross_entropy(np.log(np.maximum(wk, 1e-300)), i, w)
        out["bayes_mean"][t] = wk @ policy.k_grid
        obs, _, _, _ = venv.step(action)
        if say is not None and (t + 1) % 1000 == 0:
            say(f"collected {t + 1:,} of {n_slots:,} slots on {n_envs} envs ({time.perf_counter() - t0:.0f} s)")
    venv.close()
    out["k_grid"], out["rcs_grid"] = policy.k_grid, policy.rcs_grid
    return out


def tbptt_pass(net, x, rows, chunk: int, slot_losses, opt=None, sched=None) -> list[float]:
    """One pass of the recurrent ``net`` (:func:`agents.estimator.recurrent_heads`) over the slots of ``x`` (T, N, F,
    a tensor) for the envs ``rows`` (a slice or an index array), by truncated back-propagation through time: chunks of
    ``chunk`` slots, the state carried (detached) from one to the next. ``slot_losses(t, logits)`` gives slot ``t``'s
    loss terms, each summed over the rows. With ``opt``, one step a chunk on the terms' sum over the chunk's
    row-slots (the gradient's norm clipped to 1; ``sched`` stepped after it); without, no gradients. Returns each
    term's mean per row-slot.
    """
    import torch

    n_slots, n = x.shape[0], x[0, rows].shape[0]
    h = torch.zeros(n, net.hidden)
    totals = None
    for start in range(0, n_slots, chunk):
        end = min(start + chunk, n_slots)
        losses = None
        with torch.set_grad_enabled(opt is not None):
            for t in range(start, end):
                *logits, h = net.step(x[t, rows], h)
                terms = slot_losses(t, logits)
                losses = list(terms) if losses is None else [a + b for a, b in zip(losses, terms, strict=True)]
        if opt is not None:
            opt.zero_grad()
            (sum(losses) / (n * (end - start))).backward()
            torch.nn.utils.clip_grad_norm_(net.parameters(), 1.0)
            opt.step()
            if sched is not None:
                sched.step()
        h = h.detach()
        done = [float(loss.detach()) for loss in losses]
        totals = done if totals is None else [a + b for a, b in zip(totals, done, strict=True)]
    return [total / (n * n_slots) for total in totals]


def fit(data: dict, hidden: int, epochs: int, chunk: int, learning_rate: float, held_out: float, seed: int,
        say=None):
    """Fit :func:`agents.estimator.WorldEstimator` on :func:`collect`'s data (the last ``held_out`` share of the
    envs held out); returns ``(net, report)``, the epoch with the lowest held-out K cross-entropy.
    """
    import torch
    from iscc_gym.agents.estimator import WorldEstimator

    torch.manual_seed(seed)
    n_slots, n_envs, _ = data["x"].shape
    n_val = max(1, int(round(held_out * n_envs))) if n_envs > 1 else 0
    fit_rows, val_rows = slice(0, n_envs - n_val), slice(n_envs - n_val, n_envs)
    x = torch.from_numpy(data["x"])
    targets = []
    for key, grid in (("k", data["k_grid"]), ("rcs", data["rcs_grid"])):
        i, w = two_hot(data[key], grid)
        targets.append((torch.from_numpy(i), torch.from_numpy(w).float()))
    net = WorldEstimator(len(data["k_grid"]), len(data["rcs_grid"]), hidden)
    opt = torch.optim.Adam(net.parameters(), lr=learning_rate)
    steps = epochs * -(-n_slots // chunk)  # the rate anneals to a tenth over the fit, cosine
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps, eta_min=0.1 * learning_rate)
    k_grid = torch.as_tensor(data["k_grid"], dtype=torch.float32)

    def run(rows, train: bool):
        mean_k = np.empty((n_slots, rows.stop - rows.start))

        def slot_losses(t, logits):
            pk, pr = torch.log_softmax(logits[0], 1), torch.log_softmax(logits[1], 1)
            if not train:
                mean_k[t] = (pk.exp() @ k_grid).numpy()
            return (_cross_entropy(pk, targets[0][0][t, rows], targets[0][1][t, rows]).sum(),
                    _cross_entropy(pr, targets[1][0][t, rows], targets[1][1][t, rows]).sum())

        ce_k, ce_r = tbptt_pass(net, x, rows, chunk, slot_losses, *((opt, sched) if train else ()))
        return ce_k, ce_r, mean_k

    best, report = None, None
    for epoch in range(epochs):
        net.train()
        fit_k, fit_r, _ = run(fit_rows, True)
        net.eval()
        val_k, val_r, mean_k = run(val_rows, False) if n_val else (fit_k, fit_r, None)
        if say is not None:
            say(f"epoch {epoch + 1}/{epochs}: K cross-entropy {fit_k:.4f} (held out {val_k:.4f}), RCS {fit_r:.4f} "
                f"(held out {val_r:.4f})")
        if best is None or val_k < best:
            best = val_k
            state = {k: v.clone() for k, v in net.state_dict().items()}
            report = {"epoch": epoch + 1, "held_out_envs": n_val, "k_cross_entropy": round(val_k, 5),
                      "rcs_cross_entropy": round(val_r, 5)}
            if mean_k is not None:
                truth = data["k"][:, val_rows]
                report.update({
                    "k_mean_abs_error_db": round(float(np.mean(np.abs(mean_k - truth))), 4),
                    "bayes_k_cross_entropy": round(float(np.mean(data["bayes_ce"][:, val_rows])), 5),
                    "bayes_k_mean_abs_error_db": round(float(np.mean(np.abs(data["bayes_mean"][:, val_rows] - truth))),
                                                       4)})
    net.load_state_dict(state)
    net.eval()
    return net, report


def settings_of(args, defaults: dict) -> dict:
    """``defaults`` with the run's ``--set`` overrides, each checked: a positive number (an integer where the default
    is one), ``held_out`` in [0, 1), ``beta`` in [0, 1].
    """
    unknown = set(args.overrides) - set(defaults)
    if unknown:
        raise ValueError(f"--set {sorted(unknown)[0]}: this learner's settings are {', '.join(defaults)}")
    out = {**defaults, **args.overrides}
    for k, v in out.items():
        kind = float if isinstance(defaults[k], float) else int
        if k == "beta":
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0.0 <= v <= 1.0:
                raise ValueError(f"--set beta={v!r}: use a number in [0, 1] (the teacher's share decays as beta^round)")
            out[k] = float(v)
            continue
        bad = isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)
        if bad or (v <= 0 and k != "held_out") or (k == "held_out" and not 0.0 <= v < 1.0) \
                or (kind is int and v != int(v)):
            raise ValueError(f"--set {k}={v!r}: use a positive {'integer' if kind is int else 'number'}"
                             + (" in [0, 1)" if k == "held_out" else ""))
        out[k] = kind(v)
    return out


def check_out(out: Path, overwrite: bool, files) -> None:
    """``OUT`` new or empty, or holding only a previous run's ``files`` with ``--overwrite``."""
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out}: not a directory; name a new or empty directory")
    if out.is_dir() and any(out.iterdir()):
        others = sorted(p.name for p in out.iterdir() if p.name not in files)
        if not overwrite or others:
            raise ValueError(f"--out {out}: not empty ({', '.join(sorted(p.name for p in out.iterdir())[:4])}); "
                             + ("name a new directory or pass --overwrite" if not others else
                                f"it holds files this trainer did not write ({', '.join(others[:4])}): name a new "
                                "directory"))


def learner_scenario(args, learner: str):
    """The Scenario a ``--learner`` run trains on: the env id's registered preset (or ``--scenario``, the same task's)
    with ``--env-set``; ``ValueError`` for an env without the field task's hidden world or one that shows it.
    """
    from iscc_gym.scenario import make_scenario
    from iscc_gym.sim.effects import task_effects
    from iscc_gym.tasks import TASKS, registered_scenario

    from .config import check_no_world_shown, check_task

    if args.env_id not in TASKS:
        raise ValueError(f"--learner {learner}: env {args.env_id!r} is not one of the project's tasks; use "
                         "iscc_gym/ISCC-Field-v0")
    preset = args.scenario or registered_scenario(args.env_id)
    check_task(args.env_id, preset)
    check_no_world_shown(args.env_overrides)
    scenario = make_scenario(preset, **args.env_overrides)
    if not task_effects(scenario).field:
        raise ValueError(f"--learner {learner} needs the field task's hidden world (iscc_gym/ISCC-Field-v0); "
                         f"{args.env_id} has none to learn")
    return preset, scenario


def main(args) -> dict:
    """Train the estimator of ``args`` (``env_id``, ``out``, ``seed``, ``n_envs``, ``total_timesteps`` slots in all,
    ``overrides``: :data:`SETTINGS`, ``env_overrides``); returns the summary.
    """
    from iscc_gym.agents.estimator import FILE, save_estimator

    say = printer(args)
    preset, scenario = learner_scenario(args, "estimator")
    settings = settings_of(args, SETTINGS)
    n_envs = int(args.n_envs or 64)
    total = int(args.total_timesteps or 320_000)
    n_slots = max(1, total // n_envs)
    out = Path(args.out)
    check_out(out, args.overwrite, (FILE, "config.yml", "summary.yml"))
    import torch

    torch.set_num_threads(args.torch_threads)
    t0 = time.perf_counter()
    say(f"estimator on {args.env_id}: playing bayes on {n_envs} training missions from seed {args.seed}, "
        f"{n_slots:,} slots each")
    worlds = draw_worlds(settings["worlds"], args.seed)
    if len(worlds) > 1:
        say(f"over {len(worlds)} randomised worlds (iscc_gym.tasks.field.FIELD_WORLD_RANGES), bayes on the preset's "
            "prior playing")
    data = collect(scenario, n_envs, n_slots, args.seed, say, worlds)
    t_collect = time.perf_counter() - t0
    net, report = fit(data, settings["hidden"], settings["epochs"], settings["chunk"], settings["learning_rate"],
                      settings["held_out"], args.seed, say)
    meta = {"kind": "estimator", "inputs": len(ESTIMATOR_INPUTS), "scenario": preset,
            "env_overrides": dict(args.env_overrides), "hidden": settings["hidden"],
            "k_grid": [float(v) for v in data["k_grid"]], "rcs_grid": [float(v) for v in data["rcs_grid"]]}
    out.mkdir(parents=True, exist_ok=True)
    save_estimator(out / FILE, net, meta)
    wall = time.perf_counter() - t0
    config = {"learner": "estimator", "env_id": args.env_id, "scenario": preset,
              "env_overrides": dict(args.env_overrides), "seed": args.seed, "n_envs": n_envs,
              "total_timesteps": n_slots * n_envs, "settings": settings, "worlds": worlds}
    write_atomic(out / "config.yml", yaml.safe_dump(config, sort_keys=False))
    summary = {"learner": "estimator", "timesteps": n_slots * n_envs, "wall_time_s": round(wall, 1),
               "collect_time_s": round(t_collect, 1), "held_out": report, "out": str(out)}
    write_atomic(out / "summary.yml", yaml.safe_dump(summary, sort_keys=False))
    return summary
