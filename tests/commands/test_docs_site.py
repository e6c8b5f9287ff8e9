"""The documentation site (``docs/site``): it builds with warnings as errors, its generated tables are there, and
every ```python block of its own pages runs as written (issue 35, point 6).

The build imports the package's modules (autodoc) and takes ~20 s, so it is marked ``slow`` (CI runs
``python -m pytest tests -m slow`` as its second command); the code blocks run in one new interpreter started
outside the checkout, each block in a namespace of its own, in a few seconds.
"""

import json
import os
import pathlib
import re
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
SITE = ROOT / "docs" / "site"
#: single-threaded pools: the tests run beside each other on a small machine
QUIET = {"NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def site_blocks() -> list[dict]:
    """Every ```python block of the site's own pages (the included repository documents have none of their own:
    the README's are run by tests/commands/test_readme.py)."""
    blocks = []
    for page in sorted(SITE.rglob("*.md")):
        if "_build" in page.parts:
            continue
        text = page.read_text()
        for m in re.finditer(r"^```python\n(.*?)^```", text, re.S | re.M):
            blocks.append({"id": f"{page.relative_to(SITE)}:{text.count(chr(10), 0, m.start()) + 1}",
                           "line": text.count("\n", 0, m.start()) + 1, "file": str(page), "code": m.group(1)})
    return blocks


RUNNER = r'''
import ast, contextlib, io, json, sys, traceback

blocks, done = json.loads(open(sys.argv[1]).read()), {}
for b in blocks:
    tree = ast.parse(b["code"])
    ast.increment_lineno(tree, b["line"])  # tracebacks give the page's line numbers
    out, error = io.StringIO(), None
    try:
        with contextlib.redirect_stdout(out):
            exec(compile(tree, b["file"], "exec"), {"__name__": "__main__"})
    except BaseException:
        error = traceback.format_exc()
    done[b["id"]] = {"error": error, "stdout": out.getvalue()}
print(json.dumps(done))
'''

BLOCKS = site_blocks()


def test_the_site_has_code_blocks():
    pages = {b["id"].split(":")[0] for b in BLOCKS}
    assert {"getting-started.md", "extending.md", "tasks/paper.md", "tasks/urban.md", "tasks/multi.md"} <= pages


@pytest.fixture(scope="module")
def ran(tmp_path_factory):
    where = tmp_path_factory.mktemp("site-blocks")  # outside the checkout: the installed package
    (where / "blocks.json").write_text(json.dumps(BLOCKS))
    (where / "runner.py").write_text(RUNNER)
    proc = subprocess.run([sys.executable, "runner.py", "blocks.json"], cwd=where, capture_output=True, text=True,
                          timeout=300, env={**os.environ, **QUIET})
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("block", BLOCKS, ids=[b["id"] for b in BLOCKS])
def test_code_block_runs(ran, block):
    result = ran[block["id"]]
    assert result["error"] is None, f"{block['id']} failed:\n{result['error']}"
    assert result["stdout"].strip(), f"{block['id']} printed nothing; each block shows its result"


@pytest.mark.slow
def test_site_builds_with_warnings_as_errors(tmp_path):
    out = tmp_path / "html"
    proc = subprocess.run([sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html", str(SITE),
                           str(out), "-d", str(tmp_path / "doctrees")], capture_output=True, text=True, timeout=900,
                          cwd=tmp_path, env={**os.environ, **QUIET})
    assert proc.returncode == 0, f"the site's build failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-6000:]}"
    pages = {p: (out / p).read_text() for p in ["index.html", "getting-started.html", "tasks/paper.html",
                                                 "tasks/urban.html", "tasks/multi.html", "api/physics.html",
                                                 "api/envs.html", "extending.html", "versioning.html",
                                                 "results.html", "reproduction.html", "model.html", "changelog.html"]}
    from iscc_gym.scenario import SCENARIOS
    from iscc_gym.sim.schema import obs_names

    # each task page carries the observation table generated from the schema, every entry in order
    for page, preset in [("tasks/paper.html", "paper"), ("tasks/urban.html", "urban"), ("tasks/multi.html", "paper")]:
        names = obs_names(SCENARIOS[preset])
        table = re.search(r'<table class="[^"]*iscc-obs-table.*?</table>', pages[page], re.S)
        assert table, f"{page} has no generated observation table"
        assert re.findall(r'<span class="pre">([a-z_0-9]+)</span>', table.group(0)) == list(names), page
        assert f"({len(names)},), float32), generated from" in pages[page]
    assert "p_los_ahead_10" in pages["tasks/urban.html"] and "p_los_ahead" not in pages["tasks/paper.html"]
    # the reward from the env's docstring, the results from docs/results.md, the API from the docstrings
    assert "w_\\mathrm{rate}" in pages["tasks/paper.html"]
    assert "Learned vs scripted allocation" in pages["tasks/paper.html"]
    assert "ctrl_bler_one" in pages["api/physics.html"] and "ISCCMultiEnv" in pages["api/envs.html"]
    assert "rises when its dynamics change" in pages["versioning.html"]
    assert "Unreleased" in pages["changelog.html"]
    # issue 43.13: no role left unrendered (a docstring paragraph numpydoc read as parameters showed ":func:`...`"),
    # on any page, outside code literals; the getting-started page names every task
    for page in sorted(out.rglob("*.html")):
        text = re.sub(r'<code class="docutils literal[^"]*">.*?</code>', "", page.read_text(), flags=re.S)
        assert not re.search(r":(func|class|meth|mod|data|attr):`", text), page
    from iscc_gym.tasks import TASKS

    assert all(env_id in pages["getting-started.html"] for env_id in TASKS)
    assert "tasks/field.html" in pages["getting-started.html"]


def test_citation_cff_names_the_project_and_the_seed_paper():
    import yaml

    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    assert cff["cff-version"] == "1.2.0" and cff["type"] == "software"
    assert {"message", "title", "authors"} <= set(cff) and cff["title"].startswith("iscc-gym")
    (paper,) = cff["references"]
    assert paper["title"] == "Closed-Loop Integrated Sensing, Communication, and Control for Efficient Drone Flight"
    assert paper["authors"][0] == {"family-names": "Li", "given-names": "Jingli"} and len(paper["authors"]) == 13
    import iscc_gym

    assert cff["version"] == iscc_gym.__version__


def test_changelog_keeps_the_format_and_the_version_rule():
    text = (ROOT / "CHANGELOG.md").read_text()
    assert "## [Unreleased]" in text and "Keep a Changelog" in text
    assert "An env id's version `-vN` rises when its dynamics change" in text


def test_py_typed_is_package_data():
    tomllib = pytest.importorskip("tomllib")
    assert (ROOT / "iscc_gym" / "py.typed").is_file()
    data = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]
    assert "py.typed" in data["iscc_gym"]
