"""Sphinx extension of the iscc-gym site: tables generated from the code at build time.

* ``obs-table``: the observation table of a scenario preset, from
  ``iscc_gym.sim.schema.observation_table`` where it exists, else from ``obs_names`` and ``OBS_SCALING``.
* ``env-doc``: one section (``## Rewards``, ``## Episode End``, ...) of an env class's docstring,
  rendered as on the API page, so a task page shows the reward as the code documents it.
* ``autodoc-process-docstring``: the env docstrings follow Gymnasium's habit of Markdown section
  headings and pipe tables inside a reStructuredText docstring (the design notes' habit 1); they are turned
  into ``rubric`` and ``list-table`` here, before numpydoc reads the docstring, and the pipes of plain-text
  absolute values are escaped.
"""

from __future__ import annotations

import importlib
import inspect
import re

from docutils import nodes
from docutils.parsers.rst import Directive, Parser, directives
from docutils.utils import new_document

_HEADING = re.compile(r"^(\s*)#{2,4}\s+(.+?)\s*$")
_ROW = re.compile(r"^\s*\|.*\|\s*$")
_RULE = re.compile(r"^\s*\|?\s*:?-{3,}:?\s*(\|\s*:?-{3,}:?\s*)*\|?\s*$")


def _cells(line: str) -> list[str]:
    # split on pipes with a space either side, so a pipe inside a cell (x_hat_{n|n-1}) stays in it
    inner = line.strip()[1:-1]
    return [c.strip() for c in re.split(r"(?<=\s)\|(?=\s)", f" {inner} ")]


def markdown_to_rst(lines: list[str]) -> list[str]:
    """Markdown headings and pipe tables of a docstring as reStructuredText ``rubric`` and ``list-table``."""
    out: list[str] = []
    i = 0
    while i < len(lines):
        line = lines[i]
        head = _HEADING.match(line)
        if head:
            out += [f"{head.group(1)}.. rubric:: {head.group(2)}", ""]
            i += 1
            continue
        if _ROW.match(line) and i + 1 < len(lines) and _RULE.match(lines[i + 1]):
            indent = line[: len(line) - len(line.lstrip())]
            rows = [_cells(line)]
            i += 2
            while i < len(lines) and _ROW.match(lines[i]):
                rows.append(_cells(lines[i]))
                i += 1
            out += _list_table(rows, indent)
            continue
        out.append(line)
        i += 1
    return out


def _list_table(rows: list[list[str]], indent: str = "") -> list[str]:
    width = len(rows[0])
    out = [f"{indent}.. list-table::", f"{indent}   :header-rows: 1", ""]
    for row in rows:
        row = (row + [""] * width)[:width]
        for j, cell in enumerate(row):
            out.append(f"{indent}   {'*' if j == 0 else ' '} - {cell or ' '}")
    return out + [""]


_CODE = re.compile(r"(``.+?``|`[^`]*`)")


def escape_bars(lines: list[str]) -> list[str]:
    """Escape the pipes of plain-text absolute values (``ln(1 + |x|/c)``) outside math and code.

    No docstring defines a reStructuredText substitution, so ``|x|`` is never one; left as it is, docutils
    reports an undefined substitution. Math blocks, inline code and math, and lines that open with a pipe
    (grid tables, line blocks) are left as they are.
    """
    out, math_indent = [], None
    for line in lines:
        stripped = line.lstrip()
        indent = len(line) - len(stripped)
        if math_indent is not None and (not stripped or indent > math_indent):
            out.append(line)
            continue
        math_indent = indent if stripped.startswith(".. math::") else None
        if "|" not in line or stripped.startswith("|") or math_indent is not None:
            out.append(line)
            continue
        parts = _CODE.split(line)
        out.append("".join(p if k % 2 else p.replace("|", "\\|") for k, p in enumerate(parts)))
    return out


#: numpydoc's names of a section, and the names some docstrings use for them.
_SECTION_ALIASES = {"Arguments": "Parameters", "Args": "Parameters", "Keyword Arguments": "Other Parameters"}


def section_aliases(lines: list[str]) -> list[str]:
    """Underlined sections under another name than numpydoc's (``Arguments``) renamed to numpydoc's."""
    out = list(lines)
    for i in range(len(out) - 1):
        name, rule = out[i].strip(), out[i + 1].strip()
        if name in _SECTION_ALIASES and rule and set(rule) == {"-"} and len(rule) >= len(name):
            indent = out[i][: len(out[i]) - len(out[i].lstrip())]
            new = _SECTION_ALIASES[name]
            out[i], out[i + 1] = indent + new, indent + "-" * len(new)
    return out


def _process_docstring(app, what, name, obj, options, lines):
    if any(_HEADING.match(x) for x in lines) or any(_RULE.match(x) for x in lines):
        lines[:] = markdown_to_rst(lines)
    lines[:] = escape_bars(section_aliases(lines))


def _parse_rst(directive: Directive, text: str) -> list[nodes.Node]:
    """Parse reStructuredText (Sphinx roles included) inside a page of any source format."""
    document = directive.state.document
    doc = new_document(document["source"], document.settings)
    doc.reporter = document.reporter
    Parser().parse(text, doc)
    return list(doc.children)


def _scaling(entry) -> str:
    if isinstance(entry, str):
        return entry
    kind, c = entry
    if kind == "symlog":
        return f"symlog(x, {c:g})"
    if kind == "linear":
        return "x" if c == 1 else f"{c:g} x"
    return {"range": "x / coverage radius", "time_left": "1 - n / n_slots"}.get(kind, kind)


def _cell(value) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


def observation_rows(scenario: str) -> tuple[list[str], list[list[str]]]:
    """Header and rows of a preset's observation table, generated from the schema."""
    from iscc_gym.scenario import SCENARIOS
    from iscc_gym.sim import schema

    s = SCENARIOS[scenario]
    table = getattr(schema, "observation_table", None)
    if table is not None:
        rows = list(table(s))
        if rows and isinstance(rows[0], dict):
            keys = list(rows[0])
            labels = {"index": "Num"}
            return ([labels.get(k, k[:1].upper() + k[1:]) for k in keys],
                    [[_cell(r[k]) for k in keys] for r in rows])
        return [], [[_cell(c) for c in r] for r in rows]
    # until the schema writes the table itself: names from obs_names, scalings from OBS_SCALING
    extra = {
        "backlog": "ln(1 + B / (arrival rate x dt))", "oldest_age": "age / deadline",
        "echo_snr_db": f"{schema.SNR_SCALE:g} x (dB)", "p_los_ahead": "x (probability)",
    }
    header = ["Num", "Name", "Scaling", "Min", "Max"]
    rows = []
    for j, name in enumerate(schema.obs_names(s)):
        base = re.sub(r"_\d+$", "", name) if name not in schema.OBS_SCALING else name
        if base in schema.OBS_SCALING:
            how = _scaling(schema.OBS_SCALING[base])
        elif base in extra:
            how = extra[base]
        else:  # the preview's SNRs, dB like snr_db
            how = f"{schema.SNR_SCALE:g} x (dB)"
        rows.append([str(j), name, how, f"{-schema.OBS_BOUND:g}", f"{schema.OBS_BOUND:g}"])
    return header, rows


def table_node(header: list[str], rows: list[list[str]], literal_col: int | None = 1,
               cls: str = "iscc-generated") -> nodes.table:
    width = len(header) if header else len(rows[0])
    table = nodes.table(classes=[cls])
    group = nodes.tgroup(cols=width)
    table += group
    group.extend(nodes.colspec(colwidth=1) for _ in range(width))

    def row(cells, head=False):
        r = nodes.row()
        for j, cell in enumerate(cells):
            text = nodes.literal(cell, cell) if (j == literal_col and not head) else nodes.Text(cell)
            r += nodes.entry("", nodes.paragraph("", "", text))
        return r

    if header:
        group += nodes.thead("", row(header, head=True))
    group += nodes.tbody("", *(row(r) for r in rows))
    return table


class ObsTable(Directive):
    """``obs-table PRESET``: the observation table of a scenario preset, generated from the code."""

    required_arguments = 1
    has_content = False

    def run(self):
        from iscc_gym.sim import schema

        header, rows = observation_rows(self.arguments[0])
        col = next((j for j, h in enumerate(header) if h.lower() == "name"), None)
        preset = self.arguments[0]
        intro = nodes.paragraph("", "", nodes.Text(
            f"Box(-{schema.OBS_BOUND:g}, {schema.OBS_BOUND:g}, ({len(rows)},), float32), generated from "
            "iscc_gym.sim.schema when this page was built (preset "), nodes.literal(preset, preset), nodes.Text(")."))
        return [intro, table_node(header, rows, col, cls="iscc-obs-table")]


class EnvDoc(Directive):
    """``env-doc dotted.Class Section``: a section of a class docstring (its Markdown ``## Section``)."""

    required_arguments = 2
    final_argument_whitespace = True
    option_spec = {"heading-level": directives.unchanged}

    def run(self):
        path, section = self.arguments
        module, _, name = path.rpartition(".")
        doc = inspect.getdoc(getattr(importlib.import_module(module), name)) or ""
        lines = doc.splitlines()
        try:
            start = next(i for i, x in enumerate(lines) if re.match(rf"^#{{2,4}}\s+{re.escape(section)}\s*$", x))
        except StopIteration:
            raise self.error(f"{path}'s docstring has no section '## {section}'") from None
        end = next((i for i in range(start + 1, len(lines)) if _HEADING.match(lines[i])), len(lines))
        text = "\n".join(escape_bars(markdown_to_rst(lines[start + 1:end])))
        self.state.document.settings.env.note_dependency(inspect.getsourcefile(importlib.import_module(module)))
        return _parse_rst(self, text)


def task_rows(env_id: str) -> list[list[str]]:
    """Facts of a registered task: from the task tables where they exist, else from Gymnasium's registry."""
    import gymnasium as gym

    import iscc_gym  # noqa: F401 (registers the ids)

    spec = gym.spec(env_id)
    rows = [["env id", env_id], ["entry point", str(spec.entry_point)],
            ["vector entry point", str(spec.vector_entry_point)],
            ["mission length (max_episode_steps)", f"{spec.max_episode_steps:,} slots"],
            ["Scenario preset", str((spec.kwargs or {}).get("scenario", "paper"))]]
    try:
        from iscc_gym.tasks import TASKS
    except ImportError:
        TASKS = {}
    task = TASKS.get(env_id)
    if task is not None:
        rows.insert(1, ["task", task.title])
        if task.variants:
            rows.append(["mission variants", ", ".join(task.variants)])
    try:
        from iscc_gym.agents.tasks import TASK_POLICIES
    except ImportError:
        TASK_POLICIES = {}
    pol = TASK_POLICIES.get(env_id)
    if pol is not None:
        rows.append(["compared by default", pol.policies.replace(",", ", ")])
        rows.append(["reference policy", pol.reference])
        if pol.agent is not None:
            rows.append(["shipped agent", str(pol.agent.relative_to(pol.agent.parents[2]))
                         if len(pol.agent.parents) > 2 else str(pol.agent)])
    return rows


def task_index_rows() -> list[list[str]]:
    """One row per task of the task table (:data:`iscc_gym.tasks.TASKS`, so a task registered at run time too):
    env id, title, preset, page on this site.
    """
    import iscc_gym  # noqa: F401 (registers the ids)
    from iscc_gym.tasks import TASKS

    return [[e, t.title, t.preset, t.docs_page] for e, t in TASKS.items()]


class TaskIndex(Directive):
    """``task-index``: every task of the task table, read from the task files."""

    def run(self):
        return [table_node(["env id", "task", "preset", "page"], task_index_rows(), literal_col=0)]


class TaskFacts(Directive):
    """``task-facts ENV_ID``: a task's registration and settings, read from the code."""

    required_arguments = 1

    def run(self):
        return [table_node(["", ""], task_rows(self.arguments[0]), literal_col=None)]


def setup(app):
    app.connect("autodoc-process-docstring", _process_docstring, priority=100)
    app.add_directive("obs-table", ObsTable)
    app.add_directive("env-doc", EnvDoc)
    app.add_directive("task-facts", TaskFacts)
    app.add_directive("task-index", TaskIndex)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
