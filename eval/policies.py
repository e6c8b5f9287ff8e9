"""Policies of ``python -m eval`` from their specs, and playing them in worker processes.

Lives apart from ``eval/__main__.py`` so that spawned worker processes can import what they run.
"""

from __future__ import annotations

from iscc_gym.eval.evaluate import run_episodes

__all__ = ["build_policy", "build_policies", "run_parallel", "SLOW_SPECS"]


def build_policy(item: str, scenario: str = "paper"):
    """``(name, policy)`` of one ``NAME=PATH`` (a trained agent) or :func:`agents.make_policy` spec."""
    from iscc_gym.agents import make_policy

    if "=" in item:
        name, path = item.split("=", 1)
        from iscc_gym.agents.sb3_policy import SB3Policy

        return name, SB3Policy.load(path)
    return item, make_policy(item, scenario)


def build_policies(specs: str, scenario: str = "paper") -> dict:
    """``{name: policy}`` from a comma-separated list of ``NAME=PATH`` or make_policy specs."""
    items = _items(specs)
    return dict(build_policy(item, scenario) for item in items)


def _items(specs: str) -> list[str]:
    items = [p.strip() for p in _split_specs(specs) if p.strip()]
    if not items:
        raise ValueError("--policies is empty; e.g. --policies sca,equal")
    return items


#: Specs whose evaluation takes longest (an optimisation every slot): started first by the workers.
SLOW_SPECS = ("sca-per-slot", "myopic", "grid", "evolutionary")


def _worker_init(torch_threads: int) -> None:
    """A worker process: one numba thread (the workers already use the cores) and ``torch_threads``."""
    import numba

    numba.set_num_threads(1)
    if torch_threads:
        import torch

        torch.set_num_threads(torch_threads)


def _run_item(item: str, seeds, scenario: str, max_steps, record: int):
    name, policy = build_policy(item, scenario)
    return name, run_episodes(policy, seeds, scenario, max_steps, record)


def run_parallel(specs: str, seeds, scenario: str = "paper", max_steps=None, record: int = 0, workers: int = 2,
                 torch_threads: int = 1) -> dict:
    """``{name: run_episodes result}`` of every policy of ``specs``, in ``workers`` processes (spawned,
    one numba thread each); every policy plays the same seeds, so the results are those of one process."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    items = _items(specs)
    order = sorted(range(len(items)), key=lambda i: items[i].split("=")[0] not in SLOW_SPECS)
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_worker_init,
                             initargs=(torch_threads,)) as pool:
        futures = {i: pool.submit(_run_item, items[i], list(seeds), scenario, max_steps, record) for i in order}
        results = [futures[i].result() for i in range(len(items))]
    names = [n for n, _ in results]
    if len(set(names)) != len(names):
        raise ValueError(f"--policies names a policy twice: {names}")
    return dict(results)


def _split_specs(specs: str) -> list[str]:
    """Split on commas, except inside ``fixed:a,b,c`` and ``margin:a,b``."""
    out, parts = [], specs.split(",")
    i = 0
    while i < len(parts):
        p = parts[i]
        width = 3 if p.strip().startswith("fixed:") else 2 if p.strip().startswith("margin:") else 1
        out.append(",".join(parts[i:i + width]))
        i += width
    return out


