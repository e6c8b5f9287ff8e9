"""The studies that regenerate this repository's docs, run from a checkout (``python -m experiments.<name>``); not
installed. ``experiments/README.md`` lists every section of ``docs/results.md`` with the command that writes it.
"""
