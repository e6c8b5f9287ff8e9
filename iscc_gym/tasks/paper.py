"""The paper's task, ``iscc_gym/ISCC-v0``: the closed loop of Li et al. as the paper gives it (preset ``paper``).

Its env side (preset, entry points, the worlds that differ from the paper's model) and its policy side (the
comparison, the reference, the shipped agent, its docs sections), as data. A task is this one file plus its physics.
"""

from __future__ import annotations

from iscc_gym.tasks.task import Task, Variant

__all__ = ["ENV_ID", "PAPER_VARIANTS", "TASK"]

#: The registered id of the paper's task.
ENV_ID = "iscc_gym/ISCC-v0"

#: Worlds that differ from the paper's model, which every scripted policy of the paper task is designed on (issue 36:
#: where learned allocation can earn its place): a constant offset each, the probe's starting point. ``python -m eval
#: --policies myopic,aware --variants ...`` plays ``myopic`` designed on the paper's model against ``aware``, ``myopic``
#: designed on the world (the model-knowledge bound).
PAPER_VARIANTS: dict[str, Variant] = {
    "rcs -10 dB": Variant({"rcs_m2": 0.001}, "the drone's radar cross section 10 dB below Table I's 0.01 m^2"),
    "rcs +10 dB": Variant({"rcs_m2": 0.1}, "the drone's radar cross section 10 dB above Table I's 0.01 m^2"),
    "noise x3": Variant({"process_noise_pos": 0.6, "process_noise_vel": 0.006},
                        "Table I's process noise tripled (a gustier flight)"),
    "noise x1/4": Variant({"process_noise_pos": 0.05, "process_noise_vel": 0.0005},
                          "Table I's process noise quartered (a calm flight)"),
    "link -6 dB": Variant({"comm_snr_offset_db": -10.2}, "the command and data link 6 dB below the calibrated budget "
                                                          "(antenna pattern, misalignment)"),
}

TASK = Task(ENV_ID, "paper", "iscc_gym.envs.env:ISCCEnv", "iscc_gym.envs.vector:ISCCVectorEnv",
            "the paper's closed loop: one drone, Rician LoS link, 500 s mission", "tasks/paper", PAPER_VARIANTS,
            policies="ppo,sca,sca-per-slot,margin,myopic,equal", reference="sca", scripted=("sca", "margin", "myopic"),
            results_section="comparison", results_title="Learned vs scripted allocation", agent="ppo_iscc",
            readme=True, agent_docs=("agent", "The shipped PPO agent", "ppo_learning_curve.png"),
            seeds_docs=("seeds", "The shipped configuration over 5 training seeds"))
