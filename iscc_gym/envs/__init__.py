"""The faces users meet: the Gymnasium envs (``env``: ``iscc_gym/ISCC-v0``; ``vector``: its native batched
vector env; ``multi``: ``iscc_gym/ISCC-Multi-v0``), the PettingZoo view (``multi_pz``), the safety wrapper
(``wrappers``) and the renderer (``render``). Thin stateful shells around :mod:`iscc_gym.sim`.
"""

from iscc_gym.lazy import lazy_names as _lazy_names

# a submodule on first use (iscc_gym.envs.<module> after import iscc_gym, as when iscc_gym imported the env eagerly)
__getattr__, __dir__ = _lazy_names(__name__, {}, globals())
