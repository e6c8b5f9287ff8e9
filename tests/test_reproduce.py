"""The reproduce command in quick mode: keys, the paper's model-level targets, calibration, the
scheme level (Table II and Fig. 9 analogs), figures and the generated docs sections."""

import json
from pathlib import Path

import numpy as np
import pytest
from iscc_gym.eval import reproduce, schemes
from iscc_gym.eval.figures import FIGURES

from iscc_gym import SCENARIOS


@pytest.fixture(scope="module")
def figures_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("figures")


@pytest.fixture(scope="module")
def quick_paper(tmp_path_factory, figures_dir):
    path = tmp_path_factory.mktemp("repro") / "out.json"
    reproduce.main(["--quick", "--json", str(path), "--figures", str(figures_dir)])
    return json.loads(path.read_text())


@pytest.fixture(scope="module")
def quick_literal():
    return reproduce.run("literal", quick=True, schemes=False)


def test_json_has_the_issue_keys(quick_paper):
    for key in ("eps_ctrl_star", "rho_m_large_alpha_ctrl", "alpha_ctrl_star", "max_comm_rate_mbps",
                "peb_m", "veb_mps", "alpha_sen", "paper", "calibration", "choices"):
        assert key in quick_paper
    assert len(quick_paper["peb_m"]) == len(quick_paper["alpha_sen"]) == len(quick_paper["veb_mps"])
    assert quick_paper["paper"]["eps_ctrl_star"] == 0.5055


def test_paper_preset_hits_the_model_level_targets(quick_paper):
    r = quick_paper
    assert r["eps_ctrl_star"] == pytest.approx(0.5055, abs=0.01)
    assert r["rho_m_large_alpha_ctrl"] == pytest.approx(0.1, abs=0.02)
    assert r["alpha_ctrl_star"] == pytest.approx(0.0403, rel=0.1)
    assert r["max_comm_rate_mbps"] == pytest.approx(35.0, rel=0.1)
    assert 0.03 <= r["peb_m_at_alpha_sen_0_2"] <= 0.07


def test_bounds_decrease_and_saturate_in_alpha_sen(quick_paper):
    peb, veb = np.array(quick_paper["peb_m"]), np.array(quick_paper["veb_mps"])
    assert np.all(np.diff(peb) < 0) and np.all(np.diff(veb) < 0)
    gains = -np.diff(peb) / np.diff(quick_paper["alpha_sen"])
    assert np.all(np.diff(gains) < 0)  # diminishing returns


def test_sharp_eps_transition_at_alpha_ctrl_star(quick_paper):
    tr = quick_paper["eps_ctrl_vs_alpha_ctrl"]
    a, e = np.array(tr["alpha_ctrl"]), np.array(tr["eps_ctrl"])
    star = quick_paper["alpha_ctrl_star"]
    assert np.all(e[a <= star - 0.01] > 0.9)
    assert np.all(e[a >= star + 0.01] < 1e-3)
    assert np.all(np.diff(e) <= 0)


def test_calibration_solved_matches_the_preset(quick_paper):
    solved = quick_paper["calibration"]["solved"]
    preset = SCENARIOS["paper"]
    assert solved["comm_snr_offset_db"] == pytest.approx(preset.comm_snr_offset_db, abs=1.0)
    assert solved["sensing_snr_offset_db"] == pytest.approx(preset.sensing_snr_offset_db, abs=1.0)
    assert solved["ctrl_deadline_s"] == pytest.approx(preset.ctrl_deadline_s, rel=0.1)


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


def test_write_docs_regenerates_only_its_sections(tmp_path, quick_paper, quick_literal):
    readme = tmp_path / "README.md"
    readme.write_text("head\n<!-- reproduce:start -->\nSTALE\n<!-- reproduce:end -->\n"
                      "<!-- bench:start -->\nbench table\n<!-- bench:end -->\ntail\n")
    results = tmp_path / "results.md"
    # a results file as the previous version of the command wrote it (no markers), plus a marked
    # section of another command that must survive
    results.write_text("# Results\n\n" + reproduce.LEGACY_LINE + "\n\n## Model-level reproduction\n\nold table\n\n"
                       "<!-- bench:start -->\n## Speed\n\nbench table\n<!-- bench:end -->\n")
    reproduce.write_docs(quick_paper, quick_literal, str(results), str(readme))
    text = readme.read_text()
    assert "STALE" not in text and text.startswith("head\n") and text.endswith("tail\n")
    assert "| eps_ctrl* |" in text and "Scheme level" in text and "bench table" in text
    doc = results.read_text()
    assert "old table" not in doc and reproduce.LEGACY_LINE not in doc
    for name in ("reproduce", "reproduce-schemes", "bench"):
        assert doc.count(f"<!-- {name}:start -->") == 1 and doc.count(f"<!-- {name}:end -->") == 1
    assert "| eps_ctrl* |" in doc and "Table II analog" in doc and "Fig. 9 analog" in doc and "## Speed" in doc
    assert "alloc_tracking_error.png" in doc  # figure links
    assert doc.index("<!-- reproduce:start -->") < doc.index("<!-- bench:start -->")  # migrated in place
    before = doc
    reproduce.write_docs(quick_paper, quick_literal, str(results), str(readme))
    assert results.read_text() == before  # idempotent


# --- scheme level ---------------------------------------------------------------------------------
ALLOC_KEYS = ("tracking_error_m", "rate_mbps", "peb_m", "lqg_cost", "time_s", "alpha_sen", "alpha_ctrl",
              "alpha_comm")


def test_scheme_level_json_has_the_issue_keys(quick_paper):
    r = quick_paper
    for method in ("sca", "grid", "evolutionary"):
        for key in ALLOC_KEYS:
            assert np.isfinite(r["allocation"][method][key]), (method, key)
            assert key in r["paper"]["allocation"][method]
        a = [r["allocation"][method][k] for k in ("alpha_sen", "alpha_ctrl", "alpha_comm")]
        assert min(a) >= 0.0 and sum(a) == pytest.approx(1.0)
    for scheme in ("open_loop", "gnss", "ignore_loss", "iscc"):
        for key in ("tracking_error_m", "terminated", "tracking_error_full_horizon_m"):
            assert key in r["schemes"][scheme]
        assert "tracking_error_m" in r["paper"]["schemes"][scheme]
    assert np.isfinite(r["iscc_over_gnss"])
    assert r["paper"]["iscc_over_gnss"] == 0.1737
    assert r["paper"]["allocation"]["sca"]["time_s"] == 68.60
    names = [t["name"] for t in r["targets"]]
    assert len(names) == 10 and all(isinstance(t["holds"], bool) for t in r["targets"])


def test_scheme_level_sanity(quick_paper):
    al, sc = quick_paper["allocation"], quick_paper["schemes"]
    sca = al["sca"]["tracking_error_m"]
    assert 0.3 < sca < 0.6  # paper 0.41 m
    for method in ("grid", "evolutionary"):
        assert al[method]["tracking_error_m"] == pytest.approx(sca, rel=0.05)
        assert al[method]["lqg_cost"] == pytest.approx(al["sca"]["lqg_cost"], rel=0.05)
    assert sc["iscc"]["tracking_error_m"] == sca  # the proposed scheme is the SCA allocation
    assert sc["iscc"]["terminated"] == 0.0 and sc["gnss"]["terminated"] == 0.0
    assert sc["ignore_loss"]["terminated"] == 1.0  # every mission loses track
    assert sc["ignore_loss"]["tracking_error_full_horizon_m"] > 100.0
    assert sc["open_loop"]["tracking_error_m"] > 5.0 * sca
    assert sca < sc["gnss"]["tracking_error_m"] < sc["open_loop"]["tracking_error_m"]
    assert sc["gnss"]["alpha"][0] == 0.0  # GNSS does not sense
    assert quick_paper["iscc_over_gnss"] == pytest.approx(sca / sc["gnss"]["tracking_error_m"])
    for method in ("sca", "grid", "evolutionary"):
        assert 0.0 < al[method]["time_s"] < 60.0


def test_figures_written(quick_paper, figures_dir):
    assert set(quick_paper["figures"]) == set(FIGURES)
    for name in FIGURES:
        data = (figures_dir / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 5000


def test_gnss_steady_state_matches_the_env(quick_paper):
    wi = quick_paper["schemes"]["gnss"]["what_if"]
    env = quick_paper["schemes"]["gnss"]["tracking_error_m"]
    assert wi["env_reading_m"] == pytest.approx(env, rel=0.1)
    assert wi["env_fix_period_s"] == pytest.approx(SCENARIOS["paper"].gnss_update_period_s)
    # a slower receiver, an unfiltered fix and a noisier fix all make the GNSS loop worse
    assert wi["receiver_1hz_m"] > wi["fix_every_slot_m"]
    assert wi["unfiltered_fix_m"] > wi["fix_every_slot_m"]
    assert wi["gnss_pos_std_for_paper_m"] > SCENARIOS["paper"].gnss_pos_std_m
    s = SCENARIOS["paper"].replace(gnss_pos_std_m=wi["gnss_pos_std_for_paper_m"])
    assert schemes.gnss_steady_error_m(s, wi["eps_ctrl"]) == pytest.approx(2.36, rel=1e-3)


def test_format_prints_paper_beside_ours(quick_paper):
    text = reproduce.format_table(quick_paper)
    for snippet in ("Table II analog", "Fig. 9 analog", "68.6", "57.8", "2.36", "17.37", "holds"):
        assert snippet in text


def test_evaluator_check_rows_and_table():
    """The evaluator-vs-env table (tiny budget): env and evaluator errors side by side; the
    evaluator flags a control share below the stability threshold."""
    from iscc_gym.eval import evaluator_check

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
    from iscc_gym.eval import docs

    seen = []

    def fake_run(scenario, quick=False, seed=0, schemes=True, figures_dir=None, stage=None):
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
