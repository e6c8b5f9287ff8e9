r"""An actor-critic whose critic is shown the world and whose actor is not (asymmetric actor-critic).

Pinto et al. (arXiv 1710.06542) train the value function on the simulator's full state while the policy reads only
what it will read when deployed. ``python -m train --critic world`` (PPO on the field task) builds the env with the
world block shown (the slot's true K-factor and RCS offset, the observation's last entries) and plays
:class:`WorldCriticPolicy`: SB3's ``ActorCriticPolicy`` with separate feature extractors, the actor's
(:class:`HideWorld`) setting the world block to zero, the critic's the plain flattening. The actor's first layer
therefore never sees the world: its weights on those inputs receive no gradient and multiply zeros, so its action
is the same whatever the block holds (``tests/training/test_privileged.py`` scrambles it).

Deployed, the agent reads the observation without the world block: :class:`agents.sb3_policy.SB3Policy` reports
the observation shape the env gives and pads the block with zeros (:attr:`WorldCriticPolicy.world_entries`).
"""

from __future__ import annotations

import torch
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import FlattenExtractor

__all__ = ["HideWorld", "WorldCriticPolicy"]


class HideWorld(FlattenExtractor):
    """SB3's flattening with the observation's last ``world_entries`` entries set to zero."""

    def __init__(self, observation_space, world_entries: int):
        super().__init__(observation_space)
        mask = torch.ones(self.features_dim)
        mask[self.features_dim - int(world_entries):] = 0.0
        self.register_buffer("mask", mask)

    def forward(self, observations: torch.Tensor) -> torch.Tensor:
        return super().forward(observations) * self.mask


class WorldCriticPolicy(ActorCriticPolicy):
    """SB3's ``ActorCriticPolicy`` (an MLP; ``policy_kwargs`` as PPO's) whose actor does not see the last
    ``world_entries`` observation entries and whose critic does (module docstring).
    """

    def __init__(self, observation_space, action_space, lr_schedule, world_entries: int = 2, **kwargs):
        kwargs["share_features_extractor"] = False
        if not 0 < int(world_entries) < observation_space.shape[0]:
            raise ValueError(f"world_entries = {world_entries!r}: must hide some but not all of the "
                             f"{observation_space.shape[0]} observation entries")
        self.world_entries = int(world_entries)
        super().__init__(observation_space, action_space, lr_schedule, **kwargs)

    def _build(self, lr_schedule) -> None:
        # the actor's extractor hides the world; it holds no parameters, so the optimiser _build makes is unchanged
        self.pi_features_extractor = HideWorld(self.observation_space, self.world_entries)
        super()._build(lr_schedule)

    def _get_constructor_parameters(self) -> dict:
        return {**super()._get_constructor_parameters(), "world_entries": self.world_entries}
