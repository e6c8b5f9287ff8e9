"""The README's code examples run as written: every ```python block, in a new interpreter started outside the
checkout (issue 34: a block importing ``loop`` from where it no longer lives failed for readers and no test saw
it). A block too slow for the suite is marked ``<!-- readme-test: imports only: <why> -->`` on the line before
its fence: its iscc_gym imports run, and the reason names the test that runs it in miniature."""

import ast
import json
import os
import pathlib
import re
import subprocess
import sys
import tempfile

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
IMPORTS_ONLY = re.compile(r"<!-- readme-test: imports only: (.+?) -->")

#: what the tests below read from a block's namespace after it ran, by the generated section it sits in
PROBES = {"readme-multi": ['info["alpha"].shape', 'info["cost_rate"].shape', "agents.possible_agents"],
          "readme-urban": ["obs.shape", 'float(info["bits_dropped"])']}

#: run by the interpreter the blocks share: each block in a new namespace, its stdout and error kept
RUNNER = r'''
import ast, contextlib, io, json, os, sys, traceback

def iscc_gym_imports(tree):
    keep = []
    for node in tree.body:
        if isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "iscc_gym":
            keep.append(node)
        elif isinstance(node, ast.Import):
            names = [a for a in node.names if a.name.split(".")[0] == "iscc_gym"]
            if names:
                keep.append(ast.copy_location(ast.Import(names=names), node))
    tree.body = keep
    return tree

blocks = json.loads(open(sys.argv[1]).read())
done = {"cwd": os.getcwd(), "sys_path": sys.path, "blocks": {}}
for b in blocks:
    tree = ast.parse(b["code"])
    if b["imports_only"]:
        tree = iscc_gym_imports(tree)
    ast.increment_lineno(tree, b["line"])  # tracebacks give README.md's line numbers
    ns, out, error, probes = {"__name__": "__main__"}, io.StringIO(), None, {}
    try:
        with contextlib.redirect_stdout(out):
            exec(compile(tree, "README.md", "exec"), ns)
            probes = {p: json.loads(json.dumps(eval(p, ns))) for p in b["probes"]}
    except BaseException:
        error = traceback.format_exc()
    done["blocks"][str(b["line"])] = {"error": error, "stdout": out.getvalue(), "probes": probes}
with open(sys.argv[2], "w") as f:
    json.dump(done, f)
'''


def readme_blocks(text: str | None = None) -> list[dict]:
    """Every ```python block of the README: its first line's number, code, section and imports-only reason."""
    text = README.read_text() if text is None else text
    blocks = []
    for m in re.finditer(r"^```python\n(.*?)^```", text, re.S | re.M):
        before = text[:m.start()].rstrip("\n").rsplit("\n", 2)[-2:]
        marker = IMPORTS_ONLY.fullmatch(before[-1])
        section = re.fullmatch(r"<!-- ([\w-]+):start -->", before[-1] if marker is None else before[0])
        blocks.append({"line": text.count("\n", 0, m.start()) + 1, "code": m.group(1),
                       "section": section and section.group(1), "imports_only": marker and marker.group(1)})
    return blocks


def _imports_iscc_gym(code: str) -> bool:
    names = [a.name for n in ast.walk(ast.parse(code)) if isinstance(n, ast.Import) for a in n.names]
    names += [n.module or "" for n in ast.walk(ast.parse(code)) if isinstance(n, ast.ImportFrom)]
    return any(name.split(".")[0] == "iscc_gym" for name in names)


BLOCKS = readme_blocks()
_run = {}


def start_readme_blocks():
    """Start the interpreter that runs every block (once per session), in a folder outside the checkout, without
    the checkout on its path; ``tests/conftest.py`` starts it as soon as the tests are collected, so that its
    imports and the blocks (several seconds of one core) run beside the tests before this module's."""
    if "proc" in _run:
        return
    folder = tempfile.TemporaryDirectory(prefix="readme-blocks-")
    work = pathlib.Path(folder.name)
    assert ROOT not in work.resolve().parents
    # blocks that never import iscc_gym first: their "iscc_gym:" ids must import it themselves
    order = sorted(BLOCKS, key=lambda b: _imports_iscc_gym(b["code"]))
    (work / "blocks.json").write_text(json.dumps(
        [{"line": b["line"], "code": b["code"], "imports_only": bool(b["imports_only"]),
          "probes": PROBES.get(b["section"], [])} for b in order]))
    (work / "run_blocks.py").write_text(RUNNER)
    path = [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p and pathlib.Path(p).resolve() != ROOT]
    # one thread for its torch, numpy and numba pools: it runs beside the suite on the other core
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(path), "ISCC_GYM_QUIET": "1", "OMP_NUM_THREADS": "1",
           "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}
    with open(work / "output.txt", "w") as output:  # a file, not a pipe that nobody reads until the module runs
        _run.update(folder=folder, proc=subprocess.Popen(
            [sys.executable, "run_blocks.py", "blocks.json", "results.json"], cwd=work, env=env,
            stdin=subprocess.DEVNULL, stdout=output, stderr=subprocess.STDOUT))


def stop_readme_blocks():
    """Kill the blocks' interpreter if it still runs and remove its folder (the session's end)."""
    proc = _run.pop("proc", None)
    if proc is not None and proc.poll() is None:
        proc.kill()
        proc.wait()
    if "folder" in _run:
        _run.pop("folder").cleanup()


@pytest.fixture(scope="module")
def ran():
    """The blocks' results: ``{"cwd", "sys_path", "blocks": {line: {"error", "stdout", "probes"}}}``."""
    start_readme_blocks()
    work = pathlib.Path(_run["folder"].name)
    assert _run["proc"].wait(timeout=600) == 0, (work / "output.txt").read_text()
    yield json.loads((work / "results.json").read_text())
    stop_readme_blocks()


@pytest.mark.parametrize("block", BLOCKS, ids=[f"README.md:{b['line']}" for b in BLOCKS])
def test_every_python_block_of_the_readme_runs_outside_the_checkout(ran, block):
    assert ROOT != pathlib.Path(ran["cwd"]).resolve() and ROOT not in pathlib.Path(ran["cwd"]).resolve().parents
    assert ROOT not in [pathlib.Path(p or ran["cwd"]).resolve() for p in ran["sys_path"]]
    error = ran["blocks"][str(block["line"])]["error"]
    if error is not None:
        pytest.fail(f"README.md's block at line {block['line']} fails:\n{error}", pytrace=False)


def test_few_readme_blocks_run_their_imports_only_each_for_a_reason():
    """The imports-only mark is for training and heavy clients: at most three blocks, each reason naming a test
    of tests/commands/test_clients.py that runs the block in miniature; a mark anywhere else is a mistake."""
    marked = [b for b in BLOCKS if b["imports_only"]]
    assert len(marked) <= 3
    assert len(IMPORTS_ONLY.findall(README.read_text())) == len(marked)  # each mark sits right above a block
    clients = (ROOT / "tests" / "commands" / "test_clients.py").read_text()
    for b in marked:
        named = re.findall(r"tests/commands/test_clients\.py::(\w+)", b["imports_only"])
        assert named and all(f"\ndef {name}(" in clients for name in named), b["imports_only"]


def test_readme_block_reader_sees_sections_and_marks():
    text = ("<!-- readme-x:start -->\n```python\nimport iscc_gym\n```\n<!-- readme-x:end -->\n"
            "<!-- readme-test: imports only: slow -->\n```python\nimport a, iscc_gym\n```\n```bash\nls\n```\n")
    got = readme_blocks(text)
    assert [(b["line"], b["section"], b["imports_only"]) for b in got] == [(2, "readme-x", None), (7, None, "slow")]
    assert got[1]["code"] == "import a, iscc_gym\n"


def test_readme_gymnasium_sb3_example_runs(ran):
    block, = (b for b in BLOCKS if b["section"] == "readme-example")
    assert len(block["code"].strip().splitlines()) == 5  # the five-line example the README promises
    printed = ran["blocks"][str(block["line"])]["stdout"]
    alpha = [float(v) for v in re.findall(r"[0-9.]+(?:e-?\d+)?", printed)]
    assert len(alpha) == 3 and abs(sum(alpha) - 1.0) < 1e-6


def test_readme_multi_drone_example_runs_in_five_lines(ran):
    block, = (b for b in BLOCKS if b["section"] == "readme-multi")
    assert len(block["code"].strip().splitlines()) == 5  # the five lines
    got = ran["blocks"][str(block["line"])]
    assert got["probes"]['info["alpha"].shape'] == [4, 3] and got["probes"]['info["cost_rate"].shape'] == [4]
    assert got["probes"]["agents.possible_agents"] == [f"drone_{k}" for k in range(4)]
    assert "[" in got["stdout"]


def test_readme_urban_example_runs(ran):
    block, = (b for b in BLOCKS if b["section"] == "readme-urban")
    assert len(block["code"].strip().splitlines()) == 4
    got = ran["blocks"][str(block["line"])]
    assert got["probes"]["obs.shape"] == [76] and got["probes"]['float(info["bits_dropped"])'] == 0.0
    assert len(got["stdout"].split()) == 3


def _outside_generated_blocks(text: str) -> str:
    return re.sub(r"<!-- ([\w-]+):start -->.*?<!-- \1:end -->", "", text, flags=re.S)


def _comparison_row(text: str, pair: str, section: str = "comparison") -> tuple[float, float]:
    block = text[text.index(f"<!-- {section}:start -->"):text.index(f"<!-- {section}:end -->")]
    row = re.search(rf"^\| {re.escape(pair)} \| ([+-][0-9.]+) ±([0-9.]+) \|", block, re.M)
    assert row, f"no row {pair!r} in the generated comparison"
    return float(row.group(1)), float(row.group(2))


def test_readme_prose_agrees_with_its_generated_comparison():
    """The hand-written reading of the comparison states who wins; the generated table must say the same."""
    text = README.read_text()
    prose = _outside_generated_blocks(text)
    if "**The learned agent does not beat the two per-slot scripted" in prose:
        for other in ("myopic", "margin"):
            mean, half = _comparison_row(text, f"ppo vs {other}")
            assert mean + half < 0, f"README says ppo does not beat {other}, the table says {mean} ±{half}"
    else:
        raise AssertionError("README's reading of the comparison changed: update this test with it")
    for other in ("margin", "myopic", "ppo"):  # 'every policy that adapts the split ... beats the static allocation'
        mean, half = _comparison_row(text, f"{other} vs sca")
        assert mean - half > 0, f"README says {other} beats static SCA, the table says {mean} ±{half}"


def test_readme_reading_of_the_urban_comparison_agrees_with_its_table():
    """The README says the urban agent does not beat the planner, and quotes its two differences: the generated
    table in docs/results.md must hold both figures and have neither interval above zero.
    """
    results = (README.parent / "docs" / "results.md").read_text()
    flat = " ".join(_outside_generated_blocks(README.read_text()).split()).replace("−", "-")
    assert "It does **not** beat the planner" in flat
    for other in ("mpc", "myopic"):
        mean, half = _comparison_row(results, f"ppo vs {other}", "urban-comparison")
        assert mean - half <= 0, f"README says ppo does not beat {other}, the table says {mean} ±{half}"
        assert f"{mean:.1f} ±{half:.1f}" in flat, f"README's figure for ppo vs {other} is not the table's"


def test_readme_quotes_no_time_that_no_command_produced():
    """Every wall time in the README sits in a block a command generates (setup-times, bench, reproduce, ...)."""
    prose = _outside_generated_blocks(README.read_text())
    quoted = re.findall(r"(?:about|~|takes|in)\s*[0-9.,]+\s*(?:s|sec|seconds|min|minutes|h|hours)\b", prose)
    assert not quoted, f"hand-written times in README.md: {quoted}"
    assert "half a minute" not in prose


def test_ci_runs_the_readme_commands_in_a_fresh_venv():
    """.ci/run runs tools/readme_commands.py, which reads exactly the README's set-up commands: the main job, the
    tests and the slow tests (the ones the tests' command skips), each on the same install."""
    import importlib.util

    root = README.parent
    assert "tools/readme_commands.py" in (root / ".ci" / "run").read_text()
    spec = importlib.util.spec_from_file_location("readme_commands", root / "tools" / "readme_commands.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    commands = mod.readme_commands(README.read_text())
    assert list(commands) == ["main", "tests", "slow"]
    assert commands["main"].endswith("python -m eval") and commands["tests"].endswith("python -m pytest tests")
    assert commands["slow"].endswith("python -m pytest tests -m slow")
    install = commands["tests"].rsplit("&&", 1)[0]
    assert install.startswith("pip install torch==2.13.0 &&")
    assert commands["main"].startswith(install) and commands["slow"].startswith(install)
    assert "setup-times:start" in README.read_text()


def test_readme_rl_zoo3_recipe_says_enjoy_needs_requests():
    """Issue 34: ``python -m rl_zoo3.enjoy`` needs ``requests``, which ``pip install rl_zoo3`` does not bring."""
    text = README.read_text()
    recipe = text[text.index("**rl-zoo3**"):text.index("python -m rl_zoo3.enjoy")]
    assert "pip install rl_zoo3 requests" in recipe
