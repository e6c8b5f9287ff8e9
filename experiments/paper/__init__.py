"""The paper's reproduction: ``python -m experiments.paper.reproduce`` and the studies it gathers.

``reproduce`` (the model-level targets, calibration, the scheme level and the claims table; ``reproduce_docs``
writes its sections), ``paper_figures`` (the paper's Figs. 3-8 redrawn, ``paper_figures_draw``; Monte Carlo in
``paper_mc``), ``schemes`` (Table II and Fig. 9), ``evaluator_check`` (the steady-state evaluator against the env),
``fading`` (the stability threshold under fading, the evaluator's trust bound; ``fading_draw``) and
``sensitivity`` (the paper's constants varied). The comparison of policies is the installed ``iscc_gym.eval``.
"""
