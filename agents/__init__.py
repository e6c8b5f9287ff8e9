"""Policies for ``iscc_gym/ISCC-v0`` behind one SB3-style protocol (the repository's ``agents/`` folder, installed
as ``iscc_gym.agents`` by ``pyproject.toml``'s ``package-dir``; it imports the core ``iscc_gym``, never ``train`` or
``eval``).

Every policy has ``predict(obs, state=None, episode_start=None, deterministic=True) -> (action,
state)`` with the env's action in [-1, 1]^3, so evaluation code treats scripted policies and trained
SB3 models alike:

* :class:`FixedSplitPolicy`, :class:`EqualSplitPolicy`: a constant split;
* :class:`SCAPolicy`: the paper's Algorithm 1, static (``mode="static"``) or re-solved every slot
  (``mode="per_slot"``, its design loss tuned by ``python -m eval.tune sca-per-slot``), optionally
  designed ignoring packet loss;
* :func:`grid_search`, :func:`evolutionary_search`: search baselines over static splits, scored by
  :mod:`iscc_gym.analysis`; their results carry a policy that plays the split found;
* :class:`MarginPolicy`: per slot, fixed multiples of the predicted control and data needs (tuned by
  ``python -m eval.tune margin``);
* :class:`MyopicPolicy`: per slot, the split maximising the expected one-slot reward (model-based);
* on the urban task (issue 25): :class:`DriftPlusPenaltyPolicy` (``dpp``, Lyapunov drift-plus-penalty on the
  data queue) and :class:`LookaheadPolicy` (``mpc``, receding-horizon planning over the preview; ``oracle``, the
  same on the truth's preview);
* :func:`make_policy`: a policy from a short spec string.
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING

from iscc_gym.lazy import lazy_names
from iscc_gym.scenario import Scenario, make_scenario

from .tuned_records import is_params, load_tuned, record_name, record_task

if TYPE_CHECKING:  # pragma: no cover
    from .base import FixedSplitPolicy
    from .myopic import MyopicPolicy

#: The policies and searches, imported on first use (:mod:`iscc_gym.lazy`): ``import iscc_gym.agents`` (and the
#: task table ``iscc_gym.agents.tasks`` a command's parser reads) loads no compiled physics, so a command refuses a
#: mistake before it loads them (issue 43.12).
__getattr__, __dir__ = lazy_names(__name__, {
    **dict.fromkeys(("Policy", "SplitPolicy", "FixedSplitPolicy", "EqualSplitPolicy", "validate_split"), ".base"),
    "DriftPlusPenaltyPolicy": ".dpp", "MarginPolicy": ".margin", "LookaheadPolicy": ".mpc", "MyopicPolicy": ".myopic",
    **dict.fromkeys(("SCAResult", "sca_allocation", "solve_sca"), ".sca"), "SCAPolicy": ".sca_slot",
    **dict.fromkeys(("SearchResult", "evolutionary_search", "grid_search"), ".search")}, globals())

__all__ = [
    "Policy",
    "SplitPolicy",
    "FixedSplitPolicy",
    "EqualSplitPolicy",
    "SCAPolicy",
    "MarginPolicy",
    "MyopicPolicy",
    "DriftPlusPenaltyPolicy",
    "LookaheadPolicy",
    "SCAResult",
    "sca_allocation",
    "solve_sca",
    "SearchResult",
    "grid_search",
    "evolutionary_search",
    "make_policy",
    "tuned_record",
    "POLICY_SPECS",
]

#: The specs :func:`make_policy` understands.
POLICY_SPECS = ("sca", "sca-per-slot", "sca-ignore-loss", "equal", "fixed:A_SEN,A_CTRL,A_COMM", "grid",
                "evolutionary", "margin", "margin:M_CTRL,M_COMM", "myopic", "dpp", "dpp:V", "mpc", "mpc-hold", "oracle",
                "adaptive", "bayes", "bayes-learn", "estimator:PATH", "student:PATH")
#: The specs of the urban task's queue planners (they need a scenario with a data queue and a preview).
URBAN_SPECS = ("dpp", "mpc", "mpc-hold", "oracle")


def tuned_record(spec: str, scenario: Scenario | str = "paper") -> str | None:
    """The tuning record (``agents/tuned/<name>.yml``) whose ``params`` :func:`make_policy` reads for ``spec`` on
    ``scenario``, or None for a spec that reads none (a fixed split, ``dpp:V``, the static SCA, ...).
    """
    s = make_scenario(scenario) if isinstance(scenario, str) else scenario
    key, task = str(spec).strip().lower(), record_task(s)
    if key == "myopic":
        return None if task == "paper" else record_name("myopic", task)
    if key in ("margin", "dpp"):
        return record_name(key, task)
    if key in ("mpc", "mpc-hold", "oracle"):
        return record_name("mpc", task)
    if key in ("adaptive", "bayes"):  # the field task's own rungs, tuned there
        return key
    if key == "bayes-learn" or key.startswith("estimator:"):  # bayes's design: bayes's tuned parameters
        return "bayes"
    return "sca-per-slot" if key == "sca-per-slot" else None


def make_policy(spec: str, scenario: Scenario | str = "paper", seed: int = 0, tuned: dict | None = None):
    """A policy from a spec string.

    Parameters
    ----------
    spec : str
        ``"sca"`` (static SCA), ``"sca-per-slot"``, ``"sca-ignore-loss"`` (static SCA designed with
        eps_ctrl = 0), ``"equal"``, ``"fixed:0.2,0.2,0.6"`` (alpha_sen, alpha_ctrl, alpha_comm),
        ``"grid"`` (grid search, 1 % steps), ``"evolutionary"`` (differential evolution); the
        searches are deterministic, so their policies are cached per scenario (and seed).
        ``"margin"`` (the rule with the multiples tuned by ``python -m eval.tune margin``),
        ``"margin:4,1.3"`` (given m_ctrl, m_comm), ``"myopic"`` (:class:`MyopicPolicy`, cached per
        scenario: its tables are built once). On the urban task (a scenario with a queue or blockage:
        :func:`iscc_gym.agents.tuned_records.record_task`) ``margin``, ``myopic``, ``dpp`` and ``mpc`` read the
        records ``<spec>-urban`` tuned there (``python -m eval.tune <spec> --scenario urban``); ``"dpp:2"``
        (given V), ``"oracle"`` (``mpc`` on the truth's preview: its ``scenario_overrides`` make the
        evaluation show it the realised channel ahead on the same missions), ``"mpc-hold"`` (``mpc`` blind to the
        preview: the slot's channel held over the horizon). ``"adaptive"`` (the field task's
        :class:`agents.adaptive.AdaptivePolicy`, its estimators tuned by ``python -m eval.tune adaptive --scenario
        field``). ``"bayes"`` (:class:`agents.bayes.BayesPolicy`, the field task's Bayesian filter), ``"bayes-learn"``
        (the same re-estimating its prior), ``"estimator:PATH"`` (:class:`agents.estimator.EstimatorPolicy`:
        ``bayes``'s design on the learned estimator of the run directory PATH, ``python -m train --learner
        estimator``), ``"student:PATH"`` (:class:`agents.student.StudentPolicy`: the student of ``aware`` of the run
        directory PATH, ``python -m train --learner dagger``).
    scenario : Scenario or str
        The scenario (or preset name) the model-based policies design for.
    seed : int
        Seed of the evolutionary search.
    tuned : dict, optional
        The tuned parameters to play instead of those of the spec's record (:func:`tuned_record`): a residual
        agent's base plays the ones recorded with the agent. Only for a spec that reads a record.

    Raises
    ------
    ValueError
        Unknown spec (the message lists the valid ones), a malformed fixed split, ``tuned`` for a spec that
        reads no record or not a mapping of numbers (one of other names fails as the policy's constructor does).
    """
    from .base import EqualSplitPolicy, FixedSplitPolicy, validate_split
    from .dpp import DriftPlusPenaltyPolicy
    from .margin import MarginPolicy
    from .mpc import LookaheadPolicy
    from .sca_slot import SCAPolicy

    if not isinstance(spec, str):
        raise ValueError(f"spec must be a string, one of {list(POLICY_SPECS)}; got {spec!r}")
    s = make_scenario(scenario) if isinstance(scenario, str) else scenario
    key = spec.strip().lower()
    record = tuned_record(key, s)
    if tuned is not None:
        if record is None:
            raise ValueError(f"tuned = {tuned!r} for spec {spec!r}, which reads no tuned parameters; pass none")
        if not is_params(tuned):
            raise ValueError(f"tuned = {tuned!r} for spec {spec!r}: expected a mapping of names to numbers, as "
                             f"agents/tuned/{record}.yml's params")
    params = (lambda: dict(tuned)) if tuned is not None else (lambda: load_tuned(record)["params"])
    if key == "equal":
        return EqualSplitPolicy()
    if key.startswith("fixed:"):
        parts = key[len("fixed:"):].split(",")
        try:
            split = [float(p) for p in parts]
        except ValueError:
            raise ValueError(f"spec {spec!r}: 'fixed:' takes three numbers, e.g. 'fixed:0.2,0.2,0.6'") from None
        return FixedSplitPolicy(validate_split(split, f"spec {spec!r}"), name=key)
    task = record_task(s)
    if key == "margin":
        p = params()
        return MarginPolicy(p["m_ctrl"], p["m_comm"], p["sensing_floor"])
    if key.startswith("margin:"):
        parts = key[len("margin:"):].split(",")
        try:
            m_ctrl, m_comm = (float(p) for p in parts)
        except ValueError:
            raise ValueError(f"spec {spec!r}: 'margin:' takes two numbers m_ctrl,m_comm, e.g. 'margin:4,1.3'") from None
        return MarginPolicy(m_ctrl, m_comm, name=key)
    if key == "myopic":
        return _myopic(s, None if record is None else tuple(sorted(params().items())))
    if key in URBAN_SPECS and task != "urban":
        raise ValueError(f"spec {spec!r} plans over the urban task's data queue and preview; use it with the "
                         "'urban' scenario (iscc_gym/ISCC-Urban-v0)")
    if key == "dpp":
        return DriftPlusPenaltyPolicy(s, **params())
    if key.startswith("dpp:"):
        try:
            v = float(key[len("dpp:"):])
        except ValueError:
            raise ValueError(f"spec {spec!r}: 'dpp:' takes one number V > 0, e.g. 'dpp:2'") from None
        return DriftPlusPenaltyPolicy(s, v=v)
    if key in ("mpc", "mpc-hold", "oracle"):  # one planner, its tuned parameters
        p = params()
        if key == "mpc":
            return LookaheadPolicy(s, **p)
        if key == "mpc-hold":
            return LookaheadPolicy(s, preview="hold", name="mpc-hold", **p)
        return LookaheadPolicy(s, preview="truth", name="oracle", **p)
    if key == "bayes":  # the field task's Bayesian filter of the world on its prior, tuned there (python -m eval.tune)
        from .bayes import BayesPolicy

        return BayesPolicy(s, **params())
    if key == "bayes-learn":  # the same filter re-estimating its prior's moments online (empirical Bayes)
        from .bayes import BayesPolicy

        return BayesPolicy(s, learn_prior=True, **params())
    if key.startswith("estimator:"):  # bayes's design on a learned estimator of the world (RMA-style)
        from .estimator import EstimatorPolicy

        return EstimatorPolicy(s, path=spec.strip()[len("estimator:"):], **params())
    if key.startswith("student:"):  # a recurrent student of aware under DAgger
        from .student import StudentPolicy

        return StudentPolicy(s, path=spec.strip()[len("student:"):])
    if key == "adaptive":  # the field task's estimator memory, tuned there (python -m eval.tune adaptive)
        from .adaptive import AdaptivePolicy

        return AdaptivePolicy(s, **params())
    if key == "sca":
        return SCAPolicy(s, mode="static")
    if key == "sca-per-slot":
        return SCAPolicy(s, mode="per_slot", loss_design_fraction=float(params()["loss_design_fraction"]))
    if key == "sca-ignore-loss":
        return SCAPolicy(s, mode="static", ignore_loss=True)
    if key == "grid":
        return _searched(s, "grid", 0)
    if key == "evolutionary":
        return _searched(s, "evolutionary", seed)
    import difflib

    near = difflib.get_close_matches(key, [p.split(":")[0] for p in POLICY_SPECS], n=1, cutoff=0.6)
    raise ValueError(f"unknown policy spec {spec!r}" + (f" (did you mean {near[0]!r}?)" if near else "")
                     + f"; valid specs: {list(POLICY_SPECS)}")


@functools.lru_cache(maxsize=16)
def _searched(s: Scenario, method: str, seed: int) -> FixedSplitPolicy:
    """The policy of a search (deterministic, so cached per scenario, method and seed)."""
    from .base import FixedSplitPolicy
    from .search import evolutionary_search, grid_search

    res = grid_search(s) if method == "grid" else evolutionary_search(s, seed=seed)
    return FixedSplitPolicy(res.alpha, name=method)


@functools.lru_cache(maxsize=4)
def _myopic(s: Scenario, params: tuple | None) -> MyopicPolicy:
    """The myopic policy of a scenario (stateless; its tables are built once, so cached); on the urban task its
    data weight is the one tuned there (the queue's greedy price, ``myopic-urban``), ``params`` (its items).
    """
    from .myopic import MyopicPolicy

    return MyopicPolicy(s) if params is None else MyopicPolicy(s, **dict(params))
