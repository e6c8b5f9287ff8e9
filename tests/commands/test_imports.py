"""The architecture, enforced (issues 14 and 24): imports run one way and no module waits on itself.

Every module's imports are read with ``ast`` (no import is executed), at module level and inside
functions alike; imports under ``if TYPE_CHECKING:`` (annotations only, never run) are skipped.

- Layers of the core ``iscc_gym``: the base (``scenario``, ``scenario_checks``, ``trajectory``, ``units``,
  ``files`` and the other top-level helpers) imports none of the sub-packages; ``physics`` nothing of
  ``sim``, ``envs``, ``analysis`` or ``gpu``; ``sim`` nothing of ``envs``, ``analysis`` or ``gpu``; ``envs`` and
  ``analysis`` nothing of each other nor of ``gpu``; ``gpu`` (the device env, the gpu extra) nothing of ``analysis``
  and, of what lies outside the core, torch alone. The package's ``__init__`` (its public face) may import any of them.
- The core imports nothing of ``agents``, the command tooling (``iscc_gym.commands``: the console convention,
  options, protocol, docs writing), ``train``, ``eval``, torch, SB3 or optuna; ``agents`` nothing of ``commands``,
  ``train`` or ``eval``; ``commands`` nothing of torch, SB3, ``train`` or ``eval``; ``train`` and
  ``eval``, siblings, nothing of each other (eval reaches training through the command line,
  :mod:`iscc_gym.eval.training`).
- No circle: the graph of imports between the project's modules (all four folders) has no cycle.
- No private name (``_x``) is imported from another module.
"""

import ast
import importlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
#: folder -> the package it installs as (pyproject's package-dir)
FOLDERS = {ROOT / "iscc_gym": "iscc_gym", ROOT / "agents": "iscc_gym.agents", ROOT / "commands": "iscc_gym.commands",
           ROOT / "train": "iscc_gym.train",
           ROOT / "eval": "iscc_gym.eval", ROOT / "experiments": "experiments"}
OUTSIDE_CORE = ("iscc_gym.agents", "iscc_gym.train", "iscc_gym.eval", "iscc_gym.commands", "agents", "commands",
                "train", "eval", "experiments", "torch", "stable_baselines3", "sb3_contrib", "optuna")
SUBPACKAGES = ("physics", "sim", "envs", "analysis", "gpu")
#: layer -> names its modules must not import
RULES = {
    "base": tuple(f"iscc_gym.{p}" for p in SUBPACKAGES) + OUTSIDE_CORE,
    "physics": ("iscc_gym.sim", "iscc_gym.envs", "iscc_gym.analysis", "iscc_gym.gpu") + OUTSIDE_CORE,
    "sim": ("iscc_gym.envs", "iscc_gym.analysis", "iscc_gym.gpu") + OUTSIDE_CORE,
    "envs": ("iscc_gym.analysis", "iscc_gym.gpu") + OUTSIDE_CORE,
    "analysis": ("iscc_gym.envs", "iscc_gym.gpu") + OUTSIDE_CORE,
    # the device env (the gpu extra): on top of the core's sim and envs, with torch; nothing of analysis or the
    # project's outer folders
    "gpu": ("iscc_gym.analysis",) + tuple(m for m in OUTSIDE_CORE if m != "torch"),
    "face": OUTSIDE_CORE,
    # the command tooling: on top of the core, below the commands; nothing of torch or SB3
    "commands": ("iscc_gym.train", "iscc_gym.eval", "train", "eval", "experiments", "torch", "stable_baselines3",
                 "sb3_contrib", "optuna"),
    "agents": ("iscc_gym.train", "iscc_gym.eval", "iscc_gym.commands", "commands", "train", "eval", "experiments"),
    "train": ("iscc_gym.eval", "eval", "experiments"),
    "eval": ("iscc_gym.train", "train", "experiments"),
    # the studies of this repository's docs (not installed): on top of everything, imported by nothing installed
    "experiments": (),
}


def modules() -> dict[str, Path]:
    """Every module of the project: its import name -> its file."""
    out = {}
    for folder, package in FOLDERS.items():
        for path in sorted(folder.rglob("*.py")):
            rel = path.relative_to(folder).with_suffix("").parts
            if package == "iscc_gym" and rel[0] in ("agents", "commands", "train", "eval"):
                continue  # an installed copy inside the package folder (never in a checkout)
            parts = rel[:-1] if rel[-1] == "__init__" else rel
            out[".".join((package, *parts))] = path
    return out


def layer(name: str) -> str:
    """The layer of module ``name``."""
    parts = name.split(".")
    if name == "iscc_gym":
        return "face"
    if parts[0] == "experiments":
        return "experiments"
    if parts[1] in ("agents", "commands", "train", "eval"):
        return parts[1]
    return parts[1] if parts[1] in SUBPACKAGES else "base"


def imports(path: Path, name: str) -> list[tuple[str, list[str], bool]]:
    """``(module, names, in_function)`` of every import of the module ``name`` at ``path`` (relative imports
    resolved; ``if TYPE_CHECKING:`` blocks skipped)."""
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    out = []

    def walk(node, inner):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and "TYPE_CHECKING" in ast.unparse(child.test):
                continue
            fn = inner or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
            if isinstance(child, ast.Import):
                out.extend((a.name, [], fn) for a in child.names)
            elif isinstance(child, ast.ImportFrom):
                if child.level:
                    base = package.rsplit(".", child.level - 1)[0] if child.level > 1 else package
                    mod = f"{base}.{child.module}" if child.module else base
                else:
                    mod = child.module
                out.append((mod, [a.name for a in child.names], fn))
            walk(child, fn)

    walk(ast.parse(path.read_text()), False)
    return out


def targets(mod: str, names: list[str], known) -> set[str]:
    """The project modules an import statement loads (``from pkg import submodule`` counts the submodule)."""
    out = {f"{mod}.{n}" for n in names if f"{mod}.{n}" in known}
    if len(out) < len(names) or not names:
        while mod and mod not in known:
            mod = mod.rpartition(".")[0]
        if mod:
            out.add(mod)
    return out


def violations() -> list[str]:
    known = modules()
    bad = []
    for name, path in known.items():
        banned = RULES[layer(name)]
        for mod, names, _ in imports(path, name):
            for full in [mod, *(f"{mod}.{n}" for n in names)]:
                if any(full == b or full.startswith(b + ".") for b in banned):
                    bad.append(f"{name} imports {full}")
                    break
    return bad


def graph() -> dict[str, set[str]]:
    """Module -> the project modules it imports (at module level or inside functions)."""
    known = modules()
    g = {}
    for name, path in known.items():
        g[name] = set()
        for mod, names, _ in imports(path, name):
            g[name] |= {t for t in targets(mod, names, known) if t != name and t != "iscc_gym"
                        and not name.startswith(t + ".")}  # a package's own __init__ runs first anyway
    return g


def circles(g: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in g[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(g):
        if v not in index:
            visit(v)
    return out


def test_every_module_has_a_layer_and_the_layers_exist():
    names = modules()
    assert {layer(n) for n in names} >= {"base", "physics", "sim", "envs", "analysis", "face", "agents", "train",
                                        "eval"}
    assert "iscc_gym.sim.kernel" in names and "iscc_gym.agents.sca" in names and "iscc_gym.eval.evaluate" in names


def test_no_import_runs_against_the_direction():
    assert violations() == []


def test_no_import_circle():
    assert circles(graph()) == []


def test_no_private_name_is_imported_from_another_module():
    known = modules()
    bad = [f"{name}: from {mod} import {n}" for name, path in known.items() for mod, names, _ in imports(path, name)
           if mod and mod.startswith("iscc_gym") for n in names if n.startswith("_") and n != "__version__"]
    assert bad == []


def test_the_checks_can_fail(tmp_path, monkeypatch):
    """Planted imports against the direction, a planted circle and a private import are all reported."""
    pkg = tmp_path / "iscc_gym"
    for sub in ("physics", "sim", "envs"):
        (pkg / sub).mkdir(parents=True)
        (pkg / sub / "__init__.py").write_text("")
    (pkg / "__init__.py").write_text("")
    (pkg / "physics" / "chan.py").write_text("def f():\n    from iscc_gym.sim import slot\n")
    (pkg / "sim" / "slot.py").write_text("from iscc_gym.physics.chan import _g\nfrom ..envs import face\n")
    (pkg / "envs" / "face.py").write_text("import torch\nfrom typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
                                          "    from iscc_gym.envs import other\n")
    (pkg / "envs" / "other.py").write_text("from iscc_gym.envs.face import x\n")
    monkeypatch.setattr(__import__(__name__), "FOLDERS", {pkg: "iscc_gym"})
    assert set(violations()) == {"iscc_gym.physics.chan imports iscc_gym.sim",
                                 "iscc_gym.sim.slot imports iscc_gym.envs", "iscc_gym.envs.face imports torch"}
    assert circles(graph()) == [["iscc_gym.physics.chan", "iscc_gym.sim.slot"]]  # the TYPE_CHECKING one is not
    with pytest.raises(AssertionError, match="_g"):
        test_no_private_name_is_imported_from_another_module()


def test_every_deferred_import_resolves():
    """Imports inside functions (figure drawing, optional heavy dependencies) run only when called; each
    ``from iscc_gym... import name`` of the project must name something that exists (a moved helper left
    behind fails here, not in a long command)."""
    missing = []
    for name, path in modules().items():
        for mod, names, in_function in imports(path, name):
            if not in_function or not mod.startswith("iscc_gym"):
                continue
            target = importlib.import_module(mod)
            for n in names:
                if not hasattr(target, n):
                    try:
                        importlib.import_module(f"{mod}.{n}")
                    except ImportError:
                        missing.append(f"{name}: from {mod} import {n}")
    assert missing == []
