"""Evaluation commands: ``python -m eval`` (the repository's ``eval/`` folder, installed as ``iscc_gym.eval`` by
``pyproject.toml``'s ``package-dir``; it imports the core and ``agents``, never ``train``: training runs through
the command line, :mod:`iscc_gym.eval.training`).

The comparison of policies on common random numbers (``__main__``, ``evaluate``, ``policies``), tuning
(``tune``), the studies (``seeds``, ``outage``, ``pareto``, ``multi``, ``probes``), the benchmark (``bench``) and
the paper's reproduction (:mod:`iscc_gym.eval.paper`).
"""
