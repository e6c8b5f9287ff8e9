"""Command tooling, installed as ``iscc_gym.commands``: what every ``python -m`` command shares and the core
library never needs. :mod:`~iscc_gym.commands.cli` (the one convention for ending: exit codes, SIGTERM),
:mod:`~iscc_gym.commands.options` (the parser, checked numbers, seeds, paths and progress bars),
:mod:`~iscc_gym.commands.protocol` (the experiment protocol: seed ranges, study constants) and
:mod:`~iscc_gym.commands.docs` (the generated sections of this repository's docs, written by ``experiments`` only).

It sits above the core (``iscc_gym``) and ``agents``, below ``train``, ``eval`` and ``experiments``.
"""
