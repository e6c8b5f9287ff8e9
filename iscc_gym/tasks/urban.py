"""The urban task, ``iscc_gym/ISCC-Urban-v0`` (issue 25): a low-altitude urban flight with blocked line of sight, a
map preview and a data queue (preset ``urban``, a 1,200-slot mission).

Its env side (preset, entry points, shifted missions and levers) and its policy side (the comparison, the
reference, the shipped agent, its docs sections), as data.
"""

from __future__ import annotations

from iscc_gym.tasks.task import Task, Variant

__all__ = ["URBAN_ENV_ID", "URBAN_VARIANTS", "TASK"]

#: The urban task (issue 25): the ``urban`` preset, a 1,200-slot mission.
URBAN_ENV_ID = "iscc_gym/ISCC-Urban-v0"

_MAP_ERROR = {"map_error_std": 0.8}

#: The urban task's variants: the shifted missions (``none`` .. ``map error 0.8``) and the levers of
#: ``experiments/urban_levers.py`` (``urban`` .. ``umi_av``: a change of the blockage statistics, the data's deadline,
#: rate or weight, the map's error).
URBAN_VARIANTS: dict[str, Variant] = {
    "none": Variant({}, "the preset's missions (UMa-AV, 30-60 m, 5 Mbit/s within 1 s, map error 0.4)"),
    "umi_av": Variant({"blockage": "umi_av"}, "TR 36.777 UMi-AV instead of UMa-AV: more of the path blocked"),
    "altitude 60-100 m": Variant({"altitude_min_m": 60.0, "altitude_max_m": 100.0},
                                 "higher flights (UMa-AV's LoS probability rises with height)"),
    "10 Mbit/s within 2 s": Variant({"queue_arrival_bps": 10e6, "queue_deadline_s": 2.0},
                                    "twice the data, twice the deadline"),
    "map error 0.8": Variant(_MAP_ERROR, "the channel map's error doubled"),
    "urban": Variant({}, "the preset (TR 38.901's exponential LoS field, 1 s deadline, 5 Mbit/s, w_rate 1)"),
    "smooth": Variant({"los_field_kernel": "gaussian"},
                      "smooth LoS field, the same 50 m correlation distance: building-scale blocked stretches"),
    "smooth w_rate=5": Variant({"los_field_kernel": "gaussian", "w_rate": 5.0},
                               "a dropped slot of data costs 5 m-slots of tracking error"),
    "smooth deadline=3s": Variant({"los_field_kernel": "gaussian", "queue_deadline_s": 3.0},
                                  "a buffered video stream's latency budget"),
    "smooth 15Mbps": Variant({"los_field_kernel": "gaussian", "queue_arrival_bps": 15e6}, "a 4K video downlink"),
    "w_rate=5": Variant({"w_rate": 5.0}, "the preset, data worth 5x"),
    "map_error=0.8": Variant(_MAP_ERROR, "a coarse map (correlation 0.6 with the truth)"),
    "smooth 40Mbps deadline=5s": Variant(
        {"los_field_kernel": "gaussian", "queue_arrival_bps": 40e6, "queue_deadline_s": 5.0},
        "data scarce while the link is clear (about 3/4 of a clear link's capacity), a 5 s buffer"),
    "calm smooth 20Mbps deadline=3s": Variant(
        {"process_noise_pos": 0.005, "process_noise_vel": 0.05, "los_field_kernel": "gaussian",
         "queue_arrival_bps": 20e6, "queue_deadline_s": 3.0},
        "light wind: process noise 5 mm and 0.05 m/s per slot (the diagonal of a white-noise acceleration model, "
        "0.5-1 m/s^2), so that tracking depends on sensing while the link is clear; the paper's R_min 20 Mbit/s, a "
        "3 s buffer"),
}

# the shipped agent, the per-slot rules, the queue's drift-plus-penalty, the look-ahead planner and its oracle bound;
# myopic, the model's per-slot optimum, is the reference (mpc is within noise of it)
TASK = Task(URBAN_ENV_ID, "urban", "iscc_gym.envs.env:ISCCEnv", "iscc_gym.envs.vector:ISCCVectorEnv",
            "a low-altitude urban flight: blocked line of sight, a map preview, a data queue with a deadline",
            "tasks/urban", URBAN_VARIANTS,
            shifts=("none", "umi_av", "altitude 60-100 m", "10 Mbit/s within 2 s", "map error 0.8"),
            policies="ppo,myopic,margin,dpp,mpc,oracle", reference="myopic",
            scripted=("myopic", "margin", "dpp", "mpc"), results_section="urban-comparison",
            results_title="The urban task: the learned agent, look-ahead and per-slot policies", agent="ppo_urban",
            agent_docs=("urban-agent", "The shipped PPO agent of the urban task", "ppo_urban_learning_curve.png"),
            seeds_docs=("urban-seeds", "The urban task's shipped configuration over 5 training seeds"),
            tuned=("myopic", "dpp", "mpc"))
