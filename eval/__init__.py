"""Evaluation commands: ``python -m eval`` (the repository's ``eval/`` folder, installed as ``iscc_gym.eval`` by
``pyproject.toml``'s ``package-dir``; it imports the core and ``agents``, never ``train``: training runs through
the command line, :mod:`iscc_gym.eval.training`).

The comparison engine (``engine``: policies x mission variants x seeds on a task of the task table), its rollout
loop, tables and confidence intervals (``evaluate``), the policy factory and worker pool (``policies``), the command
line (``__main__``), tuning (``tune``), the outage search (``outage``), the multi-drone comparison (``multi``) and
the benchmark (``bench``): what a user runs on an installed copy. The studies that regenerate this repository's
docs (the paper's reproduction, the seeds, probes, Pareto and urban studies) are the checkout's ``experiments/``,
not installed.
"""
