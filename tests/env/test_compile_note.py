"""The one-line note when the compiled kernels are built: printed on a numba cache miss, silent on a hit."""

import os
import subprocess
import sys
import textwrap

MODULE = textwrap.dedent("""
    from numba import njit

    @njit(cache=True)
    def twice(x):
        return 2 * x
""")

RUN = textwrap.dedent("""
    import importlib.util, sys
    from numba.core import event
    # the module alone (importing the iscc_gym package costs seconds a process): it needs numba only
    spec = importlib.util.spec_from_file_location("compile_note", sys.argv[1])
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    event.unregister("numba:compile", mod.LISTENER)
    CompileNote, NOTE = mod.CompileNote, mod.NOTE
    note = CompileNote(stream=sys.stdout, package="probe_pkg")
    event.register("numba:compile", note)
    from probe_pkg.mod import twice
    twice(3.0)
    twice(4.0)  # the same signature: no second compilation, no second note
""")


def _run(tmp_path, **env):
    import iscc_gym.compile_note

    env = {**os.environ, "PYTHONPATH": str(tmp_path), "NUMBA_CACHE_DIR": str(tmp_path / "cache"), **env}
    return subprocess.run([sys.executable, "-c", RUN, iscc_gym.compile_note.__file__], capture_output=True, text=True,
                          timeout=300, cwd=tmp_path, env=env)


def test_note_once_on_a_cache_miss_and_none_on_a_hit(tmp_path):
    from iscc_gym.compile_note import NOTE

    (tmp_path / "probe_pkg").mkdir()
    (tmp_path / "probe_pkg" / "__init__.py").write_text("")
    (tmp_path / "probe_pkg" / "mod.py").write_text(MODULE)
    first = _run(tmp_path)
    assert first.returncode == 0, first.stderr
    assert first.stdout.count(NOTE) == 1
    second = _run(tmp_path)  # loaded from the cache written by the first run
    assert second.returncode == 0, second.stderr
    assert NOTE not in second.stdout


def test_note_in_process_and_quiet_silences_it(monkeypatch):
    import io

    from numba import njit
    from numba.core import event

    from iscc_gym.compile_note import NOTE, CompileNote

    for quiet, expected in ((True, ""), (False, NOTE + "\n")):
        if quiet:
            monkeypatch.setenv("ISCC_GYM_QUIET", "1")
        else:
            monkeypatch.delenv("ISCC_GYM_QUIET", raising=False)
        stream = io.StringIO()
        note = CompileNote(stream=stream, package=__name__.split(".")[0])  # this test module's functions
        event.register("numba:compile", note)
        try:
            njit(lambda x: x * 2.0)(1.0)
        finally:
            event.unregister("numba:compile", note)
        assert stream.getvalue() == expected


def test_other_packages_compilations_print_nothing(tmp_path):
    import io

    from numba import njit
    from numba.core import event

    from iscc_gym.compile_note import CompileNote

    stream = io.StringIO()
    note = CompileNote(stream=stream)
    event.register("numba:compile", note)
    try:
        njit(lambda x: x + 1)(1.0)  # a function of this test module, not of iscc_gym
    finally:
        event.unregister("numba:compile", note)
    assert stream.getvalue() == "" and not note.noted


def test_note_once_per_run_across_its_worker_processes(tmp_path, monkeypatch):
    """Issue 34: ``python -m eval`` printed the note once per worker. Each worker process builds its own listener when
    it imports the package and inherits the run's marker name (:data:`RUN_ENV`) from the first process: here three
    such listeners (the first process and two workers) each see a compilation of the package; one note in all."""
    import io
    import types

    from iscc_gym.compile_note import NOTE, RUN_ENV, CompileNote
    from iscc_gym.sim.loop import step_one

    monkeypatch.delenv("ISCC_GYM_QUIET", raising=False)
    monkeypatch.setenv(RUN_ENV, str(tmp_path / "note"))
    compiling = types.SimpleNamespace(data={"dispatcher": step_one})  # numba's numba:compile event, as it starts
    streams = [io.StringIO() for _ in range(3)]
    for stream in streams:
        note = CompileNote(stream=stream, per_run=True)
        note.on_start(compiling)
        note.on_start(compiling)
    assert "".join(s.getvalue() for s in streams) == NOTE + "\n"
    monkeypatch.delenv(RUN_ENV)  # no run's marker: each process notes for itself, once
    for stream in streams:
        CompileNote(stream=stream, per_run=True).on_start(compiling)
    assert sum(s.getvalue().count(NOTE) for s in streams) == 4
