"""``python -m experiments.field_learned``: what the field task's agent learned, beside ``adaptive``'s estimates.

One held-out mission of ``iscc_gym/ISCC-Field-v0`` flown three times on the same draws (common random numbers):
by ``aware`` (shown the slot's true K-factor and RCS), by ``adaptive`` (its K estimate recorded slot by slot) and by
the shipped agent (a residual on ``adaptive``). The figure draws the true K along the path beside ``adaptive``'s
estimate, and each policy's control and sensing shares; the table gives, over ``--missions`` held-out missions,
how each policy's control share follows the true K (the correlation of the share with K, slot by slot),
``adaptive``'s estimation error, and the per-slot reward noise against the per-slot room ``aware`` - ``adaptive``.

Example::

    python -m experiments.field_learned --write-docs
"""

from __future__ import annotations

import sys
import time

import numpy as np
from iscc_gym.agents import make_policy
from iscc_gym.agents.sb3_policy import SB3Policy
from iscc_gym.agents.tasks import task_policies
from iscc_gym.commands.options import Parser, check_writable_file, docs_command, positive_int, run_console
from iscc_gym.commands.protocol import EVAL_SEED_START, seed_list

from iscc_gym.envs.vector import ISCCVectorEnv
from iscc_gym.scenario import make_scenario
from iscc_gym.sim.mission import world_column
from iscc_gym.sim.task import action_to_split
from iscc_gym.tasks import FIELD_ENV_ID

__all__ = ["fly", "main"]

SECTION = "field-learned"
FIGURE = "field_learned.png"


def fly(seeds, max_steps: int | None = None, estimator: str | None = None, student: str | None = None) -> dict:
    """Fly ``seeds`` with aware, adaptive, bayes and the shipped agent (and the learned ``estimator`` and the DAgger
    ``student`` of those run directories, where given); per policy the splits (T, B, 3), and the true K (T, B),
    ``adaptive``'s estimate of it and ``bayes``'s (and the estimator's) posterior mean and standard deviation (T, B),
    dB.
    """
    s = make_scenario("field")
    k = len(seeds)
    steps = s.n_slots if max_steps is None else min(max_steps, s.n_slots)
    policies = {"aware": make_policy("myopic", s.replace(show_world=True)), "adaptive": make_policy("adaptive", s),
                "bayes": make_policy("bayes", s),
                "ppo": SB3Policy.load(task_policies(FIELD_ENV_ID).agent, check_env=FIELD_ENV_ID)}
    if estimator is not None:
        policies["estimator"] = make_policy(f"estimator:{estimator}", s)
    if student is not None:
        policies["student"] = make_policy(f"student:{student}", s)
    posteriors = [name for name in ("bayes", "estimator") if name in policies]
    envs = {name: ISCCVectorEnv(num_envs=k, scenario=s.replace(**getattr(p, "scenario_overrides", {}) or {}))
            for name, p in policies.items()}
    obs = {name: env.reset(seed=list(seeds))[0] for name, env in envs.items()}
    rows = envs["adaptive"].missions(k)
    w = world_column(s)
    splits = {name: [] for name in policies}
    rewards = {name: [] for name in policies}
    k_true, k_est = [], []
    k_post = {name: ([], []) for name in posteriors}
    states = {name: None for name in policies}
    for t in range(steps):
        for name, pol in policies.items():
            action, states[name] = pol.predict(obs[name], state=states[name], episode_start=np.full(k, t == 0))
            if name == "adaptive":
                k_est.append(pol._k_db.copy())
            if name in k_post:  # its posterior of this slot's K (the one it designed the slot on)
                mean, sd = pol.k_estimate_db()
                k_post[name][0].append(mean)
                k_post[name][1].append(sd)
            splits[name].append(action_to_split(action))
            obs[name], reward, *_ = envs[name].step(np.asarray(action, np.float32))
            rewards[name].append(reward)
        k_true.append(np.array([r[t, w] for r in rows]))
    return {"splits": {n: np.array(v) for n, v in splits.items()},
            "rewards": {n: np.array(v) for n, v in rewards.items()}, "k_true": np.array(k_true),
            "k_est": np.array(k_est), **{f"k_{n}": np.array(m) for n, (m, _) in k_post.items()},
            **{f"k_{n}_sd": np.array(sd) for n, (_, sd) in k_post.items()},
            "rcs_db": np.array([r[0, w + 1] for r in rows]), "seeds": list(seeds)}


def _corr(a, b):
    a, b = a - a.mean(), b - b.mean()
    return float((a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum()))


def summary(res: dict) -> dict:
    """Per policy: the slot-by-slot correlation of its control share with the true K, pooled over missions; and
    ``adaptive``'s K error (mean absolute, dB) and the correlation of its estimate with the truth.
    """
    kt = res["k_true"].ravel()
    out = {name: {"ctrl_vs_k": _corr(sp[..., 1].ravel(), kt), "ctrl_mean": float(sp[..., 1].mean()),
                  "sen_mean": float(sp[..., 0].mean())} for name, sp in res["splits"].items()}
    out["estimate"] = {"mae_db": float(np.abs(res["k_est"] - res["k_true"]).mean()),
                       "corr": _corr(res["k_est"].ravel(), kt)}
    for name in ("bayes", "estimator"):
        if f"k_{name}" not in res:
            continue
        err = res[f"k_{name}"] - res["k_true"]
        out[f"{name}_estimate"] = {"mae_db": float(np.abs(err).mean()), "corr": _corr(res[f"k_{name}"].ravel(), kt),
                                   "rmse_db": float(np.sqrt(np.mean(err ** 2))),
                                   "sd_db": float(np.sqrt(np.mean(res[f"k_{name}_sd"] ** 2))),
                                   "covered": float(np.mean(np.abs(err) <= 1.645 * res[f"k_{name}_sd"]))}
    gap = res["rewards"]["aware"] - res["rewards"]["adaptive"]
    out["per_slot"] = {"adaptive_std": float(res["rewards"]["adaptive"].std()), "gap_mean": float(gap.mean()),
                       "gap_std": float(gap.std())}
    return out


def figure(res: dict, path) -> None:
    """The first mission's figure (see the module docstring), written atomically
    (:func:`iscc_gym.eval.figures.save_figure`).
    """
    from iscc_gym.eval.figures import new_figure, save_figure

    t = np.arange(res["k_true"].shape[0]) * 0.1
    fig = new_figure((9, 7), dpi=110)
    ax = fig.subplots(3, 1, sharex=True)
    ax[0].plot(t, res["k_true"][:, 0], color="k", lw=1.0, label="true K (the world)")
    ax[0].plot(t, res["k_est"][:, 0], color="tab:orange", lw=0.8, label="adaptive's estimate")
    m, sd = res["k_bayes"][:, 0], res["k_bayes_sd"][:, 0]
    ax[0].fill_between(t, m - sd, m + sd, color="tab:green", alpha=0.25, lw=0)
    ax[0].plot(t, m, color="tab:green", lw=0.8, label="bayes's posterior (mean +- sd)")
    if "k_estimator" in res:
        ax[0].plot(t, res["k_estimator"][:, 0], color="tab:purple", lw=0.8, label="the learned estimator's mean")
    ax[0].axhline(9.0, color="grey", ls=":", lw=0.8, label="the model's 9 dB")
    ax[0].set_ylabel("K-factor (dB)")
    ax[0].legend(loc="lower right", fontsize=8)
    for j, (row, label) in enumerate(((1, "control share"), (0, "sensing share")), start=1):
        for name, color in (("aware", "k"), ("adaptive", "tab:orange"), ("bayes", "tab:green"),
                            ("ppo", "tab:blue"), ("estimator", "tab:purple"), ("student", "tab:red")):
            if name not in res["splits"]:
                continue
            ax[j].plot(t, res["splits"][name][:, 0, row], color=color, lw=0.7, label=name)
        ax[j].set_ylabel(label)
        ax[j].legend(loc="upper right", fontsize=8)
    ax[2].set_xlabel("time (s)")
    ax[0].set_title(f"mission {res['seeds'][0]}: the drone's RCS {res['rcs_db'][0]:+.1f} dB from the model's")
    fig.tight_layout()
    save_figure(fig, path)


def markdown(stats: dict, seeds, command: str) -> str:
    lines = [f"Generated by `{command}`: {len(seeds)} held-out missions (seeds {seeds[0]}-{seeds[-1]}), each flown by "
             "every policy on the same draws. The control share's slot-by-slot correlation with the true K-factor "
             "(pooled over the missions; a lower K fades deeper, so the share should rise where K falls: a "
             "negative correlation), the mean shares, and `adaptive`'s estimate and `bayes`'s posterior of K against "
             "the truth.", "",
             "| policy | control share vs true K (corr.) | mean control share | mean sensing share |",
             "|---|--:|--:|--:|"]
    for name in ("aware", "adaptive", "bayes", "ppo", "estimator", "student"):
        if name not in stats:
            continue
        r = stats[name]
        lines.append(f"| {name} | {r['ctrl_vs_k']:+.2f} | {r['ctrl_mean']:.3f} | {r['sen_mean']:.3f} |")
    e = stats["estimate"]
    p = stats["per_slot"]
    b = stats["bayes_estimate"]
    lines += ["", f"`adaptive`'s K estimate: mean absolute error {e['mae_db']:.2f} dB, correlation with the truth "
                  f"{e['corr']:+.2f}. `bayes`'s posterior mean: mean absolute error {b['mae_db']:.2f} dB (RMS "
                  f"{b['rmse_db']:.2f} against its posterior's {b['sd_db']:.2f}), correlation {b['corr']:+.2f}, the "
                  f"truth within its 90 % interval in {100 * b['covered']:.0f} % of the slots. Per slot, `adaptive`'s "
                  f"reward has standard deviation {p['adaptive_std']:.2f}; "
                  f"`aware` - `adaptive` (paired slot by slot on the same draws, while both fly) is "
                  f"{p['gap_mean']:+.4f} on average with standard deviation {p['gap_std']:.2f}: the room a learner "
                  "has to find, against the noise it sees."]
    if "estimator_estimate" in stats:
        b = stats["estimator_estimate"]
        lines[-1] += (f" The learned estimator (`estimator`, python -m train --learner estimator): mean absolute error "
                      f"{b['mae_db']:.2f} dB (RMS {b['rmse_db']:.2f} against its law's {b['sd_db']:.2f}), "
                      f"correlation {b['corr']:+.2f}, the truth within its 90 % interval in "
                      f"{100 * b['covered']:.0f} % of the slots.")
    lines += ["", f"![the field task's first mission](figures/{FIGURE})"]
    return "\n".join(lines)


def build_parser(prog: str = "python -m experiments.field_learned") -> Parser:
    ap = Parser(prog=prog, description=__doc__.split("\n")[0])
    ap.add_argument("--missions", type=positive_int, default=8, metavar="N",
                    help=f"held-out missions, seeds from {EVAL_SEED_START} (default: 8; the figure draws the first)")
    ap.add_argument("--max-steps", type=positive_int, default=None, metavar="N",
                    help="slots per mission (default: the whole mission)")
    ap.add_argument("--estimator", default=None, metavar="DIR",
                    help="fly the learned estimator of this run too (python -m train --learner estimator)")
    ap.add_argument("--student", default=None, metavar="DIR",
                    help="fly the DAgger student of this run too (python -m train --learner dagger)")
    ap.add_argument("--write-docs", action="store_true",
                    help=f"write the table into docs/results.md (section {SECTION}) and the figure into "
                         f"docs/figures/{FIGURE}")
    return ap


def main(argv: list[str] | None = None, prog: str = "python -m experiments.field_learned") -> dict:
    args = build_parser(prog).parse_args(argv)
    from iscc_gym.commands.docs import RESULTS_PATH, docs_path, write_section

    if args.write_docs:
        check_writable_file(docs_path(RESULTS_PATH), "--write-docs")
    seeds = seed_list(EVAL_SEED_START, args.missions)
    t0 = time.perf_counter()
    res = fly(seeds, args.max_steps, args.estimator, args.student)
    stats = summary(res)
    table = markdown(stats, seeds, docs_command(prog, argv))
    print(table)
    print(f"flew {len(seeds)} missions x {len(res['splits'])} policies in {time.perf_counter() - t0:.0f} s")
    if args.write_docs:
        figure(res, docs_path("docs/figures") / FIGURE)
        write_section(docs_path(RESULTS_PATH), SECTION, f"## What the field task's agent learned\n\n{table}")
        print(f"wrote {docs_path(RESULTS_PATH)}")
    return stats


if __name__ == "__main__":
    sys.exit(run_console(main, None, "python -m experiments.field_learned"))
