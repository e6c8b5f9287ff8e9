"""The reproduce command in quick mode: the paper's model-level targets, calibration, the scheme
level (Table II and Fig. 9), the paper's Figs. 3-8 and their claims, figures and the generated docs
sections. Every assert checks a value computed independently of the one it tests (a closed form, the
paper's number with a stated tolerance, a property the physics implies), not a constant echoed back.

The tests reading the quick run (the ``quick_paper`` and ``quick_literal`` fixtures: the reproduction command run end
to end, figures included, about 25 s of one core) are ``slow``: the README's **Slow tests** command runs them. The
pieces below them (the Monte Carlo, the evaluator's check rows, the figure folders, the calibration cache) run by
default, and the physics they rest on has its own oracles (tests/physics/test_sensing.py, test_stability.py, ...)."""

import json
import sys
import types
from pathlib import Path

import numpy as np
import pytest
from iscc_gym.eval.figures import FIGURES

from experiments.paper import paper_figures, reproduce
from experiments.paper.paper_mc import fly_splits
from iscc_gym import SCENARIOS
from iscc_gym.analysis import static_model


@pytest.fixture(scope="module")
def figures_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("figures")


@pytest.fixture(scope="module")
def quick_paper(tmp_path_factory, figures_dir):
    path = tmp_path_factory.mktemp("repro") / "out.json"
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(reproduce, "OTHER_MODULES", ())  # the other modules' own tests time them
        reproduce.main(["--quick", "--quiet", "--json", str(path), "--figures", str(figures_dir)])
    return json.loads(path.read_text())


@pytest.fixture(scope="module")
def quick_literal(quick_paper):
    # after quick_paper: the paper preset's sensing calibration, the same for both presets, is then cached
    return reproduce.run("literal", quick=True, schemes=False)


@pytest.mark.slow
def test_claims_are_machine_readable(quick_paper):
    claims = quick_paper["claims"]
    ids = [c["id"] for c in claims]
    assert len(ids) == len(set(ids)) >= 30
    for c in claims:
        assert set(c) >= {"id", "figure", "paper", "ours", "holds", "why"}
        assert isinstance(c["holds"], bool) and c["figure"].startswith(("Fig.", "Table II"))
    figs = {c["figure"].split("(")[0].split(" /")[0].strip() for c in claims}
    assert {"Fig. 3", "Fig. 4", "Fig. 5", "Fig. 6", "Fig. 7", "Fig. 8", "Fig. 9", "Table II"} <= figs
    assert quick_paper["claims_holding"] == sum(c["holds"] for c in claims)


@pytest.mark.slow
def test_paper_preset_hits_the_model_level_targets(quick_paper):
    """The paper's Sec. IV-C.1 and Table II numbers, each with its tolerance."""
    r = quick_paper
    assert r["eps_ctrl_star"] == pytest.approx(0.5055, abs=0.01)
    assert r["rho_m_large_alpha_ctrl"] == pytest.approx(0.1, abs=0.02)
    assert r["alpha_ctrl_star"] == pytest.approx(0.0403, rel=0.1)
    assert r["max_comm_rate_mbps"] == pytest.approx(35.0, rel=0.1)
    # rho(M) at large alpha_ctrl tends to rho(A - BK)^2 (eps -> 0 in eq:M)
    assert r["rho_m_large_alpha_ctrl"] == pytest.approx(r["rho_a_minus_bk_squared"], rel=1e-3)
    # angle-limited sensing: PEB ~ alpha_sen^-1/2, so quadrupling alpha_sen halves it
    a, peb = np.array(r["alpha_sen"]), np.array(r["peb_m"])
    assert peb[a == 0.8][0] / peb[a == 0.2][0] == pytest.approx(0.5, rel=0.1)


@pytest.mark.slow
def test_bounds_decrease_and_saturate_in_alpha_sen(quick_paper):
    peb, veb = np.array(quick_paper["peb_m"]), np.array(quick_paper["veb_mps"])
    assert np.all(np.diff(peb) < 0) and np.all(np.diff(veb) < 0)
    gains = -np.diff(peb) / np.diff(quick_paper["alpha_sen"])
    assert np.all(np.diff(gains) < 0)  # diminishing returns


@pytest.mark.slow
def test_sharp_eps_transition_at_alpha_ctrl_star(quick_paper):
    tr = quick_paper["eps_ctrl_vs_alpha_ctrl"]
    a, e = np.array(tr["alpha_ctrl"]), np.array(tr["eps_ctrl"])
    star = quick_paper["alpha_ctrl_star"]
    assert np.all(e[a <= star - 0.01] > 0.9)
    assert np.all(e[a >= star + 0.01] < 1e-3)
    assert np.all(np.diff(e) <= 0)


@pytest.mark.slow
def test_calibration_solved_matches_the_preset(quick_paper):
    solved = quick_paper["calibration"]["solved"]
    preset = SCENARIOS["paper"]
    assert solved["comm_snr_offset_db"] == pytest.approx(preset.comm_snr_offset_db, abs=1.0)
    assert solved["sensing_snr_offset_db"] == pytest.approx(preset.sensing_snr_offset_db, abs=1.0)
    assert solved["ctrl_deadline_s"] == pytest.approx(preset.ctrl_deadline_s, rel=0.1)


@pytest.mark.slow
def test_literal_preset_shows_the_mismatch(quick_literal):
    r = quick_literal
    assert r["alpha_ctrl_star"] < 1e-3  # collapses far below 4.03 %
    assert r["max_comm_rate_mbps"] > 80.0  # far above 35 Mbps
    assert r["peb_m_at_alpha_sen_0_2"] > 100.0  # the radar sees nothing useful
    assert r["choices"]["process_noise_reading"]["variance"] > 2 * r["choices"][
        "process_noise_reading"]["std"]


def test_closed_loop_at_table2_split_tracks_near_paper():
    s = SCENARIOS["paper"].replace(mission_duration_s=100.0)
    err, n_div = reproduce.closed_loop_error_m(s, 2)
    assert n_div == 0
    assert 0.3 < err < 0.5  # paper: 0.41 m


@pytest.mark.slow
def test_write_docs_regenerates_only_its_sections(tmp_path, quick_paper, quick_literal):
    readme = tmp_path / "README.md"
    readme.write_text("head\n<!-- reproduce:start -->\nSTALE\n<!-- reproduce:end -->\n"
                      "<!-- bench:start -->\nbench table\n<!-- bench:end -->\ntail\n")
    results = tmp_path / "results.md"
    # a stale section of this command, plus a marked section of another command that must survive
    results.write_text("# Results\n\n<!-- reproduce:start -->\nold table\n<!-- reproduce:end -->\n\n"
                       "<!-- bench:start -->\n## Speed\n\nbench table\n<!-- bench:end -->\n")
    reproduce.write_docs(quick_paper, quick_literal, str(results), str(readme))
    text = readme.read_text()
    assert "STALE" not in text and text.startswith("head\n") and text.endswith("tail\n")
    assert "| eps_ctrl* |" in text and "Scheme level" in text and "bench table" in text
    doc = results.read_text()
    assert "old table" not in doc
    for name in ("reproduce", "reproduce-schemes", "bench"):
        assert doc.count(f"<!-- {name}:start -->") == 1 and doc.count(f"<!-- {name}:end -->") == 1
    assert "| eps_ctrl* |" in doc and "Table II analog" in doc and "Fig. 9 analog" in doc and "## Speed" in doc
    assert "fig6_tracking_error.png" in doc and "fig9b_schemes_tracking_error.png" in doc  # figure links
    assert doc.count("<!-- reproduce-claims:start -->") == 1
    section = doc.split("<!-- reproduce-claims:start -->")[1].split("<!-- reproduce-claims:end -->")[0]
    rows = [line for line in section.splitlines() if line.startswith("| fig") or line.startswith("| table2")]
    assert len(rows) == len(quick_paper["claims"])
    assert sum("**does not hold**" in line for line in rows) == len(rows) - quick_paper["claims_holding"]
    assert "Fig. 4a" not in doc and "Fig. 7 analog" not in doc  # the paper's numbering
    assert doc.index("<!-- reproduce:start -->") < doc.index("<!-- bench:start -->")  # migrated in place
    before = doc
    reproduce.write_docs(quick_paper, quick_literal, str(results), str(readme))
    assert results.read_text() == before  # idempotent


# --- scheme level ---------------------------------------------------------------------------------
ALLOC_KEYS = ("tracking_error_m", "rate_mbps", "peb_m", "lqg_cost", "time_s", "alpha_sen", "alpha_ctrl",
              "alpha_comm")


@pytest.mark.slow
def test_scheme_level_json_has_the_issue_keys(quick_paper):
    r = quick_paper
    for method in ("sca", "grid", "evolutionary"):
        for key in ALLOC_KEYS:
            assert np.isfinite(r["allocation"][method][key]), (method, key)
        a = [r["allocation"][method][k] for k in ("alpha_sen", "alpha_ctrl", "alpha_comm")]
        assert min(a) >= 0.0 and sum(a) == pytest.approx(1.0)
    names = [t["name"] for t in r["targets"]]
    assert len(names) == 10 and all(isinstance(t["holds"], bool) for t in r["targets"])


@pytest.mark.slow
def test_scheme_level_sanity(quick_paper):
    al, sc = quick_paper["allocation"], quick_paper["schemes"]
    sca = al["sca"]["tracking_error_m"]
    assert 0.3 < sca < 0.6  # paper 0.41 m
    for method in ("grid", "evolutionary"):
        assert al[method]["tracking_error_m"] == pytest.approx(sca, rel=0.05)
        assert al[method]["lqg_cost"] == pytest.approx(al["sca"]["lqg_cost"], rel=0.05)
    assert sc["iscc"]["terminated"] == 0.0 and sc["gnss"]["terminated"] == 0.0
    assert sc["ignore_loss"]["terminated"] == 1.0  # every mission loses track
    assert sc["ignore_loss"]["tracking_error_full_horizon_m"] > 100.0
    assert sc["open_loop"]["tracking_error_m"] > 5.0 * sca
    assert sca < sc["gnss"]["tracking_error_m"] < sc["open_loop"]["tracking_error_m"]
    for method in ("sca", "grid", "evolutionary"):
        assert 0.0 < al[method]["time_s"] < 60.0


@pytest.mark.slow
def test_figures_written(quick_paper, figures_dir):
    assert set(quick_paper["figures"]) == set(FIGURES) | set(paper_figures.FIGURES)
    for name in quick_paper["figures"]:
        data = (figures_dir / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 5000


@pytest.mark.slow
def test_gnss_steady_state_matches_the_env(quick_paper):
    wi = quick_paper["schemes"]["gnss"]["what_if"]
    env = quick_paper["schemes"]["gnss"]["tracking_error_m"]
    assert wi["env_reading_m"] == pytest.approx(env, rel=0.1)
    # a slower receiver, an unfiltered fix and a noisier fix all make the GNSS loop worse
    assert wi["receiver_1hz_m"] > wi["fix_every_slot_m"]
    assert wi["unfiltered_fix_m"] > wi["fix_every_slot_m"]
    assert wi["gnss_pos_std_for_paper_m"] > SCENARIOS["paper"].gnss_pos_std_m


@pytest.mark.slow
def test_format_prints_paper_beside_ours(quick_paper):
    text = reproduce.format_table(quick_paper)
    for snippet in ("Table II analog", "Fig. 9 analog", "68.6", "57.8", "2.36", "17.37", "holds"):
        assert snippet in text


def test_evaluator_check_rows_and_table():
    """The evaluator-vs-env table (tiny budget): env and evaluator errors side by side; the
    evaluator flags a control share below the stability threshold."""
    from experiments.paper import evaluator_check

    rows = evaluator_check.run(seeds=range(1000, 1002), splits=((0.2, 0.2, 0.6), (0.2, 0.05, 0.75)),
                               max_steps=30)
    ok, unstable = rows
    assert ok["missions"] == 2 and 0.0 < ok["env_error_m"] < 5.0
    assert 0.3 < ok["evaluator_exact_m"] < 0.5 and 0.0 < ok["evaluator_eps_ctrl"] < 0.05
    assert unstable["evaluator_exact_m"] is None and unstable["evaluator_eps_ctrl"] > ok["evaluator_eps_ctrl"]
    table = evaluator_check.markdown(rows)
    assert "| 0.2, 0.2, 0.6 |" in table and "unstable" in table


def test_figures_go_to_the_output_directory_unless_write_docs(tmp_path, monkeypatch):
    """Without --write-docs the committed docs/figures are never the target: runs/reproduce/figures (relative
    to the working directory) or --figures; with it, the checkout's docs/figures."""
    from iscc_gym.commands import docs

    seen = []

    def fake_run(scenario, quick=False, seed=0, schemes=True, figures_dir=None, stage=None, paper_figs=None):
        seen.append(figures_dir)
        return {"wall_time_s": 0.0}

    monkeypatch.setattr(reproduce, "run", fake_run)
    monkeypatch.setattr(reproduce, "format_table", lambda res: "")
    monkeypatch.setattr(reproduce, "write_docs", lambda *a, **k: None)
    monkeypatch.chdir(tmp_path)
    reproduce.main(["--quick", "--quiet"])
    assert seen[-1] == reproduce.DEFAULT_FIGURES == Path("runs/reproduce/figures")
    reproduce.main(["--quick", "--quiet", "--figures", "out"])
    assert seen[-1] == Path("out")
    reproduce.main(["--quick", "--quiet", "--no-figures"])
    assert seen[-1] is None
    reproduce.main(["--quick", "--quiet", "--write-docs"])
    assert seen[-2:] == [docs.project_root() / "docs" / "figures"] * 2
    assert not (tmp_path / "docs").exists() and list(tmp_path.iterdir()) == []


# --- the paper's Figs. 3-8 and their claims -----------------------------------------------------------
@pytest.fixture(scope="module")
def tiny_mc():
    s = SCENARIOS["paper"]
    splits = [(0.2, 0.2, 0.6), (0.05, 0.02, 0.93), (0.2, 0.2, 0.6)]
    return s, fly_splits(s, splits, 2, seed=3, n_slots=300)


def test_monte_carlo_uses_common_random_numbers(tiny_mc):
    s, r = tiny_mc
    per = r["per_mission"]
    for key in ("tracking_error_m", "lqg_cost", "peb_m"):
        np.testing.assert_array_equal(per[key][0], per[key][2])  # same split, same missions: same numbers
    alone = fly_splits(s, [(0.2, 0.2, 0.6)], 2, seed=3, n_slots=300)  # a split's result ignores its batch
    np.testing.assert_allclose(alone["per_mission"]["tracking_error_m"][0], per["tracking_error_m"][0], rtol=1e-12)


def test_monte_carlo_against_the_steady_state_evaluator(tiny_mc):
    """Far from the stability edge the env's error and LQG cost (recovered from the transition) meet the
    closed-form steady state; below alpha_ctrl* every mission loses track."""
    s, r = tiny_mc
    an = static_model(s).evaluate(np.array([0.2, 0.2, 0.6]))
    assert r["lost"][0] == 0.0
    assert r["tracking_error_m"][0] == pytest.approx(float(an.tracking_error_m[0]), rel=0.15)
    assert r["lqg_cost"][0] == pytest.approx(float(an.lqg_cost[0]), rel=0.25)
    assert r["tracking_rmse_m"][0] > r["tracking_error_m"][0]  # Jensen
    assert r["lost"][1] == 1.0 and np.all(r["per_mission"]["slots"][1] < 300)


def test_fit_line_recovers_a_line():
    x = np.linspace(0.05, 0.3, 7)
    k, c, r2 = paper_figures.fit_line(x, 0.16 * x + 0.39)
    assert (k, c, r2) == pytest.approx((0.16, 0.39, 1.0))
    k, c, r2 = paper_figures.fit_line(x, 0.16 * x + 0.39 + 0.01 * np.cos(40 * x))
    assert r2 < 1.0 and k == pytest.approx(0.16, abs=0.05)


@pytest.mark.slow
def test_fig3_fig4_physics(quick_paper):
    pf = quick_paper["paper_figures"]
    curves = pf["fig3"]["curves"]
    for lo, hi in zip(curves, curves[1:], strict=False):  # more echo SNR, lower bounds, everywhere
        assert hi["echo_snr_db"] > lo["echo_snr_db"]
        assert np.all(np.array(hi["peb_m"]) < np.array(lo["peb_m"]))
        assert np.all(np.array(hi["veb_mps"]) < np.array(lo["veb_mps"]))
    f4 = pf["fig4"]
    eps, rho = np.array(f4["eps"]), np.array(f4["rho_vs_eps"])
    # the grid curve crosses rho = 1 where the root finder put eps*
    assert eps[np.argmax(rho >= 1.0)] == pytest.approx(f4["eps_star"], abs=eps[1] - eps[0])
    # fading can only make the loss rate worse at the worst position than on average
    assert f4["alpha_ctrl_star_faded_worst"] > f4["alpha_ctrl_star_faded_mean"] > 0.0


@pytest.mark.slow
def test_claims_follow_the_measurements(quick_paper):
    """A claim flips when the measured numbers it reads flip."""
    pf = json.loads(json.dumps(quick_paper["paper_figures"]))
    by_id = {c["id"]: c for c in paper_figures.claims(pf)}
    g = pf["grid"]
    ctrl = g["alpha_ctrl"]
    assert by_id["fig6-5-to-6"]["holds"] is bool(np.asarray(g["lost"])[ctrl.index(0.05)].max() == 0.0)
    i5 = ctrl.index(0.05)
    g["lost"][i5] = [0.0] * len(g["alpha_sen"])  # as if every mission kept track at 5 %
    g["tracking_error_m"][i5] = [2.0] * len(g["alpha_sen"])
    assert {c["id"]: c for c in paper_figures.claims(pf)}["fig6-5-to-6"]["holds"]
    top = len(ctrl) - 1
    g["tracking_error_m"][top] = [0.5 * x for x in g["tracking_error_m"][top]]
    assert not {c["id"]: c for c in paper_figures.claims(pf)}["fig6-floor-0.4"]["holds"]
    for row in pf["fig7"]["rows"]:  # slopes falling with alpha_ctrl: the paper's Fig. 7
        if "k" in row:
            row["k"] = 1.0 - row["alpha_ctrl"]
    claims = {c["id"]: c for c in paper_figures.claims(pf)}
    assert claims["fig7-k-falls"]["holds"] and claims["fig7-k-below-1"]["holds"] is not False


def test_other_modules_are_merged(tmp_path, monkeypatch):
    """A module of OTHER_MODULES that exists runs; its claims and figures join the command's."""
    mod = types.ModuleType("experiments.paper.fake_study")
    mod.run = lambda quick=False, seed=0: {"claims": [{"id": "fake-1", "figure": "Fig. 4(b)", "paper": "p",
                                                        "ours": "o", "holds": False, "why": "w"}], "x": 1}

    def draw(res, figures_dir):
        path = Path(figures_dir) / "fake.png"
        path.write_bytes(b"png")
        return {"fake.png": str(path)}

    mod.draw = draw
    monkeypatch.setitem(sys.modules, "experiments.paper.fake_study", mod)
    monkeypatch.setattr(reproduce, "OTHER_MODULES", ("fake_study", "no_such_module"))
    monkeypatch.setattr(reproduce.paper_figures, "run", lambda *a, **k: {"claims": [], "sources": {}})
    monkeypatch.setattr(reproduce.paper_figures, "draw", lambda res, d: {})
    monkeypatch.setattr(reproduce, "calibrate", lambda *a, **k: {"comm_snr_offset_db": 0.0})  # timed elsewhere
    res = reproduce.run("paper", quick=True, schemes=False, paper_figs=True, figures_dir=tmp_path)
    assert [c["id"] for c in res["claims"]] == ["fake-1"]
    assert res["claims"][0]["module"] == "experiments.paper.fake_study"
    assert res["figures"] == {"fake.png": str(tmp_path / "fake.png")} and res["other_modules"]["fake_study"]["x"] == 1
    assert res["claims_holding"] == 0


def test_sensing_calibration_is_computed_once_per_scenario_and_budget(monkeypatch):
    """--write-docs runs both presets, each calibrating the paper preset the same way: the second call reuses
    the first's rollouts, and a caller editing its result cannot change what the next one gets."""
    from experiments.paper import fading

    calls = []
    target = reproduce.PAPER["peb_m_table2_sca"]

    def fake_rollout(splits, seeds, s, max_steps=None):
        calls.append(len(seeds))
        return {"peb_m": np.array([[target * (1.0 + 0.01 * (s.sensing_snr_offset_db == 7.0))]])}

    monkeypatch.setattr(fading, "rollout", fake_rollout)
    s = SCENARIOS["paper"].replace(sensing_snr_offset_db=7.0)
    first = reproduce.calibrate_sensing_offset(s, n_missions=3, rtol=1e-6)
    assert calls == [3, 3] and first["iterations"] == 2 and first["sensing_snr_offset_db"] != 7.0
    first["sensing_snr_offset_db"] = -1.0
    again = reproduce.calibrate_sensing_offset(s, n_missions=3, rtol=1e-6)
    assert calls == [3, 3] and again["sensing_snr_offset_db"] == pytest.approx(7.0 + 20 * np.log10(1.01))
    reproduce.calibrate_sensing_offset(s, n_missions=5, rtol=1e-6)  # another budget: computed
    assert calls == [3, 3, 5, 5]
