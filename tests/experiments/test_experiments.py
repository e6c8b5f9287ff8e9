"""The studies behind the docs live outside the installed package (issue 35 point 3) and are one table run by one
command (issue 44 point 3): every generated section of the docs is written by exactly one entry of
:data:`experiments.studies.STUDIES` and names ``python -m experiments NAME``; installed commands write no docs."""

import importlib
import re
from pathlib import Path

import pytest

from experiments.studies import STUDIES, get_study, section_index

ROOT = Path(__file__).resolve().parents[2]
SECTION = re.compile(r"<!-- (\S+):start -->(.*?)<!-- \1:end -->", re.S)
GENERATED = re.compile(r"(?:Generated|Measured|Written|generated) by `(python -m [^`]*)`")
#: Generated blocks no study writes: the README's setup times (tools/readme_commands.py, which builds a venv), the
#: experiments list itself (python -m experiments index) and the README's examples (run by tests/commands/test_readme).
NOT_STUDIES = {"README.md#setup-times", "README.md#readme-example", "README.md#readme-multi",
               "README.md#readme-urban", "experiments/README.md#studies"}


def _sections() -> dict[str, str]:
    out = {}
    for rel in ("docs/results.md", "docs/learning.md", "docs/model.md", "README.md", "experiments/README.md"):
        out.update({f"{rel}#{m.group(1)}": m.group(2) for m in SECTION.finditer((ROOT / rel).read_text())})
    return out


def test_every_generated_section_is_written_by_one_study_that_names_itself():
    owners = {}
    for study in STUDIES.values():
        for where in study.sections:
            assert where not in owners, f"{where}: {owners.get(where)} and {study.name}"
            owners[where] = study.name
    sections = _sections()
    assert set(owners) | NOT_STUDIES == set(sections), set(sections) ^ (set(owners) | NOT_STUDIES)
    for where, name in owners.items():
        generated = GENERATED.search(sections[where].replace("\n", " "))
        if generated is not None:  # a section's own line names its study
            assert generated.group(1) == f"python -m experiments {name}", where


@pytest.mark.parametrize("name", list(STUDIES))
def test_every_study_runs_a_module_that_takes_its_arguments(name, capsys):
    study = get_study(name)
    module = importlib.import_module(study.module)
    assert callable(module.main)
    from experiments.__main__ import run_study

    with pytest.raises(SystemExit) as e:  # its parser takes the entry's arguments, then --help stops it
        run_study(name, ["--help"])
    assert e.value.code == 0
    assert capsys.readouterr().out.startswith(f"python -m experiments {name}: {study.what}")


def test_the_list_of_sections_is_the_tables():
    text = (ROOT / "experiments/README.md").read_text()
    assert f"<!-- studies:start -->\n{section_index()}\n<!-- studies:end -->" in text, \
        "python -m experiments index rewrites it from experiments/studies.py"
    with pytest.raises(ValueError, match="'nope' is not a study; use one of reproduce, tasks, agent"):
        get_study("nope")


def test_the_studies_are_not_installed_and_nothing_installed_imports_them_or_writes_the_docs():
    packages = re.search(r"^packages = \[(.*?)\]", (ROOT / "pyproject.toml").read_text(), re.M | re.S).group(1)
    assert "iscc_gym.eval" in packages and "experiments" not in packages
    for folder in ("iscc_gym", "agents", "commands", "train", "eval"):
        for path in (ROOT / folder).rglob("*.py"):
            text = path.read_text()
            assert not re.search(r"^\s*(from|import) experiments\b", text, re.M), path
            if path != ROOT / "commands" / "docs.py":  # where they are defined: only the studies call them
                assert not re.search(r"\b(write_section|publish|docs_path)\(", text), path
