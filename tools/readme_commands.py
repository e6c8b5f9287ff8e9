"""Run the README's set-up commands as a new user would: in a fresh virtual environment, from a checkout.

``python tools/readme_commands.py`` creates a new venv (``--venv DIR``, default a temporary folder removed
afterwards), activates it, and runs the README's **Main job**, **Tests** and **Slow tests** commands in it, in
that order, exactly as the README prints them, each step of a command (the parts joined by ``&&``) timed. It exits
with the first failing command's status, so CI (``.ci/run``) runs nothing the README does not tell a user: a
package installed by hand on the machine cannot hide a missing step.

``--write-docs`` writes the measured times into the README's ``setup-times`` block (through the new venv's
``iscc_gym.commands.docs.write_section``, the one writer of generated sections). ``--only main``, ``--only tests`` or
``--only slow`` runs one command (the others' times are then not written). Standard library only: it runs before
anything is installed.
"""

from __future__ import annotations

import argparse
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import time
import venv
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
#: The README paragraphs whose first ``bash`` block is a set-up command, in the order a user runs them.
COMMANDS = {"main": "**Main job**", "tests": "**Tests**", "slow": "**Slow tests**"}


def readme_commands(text: str) -> dict[str, str]:
    """The README's set-up commands: the first ```bash block after each heading of :data:`COMMANDS`."""
    found = {}
    for name, heading in COMMANDS.items():
        if heading not in text:
            raise SystemExit(f"README.md has no paragraph starting {heading!r}: the set-up commands moved")
        block = re.search(r"```bash\n(.*?)```", text[text.index(heading):], re.S)
        if block is None:
            raise SystemExit(f"README.md has no ```bash block after {heading!r}")
        found[name] = " ".join(block.group(1).split())
    return found


def _fmt(seconds: float) -> str:
    return f"{seconds / 60:.1f} min" if seconds >= 90 else f"{seconds:.0f} s"


def run(command: str, env_dir: Path) -> list[tuple[str, float]]:
    """Run ``command`` step by step (its ``&&`` parts) in ``env_dir``'s activated venv from the checkout;
    return each step with its wall time. Exits with the step's status on failure.
    """
    times = []
    for step in (p.strip() for p in command.split("&&")):
        print(f"[readme_commands] $ {step}", file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        r = subprocess.run(["bash", "-c", f'source "{env_dir}/bin/activate" && {step}'], cwd=ROOT)
        dt = time.perf_counter() - t0
        print(f"[readme_commands] {_fmt(dt)}, exit {r.returncode}: {step}", file=sys.stderr, flush=True)
        if r.returncode != 0:
            raise SystemExit(r.returncode)
        times.append((step, dt))
    return times


def table(results: dict[str, list[tuple[str, float]]]) -> str:
    """The README block of the measured times."""
    cores = os.cpu_count()
    lines = [f"Measured by `python tools/readme_commands.py --write-docs` in a new virtual environment on this "
             f"machine ({cores} cores, Python {platform.python_version()}), the commands run in the README's order "
             "(so the later ones' installs find everything in place); a download's time depends on the network.",
             "", "| command | step | wall time |", "|---|---|--:|"]
    for name, steps in results.items():
        for step, dt in steps:
            lines.append(f"| {name} | `{step}` | {_fmt(dt)} |")
        lines.append(f"| {name} | **total** | **{_fmt(sum(dt for _, dt in steps))}** |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--venv", type=Path, help="where to create the venv (must not exist; default: a temporary "
                    "folder, removed afterwards)")
    ap.add_argument("--only", choices=sorted(COMMANDS), help="run one of the commands")
    ap.add_argument("--write-docs", action="store_true", help="write the times into README.md's setup-times block")
    args = ap.parse_args(argv)
    commands = readme_commands(README.read_text())
    if args.only:
        commands = {args.only: commands[args.only]}
    if args.venv is not None and args.venv.exists():
        ap.error(f"--venv {args.venv} exists; give a new folder (the point is a fresh environment)")
    tmp = None if args.venv else Path(tempfile.mkdtemp(prefix="iscc-readme-"))
    env_dir = args.venv or tmp / "venv"
    try:
        print(f"[readme_commands] new venv {env_dir} (python {platform.python_version()})", file=sys.stderr,
              flush=True)
        venv.EnvBuilder(with_pip=True, clear=False).create(env_dir)
        results = {name: run(cmd, env_dir) for name, cmd in commands.items()}
        text = table(results)
        print(text)
        if args.write_docs:
            if args.only:
                ap.error("--write-docs needs every command (no --only)")
            code = ("import sys; from iscc_gym.commands.docs import write_section, docs_path, README_PATH; "
                    "write_section(docs_path(README_PATH), 'setup-times', sys.stdin.read())")
            subprocess.run([str(env_dir / "bin" / "python"), "-c", code], input=text, text=True, check=True,
                           cwd=ROOT)
            print(f"wrote {README}", file=sys.stderr)
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
