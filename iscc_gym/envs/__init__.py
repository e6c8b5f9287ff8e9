"""The faces users meet: the Gymnasium envs (``env``: ``iscc_gym/ISCC-v0``; ``vector``: its native batched
vector env; ``multi``: ``iscc_gym/ISCC-Multi-v0``), the PettingZoo view (``multi_pz``), the safety wrapper
(``wrappers``) and the renderer (``render``). Thin stateful shells around :mod:`iscc_gym.sim`.
"""
