"""The installed wheel: everything under the ``iscc_gym`` namespace, light core requirements, console
scripts that work from any directory, and no shadowing by a user's own ``agents.py``/``train.py``/``eval.py``.

Builds the wheel from a copy of the sources (so the checkout gets no ``build/``), installs it with
``--no-deps`` into a temporary venv that sees the packages of the interpreter running the tests (a ``.pth`` file
listing its site-packages folders, after the new venv's own: ``system_site_packages=True`` would expose the *base*
interpreter's packages, not those of the venv the tests run in), and runs it from a folder holding generic modules
that would shadow top-level ``agents``/``train``/``eval`` packages.

The tests of the built wheel and of the subprocesses are ``slow`` (the build, the venv and the launches: about 30 s
of two cores), run by the README's **Slow tests** command; the in-process check of the core install is not.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import venv
import zipfile
from importlib import metadata
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
def _sources() -> tuple[str, ...]:
    """What the wheel is built from: pyproject, the README and every package folder pyproject maps (read from it,
    so a new folder such as ``commands/`` is never left out)."""
    import tomllib

    folders = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"].values()
    return ("pyproject.toml", "README.md", "iscc_gym", *folders)


SOURCES = _sources()


def _run(cmd, cwd, **kw):
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    return subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=300, env=env, **kw)


def _has_build_backend() -> bool:
    """Whether this interpreter has pyproject's build requirements (setuptools>=68, wheel)."""
    try:
        return int(metadata.version("setuptools").split(".")[0]) >= 68 and bool(metadata.version("wheel"))
    except (metadata.PackageNotFoundError, ValueError):
        return False


#: A core install (no torch, SB3, Optuna, TensorBoard, rich): the env, the physics and the scripted policies,
#: evaluated; the number of slots played is printed.
CORE_ONLY = """
import sys
class Block:
    def find_spec(self, name, path=None, target=None):
        if name.split('.')[0] in ('torch', 'stable_baselines3', 'optuna', 'tensorboard', 'rich'):
            raise ImportError('not installed: ' + name)
sys.meta_path.insert(0, Block())
import gymnasium as gym, iscc_gym
from iscc_gym.agents import make_policy
from iscc_gym.eval.evaluate import run_episodes
env = gym.make(iscc_gym.ENV_ID)
env.reset(seed=0)
env.step(env.action_space.sample())
res = run_episodes(make_policy('margin'), seeds=[0], max_steps=3)
print(res['slots'])
"""


@pytest.fixture(scope="module")
def core_only():
    """:data:`CORE_ONLY` run by this interpreter on the checkout (its compiled kernels cached), started before the
    wheel is built so the two overlap on two cores (the build is a chain of one-core subprocesses): its Popen."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    with subprocess.Popen([sys.executable, "-c", CORE_ONLY], cwd=ROOT, env=env, stdout=subprocess.PIPE,
                          stderr=subprocess.PIPE, text=True) as proc:
        yield proc
        if proc.poll() is None:
            proc.kill()


@pytest.fixture(scope="module")
def installed(tmp_path_factory, core_only):  # core_only: started first, to run beside the build
    tmp = tmp_path_factory.mktemp("install")
    src = tmp / "src"
    src.mkdir()
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "*.nbi", "*.nbc")
    for name in SOURCES:
        p = ROOT / name
        if p.is_dir():
            shutil.copytree(p, src / name, ignore=ignore)
        else:
            shutil.copy2(p, src / name)
    wheels = tmp / "wheels"
    # the build backend this interpreter already has, if it meets pyproject's build-system requirements,
    # spares pip an isolated build environment (~4 s); a fresh venv without setuptools gets one
    isolation = ["--no-build-isolation"] if _has_build_backend() else []
    r = _run([sys.executable, "-m", "pip", "wheel", str(src), "--no-deps", "-q", *isolation,
              "-w", str(wheels)], cwd=tmp)
    assert r.returncode == 0, r.stderr
    (wheel,) = wheels.glob("iscc_gym-*.whl")
    env_dir = tmp / "venv"
    venv.EnvBuilder(with_pip=False).create(env_dir)
    py = env_dir / "bin" / "python"
    purelib = _run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], cwd=tmp)
    # this interpreter's site-packages as plain path lines: their own .pth files (an editable install of the
    # checkout among them) are not processed, so the wheel's iscc_gym is the one imported
    outer = [p for p in sys.path if Path(p).name in ("site-packages", "dist-packages") and Path(p).is_dir()]
    Path(purelib.stdout.strip(), "outer-site-packages.pth").write_text("\n".join(outer) + "\n")
    r = _run([sys.executable, "-m", "pip", "--python", str(py), "install", "--no-deps", "--no-index", "-q",
              str(wheel)], cwd=tmp)
    assert r.returncode == 0, r.stderr
    work = tmp / "work"
    work.mkdir()
    for name in ("agents", "train", "eval"):  # a user's own generic modules in the working directory
        (work / f"{name}.py").write_text("raise SystemExit('the user module shadowed iscc_gym')\n")
    return {"wheel": wheel, "py": py, "bin": env_dir / "bin", "site": Path(purelib.stdout.strip()), "work": work}


@pytest.mark.slow
def test_wheel_holds_only_the_iscc_gym_namespace(installed):
    names = zipfile.ZipFile(installed["wheel"]).namelist()
    top = {n.split("/")[0] for n in names}
    assert {t for t in top if not t.endswith(".dist-info")} == {"iscc_gym"}
    for needed in ("iscc_gym/agents/trained/ppo_iscc/model.zip", "iscc_gym/agents/trained/ppo_iscc/vecnormalize.pkl",
                   "iscc_gym/agents/tuned/margin.yml", "iscc_gym/agents/tuned/sca-per-slot.yml",
                   "iscc_gym/train/hyperparams.yml", "iscc_gym/agents/trained/multi/k4_lag/lagrange.yml",
                   "iscc_gym/agents/trained/pareto/ppo-lag/0.05/model.zip",
                   "iscc_gym/agents/trained/pareto/ppo-lag/0.05/lagrange.yml",
                   "iscc_gym/agents/trained/multi/k4/model.zip", "iscc_gym/agents/trained/multi/k4/vecnormalize.pkl",
                   "iscc_gym/eval/__main__.py", "iscc_gym/train/__main__.py"):
        assert needed in names
    # every shipped agent and tuned record (issue 43: the field agent was left out of a hand-written list)
    shipped = {"iscc_gym/agents/" + p.relative_to(ROOT / "agents").as_posix()
               for folder in ("trained", "tuned") for p in (ROOT / "agents" / folder).rglob("*") if p.is_file()}
    assert "iscc_gym/agents/trained/ppo_field/model.zip" in shipped
    assert not shipped - set(names), sorted(shipped - set(names))
    # every task's shipped agent, from the task files (issue 44): its folder, its model and statistics
    from iscc_gym.tasks import TASKS

    agents = [t.agent for t in TASKS.values() if t.agent is not None]
    assert "ppo_field" in agents and len(agents) >= 3
    for agent in agents:
        folder = f"iscc_gym/agents/trained/{agent}/"
        files = {n for n in names if n.startswith(folder)}
        assert {folder + "model.zip", folder + "vecnormalize.pkl"} <= files, agent
        assert files == {n for n in shipped if n.startswith(folder)}, agent
    site = installed["site"]
    assert (site / "iscc_gym" / "agents" / "__init__.py").is_file()
    for generic in ("agents", "commands", "train", "eval"):
        assert not (site / generic).exists(), f"{generic}/ installed at the top of site-packages"


@pytest.mark.slow
def test_core_requirements_are_light(installed):
    """torch, SB3, tensorboard and optuna only with the ``train`` extra."""
    with zipfile.ZipFile(installed["wheel"]) as z:
        meta = z.read(next(n for n in z.namelist() if n.endswith(".dist-info/METADATA"))).decode()
    requires = [line.split(":", 1)[1].strip() for line in meta.splitlines() if line.startswith("Requires-Dist:")]
    core = [r for r in requires if "extra ==" not in r]
    heavy = ("torch", "stable-baselines3", "tensorboard", "optuna")
    assert not [r for r in core if r.split(">")[0].split("=")[0].strip().lower() in heavy], core
    for h in heavy:
        assert any(r.lower().startswith(h) and 'extra == "train"' in r for r in requires), h


#: One launch of the installed interpreter in the folder of shadowing modules (on sys.path first, as for
#: ``python -m``): ``python -m iscc_gym.eval --help`` and ``python -m iscc_gym.train --help`` run in it as
#: ``-m`` runs them (runpy), then the imports of the shadowing check; a JSON line of what each printed.
IN_ONE_LAUNCH = """
import contextlib, io, json, runpy, sys, traceback
out = {}
for mod in ("iscc_gym.eval", "iscc_gym.train"):
    buf, code = io.StringIO(), None
    sys.argv = [mod, "--help"]
    try:
        with contextlib.redirect_stdout(buf):
            runpy.run_module(mod, run_name="__main__", alter_sys=True)
    except SystemExit as e:
        code = e.code
    except BaseException:
        code = traceback.format_exc()
    out["python -m " + mod + " --help"] = [code, buf.getvalue()]
try:
    import iscc_gym, iscc_gym.agents, iscc_gym.eval.evaluate, iscc_gym.train.train
    from iscc_gym.agents import make_policy
    out["shadow"] = [0, iscc_gym.agents.__file__ + " " + make_policy("margin").__class__.__name__]
except BaseException:
    out["shadow"] = [traceback.format_exc(), ""]
print(json.dumps(out))
"""
#: The console scripts, each launched as a user would.
SCRIPTS = (("iscc-eval", "--help"), ("iscc-train", "--help"))
#: Issue 43: the field task's shipped agent played from the installed wheel (it was not in the wheel: exit 2, "no
#: trained agent there").
FIELD_EVAL = ("-m", "iscc_gym.eval", "--env", "iscc_gym/ISCC-Field-v0", "--policies", "ppo,myopic", "--episodes", "1",
              "--max-steps", "2", "--workers", "1", "--quiet")


@pytest.fixture(scope="module")
def launched(installed):
    """The launches from the folder of shadowing modules, started together so their imports overlap
    (the console scripts, and one interpreter for ``-m`` and the shadowing check): {name: Popen}."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    runs = {"one": [str(installed["py"]), "-c", IN_ONE_LAUNCH]}
    runs.update({" ".join(c): [str(installed["bin"] / c[0]), *c[1:]] for c in SCRIPTS})
    runs["field"] = [str(installed["py"]), *FIELD_EVAL]
    procs = {name: subprocess.Popen(cmd, cwd=installed["work"], env=env, stdout=subprocess.PIPE,
                                    stderr=subprocess.PIPE, text=True) for name, cmd in runs.items()}
    results = {}

    def result(name):
        if name not in results:
            results[name] = procs[name].communicate(timeout=300)
        return procs[name].returncode, *results[name]

    yield result
    for p in procs.values():
        if p.poll() is None:
            p.kill()
        p.communicate()


def _in_one_launch(launched) -> dict:
    code, out, err = launched("one")
    assert code == 0, err
    return json.loads(out.splitlines()[-1])


@pytest.mark.slow
def test_installed_package_is_not_shadowed_by_user_modules(installed, launched):
    code, out = _in_one_launch(launched)["shadow"]
    assert code == 0, code
    path, name = out.split()
    assert Path(path).resolve().is_relative_to(installed["site"].resolve())
    assert name == "MarginPolicy"


@pytest.mark.slow
def test_console_commands_run_from_any_directory(launched):
    for command in SCRIPTS:
        code, out, err = launched(" ".join(command))
        assert code == 0, (command, err)
        assert "usage" in out.lower(), command
    for command, (code, out) in _in_one_launch(launched).items():
        if command.startswith("python -m"):
            assert code in (0, None), (command, code)
            assert "usage" in out.lower(), command


@pytest.mark.slow
def test_env_and_scripted_policies_work_without_the_train_extra(core_only):
    """What a core install (no torch, SB3, Optuna, TensorBoard, rich) offers: the env, the physics and
    the scripted policies, evaluated."""
    out, err = core_only.communicate(timeout=300)
    assert core_only.returncode == 0, err
    assert int(out.split()[-1]) == 3


@pytest.mark.parametrize("command", ["iscc-train", "iscc-eval"])
def test_commands_without_the_train_extra_exit_2_with_one_line_naming_it(command, monkeypatch, capsys, tmp_path):
    """Issue 34: on the core install, ``iscc-train`` ended in a traceback (``No module named 'torch'``). Simulated in
    process: torch and SB3 cannot be imported (``None`` in ``sys.modules``, what ``import`` and ``find_spec`` take for
    a missing module), after the commands themselves are imported, as a core install imports them."""
    from iscc_gym.eval.__main__ import console as eval_console
    from iscc_gym.train.cli import console as train_console

    for name in ("torch", "stable_baselines3"):
        monkeypatch.setitem(sys.modules, name, None)
    if command == "iscc-train":
        code = train_console(["--total-timesteps", "64", "--out", str(tmp_path / "run")], prog=command)
    else:
        code = eval_console(["--policies", "ppo,sca", "--episodes", "1", "--max-steps", "2", "--quiet"], prog=command)
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and err.startswith(f"{command}: error: "), err
    assert "torch" in err and "pip install 'iscc-gym[train]'" in err and "Traceback" not in err
    assert not (tmp_path / "run").exists()


@pytest.mark.slow
def test_installed_wheel_plays_the_field_tasks_shipped_agent(installed, launched):
    """Issue 43: ``python -m iscc_gym.eval --env iscc_gym/ISCC-Field-v0`` from the wheel finds the field agent."""
    code, out, err = launched("field")
    assert code == 0, err
    assert "no trained agent" not in err
    assert any(line.lstrip("| ").startswith("ppo ") for line in out.splitlines()), out
