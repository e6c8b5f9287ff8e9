"""Benchmarks: steps per second of the ISCC env beside a reference measured the same way.

Usage::

    python -m eval.bench [--full] [--steps N] [--repeats R] [--json PATH] [--quick] [--skip-ppo] [--quiet]

The default is a short run (:data:`PROFILES`, the expected duration printed at the start); ``--full`` measures
every figure, the README's table (``python -m experiments bench`` writes it into the docs). A line per stage goes
to stderr (``--quiet``: none).

Every figure is the median over ``repeats`` runs, with its reference measured in the same process:

* single env steps/s through ``gymnasium.make`` (default wrappers), actions drawn in advance so
  ``Box.sample()`` (about 16 us) is not timed; reference: Gymnasium's Pendulum-v1 measured alike;
* vector env env-steps/s at 1, 64 and 1024 envs (``gymnasium.make_vec``, native batched env);
* the multi-drone vector env's drone-slots/s at 1024 envs x 4 drones, against the single-drone
  vector env at 1024 envs (cost per drone-slot);
* the urban task's vector env at 1024 envs against the paper's (goal: at least half its env-steps/s);
* PPO training env-steps/s end to end (SB3 defaults, 4 envs, ``torch.set_num_threads(1)``) on
  DummyVecEnv, SubprocVecEnv and the batched env; reference: the same PPO on Pendulum-v1 with
  DummyVecEnv;
* PPO training env-steps/s of ``python -m train``'s own configuration (the YAML's env count and
  hyperparameters, VecNormalize, batched env) for each (numba threads, torch threads) setting.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time

import gymnasium as gym
import numpy as np
from iscc_gym.commands.docs import save_json
from iscc_gym.commands.options import Parser, Stages, check_writable_file, positive_int, run_console

import iscc_gym
from iscc_gym import threads

from .bench_report import format_compile, format_report


def env_steps_per_second(env_id: str, n_steps: int, repeats: int, seed: int = 0, **kwargs) -> dict:
    """Median steps/s of ``env.step`` over ``repeats`` runs of ``n_steps`` pre-drawn actions."""
    env = gym.make(env_id, **kwargs)
    env.action_space.seed(seed)
    actions = [env.action_space.sample() for _ in range(n_steps)]
    env.reset(seed=seed)
    env.step(actions[0])  # warm-up: compiled kernels loaded, first-step checks done
    rates = []
    for r in range(repeats):
        env.reset(seed=seed + r)
        t0 = time.perf_counter()
        for a in actions:
            _, _, terminated, truncated, _ = env.step(a)
            if terminated or truncated:
                env.reset()
        rates.append(n_steps / (time.perf_counter() - t0))
    env.close()
    return {"median_steps_per_s": statistics.median(rates), "runs": rates, "n_steps": n_steps}


def vector_steps_per_second(num_envs: int, n_steps: int, repeats: int, seed: int = 0, warmup: int = 1,
                            n_drones: int | None = None, env_id: str = iscc_gym.ENV_ID) -> dict:
    """Median env-steps/s of the native vector env (``n_steps`` batched steps per run, after ``warmup``
    untimed steps: compiled kernels loaded, the ``auto`` kernel choice made); with ``n_drones``, of the
    multi-drone env (``iscc_gym/ISCC-Multi-v0``), also as drone-slots/s; ``env_id`` the single-drone env's id
    (``iscc_gym/ISCC-Urban-v0``: the urban task).
    """
    if n_drones is None:
        venv = gym.make_vec(env_id, num_envs=num_envs, vectorization_mode="vector_entry_point")
    else:
        venv = gym.make_vec(iscc_gym.MULTI_ENV_ID, num_envs=num_envs, vectorization_mode="vector_entry_point",
                            n_drones=n_drones)
    venv.reset(seed=seed)
    width = 3 * (n_drones or 1)
    actions = np.random.default_rng(seed).uniform(-1, 1, (n_steps, num_envs, width)).astype(np.float32)
    for i in range(warmup):
        venv.step(actions[i % n_steps])
    rates = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for a in actions:
            venv.step(a)
        rates.append(n_steps * num_envs / (time.perf_counter() - t0))
    venv.close()
    med = statistics.median(rates)
    return {"median_env_steps_per_s": med, "runs": rates, "n_steps": n_steps, "num_envs": num_envs,
            "n_drones": n_drones, "median_drone_slots_per_s": med * (n_drones or 1)}


def urban_speed(num_envs: int = 1024, n_steps: int = 300, repeats: int = 3) -> dict:
    """The urban task's vector env (``iscc_gym/ISCC-Urban-v0``) against the paper's at ``num_envs``, measured alike
    in this process: ``ratio`` of env-steps/s (goal >= 0.5). A run's ``n_steps`` stay inside the 1,200-slot
    missions, so the reset's cost (the channel along the path) is reported apart: ``reset_ms_per_env``, one vector
    reset of all ``num_envs`` over their number.
    """
    urban = vector_steps_per_second(num_envs, n_steps, repeats, warmup=4, env_id=iscc_gym.URBAN_ENV_ID)
    paper = vector_steps_per_second(num_envs, n_steps, repeats, warmup=4)
    venv = gym.make_vec(iscc_gym.URBAN_ENV_ID, num_envs=num_envs, vectorization_mode="vector_entry_point")
    t0 = time.perf_counter()
    venv.reset(seed=1)
    reset_s = time.perf_counter() - t0
    venv.close()
    return {"urban": urban, "paper": paper, "reset_ms_per_env": 1e3 * reset_s / num_envs,
            "ratio": urban["median_env_steps_per_s"] / paper["median_env_steps_per_s"]}


def multi_drone_cost(num_envs: int = 1024, n_drones: int = 4, n_steps: int = 300, repeats: int = 3) -> dict:
    """Drone-slots/s of the multi-drone vector env (``num_envs`` envs of ``n_drones`` drones) against
    the single-drone vector env's env-steps/s at the same number of loops and at ``num_envs``, measured
    alike in this process; ``cost_ratio``: the multi env's time per drone-slot over the single env's
    at ``num_envs`` (goal <= 1.5).
    """
    multi = vector_steps_per_second(num_envs, n_steps, repeats, warmup=4, n_drones=n_drones)
    single = vector_steps_per_second(num_envs, n_steps, repeats, warmup=4)
    return {"multi": multi, "single": single,
            "cost_ratio": single["median_env_steps_per_s"] / multi["median_drone_slots_per_s"]}


#: The vector env's kernel, old default first: parallel from 64 envs, then serial (the default since issue 12).
PARALLEL_MODES = (True, False)


def vector_under_load(sizes=(64, 1024), n_steps: int = 3000, repeats: int = 3) -> dict:
    """Median env-steps/s of the native vector env per kernel mode (:mod:`iscc_gym.threads`), on a quiet
    machine and beside a busy process (``python -c "while True: pass"`` spinning on one core).

    ``n_steps`` batched steps per run at the smallest size, scaled down by the batch size for larger ones.
    """
    import subprocess

    out: dict = {}
    mode0 = threads.get_parallel()
    names = {True: "parallel", False: "serial"}
    try:
        for load in ("quiet", "busy"):
            busy = None
            if load == "busy":
                busy = subprocess.Popen([sys.executable, "-c", "while True: pass"])
                time.sleep(0.5)
            try:
                for mode in PARALLEL_MODES:
                    threads.set_parallel(mode)
                    for n in sizes:
                        steps = max(n_steps * min(sizes) // n, 20)
                        r = vector_steps_per_second(n, steps, repeats, warmup=8)
                        out.setdefault(load, {}).setdefault(names[mode], {})[str(n)] = r["median_env_steps_per_s"]
            finally:
                if busy is not None:
                    busy.kill()
                    busy.wait()
    finally:
        threads.set_parallel(mode0)
    return out


def ppo_steps_per_second(kind: str, total_steps: int, repeats: int, n_envs: int = 4) -> dict:
    """Median env-steps/s of SB3 PPO (default hyperparameters) learning ``total_steps`` steps."""
    import torch
    from iscc_gym.agents.sb3_logging import stdout_logger
    from iscc_gym.agents.sb3_vec_env import ISCCBatchedVecEnv
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecMonitor

    torch.set_num_threads(1)
    rates = []
    for r in range(repeats):
        if kind == "batched":
            venv = VecMonitor(ISCCBatchedVecEnv(n_envs))
        else:
            env_id = "Pendulum-v1" if kind == "pendulum_dummy" else iscc_gym.ENV_ID
            cls = SubprocVecEnv if kind == "subproc" else DummyVecEnv
            venv = make_vec_env(env_id, n_envs=n_envs, seed=r, vec_env_cls=cls)
        model = PPO("MlpPolicy", venv, seed=r, device="cpu", n_steps=min(2048, total_steps // n_envs))
        model.set_logger(stdout_logger(0))  # SB3's default logger leaves a folder in $TMPDIR per run
        t0 = time.perf_counter()
        model.learn(total_steps)
        rates.append(total_steps / (time.perf_counter() - t0))
        venv.close()
    return {"median_env_steps_per_s": statistics.median(rates), "runs": rates, "total_steps": total_steps,
            "n_envs": n_envs}


#: Thread settings of the shipped-configuration PPO figure: (numba threads, torch threads).
THREAD_SETTINGS = ((1, 1), (2, 1), (1, 2), (2, 2))


def ppo_shipped_steps_per_second(total_steps: int, repeats: int, settings=THREAD_SETTINGS) -> dict:
    """Median env-steps/s of ``python -m train``'s default run (the YAML's env count and
    hyperparameters, VecNormalize, the batched env), learning ``total_steps`` steps without
    evaluations, checkpoints or warm start, per (numba threads, torch threads) setting. Numba threads
    above 1 mean the env's parallel kernel on that many threads (:func:`iscc_gym.threads.set_parallel`);
    1 means the serial kernel, the default.
    """
    import tempfile

    from iscc_gym.eval.training import run_training

    # the default mode as the figure is asked for (read before training: another figure may switch it meanwhile)
    numba_default = os.cpu_count() if threads.get_parallel() else 1
    out = {}
    config = None
    with tempfile.TemporaryDirectory() as tmp:
        for numba_threads, torch_threads in settings:
            if numba_threads > os.cpu_count() or torch_threads > os.cpu_count():
                continue
            rates = []
            for r in range(repeats):
                # PPO itself: a warm start of the YAML (a fixed cost before learning) is left out
                run = run_training(["--total-timesteps", total_steps, "--seed", r, "--eval-freq", 0,
                                    "--checkpoint-freq", 0, "--no-tensorboard", "--numba-threads", numba_threads,
                                    "--torch-threads", torch_threads, "--init-policy", "none"],
                                   f"{tmp}/run_numba{numba_threads}_torch{torch_threads}_{r}",
                                   env={"ISCC_GYM_PARALLEL": "1" if numba_threads > 1 else "0"})
                rates.append(run["summary"]["env_steps_per_s"])
                config = run["config"]
            out[f"numba{numba_threads}_torch{torch_threads}"] = {
                "median_env_steps_per_s": statistics.median(rates), "runs": rates, "numba_threads": numba_threads,
                "torch_threads": torch_threads}
    hp = (config or {}).get("hyperparams", {})
    return {"settings": out, "n_envs": (config or {}).get("args", {}).get("n_envs"), "total_steps": total_steps,
            "hyperparams": {k: hp[k] for k in ("n_steps", "batch_size", "n_epochs") if k in hp},
            "default": f"numba{numba_default}_torch1"}


def render_ms(frames: int = 50, steps_before: int = 300) -> dict:
    """Median milliseconds per ``rgb_array`` frame (a step and a render each), after ``steps_before``
    slots; the first frame (the figure built) is timed apart.
    """
    env = gym.make(iscc_gym.ENV_ID, render_mode="rgb_array")
    env.reset(seed=0)
    actions = np.random.default_rng(0).uniform(-1, 1, (steps_before + frames, 3)).astype(np.float32)
    for a in actions[:steps_before]:
        env.step(a)
    t0 = time.perf_counter()
    env.render()
    first = time.perf_counter() - t0
    times = []
    for a in actions[steps_before:]:
        env.step(a)
        t0 = time.perf_counter()
        env.render()
        times.append(time.perf_counter() - t0)
    env.close()
    return {"median_ms": 1e3 * statistics.median(times), "first_ms": 1e3 * first, "frames": frames}


def eval_sca_seconds(episodes: int, max_steps: int | None = None) -> dict:
    """Wall time of evaluating static SCA on ``episodes`` full missions (batched, common seeds)."""
    from iscc_gym.agents import make_policy
    from iscc_gym.eval.evaluate import run_episodes

    policy = make_policy("sca")
    run_episodes(policy, seeds=[0], max_steps=5)  # warm: kernels and the policy's design loaded
    t0 = time.perf_counter()
    res = run_episodes(policy, seeds=range(episodes), max_steps=max_steps)
    return {"seconds": time.perf_counter() - t0, "episodes": episodes, "slots": res["slots"]}


def solver_seconds(quick: bool = False) -> dict:
    """Wall times of the allocation solvers on the paper preset (the shared analytic model built
    first, outside the timing), beside the paper's. ``quick``: a 0.1 grid and 20 generations of the evolution.
    """
    from iscc_gym.agents import evolutionary_search, grid_search, sca_allocation

    from iscc_gym.analysis import static_model
    from iscc_gym.scenario import make_scenario

    s = make_scenario("paper")
    static_model(s)
    out = {}
    out["sca"] = {"seconds": sca_allocation(s).wall_time_s, "paper_s": 68.60, "target_s": 1.0}
    r = grid_search(s, step=0.1 if quick else 0.01)
    out["grid"] = {"seconds": r.wall_time_s, "paper_s": 10154.78, "target_s": 10.0}
    r = evolutionary_search(s, seed=0, maxiter=20 if quick else 200)  # quick: 20 generations (2 s -> 0.2 s)
    out["evolutionary"] = {"seconds": r.wall_time_s, "paper_s": 694.84, "target_s": 10.0}
    return out


#: What each profile measures, and how long it took on this project's 2-core machine when quiet (stated at the start
#: of a run; a loaded machine takes several times longer). The short profile is the default.
PROFILES = {
    "short": ("the env, vector env, multi-drone, render, evaluation and solver figures", "about 1-2 min"),
    "full": ("every figure: also the kernel modes beside a busy process and the PPO training rates", "10-15 min"),
}


def run(n_steps: int = 5000, repeats: int = 5, quick: bool = False, ppo: bool = True, full: bool = True,
        quiet: bool = True) -> dict:
    """All benchmark figures as a JSON-able dict (``quick``: tiny sizes, for the tests; ``full=False``: without
    the kernel modes under load and, unless ``ppo``, the PPO rates). A line per stage on stderr unless ``quiet``.
    """
    vec_steps = 5 if quick else 200
    under_load = full or quick
    ppo = ppo and (full or quick)
    stages = ["single env", "vector env", "multi-drone", "urban task",
              *(["kernel modes under load"] if under_load else []),
              "render", "static SCA evaluation", "solvers", *(["PPO training"] if ppo else [])]
    t0 = time.perf_counter()
    with Stages(len(stages), "python -m eval.bench", enabled=not quiet) as st:
        st.next(stages[0])
        res = {
            "machine": {"python": platform.python_version(), "numpy": np.__version__,
                        "gymnasium": gym.__version__, "processor": platform.processor() or "unknown",
                        "cpu_count": os.cpu_count()},
            "single_env": {
                "iscc": env_steps_per_second(iscc_gym.ENV_ID, n_steps, repeats),
                "reference_pendulum_v1": env_steps_per_second("Pendulum-v1", n_steps, repeats),
            },
        }
        st.next("vector env")
        res["vector_env"] = {str(n): vector_steps_per_second(n, vec_steps if n < 1024 else vec_steps // 4 + 1,
                                                             repeats)
                             for n in ((1, 64) if quick else (1, 64, 1024))}
        st.next("multi-drone")
        res["multi_drone"] = multi_drone_cost(16 if quick else 1024, 4, 20 if quick else 300,
                                              1 if quick else repeats)
        st.next("urban task")
        res["urban"] = urban_speed(16 if quick else 1024, 20 if quick else 300, 1 if quick else repeats)
        if under_load:
            st.next("kernel modes under load")
            res["vector_under_load"] = (vector_under_load(sizes=(64,), n_steps=20, repeats=1) if quick
                                        else vector_under_load(n_steps=3000, repeats=repeats))
        st.next("render")
        res["render"] = render_ms(5 if quick else 50)
        st.next("static SCA evaluation")
        res["eval_static_sca"] = eval_sca_seconds(2 if quick else 100, max_steps=20 if quick else None)
        st.next("solvers")
        res["solvers"] = solver_seconds(quick)
        if ppo:
            st.next("PPO training")
            total = 256 if quick else 16384
            res["ppo_training"] = {kind: ppo_steps_per_second(kind, total, 1 if quick else repeats)
                                   for kind in ("dummy", "subproc", "batched", "pendulum_dummy")}
            res["ppo_shipped"] = ppo_shipped_steps_per_second(2048 if quick else 409_600, 1 if quick else 3,
                                                              THREAD_SETTINGS[:1] if quick else THREAD_SETTINGS)
    res["wall_time_s"] = time.perf_counter() - t0
    res["profile"] = "quick" if quick else ("full" if full else "short")
    return res


#: One cold process of :func:`compile_times`: each env id made, reset and stepped once (its kernels compiled), then
#: the device env's CPU stand-in of the single-drone ones, where numba-cuda is installed; a JSON line of the seconds.
_COMPILE_SCRIPT = """
import json, sys, time
import numpy as np
t = time.perf_counter()
import gymnasium as gym, iscc_gym
out = {"import": time.perf_counter() - t}
import importlib, os
for module in filter(None, os.environ.get("ISCC_GYM_PACKAGES", "").split(",")):
    importlib.import_module(module)
for env_id in sys.argv[1:]:
    t = time.perf_counter()
    env = gym.make(env_id)
    env.reset(seed=0)
    env.action_space.seed(0)
    env.step(env.action_space.sample())
    out[env_id] = time.perf_counter() - t
try:
    import torch
    from iscc_gym.gpu.vector_env import DeviceVectorEnv
except ImportError:
    DeviceVectorEnv = None
from iscc_gym.tasks import is_fleet
for env_id in sys.argv[1:] if DeviceVectorEnv is not None else ():
    if not is_fleet(env_id):
        t = time.perf_counter()
        d = DeviceVectorEnv(env_id, num_envs=8, device="cpu")
        d.reset(seed=0)
        d.step(torch.zeros(8, 3))
        out[env_id + " (device stand-in)"] = time.perf_counter() - t
print(json.dumps(out))
"""


def bench_env_ids() -> list[str]:
    """The env ids whose kernels :func:`compile_times` builds: every task of the task table (a task registered at
    run time, by ``--gym-packages``, too).
    """
    from iscc_gym.tasks import TASKS

    return list(TASKS)


def compile_times(env_ids=None) -> dict:
    """Seconds to build the compiled kernels from a cold cache (a new process, numba's cache in an empty folder):
    the package's import, then each task's env (``gym.make``, reset, a step), in the order given (a later task reuses
    the functions an earlier one compiled), then the device env's stand-in of each single-drone task. What the
    compile note (:mod:`iscc_gym.compile_note`) says is measured here.
    """
    import json
    import subprocess
    import tempfile

    from iscc_gym.commands.options import GYM_PACKAGES

    env_ids = bench_env_ids() if env_ids is None else list(env_ids)
    with tempfile.TemporaryDirectory(prefix="iscc_gym-cold-") as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache, "ISCC_GYM_QUIET": "1",
               "ISCC_GYM_PACKAGES": ",".join(GYM_PACKAGES)}  # the modules that registered tasks of their own
        r = subprocess.run([sys.executable, "-c", _COMPILE_SCRIPT, *env_ids], capture_output=True, text=True,
                           env=env, timeout=1800)
    if r.returncode != 0:
        raise RuntimeError(f"the cold-cache process failed: {r.stderr.strip().splitlines()[-1:]}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def build_parser(prog: str = "python -m eval.bench") -> argparse.ArgumentParser:
    ap = Parser(prog=prog, gym_packages=True,
                description=__doc__.split("\n")[0] + f" Default: a short run ({PROFILES['short'][0]}; "
                f"{PROFILES['short'][1]} on a quiet 2-core machine); --full: {PROFILES['full'][0]} "
                f"({PROFILES['full'][1]}).")
    ap.add_argument("--full", action="store_true",
                    help="every figure (the README's table: python -m experiments bench)")
    ap.add_argument("--steps", type=positive_int, default=None, metavar="N",
                    help="steps per run (default: 2000, 5000 with --full)")
    ap.add_argument("--repeats", type=positive_int, default=None, metavar="N",
                    help="runs per figure, the median reported (default: 3, 5 with --full)")
    ap.add_argument("--json", metavar="PATH", help="write the figures as JSON to PATH (checked before the run)")
    ap.add_argument("--quick", action="store_true", help="tiny sizes of every figure (a smoke run, for the tests)")
    ap.add_argument("--skip-ppo", action="store_true", help="skip the PPO training figures")
    ap.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    ap.add_argument("--device", choices=("cpu", "cuda", "standin"), default="cpu",
                    help="cpu: the CPU figures (default); cuda: the device env on a GPU (gpu extra), with the CPU "
                         "vector env's row of the same run; standin: those rows on the device env's CPU stand-in "
                         "(eval/bench_device.py); the device PPO's rows: python -m experiments.device_ppo")
    ap.add_argument("--compile", action="store_true",
                    help="only the time to build the compiled kernels from a cold cache, per task (what the note "
                         "printed on a first run says)")
    return ap


def main(argv: list[str] | None = None, prog: str = "python -m eval.bench") -> dict:
    args = build_parser(prog).parse_args(argv)
    if args.json:
        check_writable_file(args.json, "--json")
    if args.compile:
        if args.device != "cpu":
            raise ValueError("--compile measures the CPU kernels' build alone: drop --device")
        res = compile_times()
        print(format_compile(res))
        if args.json:
            save_json(args.json, res)
        return res
    if args.device != "cpu":
        from iscc_gym.eval.bench_device import format_device, run_device

        res = run_device(args.device, quick=args.quick, cpu_row=vector_steps_per_second)
        print(format_device(res))
        if args.json:
            save_json(args.json, res)
        return res
    profile = "full" if args.full else "short"
    if not args.quiet and not args.quick:
        print(f"{prog}: {profile} run, {PROFILES[profile][0]}; {PROFILES[profile][1]} on a quiet 2-core machine, "
              "several times longer beside busy processes", file=sys.stderr, flush=True)
    steps = args.steps or (5000 if args.full else 2000)
    repeats = args.repeats or (5 if args.full else 3)
    res = run(steps, repeats, quick=args.quick, ppo=not args.skip_ppo, full=args.full, quiet=args.quiet)
    print(format_report(res))
    if args.json:
        save_json(args.json, res)
    return res


if __name__ == "__main__":
    sys.exit(run_console(main, None, "python -m eval.bench"))
