"""The studies behind the docs live outside the installed package (issue 35 point 3), each section of
``docs/results.md`` listed with the command that regenerates it."""

import importlib
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SECTION = re.compile(r"<!-- (\S+):start -->(.*?)<!-- \1:end -->", re.S)
GENERATED = re.compile(r"(?:Generated|Measured|Written|generated) by `(python -m [^`]*)`")


def _listed() -> dict[str, str]:
    rows = re.findall(r"^\| `([^`]+)` \| .* \| `(python -m [^`]+)` \|$", (ROOT / "experiments/README.md").read_text(),
                      re.M)
    return dict(rows)


def _module(command: str) -> str:
    name = command.split()[2]
    return name if name.startswith("experiments") else f"iscc_gym.{name}" + (
        ".__main__" if name in ("eval", "train") else "")


def test_every_results_section_is_listed_with_the_command_that_wrote_it():
    listed = _listed()
    sections = {m.group(1): m.group(2) for m in SECTION.finditer((ROOT / "docs/results.md").read_text())}
    assert set(listed) == set(sections), "experiments/README.md lists every section of docs/results.md"
    for name, body in sections.items():
        generated = GENERATED.search(body)
        if generated is not None:  # a section's own line names its command
            assert listed[name] == generated.group(1), name
        importlib.import_module(_module(listed[name]))  # the command exists


def test_the_studies_are_not_installed_and_nothing_installed_imports_them():
    packages = re.search(r"^packages = \[(.*?)\]", (ROOT / "pyproject.toml").read_text(), re.M | re.S).group(1)
    assert "iscc_gym.eval" in packages and "experiments" not in packages
    for folder in ("iscc_gym", "agents", "train", "eval"):
        for path in (ROOT / folder).rglob("*.py"):
            assert not re.search(r"^\s*(from|import) experiments\b", path.read_text(), re.M), path
