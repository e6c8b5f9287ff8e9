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
