r"""``estimator:PATH``: the per-slot design of :mod:`agents.bayes` on a learned estimate of the world (RMA-style).

Kumar et al.'s rapid motor adaptation (arXiv 2107.04034) trains, in simulation, a module that reads the history of
what a deployed policy measures and regresses the world parameters only the simulator knows. Here the module is a
GRU over the measurements :class:`agents.bayes.BayesPolicy`'s filter reads (:data:`agents.bayes.ESTIMATOR_INPUTS`:
the link's last fading gain, the echo over its prediction, the distance flown), and it outputs a *distribution*:
a categorical law of this slot's K-factor on the filter's grid and one of the RCS offset on its grid (two heads,
trained by cross-entropy against the true values' two-hot bins, ``python -m train --learner estimator``:
:mod:`iscc_gym.train.estimator`). :class:`EstimatorPolicy` designs each slot on it exactly as ``bayes`` designs on its
posterior (the posterior-predictive fading law of the K head, the RCS head's mean inverse power): the only thing
that differs from ``bayes`` is where the law of the world comes from, a hand-derived likelihood and prior or
what the simulator taught. Stated approximation: the two heads are independent (the filter's posterior is joint).

The deployed estimator reads the observation's measured block, never the world block (it is trained from it); a
test feeds it observations whose world block is scrambled (``tests/agents/test_estimator.py``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from iscc_gym.scenario import Scenario

from .bayes import ESTIMATOR_INPUTS, BayesPolicy

__all__ = ["EstimatorPolicy", "RecurrentPolicy", "WorldEstimator", "recurrent_heads", "FILE", "load_estimator",
           "save_estimator", "require_torch"]

#: The file of a trained estimator in its run directory.
FILE = "estimator.pt"


def require_torch():
    try:
        import torch
    except ModuleNotFoundError:
        raise ModuleNotFoundError("a learned estimator needs torch: pip install 'iscc-gym[train]'", name="torch") \
            from None
    return torch


def recurrent_heads(n_inputs: int, heads: tuple[int, ...], hidden: int = 64):
    """A GRU cell of ``hidden`` units over ``n_inputs`` inputs a slot and linear heads of ``heads`` logits each (torch
    loads lazily). ``step(x, h)`` advances one slot: ``(*logits, h)``; a row whose first input (``new mission``)
    is 1 starts from a zero state.
    """
    torch = require_torch()

    class _Net(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.hidden = hidden
            self.cell = torch.nn.GRUCell(n_inputs, hidden)
            self.heads = torch.nn.ModuleList(torch.nn.Linear(hidden, n) for n in heads)

        def step(self, x, h):
            h = self.cell(x, h * (1.0 - x[:, :1]))
            return (*(head(h) for head in self.heads), h)

    return _Net()


def WorldEstimator(n_k: int, n_rcs: int, hidden: int = 64):  # noqa: N802  (a network factory: torch loads lazily)
    """The estimator network: :func:`recurrent_heads` over :data:`agents.bayes.ESTIMATOR_INPUTS`, the logits of the
    K-factor's ``n_k`` bins and of the RCS offset's ``n_rcs``.
    """
    return recurrent_heads(len(ESTIMATOR_INPUTS), (n_k, n_rcs), hidden)


def save_estimator(path, net, meta: dict) -> Path:
    """Write ``net``'s weights and ``meta`` (its kind, sizes, grids and the scenario it was trained on) to ``path``
    through a temporary name (an interrupted write leaves the previous file).
    """
    torch = require_torch()
    from iscc_gym.files import atomic_target

    with atomic_target(path) as tmp:
        torch.save({"state_dict": net.state_dict(), "meta": dict(meta)}, tmp)
    return Path(path)


def load_estimator(path, kind: str = "estimator"):
    """``(net, meta)`` of a learned file of ``kind`` (``estimator``: :data:`FILE`; ``student``:
    ``agents.student.FILE``) in a run directory, or the file; ``FileNotFoundError`` / ``ValueError`` naming the path
    and the fix.
    """
    torch = require_torch()
    name = FILE if kind == "estimator" else f"{kind}.pt"
    learner = "estimator" if kind == "estimator" else "dagger"
    p = Path(path).expanduser()
    f = p / name if p.is_dir() else p
    if not f.is_file():
        raise FileNotFoundError(f"{kind}:{path}: no {name} there; train one with python -m train --env "
                                f"iscc_gym/ISCC-Field-v0 --learner {learner} --out DIR")
    try:
        blob = torch.load(f, map_location="cpu", weights_only=True)
        meta = blob["meta"]
        if meta.get("kind", "estimator") != kind:
            raise ValueError(f"a {meta.get('kind')}, not a {kind}")
        heads = (len(meta["k_grid"]), len(meta["rcs_grid"])) if kind == "estimator" else (3,)
        net = recurrent_heads(int(meta["inputs"]), heads, int(meta["hidden"]))
        net.load_state_dict(blob["state_dict"])
    except Exception as e:  # noqa: BLE001  (a damaged or foreign file: one message)
        raise ValueError(f"{f}: not a file python -m train --learner {learner} wrote ({type(e).__name__}: {e}); "
                         "retrain it") from None
    net.eval()
    return net, meta


class RecurrentPolicy(BayesPolicy):
    """:class:`agents.bayes.BayesPolicy`'s measurements fed each slot to a recurrent network (:func:`recurrent_heads`,
    :attr:`net`), one state per env of the batch (a row at slot 0 starts from zero): the base of
    :class:`EstimatorPolicy` and :class:`agents.student.StudentPolicy`. The filter itself is not run.
    """

    def _restart(self, n: int) -> None:
        super()._restart(n)
        self._h = np.zeros((n, self.net.hidden), dtype=np.float32)

    def net_inputs(self, obs) -> np.ndarray:
        """The network's inputs this slot (n, F), float32: the measurements (:meth:`measured_inputs`)."""
        return self.measured_inputs()

    def advance(self, decoded: dict, obs=None) -> list[np.ndarray]:
        """Take in each row's measurements (``decoded``, the observations ``obs`` they were decoded from), advance
        the network one slot and return its heads' laws (softmax, float64 (n, m) each); the inputs are kept in
        :attr:`inputs`.
        """
        torch = require_torch()
        n = decoded["snr_db"].shape[0]
        if self._rows != n:
            self._restart(n)
        g, e_db, step, pos, echo_pred_db = self.measure(decoded)
        self.measured = (decoded["slot"] < 0.5, g, e_db, step)
        self.inputs = self.net_inputs(obs)
        with torch.no_grad():
            *logits, h = self.net.step(torch.from_numpy(self.inputs), torch.from_numpy(self._h))
            laws = [torch.softmax(x.double(), 1).numpy() for x in logits]
        self._h = h.numpy()
        self.remember(pos, echo_pred_db)
        return laws

    def __repr__(self) -> str:
        return f"{type(self).__name__}(path={self.path!r}, hidden={self.net.hidden})"


class EstimatorPolicy(RecurrentPolicy):
    """:class:`agents.bayes.BayesPolicy`'s design on a learned estimator's law of the world (module docstring).

    Parameters
    ----------
    scenario : Scenario or str
        The designer's model (the field task's): its grids must be the ones the estimator was trained on.
    path : str or Path
        A run directory of ``python -m train --learner estimator`` (or its :data:`FILE`).
    **kwargs
        :class:`agents.bayes.BayesPolicy`'s (its tuned ``correlation_scale`` scales the distance input as in
        training; ``echo_weight`` is unused).
    """

    def __init__(self, scenario: Scenario | str = "field", path: str | Path = "", **kwargs):
        net, meta = load_estimator(path)
        super().__init__(scenario, k_points=len(meta["k_grid"]), rcs_points=len(meta["rcs_grid"]), **kwargs)
        for name, grid in (("k_grid", self.k_grid), ("rcs_grid", self.rcs_grid)):
            if not np.allclose(grid, np.asarray(meta[name], dtype=float), rtol=0.0, atol=1e-9):
                raise ValueError(f"estimator:{path} was trained on another {name} (scenario {meta.get('scenario')!r})"
                                 f"; retrain it on this scenario's")
        self.net, self.meta = net, meta
        self.path = str(path)
        self.name = "estimator"

    def update(self, decoded: dict) -> None:
        """Advance the estimator one slot on each row's measurements; the posterior is its two heads' product."""
        pk, pr = self.advance(decoded)
        self.posterior = pk[:, :, None] * pr[:, None, :]
