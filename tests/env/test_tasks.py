"""The task table (issue 35 point 1): each env id's settings written once and read by every command."""

import gymnasium as gym
import pytest
from iscc_gym.agents.tasks import SHIPPED_AGENTS, TASK_POLICIES, task_policies

import iscc_gym
from iscc_gym.scenario import SCENARIOS
from iscc_gym.tasks import TASKS, URBAN_ENV_ID, Task, Variant, get_task, variant_scenario


@pytest.mark.parametrize("env_id", list(TASKS))
def test_every_task_is_registered_as_its_entry_says(env_id):
    task, spec = TASKS[env_id], gym.spec(env_id)
    assert (spec.entry_point, spec.vector_entry_point) == (task.entry_point, task.vector_entry_point)
    assert spec.max_episode_steps == task.max_episode_steps == SCENARIOS[task.preset].n_slots
    assert dict(spec.kwargs or {}) == task.kwargs
    assert iscc_gym.envs.env.registered_scenario(env_id) == task.preset


@pytest.mark.parametrize("env_id", list(TASKS))
def test_every_task_has_its_policies_and_every_variant_is_a_valid_scenario(env_id):
    pol = task_policies(env_id)
    assert pol.task is TASKS[env_id]
    names = pol.policies.split(",")
    assert pol.reference in names and set(pol.scripted) <= set(names) | {"dpp", "mpc"}
    for name in TASKS[env_id].variants:
        assert variant_scenario(env_id, name).n_slots > 0
    if pol.ships_agent:
        assert SHIPPED_AGENTS[env_id] == pol.shipped_agent() and (pol.shipped_agent() / "model.zip").is_file()


def test_a_task_refuses_an_unknown_preset_a_shift_outside_its_variants_and_an_unknown_id():
    with pytest.raises(ValueError, match="preset 'nope'"):
        Task("x/Y-v0", "nope", "a:B", "a:C", "t", "p")
    with pytest.raises(ValueError, match=r"shifts \['b'\]"):
        Task("x/Y-v0", "paper", "a:B", "a:C", "t", "p", {"a": Variant({}, "why")}, shifts=("b",))
    with pytest.raises(ValueError, match="not a registered env id; use one of iscc_gym/ISCC-v0"):
        get_task("iscc_gym/ISCC-v9")
    with pytest.raises(ValueError, match="variant 'nope' is not one of iscc_gym/ISCC-Urban-v0's"):
        variant_scenario(URBAN_ENV_ID, "nope")
    with pytest.raises(TypeError):
        TASKS[URBAN_ENV_ID].variants["new"] = Variant({}, "x")  # read-only


def test_every_command_reads_the_tasks_reference_and_shifts_from_the_table():
    """The urban task's reference was myopic in python -m eval and mpc in python -m experiments.seeds (issue 35)."""
    from iscc_gym.eval.__main__ import build_parser
    from iscc_gym.train.config import randomize_sets

    from experiments.seeds import build_parser as seeds_parser
    from experiments.urban_shift import SHIFTS

    urban = TASK_POLICIES[URBAN_ENV_ID]
    assert f"reference {urban.reference}" in " ".join(build_parser().format_help().split())
    assert f"(minus {urban.reference})" in " ".join(seeds_parser().format_help().split())
    assert list(SHIFTS) == list(TASKS[URBAN_ENV_ID].shifts)
    assert randomize_sets()["urban-shifts"] == (URBAN_ENV_ID, TASKS[URBAN_ENV_ID].shift_overrides())
    assert list(randomize_sets()["urban-shifts"][1]) == [s for s in TASKS[URBAN_ENV_ID].shifts if s != "none"]


def test_a_task_added_at_run_time_is_played_by_python_m_eval(capsys):
    """Issue 44 (first part): a task is one Task of both sides as data; one registered at run time
    (``iscc_gym.register_task``) is made by Gymnasium and compared by ``python -m eval`` with no other edit."""
    import gymnasium as gym
    from iscc_gym.agents.tasks import task_policies
    from iscc_gym.eval.__main__ import main as eval_main

    import iscc_gym
    from iscc_gym.tasks import TASKS, Task

    toy = Task("iscc_gym/ISCC-Toy-v0", "literal", "iscc_gym.envs.env:ISCCEnv", "iscc_gym.envs.vector:ISCCVectorEnv",
               "a toy task: the paper's loop on the literal preset", "tasks/paper", policies="myopic,margin,equal",
               reference="myopic", scripted=("myopic", "margin"), results_section="toy", results_title="Toy")
    try:
        iscc_gym.register_task(toy)
        assert iscc_gym.register_task(toy) is toy  # once
        env = gym.make(toy.env_id)
        assert env.unwrapped.scenario.snr_convention == iscc_gym.make_scenario("literal").snr_convention
        pol = task_policies(toy.env_id)
        assert pol.policies == "myopic,margin,equal" and pol.agent is None and not pol.fleet
        res = eval_main(["--env", toy.env_id, "--episodes", "1", "--max-steps", "2", "--workers", "1"])
        assert list(res["policies"]) == ["myopic", "margin", "equal"] and res["reference"] == "myopic"
        with pytest.raises(ValueError, match="another task's already"):
            iscc_gym.register_task(Task(toy.env_id, "paper", toy.entry_point, toy.vector_entry_point, "other", "x"))
    finally:
        TASKS.pop(toy.env_id, None)
        gym.registry.pop(toy.env_id, None)


def test_every_grid_tuned_baseline_is_tuned_on_the_task_whose_file_names_it():
    """Issue 44: eval.tune's policy -> task table came from the task files (``Task.tuned``), not a list by hand."""
    from iscc_gym.eval.tune import MODEL_GRIDS, MODEL_TASKS

    assert set(MODEL_TASKS) == set(MODEL_GRIDS)
    assert MODEL_TASKS == {"myopic": "urban", "dpp": "urban", "mpc": "urban", "adaptive": "field", "bayes": "field"}
