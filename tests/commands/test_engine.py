"""The comparison engine (issue 35 point 2): policies x variants x seeds, one rollout loop, common random numbers."""

import numpy as np
import pytest
from iscc_gym.eval.__main__ import main as eval_main
from iscc_gym.eval.engine import compare, worlds

from iscc_gym.tasks import ENV_ID, URBAN_ENV_ID

SEEDS = [10000, 10001]


def test_variants_change_the_missions_only():
    kw = dict(seeds=SEEDS, max_steps=6)
    one = compare(URBAN_ENV_ID, "myopic,margin", variants=["none", "umi_av"], **kw)
    plain = compare(URBAN_ENV_ID, "myopic,margin", **kw)
    assert list(one) == ["none", "umi_av"] and list(plain) == ["urban"]
    # "none" is the preset's own missions: the same numbers as without variants; umi_av's differ
    assert one["none"]["policies"]["margin"]["episodes"] == plain["urban"]["policies"]["margin"]["episodes"]
    assert one["umi_av"]["policies"]["margin"]["episodes"] != one["none"]["policies"]["margin"]["episodes"]
    # the task's reference (myopic) is paired with every other policy on every variant
    assert one["umi_av"]["reference"] == "myopic" and set(one["umi_av"]["paired"]) == {"margin_vs_myopic"}


@pytest.mark.slow
def test_every_process_count_gives_one_result():
    """Two worker processes (spawned, each importing the engine) play the serial run's episodes."""
    kw = dict(seeds=SEEDS, max_steps=6, variants=["none", "umi_av"])
    one = compare(URBAN_ENV_ID, "myopic,margin", **kw)
    two = compare(URBAN_ENV_ID, "myopic,margin", workers=2, **kw)
    assert list(two) == list(one) == ["none", "umi_av"]
    for name in one:
        for pol in ("myopic", "margin"):
            assert one[name]["policies"][pol]["episodes"] == two[name]["policies"][pol]["episodes"]


def test_worlds_are_the_tasks_variants_and_unknown_names_are_refused():
    assert list(worlds(URBAN_ENV_ID, "shifts")) == ["none", "umi_av", "altitude 60-100 m", "10 Mbit/s within 2 s",
                                                    "map error 0.8"]
    assert worlds(URBAN_ENV_ID, ["umi_av"])["umi_av"].blockage == "umi_av"
    assert list(worlds(ENV_ID, None, "literal")) == ["literal"]
    with pytest.raises(ValueError, match="variant 'nope' is not one of iscc_gym/ISCC-Urban-v0's"):
        worlds(URBAN_ENV_ID, "umi_av,nope")
    with pytest.raises(ValueError, match="variant 'umi_av' is not one of iscc_gym/ISCC-v0's: rcs -10 dB"):
        worlds(ENV_ID, "umi_av")
    with pytest.raises(ValueError, match="--reference 'sca' is not one of the policies played"):
        compare(URBAN_ENV_ID, "myopic", SEEDS, reference="sca")


def test_the_command_line_plays_variants_and_seed_runs_and_refuses_what_it_cannot_write(tmp_path, capsys):
    res = eval_main(["--env", URBAN_ENV_ID, "--policies", "myopic,margin", "--variants", "none,umi_av",
                     "--episodes", "2", "--max-steps", "5", "--workers", "1", "--quiet"])
    out = capsys.readouterr().out
    assert list(res) == ["none", "umi_av"] and "missions: umi_av (TR 36.777 UMi-AV" in out
    assert "x 2 variants" in out
    np.testing.assert_array_equal(res["umi_av"]["policies"]["myopic"]["episodes"]["reward"],
                                  compare(URBAN_ENV_ID, "myopic", SEEDS, variants=["umi_av"], max_steps=5)
                                  ["umi_av"]["policies"]["myopic"]["episodes"]["reward"])
    with pytest.raises(ValueError, match="--variants compares on several"):
        eval_main(["--env", URBAN_ENV_ID, "--policies", "myopic", "--variants", "umi_av", "--plots", str(tmp_path)])
    with pytest.raises(FileNotFoundError, match="no seed_<s>/model.zip under .*python -m train --seeds"):
        eval_main(["--policies", "myopic", "--runs", str(tmp_path)])


def test_aware_is_myopic_designed_on_the_world_and_equals_it_where_the_world_is_the_model(monkeypatch):
    """Issue 36's model-knowledge bound: ``aware`` (``myopic@world``) is built on each variant's world, ``myopic`` on
    the task's preset. On the preset's own missions the two are one policy (every episode equal); where the world
    differs, aware's model is the world's."""
    from iscc_gym import agents

    built = []
    real = agents.make_policy

    def spy(spec, scenario="paper", **kw):
        built.append((spec, scenario if isinstance(scenario, str) else scenario.rcs_m2))
        return real(spec, scenario, **kw)

    monkeypatch.setattr(agents, "make_policy", spy)
    res = compare(ENV_ID, "myopic,aware,margin@world", SEEDS, scenario="paper", max_steps=8, reference="myopic")
    eps = res["paper"]["policies"]
    assert eps["aware"]["episodes"] == eps["myopic"]["episodes"]  # designed on the world that is the model
    res = compare(ENV_ID, "myopic,aware", SEEDS, variants=["rcs -10 dB"], max_steps=8, reference="myopic")
    assert ("myopic", 0.001) in built and ("myopic", "paper") in built  # aware knew the RCS, myopic the model's
    assert res["rcs -10 dB"]["policies"]["aware"]["episodes"] != res["rcs -10 dB"]["policies"]["myopic"]["episodes"]
    with pytest.raises(ValueError, match="unknown policy spec|not a policy spec|spec"):
        compare(ENV_ID, "nope@world", SEEDS, max_steps=2)


def test_the_field_task_prints_its_ladder_with_the_share_of_the_gap(capsys):
    """python -m eval --env iscc_gym/ISCC-Field-v0: the task's ladder, every difference against myopic, and the
    share of aware's gain each causal rung and the agent close (Task.share_of), with its interval."""
    from iscc_gym.tasks import FIELD_ENV_ID

    res = eval_main(["--env", FIELD_ENV_ID, "--episodes", "3", "--max-steps", "8", "--workers", "1"])
    out = capsys.readouterr().out
    assert list(res["policies"]) == ["ppo", "myopic", "margin", "sca", "adaptive", "bayes", "aware"]
    assert set(res["paired"]) == {f"{p}_vs_myopic" for p in ("ppo", "margin", "sca", "adaptive", "bayes", "aware")}
    assert list(res["oracle_shares"]) == ["adaptive", "bayes", "ppo"]
    share = res["oracle_share"]
    assert share["oracle"] == "aware" and share["share_ci95"] is None  # 3 missions: no resampled interval
    for rung in ("adaptive", "bayes", "ppo"):
        assert f"Share of the aware's gain over myopic that {rung} recovers" in out
    with pytest.raises(ValueError, match="use one of"):
        eval_main(["--env", "iscc_gym/ISCC-Nope-v0"])


def test_a_bare_ppo_where_no_agent_ships_names_the_fix():
    from iscc_gym.eval.policies import resolve_specs

    with pytest.raises(ValueError, match="ships no agent; name a trained one, ppo=RUN_DIR"):
        resolve_specs("myopic,ppo", None)
    assert resolve_specs("myopic,ppo=runs/x", None) == ["myopic", "ppo=runs/x"]


def test_aware_where_the_world_is_the_model_says_it_plays_as_myopic(capsys):
    """Issue 43.12: ``aware`` on a task without a hidden world played ``myopic`` without a note."""
    from iscc_gym.eval.__main__ import main as eval_main

    res = eval_main(["--policies", "myopic,aware", "--episodes", "1", "--max-steps", "2", "--workers", "1"])
    out = capsys.readouterr().out
    assert "note: aware is myopic designed on the world played" in out and "it plays as myopic" in out
    assert res["notes"] and res["policies"]["aware"]["episodes"]["reward"] == res["policies"]["myopic"]["episodes"][
        "reward"]
    shifted = compare(ENV_ID, "myopic,aware", SEEDS[:1], variants=["rcs -10 dB"], max_steps=2)
    assert "notes" not in shifted["rcs -10 dB"]  # a variant's world is not the model: aware is the bound there


def test_the_engine_retunes_a_policy_per_variant_on_training_missions_and_traces_info_keys():
    """Issue 44 point 3: what experiments.urban_levers did by hand (each variant's myopic tuned on its own training
    missions, the planners sharing one tuning) is the engine's ``retune``; ``trace_info`` records a figure's keys."""
    from iscc_gym.eval.tune import tune_model_grid

    from iscc_gym.tasks import variant_scenario

    grid = {"rate_weight": (0.3, 3.0)}
    plan = {"rate_weight": 0.3, "holding_cost": 0.2, "deadline_margin": 0.0}
    tune = [500000, 500001]
    res = compare(URBAN_ENV_ID, ["myopic@world", "mpc@world", "oracle@world"], SEEDS[:2], variants=["umi_av"],
                  max_steps=5, record=1, trace_info=("bits_dropped",), tune_seeds=tune,
                  retune={"myopic@world": grid, "mpc@world": lambda w: {k: (v,) for k, v in plan.items()},
                          "oracle@world": "mpc@world"})["umi_av"]
    direct = tune_model_grid("myopic", tune, variant_scenario(URBAN_ENV_ID, "umi_av"), log=lambda *_: None,
                             max_steps=5, grid=grid)["params"]
    assert res["tuned"]["myopic@world"] == direct
    assert res["tuned"]["oracle@world"] == res["tuned"]["mpc@world"] == plan
    assert res["traces"]["myopic@world"]["bits_dropped"].shape[0] == 5
    with pytest.raises(ValueError, match=r"retune: \['dpp'\] are not among the policies played"):
        compare(URBAN_ENV_ID, ["myopic"], SEEDS[:1], max_steps=2, retune={"dpp": grid}, tune_seeds=tune)
    with pytest.raises(ValueError, match="retune needs tune_seeds"):
        compare(URBAN_ENV_ID, ["myopic"], SEEDS[:1], max_steps=2, retune={"myopic": grid})
    with pytest.raises(ValueError, match="'margin' is not tuned on a grid"):
        compare(URBAN_ENV_ID, ["margin"], SEEDS[:1], max_steps=2, retune={"margin": grid}, tune_seeds=tune)


def test_the_engine_serves_the_fleet_task():
    """Issue 44 point 3: the fleet task's comparison is the engine's (eval.multi's is a command line over it)."""
    from iscc_gym import MULTI_ENV_ID

    res = compare(MULTI_ENV_ID, ["joint-sca", "margin"], SEEDS[:2], max_steps=3, n_drones=2)["paper"]
    assert list(res["policies"]) == ["joint-sca", "margin"] and res["reference"] == "joint-sca"
    assert "margin_vs_joint-sca" in res["paired"]
    with pytest.raises(ValueError, match="policy 'myopic': use NAME=PATH"):
        compare(MULTI_ENV_ID, ["myopic"], SEEDS[:1], max_steps=2, n_drones=2)
    with pytest.raises(ValueError, match="n_drones = 2: iscc_gym/ISCC-Urban-v0 flies one drone"):
        compare(URBAN_ENV_ID, ["myopic"], SEEDS[:1], max_steps=2, n_drones=2)
