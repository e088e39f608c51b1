"""Files of ``compare`` and ``gap``: metrics.json / gap.json, report.md and PNG plots read at a glance."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from lidar_weather_sim.gap.compare import Comparison, metrics
from lidar_weather_sim.gap.signatures import BEV_X, BEV_Y, RANGE_EDGES, ZONES, Signature


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_ranges(path: Path, curves: dict[str, Signature], title: str) -> None:
    """Per-frame range histograms of every zone, one line per signature."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(ZONES), figsize=(4 * len(ZONES), 3.2))
    for ax, zone in zip(axes, ZONES):
        edges = RANGE_EDGES[zone]
        for name, sig in curves.items():
            ax.step(edges[:-1], sig.mean(f"{zone}/range"), where="post", label=name)
        ax.set_title(zone)
        ax.set_xlabel("range (m)")
    axes[0].set_ylabel("returns per frame and bin")
    axes[0].legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_bev(path: Path, measured: Signature, others: dict[str, Signature]) -> None:
    """Bird's-eye histogram of the measurement and the difference of each simulation to it."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 1 + len(others), figsize=(4.5 * (1 + len(others)), 4.5))
    axes = np.atleast_1d(axes)
    extent = (BEV_Y[1], BEV_Y[0], BEV_X[0], BEV_X[1])  # y to the left, x up
    base = measured.mean("bev")
    axes[0].imshow(np.log1p(base)[::-1, ::-1], extent=extent, cmap="viridis", aspect="equal")
    axes[0].set_title("measured: log(1 + returns/frame)")
    lim = max(float(np.abs(o.mean("bev") - base).max()) for o in others.values()) if others else 1.0
    for ax, (name, sig) in zip(axes[1:], others.items()):
        ax.imshow((sig.mean("bev") - base)[::-1, ::-1], extent=extent, cmap="coolwarm", vmin=-lim, vmax=lim,
                  aspect="equal")  # fmt: skip
        ax.set_title(f"{name} - measured")
    for ax in axes:
        ax.set_xlim(15, -15)
        ax.set_ylim(-5, 60)
        ax.set_xlabel("y (m)")
    axes[0].set_ylabel("x (m)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_terms(path: Path, terms: dict[str, dict[str, float]]) -> None:
    """Bar chart of the gap terms of each comparison."""
    plt = _pyplot()
    keys = list(next(iter(terms.values())))
    fig, ax = plt.subplots(figsize=(max(6, 0.45 * len(keys)), 3.5))
    width = 0.8 / len(terms)
    for k, (name, values) in enumerate(terms.items()):
        ax.bar(np.arange(len(keys)) + k * width, [values.get(key, 0.0) for key in keys], width, label=name)
    ax.set_xticks(np.arange(len(keys)) + 0.4 - width / 2, keys, rotation=70, fontsize=7)
    ax.set_ylabel("systematic Bray-Curtis")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def write_compare(out: Path, comparison: Comparison, measured_name: str, simulated_name: str) -> dict:
    """metrics.json, report.md, ranges.png, bev.png, returns_by_channel.png in ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    m = metrics(comparison)
    (out / "metrics.json").write_text(json.dumps(m, indent=1, allow_nan=True))
    plot_ranges(out / "ranges.png", {"measured": comparison.measured, "simulated": comparison.simulated},
                "range histograms per zone")  # fmt: skip
    plot_bev(out / "bev.png", comparison.measured, {"simulated": comparison.simulated})
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7, 3))
    for name in ("measured", "simulated"):
        ax.plot(m["returns_by_channel"][name], drawstyle="steps-mid", label=name)
    ax.set_xlabel("channel")
    ax.set_ylabel("returns per frame")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "returns_by_channel.png", dpi=90)
    plt.close(fig)
    lines = [f"# compare: {measured_name} vs {simulated_name}", "",
             f"{m['frames']['paired']} frame pairs (paired by {m['frames']['paired_by']}). "
             f"Gap {m['gap']:.4f} (0 = indistinguishable; mean systematic Bray-Curtis of the zone histograms).", "",
             f"Bird's-eye 0.5 m cells: Pearson {m['bev']['pearson']:.3f}, Jaccard distance "
             f"{m['bev']['jaccard_distance']:.3f}, Hamming distance {m['bev']['hamming_distance']:.4f}.", "",
             "| zone | measured det./frame | simulated det./frame | range BC | intensity BC | EPW BC |",
             "|---|---:|---:|---:|---:|---:|"]  # fmt: skip
    for zone, z in m["zones"].items():
        d = z["detections_per_frame"]
        lines.append(f"| {zone} | {d['measured'][0]:.1f} | {d['simulated'][0]:.1f} | {z.get('range_bray_curtis', 0):.3f} "
                     f"| {z.get('intensity_bray_curtis', 0):.3f} | {z.get('epw_bray_curtis', float('nan')):.3f} |")  # fmt: skip
    lines += ["", "Near-field parameters (paper 2, 0.5-5 m):", "", "| parameter | measured | simulated | W1 / sd |",
              "|---|---:|---:|---:|"]  # fmt: skip
    for name, p in m["near_field_parameters"].items():
        fmt = lambda v: "-" if v is None else f"{v:.3g}"  # noqa: E731
        lines.append(f"| {name} | {fmt(p['measured_mean'])} | {fmt(p['simulated_mean'])} | {fmt(p['normalised'])} |")
    lines += ["", "![ranges](ranges.png)", "", "![bev](bev.png)", "", "![channels](returns_by_channel.png)", ""]
    (out / "report.md").write_text("\n".join(lines))
    return m


def write_gap(out: Path, diagnosis, measured: Signature, before: Signature, after: Signature,
              patched_yaml: str, runnable: bool = True, judgement=None) -> dict:  # fmt: skip
    """gap.json, patched_scenario.yaml, report.md and before/after plots in ``out``.

    ``before`` / ``after``: every measured frame re-simulated without / with the accepted effects;
    ``runnable``: the patched scenario can be run on its own (it has roads and an ego); ``judgement``: the
    :class:`~lidar_weather_sim.gap.unexplained.Judgement` after the search (None: every accepted effect named,
    nothing judged unexplained). gap.json's ``effects`` are the search's accepted effects (the patched scenario's),
    each with ``named`` and, when refused, ``refused`` (why); ``found`` names the named ones only; ``unexplained``
    lists the zones the named effects leave (zone, label, shape, sigma, residual returns per frame, bands)."""
    from lidar_weather_sim.gap.signatures import gap_terms, gap_value

    out.mkdir(parents=True, exist_ok=True)
    (out / "patched_scenario.yaml").write_text(patched_yaml)

    def params(effect) -> dict[str, float | str]:
        """Numbers as floats; a categorical main parameter as its text; other texts (a dirt sample) left out."""
        text = effect.spec.main if effect.spec.categorical else None
        return {k: v if k == text else float(v) for k, v in effect.params.items() if k == text or not isinstance(v, str)}

    def refused(effect) -> str | None:
        """Why the judgement does not name ``effect`` (None: named)."""
        return next((why for e, why in judgement.refused if e == effect), None) if judgement is not None else None

    result = {
        "gap_before": diagnosis.gap_before,
        "gap_after": diagnosis.gap_after,
        "effects": [{"name": c.effect.name, "params": params(c.effect), "gap_before": before_gap,
                     "gap_after": c.heldout_gap, "named": refused(c.effect) is None,
                     "refused": refused(c.effect)} for c, before_gap in diagnosis.accepted],  # fmt: skip
        "rejected": [{"name": c.effect.name, "gap_after": c.heldout_gap, "params": params(c.effect)}
                     for c in diagnosis.rejected],  # fmt: skip
        "found": ", ".join(f"{c.effect.name} ({format_params(params(c.effect))})" for c, _ in diagnosis.accepted
                           if refused(c.effect) is None) or "no effect",  # fmt: skip
        "unexplained": [] if judgement is None else [r.to_dict() for r in judgement.unexplained],
        "naming_rule": None if judgement is None else judgement.rule(),
        "patched_scenario": "patched_scenario.yaml",
        "all_frames": {"frames": measured.frames, "gap_before": gap_value(measured, before),
                       "gap_after": gap_value(measured, after)},  # fmt: skip
        "split": {"fit_frames": diagnosis.fit_indices, "heldout_frames": diagnosis.heldout_indices},
    }
    (out / "gap.json").write_text(json.dumps(result, indent=1))
    plot_ranges(out / "ranges_before_after.png", {"measured": measured, "before": before, "after": after},
                "range histograms per zone: measured, simulated before and after the fitted effects")  # fmt: skip
    plot_bev(out / "bev_before_after.png", measured, {"before": before, "after": after})
    plot_terms(out / "gap_terms.png", {"before": gap_terms(measured, before), "after": gap_terms(measured, after)})
    named = [e for e in result["effects"] if e["named"]]
    lines = ["# Reality gap", "",
             f"Held-out gap {diagnosis.gap_before:.4f} -> {diagnosis.gap_after:.4f} "
             f"(all {measured.frames} frames: {result['all_frames']['gap_before']:.4f} -> "
             f"{result['all_frames']['gap_after']:.4f}). The gap is the mean systematic Bray-Curtis "
             "dissimilarity of the per-zone range, intensity and EPW histograms, the bird's-eye, the "
             "channel x range and the later-echo histograms (0 = indistinguishable, 1 = disjoint).", "",
             "## Effects found", "", "| effect | parameters | held-out gap before | after |", "|---|---|---:|---:|"]  # fmt: skip
    for e in named:
        lines.append(f"| {e['name']} | {format_params(e['params'])} | {e['gap_before']:.4f} | {e['gap_after']:.4f} |")
    if not named:
        lines.append("| none | - | - | - |")
    if judgement is not None:
        lines += ["", "## Unexplained (held-out frames, with the named effects)", "",
                  f"A zone is unexplained when a range band's measured returns differ from the simulated ones by "
                  f"{SIGMA_TEXT.format(**result['naming_rule'])}. An effect is named only when it removes the "
                  f"residual of the zones that are its physics (gone, or at most {result['naming_rule']['remaining']:.0%} "
                  "of it left), not only the total gap."
                  + (" The scene is a twin of the recording, whose reflectivity holds the weather's loss on its "
                     "surfaces: the atmosphere is judged on its own echoes, the near field."
                     if result["naming_rule"].get("twin") else ""), "",
                  "| zone | shape | residual (sigma) | returns/frame beyond the noise | measured / simulated |",
                  "|---|---|---:|---:|---:|"]  # fmt: skip
        for r in result["unexplained"]:
            ratio = "-" if r["relative"] is None else f"{1.0 + r['relative']:.3f}"
            lines.append(f"| {r['label']} | {r['shape']} | {r['sigma']:.1f} | {r['residual']:.1f} | {ratio} |")
        if not result["unexplained"]:
            lines.append("| none | - | - | - | - |")
        for e in result["effects"]:
            if not e["named"]:
                lines += ["", f"Fitted but not named: {e['name']} ({format_params(e['params'])}, held-out gap "
                              f"{e['gap_before']:.4f} -> {e['gap_after']:.4f}): {e['refused']}. It stays in the "
                              "patched scenario as a fit."]  # fmt: skip
    lines += ["", "## Rejected in the last round (held-out gap with the effect fitted)", "",
              "| effect | fitted parameters | held-out gap |", "|---|---|---:|"]  # fmt: skip
    for e in result["rejected"]:
        lines.append(f"| {e['name']} | {format_params(e['params'])} | {e['gap_after']:.4f} |")
    lines += ["", "![terms](gap_terms.png)", "", "![ranges](ranges_before_after.png)", "", "![bev](bev_before_after.png)", ""]
    lines.append("Re-run the patched scenario: `lidar-weather-sim run patched_scenario.yaml`." if runnable else
                 "The patched scenario is mesh-only (no ego): use it with `gap` or `compare` on the recording.")  # fmt: skip
    (out / "report.md").write_text("\n".join(lines))
    return result


SIGMA_TEXT = "at least {sigma:g} sigma of the counting noise of the frames used and at least {min_relative:.0%} of its returns"


def format_params(params: dict[str, float | str]) -> str:
    """``key=value, ...`` with numbers to 4 significant digits (a categorical choice as it is)."""
    return ", ".join(f"{k}={v}" if isinstance(v, str) else f"{k}={v:.4g}" for k, v in params.items())
