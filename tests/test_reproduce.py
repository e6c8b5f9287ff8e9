"""The reproduce command in quick mode: keys, the paper's model-level targets, calibration."""

import json

import numpy as np
import pytest

from eval import reproduce
from iscc_gym import SCENARIOS


@pytest.fixture(scope="module")
def quick_paper(tmp_path_factory):
    path = tmp_path_factory.mktemp("repro") / "out.json"
    reproduce.main(["--quick", "--json", str(path)])
    return json.loads(path.read_text())


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


def test_literal_preset_shows_the_mismatch():
    r = reproduce.run("literal", quick=True)
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


def test_write_docs_regenerates_markers(tmp_path, quick_paper):
    readme = tmp_path / "README.md"
    readme.write_text("head\n<!-- reproduce:start -->\nold\n<!-- reproduce:end -->\ntail\n")
    results = tmp_path / "results.md"
    literal = reproduce.run("literal", quick=True)
    reproduce.write_docs(quick_paper, literal, str(results), str(readme))
    text = readme.read_text()
    assert "old" not in text and text.startswith("head\n") and text.endswith("tail\n")
    assert "| eps_ctrl* |" in text
    assert "| eps_ctrl* |" in results.read_text()
