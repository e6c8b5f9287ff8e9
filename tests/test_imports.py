"""Imports run one way (issue 14): scenario -> physics -> loop -> env/vector -> agents -> train/eval.

Every module's imports are read with ``ast`` (no import is executed): the core ``iscc_gym`` imports
nothing of ``agents``, ``train``, ``eval``, torch or SB3; ``agents`` nothing of ``train`` or ``eval``;
and ``train`` and ``eval``, siblings, nothing of each other (eval reaches training through the
command line, :mod:`iscc_gym.eval.training`).
"""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
#: layer -> (folder, names it must not import)
RULES = {
    "core": (ROOT / "iscc_gym", ("iscc_gym.agents", "iscc_gym.train", "iscc_gym.eval", "agents", "train", "eval",
                                 "torch", "stable_baselines3", "optuna")),
    "agents": (ROOT / "agents", ("iscc_gym.train", "iscc_gym.eval", "train", "eval")),
    "train": (ROOT / "train", ("iscc_gym.eval", "eval")),
    "eval": (ROOT / "eval", ("iscc_gym.train", "train")),
}


def imported_modules(path: Path, package: str) -> set[str]:
    """Absolute names of every module ``path`` imports (relative imports resolved within ``package``)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                mod = f"{base}.{node.module}" if node.module else base
                out.update([mod] + [f"{mod}.{a.name}" for a in node.names])
            else:
                out.add(node.module)
                out.update(f"{node.module}.{a.name}" for a in node.names)
    return out


def violations(layer: str) -> list[str]:
    folder, banned = RULES[layer]
    package = {"core": "iscc_gym"}.get(layer, f"iscc_gym.{layer}")
    bad = []
    for path in sorted(folder.glob("*.py")):
        for mod in imported_modules(path, package):
            if any(mod == b or mod.startswith(b + ".") for b in banned):
                bad.append(f"{path.name} imports {mod}")
    return bad


@pytest.mark.parametrize("layer", list(RULES))
def test_no_import_runs_against_the_direction(layer):
    assert violations(layer) == []


def test_the_check_can_fail(tmp_path, monkeypatch):
    """A planted eval -> train import is reported, relative and absolute (the check reads what it should)."""
    (tmp_path / "bad.py").write_text("from iscc_gym.train.train import main\nfrom .. import train\nimport numpy\n")
    monkeypatch.setitem(RULES, "eval", (tmp_path, RULES["eval"][1]))
    assert set(violations("eval")) == {"bad.py imports iscc_gym.train.train", "bad.py imports iscc_gym.train",
                                       "bad.py imports iscc_gym.train.train.main"}


def test_every_deferred_import_resolves():
    """Imports inside functions (figure drawing, optional heavy dependencies) run only when called; each
    ``from iscc_gym... import name`` of the package must name something that exists (a moved helper
    left behind fails here, not in a long command)."""
    import importlib

    missing = []
    for layer, (folder, _) in RULES.items():
        package = {"core": "iscc_gym"}.get(layer, f"iscc_gym.{layer}")
        for path in sorted(folder.glob("*.py")):
            for node in ast.walk(ast.parse(path.read_text())):
                if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    continue
                for sub in ast.walk(node):
                    if isinstance(sub, ast.ImportFrom) and (sub.level or (sub.module or "").startswith("iscc_gym")):
                        base = package if sub.level == 1 else (package.rsplit(".", sub.level - 1)[0]
                                                               if sub.level else "")
                        mod = ".".join(x for x in (base, sub.module) if x)
                        target = importlib.import_module(mod)
                        for a in sub.names:
                            if not hasattr(target, a.name):
                                try:
                                    importlib.import_module(f"{mod}.{a.name}")
                                except ImportError:
                                    missing.append(f"{path.name}: from {mod} import {a.name}")
    assert missing == []
