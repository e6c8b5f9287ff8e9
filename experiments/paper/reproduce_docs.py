"""What ``python -m experiments.paper.reproduce`` prints and writes: the console table, the README block and the
sections of ``docs/results.md`` (model level, claims, scheme level).
"""

from __future__ import annotations

import os
from pathlib import Path

from iscc_gym.commands.docs import README_PATH, RESULTS_PATH, write_section

from experiments.paper import paper_figures
from experiments.paper import schemes as scheme_level

#: The large control share at which the paper reads rho(M) off its Fig. 4(b) (~0.1).
LARGE_ALPHA_CTRL = 0.2


def format_table(res: dict) -> str:
    """Plain-text table: quantity, ours, the paper's."""
    p = res["paper"]
    rows = [
        ("eps_ctrl* (max loss rate for MS stability)", f"{res['eps_ctrl_star']:.4f}",
         f"{p['eps_ctrl_star']:.4f}"),
        (f"rho(M) at alpha_ctrl = {LARGE_ALPHA_CTRL:g}", f"{res['rho_m_large_alpha_ctrl']:.4f}",
         f"~{p['rho_m_large_alpha_ctrl']:g}"),
        ("alpha_ctrl* (trajectory-averaged SNR)", f"{100 * res['alpha_ctrl_star']:.3f} %",
         f"{100 * p['alpha_ctrl_star']:.2f} %"),
        ("trajectory-averaged SNR", f"{res['mean_snr_db']:.2f} dB", "(not given)"),
        ("max data rate (alpha_comm = 1)", f"{res['max_comm_rate_mbps']:.2f} Mbps",
         f"~{p['max_comm_rate_mbps']:g} Mbps"),
        ("PEB at alpha_sen = 0.2 (large-scale echo)", f"{res['peb_m_at_alpha_sen_0_2']:.4g} m",
         f"{p['peb_m_table2_sca']:g} m (Table II, SCA's split, env)"),
        ("VEB at alpha_sen = 0.2", f"{res['veb_mps_at_alpha_sen_0_2']:.4g} m/s", "(Fig. 3(a), no number)"),
    ]
    eb = res["echo_budget_uncalibrated"]
    w0 = max(len(r[0]) for r in rows)
    w1 = max(len(r[1]) for r in rows + [("", "ours")])
    lines = [f"Model-level reproduction, scenario '{res['scenario']}' "
             f"({res['n_trajectories']} trajectories{', quick' if res['quick'] else ''})",
             f"{'quantity':<{w0}}  {'ours':>{w1}}  paper", "-" * (w0 + w1 + 12)]
    lines += [f"{a:<{w0}}  {b:>{w1}}  {c}" for a, b, c in rows]
    lines.append("")
    lines.append(f"Table I echo budget at the mean range {res['mean_range_m']:.0f} m (no sensing offset): "
                 f"echo {eb['echo_dbm_per_element_subcarrier']:.1f} dBm per element and subcarrier, "
                 f"noise {eb['noise_dbm']:.1f} dBm, integrated SNR at alpha_sen = 0.2: "
                 f"{eb['integrated_snr_db_at_alpha_sen_0_2']:.1f} dB")
    lines.append("eps_ctrl vs alpha_ctrl (sharp transition at alpha_ctrl*):")
    tr = res["eps_ctrl_vs_alpha_ctrl"]
    for a, e, r in zip(tr["alpha_ctrl"], tr["eps_ctrl"], tr["rho_m"], strict=True):
        lines.append(f"  alpha_ctrl = {100 * a:5.1f} %   eps_ctrl = {e:9.3e}   rho(M) = {r:8.4f}")
    lines.append("PEB / VEB vs alpha_sen (trajectory average):")
    for a, pe, ve in zip(res["alpha_sen"], res["peb_m"], res["veb_mps"], strict=True):
        lines.append(f"  alpha_sen = {100 * a:5.1f} %   PEB = {pe:10.4g} m   VEB = {ve:10.4g} m/s")
    cal = res["calibration"]
    lines.append("Calibration of the 'paper' preset on this trajectory sample (solved vs preset):")
    for k, v in cal["solved"].items():
        lines.append(f"  {k:<24} solved {v:12.5g}   preset {cal['paper_preset'][k]:12.5g}")
    lines.append("Named modelling choices (docs/model.md), each beside its alternative:")
    for k, v in res["choices"].items():
        lines.append(f"  {k}: {_fmt(v)}")
    if "allocation" in res:
        lines += ["", scheme_level.format_schemes(res)]
    if res.get("claims"):
        lines += ["", f"Claims of the paper, tested ({res['claims_holding']} of {len(res['claims'])} hold):"]
        lines += [f"  [{'holds' if c['holds'] else 'does not hold'}] {c['id']} ({c['figure']}): {c['ours']}"
                  for c in res["claims"]]
    return "\n".join(lines)


def _fmt(v) -> str:
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k}: {_fmt(x)}" for k, x in v.items()) + "}"
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def markdown_table(paper_res: dict, literal_res: dict) -> str:
    """Markdown table: ours (paper preset), the paper's figure, ours (literal preset)."""
    p = paper_res["paper"]
    rows = [
        ("eps_ctrl*", "eps_ctrl_star", "{:.4f}", f"{p['eps_ctrl_star']}"),
        (f"rho(M) at alpha_ctrl = {LARGE_ALPHA_CTRL:g}", "rho_m_large_alpha_ctrl", "{:.3f}",
         f"~{p['rho_m_large_alpha_ctrl']}"),
        ("alpha_ctrl* (trajectory-averaged SNR)", "alpha_ctrl_star", "{:.3%}",
         f"{100 * p['alpha_ctrl_star']:.2f}%"),
        ("trajectory-averaged SNR (dB)", "mean_snr_db", "{:.2f}", "not given"),
        ("max data rate at alpha_comm = 1 (Mbps)", "max_comm_rate_mbps", "{:.2f}",
         f"~{p['max_comm_rate_mbps']:g}"),
        ("PEB at alpha_sen = 0.2, large-scale echo (m)", "peb_m_at_alpha_sen_0_2", "{:.4g}",
         f"{p['peb_m_table2_sca']:g} at SCA's split, Table II (claim table2-peb)"),
        ("VEB at alpha_sen = 0.2 (m/s)", "veb_mps_at_alpha_sen_0_2", "{:.4g}", "Fig. 3(a), no number"),
    ]
    out = ["| quantity | ours (`paper`) | paper | ours (`literal`) |", "|---|---|---|---|"]
    for name, key, fmt, theirs in rows:
        out.append(f"| {name} | {fmt.format(paper_res[key])} | {theirs} | "
                   f"{fmt.format(literal_res[key])} |")
    return "\n".join(out)


#: The command that regenerates this study's sections (:mod:`experiments.studies`).
COMMAND = "python -m experiments reproduce"


def model_section(paper_res: dict, literal_res: dict, command: str = COMMAND) -> str:
    """The model-level section of docs/results.md (markdown)."""
    table = markdown_table(paper_res, literal_res)
    n = paper_res["n_trajectories"]
    body = [
        f"## Model-level reproduction ({n} seeded trajectories)",
        "",
        f"Generated by `{command}`.",
        "",
        table,
        "",
        "PEB / VEB versus alpha_sen (trajectory average, `paper` preset):",
        "",
        "| alpha_sen | PEB (m) | VEB (m/s) |",
        "|---|---|---|",
    ]
    body += [f"| {a:g} | {pe:.4g} | {ve:.4g} |" for a, pe, ve in
             zip(paper_res["alpha_sen"], paper_res["peb_m"], paper_res["veb_mps"], strict=True)]
    tr = paper_res["eps_ctrl_vs_alpha_ctrl"]
    body += ["", "eps_ctrl and rho(M) versus alpha_ctrl at the trajectory-averaged SNR (`paper`):", "",
             "| alpha_ctrl | eps_ctrl | rho(M) |", "|---|---|---|"]
    body += [f"| {a:g} | {e:.3e} | {r:.4f} |" for a, e, r in
             zip(tr["alpha_ctrl"], tr["eps_ctrl"], tr["rho_m"], strict=True)]
    body += ["", "Named modelling choices (see docs/model.md), `paper` preset:", ""]
    body += [f"- `{k}`: {_fmt(v)}" for k, v in paper_res["choices"].items()]
    cal = paper_res["calibration"]
    body += ["", "Calibration of the `paper` preset, solved on this sample vs the preset's value:", ""]
    body += [f"- `{k}`: solved {v:.5g}, preset {cal['paper_preset'][k]:.5g}"
             for k, v in cal["solved"].items()]
    return "\n".join(body)


def _cell(text) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def claims_section(res: dict, results_path: Path, command: str = COMMAND) -> str:
    """The ``reproduce-claims`` section of docs/results.md: the claims table, then every figure of the
    paper (Figs. 3-8 here, Fig. 9 in the scheme-level section, the other modules' figures after)
    with where its numbers come from.
    """
    claims = res["claims"]
    pf = res.get("paper_figures", {})
    g = pf.get("grid", {})
    base = results_path.resolve().parent
    out = ["## The paper's figures and claims", "",
           f"Generated by `{command}` (`paper` preset; `--json PATH` writes "
           "the same "
           "claims, machine-readable). Figure numbers are the paper's (LaTeX order; Figs. 1-2 are illustrations). "
           f"**{res['claims_holding']} of {len(claims)} claims hold.** Each claim quotes the paper, gives our "
           "measured value and the reading and tolerance used to decide.", ""]
    if g:
        out += [f"Monte Carlo (Figs. 5-8): every split of a {len(g['alpha_sen'])} x {len(g['alpha_ctrl'])} grid "
                f"(alpha_sen {', '.join(f'{100 * a:g}' for a in g['alpha_sen'])} %; alpha_ctrl "
                f"{', '.join(f'{100 * a:g}' for a in g['alpha_ctrl'])} %; alpha_comm the rest) flown on the same "
                f"{g['n_missions']} seeded missions x {g['n_slots']} slots through the env's transition "
                "(`experiments/paper/paper_mc.py`); a mission that loses track counts up to then, as in the env. "
                "Tracking error "
                "is the mean error norm E||e|| unless marked RMS.", ""]
    out += ["| id | figure | paper | ours | holds | why |", "|---|---|---|---|---|---|"]
    for c in claims:
        mark = "holds" if c["holds"] else "**does not hold**"
        out.append(f"| {c['id']} | {_cell(c['figure'])} | {_cell(c['paper'])} | {_cell(c['ours'])} | {mark} | "
                   f"{_cell(c['why'])} |")
    figs = res.get("figures") or {}
    titles = {**paper_figures.FIGURES, **scheme_level_titles()}
    sources = pf.get("sources", {})
    shown = False
    for name, path in figs.items():
        if name not in paper_figures.FIGURES and name in scheme_level_titles():
            continue  # Fig. 9: in the scheme-level section
        if not shown:
            out += ["", "### Figures"]
            shown = True
        title = titles.get(name, name)
        fig_no = title.split(":")[0] if title.startswith("Fig.") else ""
        src = sources.get(fig_no)
        out += ["", f"{title}" + (f" (source: {src})" if src else "") + ":", "",
                f"![{title}]({os.path.relpath(Path(path).resolve(), base)})"]
    return "\n".join(out)


def scheme_level_titles() -> dict:
    from iscc_gym.eval.figures import FIGURES

    return dict(FIGURES)


def write_docs(paper_res: dict, literal_res: dict, results_path: str | Path = RESULTS_PATH,
               readme_path: str | Path = README_PATH, command: str = COMMAND) -> None:
    """Regenerate this command's sections of docs/results.md (``reproduce``: model level;
    ``reproduce-schemes``: scheme level, if ``paper_res`` has it; ``reproduce-claims``: the claims
    table and the paper's figures) and the README's ``reproduce`` block; every other section of both
    files is left as it is.
    """
    results_path, readme_path = Path(results_path), Path(readme_path)
    write_section(results_path, "reproduce", model_section(paper_res, literal_res, command))
    n = paper_res["n_trajectories"]
    readme = [f"Generated by `{command}`."]
    if "allocation" in paper_res:
        links = None
        if paper_res.get("figures"):
            base = results_path.resolve().parent
            links = {scheme_level_figure_title(name): os.path.relpath(Path(path).resolve(), base)
                     for name, path in paper_res["figures"].items()}
        links = {k: v for k, v in (links or {}).items() if k.startswith("Fig. 9")} or None
        write_section(results_path, "reproduce-schemes", scheme_level.markdown_schemes(paper_res, links))
        readme += ["", scheme_level.headline(paper_res)]
    if paper_res.get("claims"):
        write_section(results_path, "reproduce-claims", claims_section(paper_res, results_path, command))
        readme += ["", f"The paper's Figs. 3-9 and Table II redrawn, {paper_res['claims_holding']} of "
                   f"{len(paper_res['claims'])} of its claims holding: docs/results.md (claims table)."]
    readme += ["", f"Model level ({n} seeded trajectories):", "", markdown_table(paper_res, literal_res)]
    if readme_path.exists() and "<!-- reproduce:start -->" in readme_path.read_text():
        write_section(readme_path, "reproduce", "\n".join(readme))


def scheme_level_figure_title(name: str) -> str:
    from iscc_gym.eval.figures import FIGURES

    return FIGURES.get(name, name)


#: Where the figures go without ``--figures`` and ``--write-docs`` (relative to the working directory).
