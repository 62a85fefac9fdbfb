"""The evaluation's output folder: ``evaluation.json`` (every number), PNG plots and ``REPORT.md``.

Plots (matplotlib, Agg backend, imported only here and only when writing): ``coefficients.png`` (box
plots of the normalised coefficients η/η0 grouped by detector), ``influence.png`` (per detector and
disturbance, max(|main|, |square|) effect / |fault effect|), ``snr.png`` (SNR per detector) and
``scope_<detector>.png`` (one binary scope matrix per disturbance: Δ across, σ up; yellow = in scope).
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any

import numpy as np

from edge_monitor.records import to_strict


class ReportError(RuntimeError):
    """The report cannot be drawn (matplotlib missing) or written."""


def require_matplotlib() -> Any:
    """The pyplot module on the Agg backend; :class:`ReportError` saying how to install it when missing."""
    try:
        import matplotlib
    except ImportError:
        raise ReportError("the evaluation plots need matplotlib: pip install 'joint-wear-monitor[eval]' "
                          "(or pip install 'matplotlib>=3.8')") from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _fmt(x: float | None, spec: str = ".3g") -> str:
    return "–" if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, spec)


def _plot_coefficients(plt: Any, result: dict[str, Any], path: Path) -> None:
    dets = list(result["detectors"])
    data = [[v for v in result["detectors"][d]["surrogate"]["normalised"].values() if v is not None] for d in dets]
    fig, ax = plt.subplots(figsize=(1.2 * len(dets) + 2, 4))
    ax.boxplot(data, showfliers=False)
    for i, values in enumerate(data, start=1):
        ax.plot(np.full(len(values), i) + np.linspace(-0.15, 0.15, len(values)), values, ".", ms=3, alpha=0.6)
    ax.set_xticks(range(1, len(dets) + 1), dets, rotation=30, ha="right")
    ax.set_yscale("symlog", linthresh=0.1)
    for y in (-1, 1):
        ax.axhline(y, color="red", lw=0.8, ls="--")
    ax.set_ylabel("η / η0 (coefficient / fault main effect)")
    ax.set_title("Normalised surrogate coefficients (|η/η0| > 1: moves q more than the fault)")
    _save(plt, fig, path)


def _save(plt: Any, fig: Any, path: Path, dpi: int = 80) -> None:
    """Write ``fig`` as PNG (small: the report is committed) and free it."""
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)


def _plot_influence(plt: Any, result: dict[str, Any], path: Path) -> None:
    dets = list(result["detectors"])
    dist = [f["name"] for f in result["settings"]["factors"][1:]]
    m = np.array([[result["detectors"][d]["surrogate"]["influence"].get(x) or np.nan for x in dist] for d in dets])
    fig, ax = plt.subplots(figsize=(1.3 * len(dist) + 3, 0.45 * len(dets) + 1.5))
    im = ax.imshow(np.log10(np.clip(m, 1e-3, None)), cmap="viridis", aspect="auto", vmin=-3, vmax=1)
    for i in range(len(dets)):
        for j in range(len(dist)):
            ax.text(j, i, _fmt(float(m[i, j]), ".2g"), ha="center", va="center", color="w", fontsize=8)
    ax.set_xticks(range(len(dist)), dist, rotation=20, ha="right")
    ax.set_yticks(range(len(dets)), dets)
    fig.colorbar(im, ax=ax, label="log10 influence")
    ax.set_title("Disturbance influence relative to the fault effect")
    _save(plt, fig, path)


def _plot_snr(plt: Any, result: dict[str, Any], path: Path) -> None:
    dets = list(result["detectors"])
    values = [result["detectors"][d]["snr"] or 0.0 for d in dets]
    fig, ax = plt.subplots(figsize=(1.2 * len(dets) + 2, 3.5))
    ax.bar(dets, values, color=["tab:green" if v > 0 else "tab:red" for v in values])
    ax.set_xticks(range(len(dets)), dets, rotation=30, ha="right")
    s = result["settings"]["snr"]
    ax.set_ylabel("SNR (μ1 − μ0)/σ1")
    ax.set_title(f"SNR at f0 = {s['f0']}, Δ = {s['delta']}, σ = {s['sigma']} (coded)")
    ax.axhline(0, color="k", lw=0.5)
    _save(plt, fig, path)


def _plot_scope(plt: Any, det: str, entry: dict[str, Any], grid: dict[str, Any], step: float, path: Path) -> None:
    scopes, deltas, sigmas = entry["scope"], grid["deltas"], grid["sigmas"]
    fig, axes = plt.subplots(1, len(scopes), figsize=(2.4 * len(scopes) + 0.5, 2.8), squeeze=False)
    for ax, (dist, s) in zip(axes[0], scopes.items()):
        m = np.array([[c == "1" for c in row] for row in s["inside"]], dtype=float)
        ax.imshow(m, origin="lower", aspect="auto", vmin=0, vmax=1, cmap="viridis",
                  extent=(deltas[0] * step, deltas[1] * step, sigmas[0], sigmas[1]))
        ax.set_title(dist, fontsize=9)
        ax.set_xlabel("fault Δ [wear]", fontsize=8)
        ax.tick_params(labelsize=7)
    axes[0][0].set_ylabel("σ (coded)", fontsize=8)
    fig.suptitle(f"{det}: scope (Pd ≥ 0.99 at Pf = 0.01), yellow = in scope", fontsize=9)
    _save(plt, fig, path, dpi=72)


def findings(result: dict[str, Any]) -> dict[str, Any]:
    """The answers of the report: the SNR winner, each detector's dominant disturbance and scope ends
    (wear values in the fault's natural unit; σ coded)."""
    step = result["settings"]["factors"][0]["unit_step"]
    out: dict[str, Any] = {"best_snr": result["ranking_by_snr"][0] if result["ranking_by_snr"] else None,
                           "per_detector": {}}
    for d, e in result["detectors"].items():
        scopes = e["scope"]
        out["per_detector"][d] = {
            "snr": e["snr"], "validation_fit": e["validation_fit"],
            "dominant_disturbance": e["dominant_disturbance"],
            "dominant_influence": e["surrogate"]["influence"].get(e["dominant_disturbance"] or "", None),
            "dominant_significant": e["dominant_significant"],
            "runner_up": e.get("runner_up"),
            "scope_max_sigma": {x: s["max_sigma"] for x, s in scopes.items()},
            "min_fault_at_default_sigma": e["min_fault_at_default_sigma"],
            "min_fault_at_max_sigma": {x: (None if s["min_delta"][-1] is None else s["min_delta"][-1] * step)
                                       for x, s in scopes.items()},
        }
    return out


def _row(*cells: str) -> str:
    """A Markdown table row; a "|" inside a cell (e.g. |τl|) is escaped."""
    return "| " + " | ".join(c.strip().replace("|", "\\|") for c in cells) + " |"


def _scope_sentence(e: dict[str, Any], sigma_max: float) -> str:
    """Where a detector's scope ends, one clause per disturbance."""
    parts = []
    for x, v in e["scope_max_sigma"].items():
        if v is None:
            parts.append(f"{x}: nowhere")
        elif v >= sigma_max:
            parts.append(f"{x}: whole grid (σ ≤ {sigma_max:g}; wear ≥ {_fmt(e['min_fault_at_max_sigma'][x], '.0f')} "
                         f"at σ = {sigma_max:g})")
        else:
            parts.append(f"{x}: σ ≤ {v:.2f}")
    return "; ".join(parts)


def markdown(result: dict[str, Any], images: dict[str, str]) -> str:
    """``REPORT.md``: settings, findings, tables and the plots."""
    st, dets, fnd = result["settings"], result["detectors"], result["findings"]
    dist = [f["name"] for f in st["factors"][1:]]
    fault = st["factors"][0]
    snr_s, scope_s = st["snr"], st["scope"]
    noise = {"cycle": "one cycle's q (the within-point spread of the per-cycle values)",
             "mean": f"the mean of {st['test_cycles']} test cycles (the surrogate's residual)",
             "none": "none (the surrogate alone)"}[st["noise"]]
    lines = ["# Detector evaluation report", "",
             f"Produced by `edge-monitor evaluate` (how to read it: docs/EVALUATION.md). Robot: the simulator's "
             f"default robot of {st['joints']} joints (seed {st['seed']}), monitored joint {st['joint']}; "
             f"{st['nominal_cycles']} nominal cycles at no wear with the disturbances at their centre, then "
             f"{st['test_cycles']} test cycles per design point; the surrogate models the mean q over the test "
             f"cycles. Design: {st['design_runs']}-run {st.get('design_name', 'central composite')} design, "
             f"{st['validation_runs']} validation "
             f"runs; simulation {result['seconds']['simulation']:.0f} s with {st['jobs']} process(es). SNR: "
             f"f0 = {snr_s['f0']}, Δ = {snr_s['delta']}, σ = {snr_s['sigma']} (coded), {snr_s['draws']} draws. "
             f"Scope: Pd ≥ {scope_s['pd']} at Pf = {scope_s['pf']}, from no wear (f0 = {scope_s['f0']}), "
             f"{scope_s['draws']} draws per cell. Spread of q in the Monte Carlo: {noise}.", "",
             "| factor | range (coded −2 … 2) | one coded unit |", "|---|---|---|"]
    lines += [_row(f"{f['name']} ({f['label']})", f"{f['low']:g} … {f['high']:g} {f['unit']}",
                   f"{f['unit_step']:g} {f['unit']}") for f in st["factors"]]
    lines += ["", "## Findings", ""]
    if fnd["best_snr"]:
        b = fnd["best_snr"]
        lines.append(f"* **Best average performance (SNR):** `{b}` (SNR {_fmt(dets[b]['snr'])}); ranking: "
                     + ", ".join(f"`{d}` {_fmt(dets[d]['snr'])}" for d in result["ranking_by_snr"]) + ".")
    sigma_max = scope_s["sigmas"][1]
    for d, e in fnd["per_detector"].items():
        at = e["min_fault_at_default_sigma"]
        missed = [x for x, v in at.items() if v is None]
        detects = (f"no wear up to {fault['high']:g} reaches Pd ≥ {scope_s['pd']} against {', '.join(missed)}"
                   if missed else f"it detects wear ≥ {_fmt(max(at.values()), '.0f')} against every disturbance")
        runner_up = e.get("runner_up")
        if e["dominant_significant"] is None:
            noise_note = ", not testable against the noise: the fit has no residual degrees of freedom"
        elif e["dominant_significant"]:
            noise_note = ""
        elif runner_up:
            noise_note = f"; {e['dominant_disturbance']} ≈ {runner_up} (within noise)"
        else:
            noise_note = ", within the noise of the fit"
        lines.append(f"* `{d}`: moved most by **{e['dominant_disturbance']}** "
                     f"({_fmt(e['dominant_influence'], '.2g')} × the fault's main effect{noise_note}); "
                     f"at σ = {snr_s['sigma']} "
                     f"{detects}; scope ends: {_scope_sentence(e, sigma_max)}.")
    if result.get("left_out"):
        lines.append(f"* Left out (no value at some points): {', '.join(result['left_out'])}.")
    rep = result.get("replication")
    if rep:
        lines.append(f"* **Across seeds {', '.join(str(x) for x in rep['seeds'])}** (another simulated robot and "
                     f"other test cycles each; table below): best SNR per seed "
                     + ", ".join(f"`{b}`" for b in rep["best_snr"]) + ". A finding that changes between seeds "
                     "is a property of one robot, not of the detector.")
    else:
        lines.append(f"* **One seed only** (seed {st['seed']}): the SNR ranking and the dominant disturbances are "
                     "those of one simulated robot and can change with the seed (docs/EVALUATION.md); "
                     "`--seeds N` replicates the evaluation and reports the spread.")
    lines += ["", "## Per detector", "",
              "| detector | SNR | validation fit [%] | fault effect η0 | residual std | per-cycle std | dominant "
              f"disturbance | smallest wear in scope at σ = {snr_s['sigma']} |", "|---" * 8 + "|"]
    for d, e in dets.items():
        sur = e["surrogate"]
        mins = ", ".join(f"{x}: {_fmt(v, '.0f')}" for x, v in e["min_fault_at_default_sigma"].items())
        lines.append(f"| `{d}` | {_fmt(e['snr'])} | {_fmt(e['validation_fit'], '.1f')} | {_fmt(sur['fault_effect'])} "
                     f"| {_fmt(sur['residual_std'])} | {_fmt(e['noise']['cycle'])} | {e['dominant_disturbance']} "
                     f"| {mins} |")
    lines += ["", "## Disturbance influence (max(|main|, |square|) / |fault main effect|)", "",
              "| detector | " + " | ".join(dist) + " |", "|---|" + "---|" * len(dist)]
    for d, e in dets.items():
        lines.append(f"| `{d}` | " + " | ".join(_fmt(e["surrogate"]["influence"].get(x), ".2g") for x in dist) + " |")
    if rep:
        seeds = ", ".join(str(x) for x in rep["seeds"])
        lines += ["", f"## Replication across seeds {seeds} (mean [min … max])", "",
                  "| detector | SNR | dominant disturbance per seed | " + " | ".join(dist) + " |",
                  "|---|---|---|" + "---|" * len(dist)]
        for d, r in rep["detectors"].items():
            infl = " | ".join(_spread_cell(r["influence"][x], ".2g") for x in dist if x in r["influence"])
            dominant = ", ".join(map(str, r["dominant_disturbance"]))
            lines.append(f"| `{d}` | {_spread_cell(r['snr'], '.3g')} | {dominant} | {infl} |")
    lines += ["", "## Plots", ""]
    lines += [f"![{name}]({file})" for name, file in images.items()]
    lines += ["", f"Fault axis: Δ in coded units × {fault['unit_step']:g} = wear; scope matrices start at no wear, "
              "σ in coded units of the disturbance.", ""]
    return "\n".join(lines)


def _spread_cell(s: dict[str, Any], spec: str) -> str:
    return f"{_fmt(s['mean'], spec)} [{_fmt(s['min'], spec)} … {_fmt(s['max'], spec)}]"


def _rounded(value: Any) -> Any:
    """Floats to 6 significant digits, recursively (the Monte Carlo is not more precise)."""
    if isinstance(value, float):
        return float(f"{value:.6g}")
    if isinstance(value, dict):
        return {k: _rounded(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_rounded(v) for v in value]
    return value


def _compact_json(value: Any) -> str:
    """Indented JSON, floats to 6 digits, every list of numbers on one line (small, readable in a diff)."""
    text = json.dumps(_rounded(to_strict(value)), indent=1, allow_nan=False, ensure_ascii=False)
    return re.sub(r"\[\s+([-0-9.eE+,\snul]+?)\s+\]", lambda m: "[" + re.sub(r",\s+", ", ", m.group(1)) + "]", text)


def write_report(result: dict[str, Any], out: Path) -> dict[str, Path]:
    """Write the folder (created if needed); returns the files written by name."""
    plt = require_matplotlib()
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ReportError(f"--out: cannot create {out}: {exc.strerror or exc}") from None
    result["findings"] = findings(result)
    step = result["settings"]["factors"][0]["unit_step"]
    files = {"coefficients": out / "coefficients.png", "influence": out / "influence.png", "snr": out / "snr.png"}
    try:
        if result["detectors"]:
            _plot_coefficients(plt, result, files["coefficients"])
            _plot_influence(plt, result, files["influence"])
            _plot_snr(plt, result, files["snr"])
        else:
            files = {}
        for d, e in result["detectors"].items():
            files[f"scope_{d}"] = out / f"scope_{d}.png"
            _plot_scope(plt, d, e, result["settings"]["scope"], step, files[f"scope_{d}"])
        files["json"] = out / "evaluation.json"
        files["json"].write_text(_compact_json(result) + "\n", encoding="utf-8")
        files["report"] = out / "REPORT.md"
        images = {k: p.name for k, p in files.items() if p.suffix == ".png"}
        files["report"].write_text(markdown(result, images), encoding="utf-8")
    except OSError as exc:
        raise ReportError(f"--out: cannot write to {out}: {exc.strerror or exc}") from None
    return files
