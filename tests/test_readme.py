"""The README's code examples run as written."""

import pathlib
import re

README = pathlib.Path(__file__).resolve().parents[1] / "README.md"


def _block(start: str, end: str) -> str:
    text = README.read_text()
    section = text[text.index(start):text.index(end)]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_readme_gymnasium_sb3_example_runs(capsys):
    code = _block("<!-- readme-example:start -->", "<!-- readme-example:end -->")
    assert len(code.strip().splitlines()) == 5  # the five-line example the README promises
    exec(compile(code, "README example", "exec"), {})
    printed = capsys.readouterr().out
    alpha = [float(v) for v in re.findall(r"[0-9.]+(?:e-?\d+)?", printed)]
    assert len(alpha) == 3 and abs(sum(alpha) - 1.0) < 1e-6


def test_readme_multi_drone_example_runs_in_five_lines(capsys):
    code = _block("<!-- readme-multi:start -->", "<!-- readme-multi:end -->")
    assert len(code.strip().splitlines()) == 5  # the five lines
    namespace = {}
    exec(compile(code, "README multi-drone example", "exec"), namespace)
    assert namespace["info"]["alpha"].shape == (4, 3) and namespace["info"]["cost_rate"].shape == (4,)
    assert namespace["agents"].possible_agents == [f"drone_{k}" for k in range(4)]
    assert "[" in capsys.readouterr().out


def test_readme_urban_example_runs(capsys):
    code = _block("<!-- readme-urban:start -->", "<!-- readme-urban:end -->")
    assert len(code.strip().splitlines()) == 4
    namespace = {}
    exec(compile(code, "README urban example", "exec"), namespace)
    assert namespace["obs"].shape == (76,) and namespace["info"]["bits_dropped"] == 0.0
    assert len(capsys.readouterr().out.split()) == 3


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
    """.ci/run runs tools/readme_commands.py, which reads exactly the README's two set-up commands."""
    import importlib.util

    root = README.parent
    assert "tools/readme_commands.py" in (root / ".ci" / "run").read_text()
    spec = importlib.util.spec_from_file_location("readme_commands", root / "tools" / "readme_commands.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    commands = mod.readme_commands(README.read_text())
    assert list(commands) == ["main", "tests"]
    assert commands["main"].endswith("python -m eval") and commands["tests"].endswith("python -m pytest tests")
    install = commands["tests"].rsplit("&&", 1)[0]
    assert commands["main"].startswith(install) and install.startswith("pip install torch==2.13.0 &&")
    assert "setup-times:start" in README.read_text()


def test_readme_rl_zoo3_recipe_says_enjoy_needs_requests():
    """Issue 34: ``python -m rl_zoo3.enjoy`` needs ``requests``, which ``pip install rl_zoo3`` does not bring."""
    text = README.read_text()
    recipe = text[text.index("**rl-zoo3**"):text.index("python -m rl_zoo3.enjoy")]
    assert "pip install rl_zoo3 requests" in recipe
