"""The eval commands as a user meets them: exit codes, one-line errors raised before any episode is played,
help for every flag, progress only on a terminal, --write-docs into the checkout only, atomic figures."""

import argparse
import io
import re
import subprocess
import sys
from pathlib import Path

import pytest
from iscc_gym.commands import docs
from iscc_gym.commands.options import parse_seeds, show_progress
from iscc_gym.eval import __main__ as cli
from iscc_gym.eval import bench, tune
from iscc_gym.eval.policies import SHIPPED_AGENT, check_specs, resolve_specs

from experiments import probes, seeds
from experiments.paper import evaluator_check, reproduce

ROOT = Path(__file__).resolve().parents[2]
PARSERS = {"eval": cli.build_parser, "reproduce": reproduce.build_parser, "seeds": seeds.build_parser,
           "tune": tune.build_parser, "probes": probes.build_parser, "bench": bench.build_parser,
           "evaluator_check": evaluator_check.build_parser}


@pytest.fixture
def no_episodes(monkeypatch):
    """Playing any episode fails the test: the error must come before the evaluation."""
    def played(*args, **kwargs):
        raise AssertionError("an evaluation ran before the mistake was reported")

    monkeypatch.setattr(cli, "evaluate", played)
    monkeypatch.setattr(cli, "run_parallel", played)


@pytest.mark.parametrize("command", sorted(PARSERS))
def test_every_flag_has_a_help_text(command):
    parser = PARSERS[command]()
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        assert action.help and action.help != argparse.SUPPRESS and len(action.help) > 10, (command, action.dest)


@pytest.mark.parametrize("command", ["eval", "seeds"])
def test_help_says_model_files_are_pickles(command):
    text = " ".join(PARSERS[command]().format_help().split())
    assert "vecnormalize.pkl" in text and "pickles" in text and "trust" in text


def test_output_paths_are_checked_before_any_episode(tmp_path, no_episodes):
    a_file = tmp_path / "file.txt"
    a_file.write_text("x")
    base = ["--policies", "sca,equal", "--episodes", "2", "--max-steps", "5", "--quiet"]
    with pytest.raises(OSError, match="--json"):
        cli.main([*base, "--json", str(a_file / "out.json")])
    with pytest.raises(OSError, match="--json .*directory"):
        cli.main([*base, "--json", str(tmp_path)])
    with pytest.raises(OSError, match="--plots .*not a directory"):
        cli.main([*base, "--plots", str(a_file)])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file.txt"]  # nothing created


@pytest.mark.parametrize(("args", "match"), [
    (["--policies", "sca,sca"], "'sca' twice"),
    (["--policies", f"ppo,ppo={SHIPPED_AGENT}"], "'ppo' twice"),
    (["--seeds", "5,5"], "seed 5 is given twice"),
    (["--seeds", "5,x"], "comma-separated integers"),
    (["--seeds", "-1"], "negative"),
    (["--policies", "sca,equal", "--reference", "margin"], "--reference 'margin'"),
    (["--policies", "ppo=/no/such/run"], "no trained agent"),
    (["--policies", "bogus"], "no such policy"),
    (["--policies", "fixed:0.5,0.5,0.5"], "fixed:0.5,0.5,0.5"),
    (["--scenario", "nope"], "--scenario 'nope'"),
])
def test_user_mistakes_are_one_line_errors_before_any_episode(args, match, no_episodes, capsys):
    with pytest.raises((ValueError, OSError), match=match):
        cli.main([*args, "--max-steps", "5", "--quiet"])
    assert cli.console([*args, "--max-steps", "5", "--quiet"], prog="iscc-eval") == 2
    err = capsys.readouterr().err
    assert err.startswith("iscc-eval: error: ") and err.count("\n") == 1 and "Traceback" not in err


def test_train_steps_refuse_a_used_run_directory_first(tmp_path, no_episodes):
    (tmp_path / "model.zip").write_text("")
    with pytest.raises(FileExistsError, match="--train-out"):
        cli.main(["--train-steps", "64", "--train-out", str(tmp_path), "--policies", "sca", "--quiet"])


def test_train_steps_trains_through_the_command_line_then_evaluates(tmp_path, monkeypatch):
    """--train-steps runs ``python -m iscc_gym.train`` (eval never imports train) and then evaluates the fresh
    agent as ``ppo``. The command eval builds is checked and run here in process as the interpreter would run it
    (``runpy``; a new interpreter spends 10-20 s on imports, and ``test_bench`` runs one), made tiny (2 envs,
    64-step rollouts, no warm start) by flags appended to it."""
    import runpy

    from iscc_gym.eval import training

    tiny = ["--n-envs", "2", "--set", "n_steps=64", "--set", "batch_size=64", "--set", "n_epochs=1",
            "--init-policy", "none", "--eval-freq", "0", "--checkpoint-freq", "0"]
    commands, real_run = [], subprocess.run

    def run_in_process(cmd, **kw):
        if cmd[:3] != [sys.executable, "-m", "iscc_gym.train"]:  # not the training command (e.g. platform's)
            return real_run(cmd, **kw)
        commands.append(cmd)
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(sys, "argv", ["python -m iscc_gym.train", *cmd[3:], *tiny])
            try:
                runpy.run_module("iscc_gym.train", run_name="__main__", alter_sys=True)
            except SystemExit as e:
                return subprocess.CompletedProcess(cmd, e.code or 0, "", "")
        return subprocess.CompletedProcess(cmd, 0, "", "")

    monkeypatch.setattr(training.subprocess, "run", run_in_process)
    out = tmp_path / "run"
    res = cli.main(["--train-steps", "256", "--train-out", str(out), "--policies", "ppo,equal", "--workers", "1",
                    "--episodes", "2",
                    "--max-steps", "5", "--quiet"])
    assert len(commands) == 1 and commands[0][3:] == ["--env", "iscc_gym/ISCC-v0", "--total-timesteps", "256",
                                                      "--scenario", "paper", "--out", str(out), "--quiet"]
    assert (out / "model.zip").is_file() and (out / "summary.yml").is_file()
    assert {"ppo", "equal"} <= set(res["policies"])


@pytest.mark.parametrize("args", [["--max-steps", "0"], ["--episodes", "0"], ["--workers", "0"],
                                  ["--torch-threads", "-1"], ["--max-steps", "abc"]])
def test_bad_numbers_exit_2_with_one_line(args, no_episodes, capsys):
    with pytest.raises(SystemExit) as e:
        cli.main(args)
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and args[0] in err and "usage" not in err


def test_zero_slots_is_an_error_not_an_all_zero_table():
    from iscc_gym.agents import EqualSplitPolicy
    from iscc_gym.eval.evaluate import run_episodes

    with pytest.raises(ValueError, match="max_steps"):
        run_episodes(EqualSplitPolicy(), [1, 2], max_steps=0)


def test_seed_lists():
    assert parse_seeds("7, 9,8") == [7, 9, 8]
    for bad in ("", "1,,2", "1.5", "3,3"):
        with pytest.raises(ValueError, match="--seeds"):
            parse_seeds(bad)


def test_bare_ppo_is_the_shipped_agent():
    items = resolve_specs("ppo, sca,fixed:0.2,0.2,0.6")
    assert items == [f"ppo={SHIPPED_AGENT}", "sca", "fixed:0.2,0.2,0.6"]
    assert (SHIPPED_AGENT / "model.zip").is_file()
    check_specs(items)  # a valid list passes (nothing expensive is built)


def test_write_docs_is_refused_outside_a_checkout(tmp_path, monkeypatch, no_episodes):
    installed = tmp_path / "site-packages" / "iscc_gym"
    installed.mkdir(parents=True)
    monkeypatch.setattr(docs, "PACKAGE_DIR", installed)
    from experiments.comparison import main as comparison_main

    with pytest.raises(OSError, match="not in a source checkout"):
        comparison_main(["--policies", "sca,equal", "--write-docs", "--quiet"])
    with pytest.raises(OSError, match="not in a source checkout"):
        reproduce.main(["--model-only", "--write-docs", "--quiet"])
    monkeypatch.setattr(docs, "PACKAGE_DIR", ROOT / "iscc_gym")
    assert docs.project_root() == ROOT


def test_console_exit_codes(capsys, tmp_path):
    assert cli.console(["--policies", "equal,fixed:0.3,0.2,0.5", "--episodes", "2", "--max-steps", "3",
                        "--workers", "1", "--quiet"], prog="iscc-eval") == 0
    out = capsys.readouterr()
    assert "equal" in out.out and out.err == ""
    a_file = tmp_path / "f"
    a_file.write_text("")
    for console, args in ((seeds.main, [str(tmp_path / "no-runs")]), (tune.main, ["margin", "--seed-start", "10000"]),
                          (probes.main, ["--episodes", "1"]), (reproduce.main, ["--json", str(a_file / "x")]),
                          (bench.main, ["--json", str(tmp_path)]),
                          (evaluator_check.main, ["--max-steps", "0"])):
        from iscc_gym.commands.options import run_console

        try:
            code = run_console(console, args, "cmd")
        except SystemExit as e:  # argparse's own exit passes through iscc_gym.commands.cli.run
            code = e.code
        assert code == 2, console.__module__
        err = capsys.readouterr().err
        assert err.startswith("cmd: error: ") and err.count("\n") == 1, err


def test_progress_is_a_bar_on_a_terminal_and_lines_elsewhere(monkeypatch):
    """Issue 23: without a terminal a long command still reports progress, as plain lines; --quiet silences it."""
    from iscc_gym.commands.options import LineProgress, progress_bar

    assert show_progress(quiet=True) is False
    monkeypatch.setattr(sys, "stderr", io.StringIO())
    assert show_progress() is True
    assert isinstance(progress_bar(10, "x"), LineProgress)
    assert not isinstance(progress_bar(10, "x", enabled=False), LineProgress)

    class Tty(io.StringIO):
        def isatty(self):
            return True

    monkeypatch.setattr(sys, "stderr", Tty())
    assert show_progress() is True and show_progress(quiet=True) is False
    assert not isinstance(progress_bar(10, "x"), LineProgress)


def test_line_progress_prints_stages_every_interval_and_the_end():
    from iscc_gym.commands.options import LineProgress

    out = io.StringIO()
    with LineProgress(100, "cmd", unit="slot", stream=out, interval=3600) as p:
        p.set_postfix_str("stage one")
        for _ in range(50):
            p.update(1)  # within the interval: no line
        assert out.getvalue().count("\n") == 1
        p.interval = 0
        p.update(10)
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("[cmd] 0/100 slot (stage one)")
    assert lines[1].startswith("[cmd] 60/100 slot (stage one)") and "s left" in lines[1]
    assert lines[2].startswith("[cmd] done: 60/100 slot") and len(lines) == 3


def test_line_progress_writes_messages_as_tqdm_does(capsys):
    """``bar.write`` (what ``eval.tune`` logs through) exists off a terminal too: the message on stdout, not the
    progress stream (``python -m eval.tune`` failed with stderr redirected)."""
    from iscc_gym.commands.options import LineProgress

    out = io.StringIO()
    LineProgress(3, "cmd", stream=out).write("grid: best v = 1")
    assert capsys.readouterr().out == "grid: best v = 1\n" and out.getvalue() == ""


def test_python_m_eval_prints_progress_lines_without_a_terminal(capsys):
    from iscc_gym.eval.__main__ import main

    main(["--policies", "equal", "--episodes", "1", "--max-steps", "5"])
    assert "[evaluating] done: 5/5 slot" in capsys.readouterr().err  # capsys's stderr is no terminal
    main(["--policies", "equal", "--episodes", "1", "--max-steps", "5", "--quiet"])
    assert "[evaluating]" not in capsys.readouterr().err


@pytest.mark.filterwarnings("ignore:'iscc_gym.eval.__main__' found in sys.modules")  # imported above as cli
def test_python_m_eval_exits_2_with_one_line_on_a_mistake(monkeypatch, capsys):
    """Run as the interpreter runs ``python -m eval`` (``runpy``, in process: a new interpreter spends 10-20 s
    on imports; ``test_evaluate`` launches ``python -m eval`` from the checkout as a real command)."""
    import runpy

    monkeypatch.setattr(sys, "argv", ["python -m eval", "--seeds", "5,5"])
    with pytest.raises(SystemExit) as e:
        runpy.run_module("iscc_gym.eval", run_name="__main__", alter_sys=True)
    assert e.value.code == 2
    # run as iscc_gym.eval (the installed name), so named (issue 34)
    assert capsys.readouterr().err == "python -m iscc_gym.eval: error: --seeds: seed 5 is given twice; every mission " \
                                      "must be a different seed\n"


def test_figures_are_written_atomically(tmp_path):
    from iscc_gym.eval.figures import new_figure, save_figure

    fig = new_figure((2, 2), dpi=30)
    fig.add_subplot(1, 1, 1).plot([0, 1])
    path = save_figure(fig, tmp_path / "sub" / "a.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and [p.name for p in path.parent.iterdir()] == ["a.png"]
    before = path.read_bytes()

    def broken(target, **kw):
        Path(target).write_bytes(b"half a png")
        raise OSError("disk full")

    fig.savefig = broken
    with pytest.raises(OSError, match="disk full"):
        save_figure(fig, path)
    assert path.read_bytes() == before and [p.name for p in path.parent.iterdir()] == ["a.png"]


@pytest.mark.slow
def test_a_failing_worker_stops_the_others_at_once():
    """A policy failing in one worker is reported at once: the policy still being played in the other worker
    (myopic over 1000 whole missions, about 25 min on a quiet machine) is ended, not waited for. The bound is
    wide (two minutes: spawning and importing a worker takes 20 s on a loaded machine) and still far below the
    other worker's job, so the test says whether it was waited for, not how fast the machine is."""
    import multiprocessing
    import time

    from iscc_gym.eval.policies import run_parallel

    t0 = time.perf_counter()
    with pytest.raises(ValueError, match="unknown policy spec 'bogus'"):
        run_parallel("myopic,bogus", list(range(10_000, 11_000)), workers=2)
    deadline = time.perf_counter() + 5
    while any(p.is_alive() for p in multiprocessing.active_children()) and time.perf_counter() < deadline:
        time.sleep(0.05)
    assert not [p for p in multiprocessing.active_children() if p.is_alive()]
    assert time.perf_counter() - t0 < 120


def test_docs_quote_the_command_without_its_output_flags():
    from iscc_gym.commands.options import docs_command

    assert docs_command("python -m eval", ["--json", "/tmp/x.json", "--write-docs", "--episodes", "20",
                                           "--plots=figs", "--quiet"]) == "python -m eval --episodes 20"
    seeds = docs_command("python -m experiments.seeds", ["runs/seeds", "--json=/tmp/s.json"])
    assert seeds == "python -m experiments.seeds runs/seeds"


def test_an_agent_is_checked_against_the_env_it_is_compared_on(tmp_path):
    """``NAME=PATH`` on ``--env iscc_gym/ISCC-Urban-v0``: an urban model loads (it was refused with the paper env's
    shape), the shipped paper agent is refused by name with the fix, and the paper env still takes the paper agent."""
    import gymnasium as gym
    from iscc_gym.eval.policies import build_policy
    from stable_baselines3 import PPO

    import iscc_gym

    PPO("MlpPolicy", gym.make(iscc_gym.URBAN_ENV_ID), n_steps=8, batch_size=8, device="cpu").save(tmp_path / "m.zip")
    (tmp_path / "config.yml").write_text("args: {algo: ppo, normalize: false}\n")
    name, agent = build_policy(f"urban={tmp_path / 'm.zip'}", "urban")
    assert name == "urban" and agent.obs_shape == (76,)
    with pytest.raises(ValueError, match=r"--policies 'ppo=.*\(23,\).*\(76,\).*--env"):
        build_policy(f"ppo={SHIPPED_AGENT}", "urban")
    assert build_policy(f"ppo={SHIPPED_AGENT}", "paper")[1].obs_shape == (23,)


# --- issue 34: every command's --help, named as invoked; progress estimates; pickles -----------------------------

#: Every installed ``python -m`` command (under ``iscc_gym.``): ``main`` / ``cli`` called with --help.
INSTALLED = ["eval", "eval.bench", "eval.multi", "eval.outage", "eval.tune", "train"]
#: The studies that regenerate this repository's docs, run from a checkout (``experiments/``, not installed).
EXPERIMENTS = ["experiments.pareto", "experiments.probes", "experiments.seeds", "experiments.urban_figure",
               "experiments.urban_learned", "experiments.urban_levers", "experiments.urban_shift",
               "experiments.urban_task", "experiments.paper.evaluator_check", "experiments.paper.fading",
               "experiments.paper.reproduce", "experiments.paper.sensitivity", "experiments.ship",
               "experiments.multi_agents", "experiments.pareto_agents", "experiments.headroom",
               "experiments.comparison", "experiments.bench", "experiments.multi"]
COMMANDS = INSTALLED + EXPERIMENTS
#: The commands whose entry is ``cli`` (the training studies), not ``main``.
CLI_ENTRY = ("experiments.multi_agents", "experiments.pareto_agents")


def _help(command: str, capsys) -> str:
    """``python -m COMMAND --help``, in process: the command's ``main``/``cli`` prints the help and exits 0."""
    import importlib

    name = {"eval": "iscc_gym.eval.__main__", "train": "iscc_gym.train.cli"}.get(
        command, command if command.startswith("experiments.") else f"iscc_gym.{command}")
    module = importlib.import_module(name)
    entry = module.cli if command.startswith("train") or command in CLI_ENTRY else module.main
    with pytest.raises(SystemExit) as e:
        entry(["--help"])
    assert e.value.code == 0, command
    return capsys.readouterr().out


@pytest.mark.parametrize("command", COMMANDS)
def test_every_commands_help_prints(command, capsys):
    """``python -m experiments.urban_figure --help`` crashed: a ``10%`` in a help string (argparse formats help with
    %)."""
    assert _help(command, capsys).startswith(f"usage: python -m {command} ")


@pytest.mark.parametrize("command", INSTALLED)
def test_usage_names_the_command_as_invoked(command, capsys, monkeypatch):
    """``python -m iscc_gym.eval --help`` showed ``usage: python -m eval``: run under the installed name (what
    ``runpy`` sets as ``__main__``), every command's usage says that name."""
    import types

    spec = types.SimpleNamespace(name=f"iscc_gym.{command}" + (".__main__" if command in ("eval", "train") else ""))
    monkeypatch.setitem(sys.modules, "__main__", types.SimpleNamespace(__spec__=spec))
    assert _help(command, capsys).startswith(f"usage: python -m iscc_gym.{command} ")


def test_line_progress_estimates_from_the_work_after_start_up():
    """``python -m eval``'s first line said ``about 14898 s left`` for a 2.6-minute run: the start-up (spawning,
    imports, compiling the kernels) counted as if slots were played in it. Here 15,000 slots, 10 s of start-up,
    then 100 slots/s: every estimate shown is within 20 % of the time really left."""
    from iscc_gym.commands.options import LineProgress

    now = [0.0]
    out = io.StringIO()
    bar = LineProgress(15_000, "evaluating", unit="slot", stream=out, clock=lambda: now[0])
    now[0] = 10.0
    while bar.n < 15_000:
        now[0] += 1.0
        bar.update(100)
    bar.close()
    lines = out.getvalue().splitlines()
    estimates = [(int(m.group(1)), float(m.group(2))) for m in
                 (re.search(r"\] ([0-9,]+)/.* about ([0-9]+) s left", ln.replace(",", "")) for ln in lines) if m]
    assert len(lines) > 10 and estimates and "s left" not in lines[0]
    for done, left in estimates:
        true_left = (15_000 - done) / 100
        assert abs(left - true_left) <= 0.2 * true_left + 1, (done, left, true_left)


@pytest.mark.parametrize("command", ["eval", "experiments.seeds", "eval.multi", "experiments.urban_shift",
                                     "experiments.urban_learned", "experiments.urban_figure"])
def test_commands_that_load_agents_say_they_are_pickles(command, capsys):
    """Every command that loads a trained agent (``NAME=PATH``, ``--agent``) says so in its --help, in the one
    wording of :data:`iscc_gym.commands.options.PICKLE_WARNING` (experiments.urban_levers plays scripted policies
    only)."""
    from iscc_gym.commands.options import PICKLE_WARNING

    assert " ".join(PICKLE_WARNING.split()) in " ".join(_help(command, capsys).split())


def test_a_scenario_of_another_task_than_the_env_is_refused(no_episodes, tmp_path):
    """Issue 34 item 8: ``--env iscc_gym/ISCC-Urban-v0 --scenario paper`` played paper missions under the urban
    task's policies, labels and docs section; now refused naming both and the fix, also by experiments.seeds. A variant
    of the env's own task (``literal`` on ISCC-v0) still plays, but not into the docs of the env's own preset."""
    urban, paper = "iscc_gym/ISCC-Urban-v0", "iscc_gym/ISCC-v0"
    with pytest.raises(ValueError, match=rf"--scenario 'paper' is the paper task, but --env {urban} is the urban "
                                         rf"task .*: use --env {paper} for 'paper', or drop --scenario"):
        cli.main(["--env", urban, "--scenario", "paper", "--policies", "myopic,margin", "--quiet"])
    with pytest.raises(ValueError, match=rf"--scenario 'urban' is the urban task, but --env {paper} is the paper"):
        cli.main(["--scenario", "urban", "--quiet"])
    from experiments.comparison import main as comparison_main

    with pytest.raises(ValueError, match=rf"--write-docs writes the docs of --env {paper}, whose scenario is 'paper'"):
        comparison_main(["--scenario", "literal", "--write-docs", "--quiet"])
    with pytest.raises(ValueError, match=rf"--scenario 'paper' is the paper task, but --env {urban}"):
        seeds.main([str(tmp_path), "--env", urban, "--scenario", "paper", "--quiet"])
    from iscc_gym.commands.options import env_scenario

    assert env_scenario(paper, "literal") == "literal" and env_scenario(urban, None) == "urban"


@pytest.mark.parametrize("env, scenario, task, env_task, other", [
    ("iscc_gym/ISCC-Field-v0", "paper", "paper", "field", "iscc_gym/ISCC-v0"),
    ("iscc_gym/ISCC-Field-v0", "literal", "paper", "field", "iscc_gym/ISCC-v0"),
    ("iscc_gym/ISCC-v0", "field", "field", "paper", "iscc_gym/ISCC-Field-v0"),
    ("iscc_gym/ISCC-Urban-v0", "field", "field", "urban", "iscc_gym/ISCC-Field-v0"),
])
def test_the_field_task_is_a_task_of_its_own_to_the_env_scenario_checks(no_episodes, env, scenario, task, env_task,
                                                                         other):
    """Issue 43.4: ``--env iscc_gym/ISCC-Field-v0 --scenario paper`` played the paper's missions under the field
    task's labels (``task_of`` knew paper and urban only), ``--env iscc_gym/ISCC-v0 --scenario field`` failed after a
    third of the run, and the refusals named the field env the paper task. Refused before any work, naming both."""
    with pytest.raises(ValueError, match=rf"--scenario '{scenario}' is the {task} task, but --env {env} is the "
                                         rf"{env_task} task .*: use --env {other} for '{scenario}'"):
        cli.main(["--env", env, "--scenario", scenario, "--policies", "myopic", "--quiet"])
    from iscc_gym.agents.tuned_records import record_task, task_of

    from iscc_gym.scenario import make_scenario

    assert task_of(make_scenario("field")) == "field" and record_task(make_scenario("field")) == "paper"


#: Each command given a mistake, in one new process: the exit code and which heavy modules were loaded by then.
REFUSED_LIGHT = """
import sys, json
from iscc_gym.eval.__main__ import console as eval_console
from iscc_gym.train.cli import console as train_console
from iscc_gym.eval.tune import main as tune_main
from iscc_gym.commands.cli import run
codes = [eval_console(["--policies", "myopc"]),
         eval_console(["--env", "iscc_gym/ISCC-Field-v0", "--scenario", "paper"]), eval_console(["--seeds", "1,1"]),
         train_console(["--total-timesteps", "0", "--out", "x"]), train_console(["--env", "nope", "--out", "x"]),
         train_console(["--env", "iscc_gym/ISCC-Field-v0", "--env-set", "show_world=true", "--out", "x"]),
         train_console(["--device", "standin", "--algo", "sac", "--out", "x"]),
         run(tune_main, ["margin", "--scenario", "field"], "python -m eval.tune")]
heavy = ("torch", "stable_baselines3", "iscc_gym.sim.kernel", "iscc_gym.envs.env", "iscc_gym.agents.myopic")
print(json.dumps([codes, [m for m in heavy if m in sys.modules]]))
"""


def test_a_mistake_is_refused_before_torch_sb3_or_the_compiled_env_load(tmp_path):
    """Issue 43.12: every mistake was refused only after the whole package had loaded (torch, SB3, the compiled
    kernels: 40-146 s on a busy 2-core machine). python -m eval, python -m train and python -m eval.tune check their
    arguments first (the packages' heavy names load on first use)."""
    import json
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-c", REFUSED_LIGHT], cwd=tmp_path, capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr
    codes, loaded = json.loads(r.stdout.splitlines()[-1])
    assert codes == [2] * 8, r.stderr
    assert loaded == [], loaded
    assert "did you mean 'myopic'?" in r.stderr and "aware (myopic designed on the world played)" in r.stderr
    assert "NAME=PATH (a trained agent)" in r.stderr
