"""The diagnosis report: ``report.json`` (every number) and a self-contained ``report.html``.

The HTML inlines its figures as base64 PNGs so it can be mailed or attached as one file.
Figures use matplotlib's object API on Agg (as ``report.figures``): error maps, bar charts
of the "where" shares and of each effect's shrink with its bootstrap CI, the residual
spectrum, and before/after samples.
"""

from __future__ import annotations

import base64
import html
import io
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

import tactile_bench.report.figures  # noqa: F401  (selects the Agg backend)
from tactile_bench.diagnose.breakdown import REPORT_FIGURES
from tactile_bench.diagnose.ranking import EffectFit
from tactile_bench.diagnose.result import Diagnosis
from tactile_bench.diagnose.stability import warning as stability_warning
from tactile_bench.diagnose.where import WhereResult
from tactile_bench.io import atomic_write_json, atomic_write_text
from tactile_bench.sensor.timing import timed_span


def jsonable(obj: Any) -> Any:
    """Plain JSON types; NaN and infinities become null (strict JSON has neither)."""
    if isinstance(obj, Mapping):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, (np.ndarray, torch.Tensor)):
        return jsonable(np.asarray(obj).tolist())
    if isinstance(obj, (np.floating, float)):
        value = float(obj)
        return value if math.isfinite(value) else None
    if isinstance(obj, np.integer):
        return int(obj)
    if hasattr(obj, "to_dict"):
        return jsonable(obj.to_dict())
    return obj


def png_base64(fig: Figure, dpi: int = 110) -> str:
    """The figure as a base64 PNG string (for an ``<img src="data:...">``)."""
    FigureCanvasAgg(fig)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=dpi, bbox_inches="tight")
    return base64.b64encode(buffer.getvalue()).decode("ascii")


# ------------------------------------------------------------------------------ figures
def error_maps_figure(rows: Sequence[tuple[str, WhereResult]], title: str) -> Figure:
    """A row per (name, result): mean |real - sim|, signed mean per channel, contact frequency.

    Rows share their colour limits so that they compare.
    """
    vmax_abs = max(float(r.maps["mean_abs"].max()) for _, r in rows) or 1.0
    vmax_signed = max(float(np.abs(r.maps["mean_signed"]).max()) for _, r in rows) or 1.0
    fig = Figure(figsize=(14, 2.6 * len(rows) + 0.4))
    axes = fig.subplots(len(rows), 5, squeeze=False)
    for i, (name, res) in enumerate(rows):
        panels = [
            (res.maps["mean_abs"], "magma", 0.0, vmax_abs, "mean |real - sim|"),
            *[
                (res.maps["mean_signed"][c], "RdBu_r", -vmax_signed, vmax_signed, f"mean {ch}")
                for c, ch in enumerate(("R", "G", "B"))
            ],
            (res.maps["contact_frequency"], "viridis", 0.0, 1.0, "contact frequency"),
        ]
        for j, (arr, cmap, lo, hi, panel_title) in enumerate(panels):
            ax = axes[i][j]
            im = ax.imshow(arr, cmap=cmap, vmin=lo, vmax=hi, interpolation="nearest")
            ax.set_title(panel_title, fontsize=8)
            ax.set_xticks([])
            ax.set_yticks([])
            if j == 0:
                ax.set_ylabel(name, fontsize=8)
            if j in (0, 3, 4):
                fig.colorbar(im, ax=ax, fraction=0.046, pad=0.03)
    fig.suptitle(title, fontsize=10)
    return fig


def shares_figure(where: WhereResult, max_parts: int = 12) -> Figure:
    """A bar chart per axis: share of the squared error, beside the area/pair/bin share."""
    axes_data = where.summary["axes"]
    fig = Figure(figsize=(12, 2.2 * math.ceil(len(axes_data) / 2) + 0.6))
    grid = fig.subplots(math.ceil(len(axes_data) / 2), 2, squeeze=False)
    for k, (axis, parts) in enumerate(axes_data.items()):
        ax = grid[k // 2][k % 2]
        parts = parts[:max_parts][::-1]
        y = np.arange(len(parts))
        ax.barh(y, [p["share"] for p in parts], height=0.6, color="tab:red", label="error")
        key = next(
            (c for c in ("area_share", "pair_share", "bin_share") if parts and c in parts[0]), None
        )
        if key:
            ax.scatter(
                [p[key] for p in parts],
                y,
                color="black",
                marker="|",
                s=120,
                zorder=3,
                label=key.replace("_", " "),
            )
            ax.legend(fontsize=7, loc="lower right")
        ax.set_yticks(y, [p["part"] for p in parts], fontsize=7)
        ax.set_xlim(0, 1)
        shown = (
            f" (top {max_parts} of {len(axes_data[axis])})"
            if len(axes_data[axis]) > max_parts
            else ""
        )
        ax.set_title(f"by {axis}{shown}", fontsize=9)
        ax.grid(axis="x", alpha=0.3)
    for k in range(len(axes_data), grid.size):
        grid[k // 2][k % 2].set_visible(False)
    fig.suptitle("share of the squared error real - sim (each axis sums to 1)", fontsize=10)
    fig.tight_layout()
    return fig


def spectrum_figure(rows: Sequence[tuple[str, WhereResult]]) -> Figure:
    """Radially averaged power of the difference image, a line per (name, result)."""
    fig = Figure(figsize=(6, 3))
    ax = fig.subplots()
    for name, res in rows:
        power = res.maps["radial_power"]
        ax.semilogy(np.arange(len(power)), np.maximum(power, 1e-12), label=name)
    ax.set_xlabel("spatial frequency (cycles per frame)")
    ax.set_ylabel("squared error per pixel")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    ax.set_title("where in frequency the gap lies", fontsize=10)
    return fig


def shrink_figure(singles: Sequence[EffectFit], ranking: Sequence[EffectFit]) -> Figure:
    """Each candidate alone (shrink with 95% CI) and the greedy selection's remaining gap."""
    fig = Figure(figsize=(12, 0.32 * max(len(singles), len(ranking), 4) + 1.4))
    left, right = fig.subplots(1, 2)
    rows = list(singles)[::-1]
    y = np.arange(len(rows))
    values = np.array([_finite(r.shrink, 0.0) for r in rows])
    lo = np.array([_finite(r.ci_low, v) for r, v in zip(rows, values, strict=True)])
    hi = np.array([_finite(r.ci_high, v) for r, v in zip(rows, values, strict=True)])
    left.barh(
        y,
        values,
        color="tab:blue",
        xerr=np.stack([np.maximum(values - lo, 0), np.maximum(hi - values, 0)]),
        capsize=3,
    )
    left.set_yticks(y, [r.effect for r in rows], fontsize=8)
    left.axvline(0, color="black", lw=0.8)
    left.set_xlabel("shrink of the held-out gap (95% bootstrap CI)")
    left.set_title("each candidate effect alone", fontsize=10)
    left.grid(axis="x", alpha=0.3)
    if ranking:
        steps = ["sim"] + [f"+ {r.effect}" for r in ranking]
        gaps = [ranking[0].gap_before] + [r.gap_after for r in ranking]
        right.bar(range(len(steps)), gaps, color="tab:green")
        right.set_xticks(range(len(steps)), steps, rotation=30, ha="right", fontsize=8)
        right.set_ylabel("held-out gap")
        right.set_title("greedy selection: gap left after each added effect", fontsize=10)
        right.grid(axis="y", alpha=0.3)
    else:
        right.text(0.5, 0.5, "no effect selected", ha="center", va="center")
        right.set_axis_off()
    fig.tight_layout()
    return fig


def _finite(value: float, default: float) -> float:
    return value if math.isfinite(value) else default


def samples_figure(samples: Mapping[str, torch.Tensor], row_labels: Sequence[str]) -> Figure:
    """sim | sim + effects | real | |error| before | |error| after, shared error colour scale."""
    sim, after, real = samples["sim"].float(), samples["after"].float(), samples["real"].float()
    err_b = (real - sim).abs().mean(1)
    err_a = (real - after).abs().mean(1)
    vmax = float(torch.quantile(torch.cat([err_b.flatten(), err_a.flatten()]), 0.99)) or 1.0
    columns = [
        ("sim", sim),
        ("sim + effects", after),
        ("real", real),
        ("|error| before", err_b),
        ("|error| after", err_a),
    ]
    n = len(row_labels)
    fig = Figure(figsize=(8, 1.6 * n + 0.5))
    axes = fig.subplots(n, len(columns), squeeze=False)
    for j, (name, images) in enumerate(columns):
        for i in range(n):
            ax = axes[i][j]
            if images.dim() == 4:
                ax.imshow(
                    (images[i] / 255).clamp(0, 1).permute(1, 2, 0).numpy(), interpolation="nearest"
                )
            else:
                ax.imshow(
                    images[i].numpy(), cmap="magma", vmin=0, vmax=vmax, interpolation="nearest"
                )
            ax.set_xticks([])
            ax.set_yticks([])
            if i == 0:
                ax.set_title(name, fontsize=8)
            if j == 0:
                ax.set_ylabel(row_labels[i], fontsize=7)
    fig.suptitle(f"held-out pairs (error colour scale 0-{vmax:.0f})", fontsize=9)
    return fig


# ------------------------------------------------------------------------------ HTML
def _fmt(value: Any) -> str:
    if isinstance(value, Mapping):
        return ", ".join(f"{html.escape(str(k))}={_fmt(v)}" for k, v in value.items())
    if isinstance(value, float):
        return f"{value:.4g}"
    if value is None:
        return "-"
    return html.escape(str(value))


def _table(rows: Sequence[Mapping[str, Any]], columns: Sequence[str]) -> str:
    head = "".join(f"<th>{html.escape(c)}</th>" for c in columns)
    body = "".join(
        "<tr>" + "".join(f"<td>{_fmt(r.get(c))}</td>" for c in columns) + "</tr>" for r in rows
    )
    return f"<table><tr>{head}</tr>{body}</table>"


def _flatten(d: Mapping[str, Any], prefix: str = "") -> list[dict[str, Any]]:
    out = []
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out += _flatten(v, key + ".")
        else:
            out.append({"measure": key, "value": v})
    return out


_CSS = """body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}
table{border-collapse:collapse;margin:.5em 0 1.5em}td,th{border:1px solid #ccc;padding:3px 8px;
font-size:13px;text-align:left}th{background:#f2f2f2}img{max-width:100%}
.warn{background:#fff3cd;border:1px solid #e0c36b;padding:.6em}h2{margin-top:1.6em}"""


def _timing_html(timing: Mapping[str, Any]) -> str:
    """Seconds per step, then the timed spans (calls and seconds, most seconds first)."""
    steps = {k: v for k, v in timing.items() if k != "breakdown"}
    html_parts = ["<h2>Timing</h2>" + _table(_flatten(steps), ["measure", "value"])]
    spans = timing.get("breakdown")
    if isinstance(spans, Mapping) and spans:
        rows = [{"span": name, **dict(row)} for name, row in spans.items()]
        html_parts.append(
            "<h3>where the time went (timed spans up to the report's writing; a span's "
            "seconds exclude the spans inside it, inclusive seconds count them)</h3>"
            + _table(rows, ["span", "calls", "seconds", "inclusive_seconds"])
        )
    return "".join(html_parts)


def render_html(result: Diagnosis, figures: Mapping[str, str]) -> str:
    """The report page; ``figures`` maps names to base64 PNGs."""

    def img(name: str) -> str:
        return (
            f'<img alt="{name}" src="data:image/png;base64,{figures[name]}">'
            if name in figures
            else ""
        )

    where, which = result.where.summary, result.which
    parts = [
        f"<h1>Sim-to-real gap diagnosis</h1><p>{result.n_pairs} pairs of {where['size']} x "
        f"{where['size']} px from <code>{_fmt(result.input.get('root'))}</code> "
        f"(layout {_fmt(result.input.get('layout'))}, sha256 "
        f"{_fmt(str(result.input.get('hash'))[:16])}...); fit/held-out split "
        f"{result.split.n_fit}/{result.split.n_held} stratified by label. "
        f"Mean squared error real - sim: {where['mse']:.2f} (0-255 scale).</p>"
    ]
    if which.residual_flagged:
        parts.append(
            f'<p class="warn">A large part of the gap ({_fmt(which.unexplained)} of the '
            "held-out gap) is left after the selected effects and no candidate explains it: "
            "an effect outside the candidate list is likely at work.</p>"
        )
    unstable = stability_warning(which.stability)
    if unstable:
        parts.append(f'<p class="warn">{html.escape(unstable[0].upper() + unstable[1:])}.</p>')
    parts.append("<h2>1. Where the gap lies</h2>")
    parts.append(_table(where["dominant"], ["axis", "part", "share", "intensity"]))
    parts.append(img("error_maps") + img("shares") + img("spectrum"))
    for axis, rows in where["axes"].items():
        cols = ["part", "share"] + [
            c
            for c in ("area_share", "bin_share", "pair_share", "intensity")
            if rows and c in rows[0]
        ]
        parts.append(f"<h3>by {html.escape(axis)}</h3>" + _table(rows, cols))
    parts.append(f"<h2>2. Which effect causes it</h2><p>gap measure: {_fmt(which.gap_metric)}</p>")
    cols = ["effect", "params", "gap_before", "gap_after", "shrink", "ci_low", "ci_high"]
    first = [which.background] if which.background else []
    parts.append(
        f"<p>background: {_fmt(which.background_note)}</p>"
        "<h3>selected (first line: the measured background; then greedy forward selection on "
        "what it leaves)</h3>" + _table([r.to_dict() for r in first + which.ranking], cols)
    )
    if which.shapley:
        parts.append(
            "<h3>each selected effect's share whatever the order (Shapley value over every "
            "order of the selected effects, each subset refitted; shares of the held-out gap, "
            "summing to what the selection removes)</h3>"
            + _table(
                [s.to_dict() for s in sorted(which.shapley, key=lambda s: -s.share)],
                ["effect", "share", "ci_low", "ci_high"],
            )
        )
    parts.append(f"<p>unexplained share of the held-out gap: {_fmt(which.unexplained)}</p>")
    singles = [r.to_dict() for r in which.singles]
    parts.append("<h3>every candidate alone</h3>" + _table(singles, cols) + img("shrinks"))
    parts.append("<h2>3. How far it shrinks</h2>")
    parts.append(_table(_flatten(result.how_far.to_dict()), ["measure", "value"]))
    if result.where_held is not None:
        before, after = (w.summary for w in result.where_held)
        parts.append(
            f"<h3>where the residual lies (held-out pairs)</h3><p>mean squared error "
            f"{before['mse']:.2f} before, {after['mse']:.2f} after the selected "
            "effects; the top part of each axis after them:</p>"
        )
        parts.append(_table(after["dominant"], ["axis", "part", "share", "intensity"]))
    parts.append(img("residual_maps") + img("samples"))
    parts.append(_timing_html(result.timing_s))
    body = "\n".join(parts)
    head = f'<meta charset="utf-8"><title>gap diagnosis</title><style>{_CSS}</style>'
    return f"<!doctype html><html><head>{head}</head><body>{body}</body></html>\n"


def write_report(
    out_dir: str | Path,
    result: Diagnosis,
    samples: Mapping[str, torch.Tensor] | None,
    sample_labels: Sequence[str] = (),
) -> dict[str, Path]:
    """Write ``report.json`` and ``report.html`` (figures inlined) into ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    with timed_span(REPORT_FIGURES):
        figures = _report_figures(result, samples, sample_labels)
    json_path = atomic_write_json(out / "report.json", jsonable(result.to_dict()))
    html_path = atomic_write_text(out / "report.html", render_html(result, figures))
    return {"json": json_path, "html": html_path}


def _report_figures(
    result: Diagnosis,
    samples: Mapping[str, torch.Tensor] | None,
    sample_labels: Sequence[str] = (),
) -> dict[str, str]:
    """The report's figures as base64 PNGs, by name."""
    where, held = result.where, result.where_held
    figures = {
        "error_maps": png_base64(
            error_maps_figure([("all pairs", where)], "per-pixel error, sim vs real (0-255)")
        ),
        "shares": png_base64(shares_figure(where)),
        "shrinks": png_base64(shrink_figure(result.which.singles, result.which.ranking)),
    }
    if held is not None:
        rows = [("sim (held-out)", held[0]), ("sim + effects (held-out)", held[1])]
        figures["residual_maps"] = png_base64(
            error_maps_figure(rows, "held-out pairs before and after the selected effects")
        )
        figures["spectrum"] = png_base64(spectrum_figure(rows))
    else:
        figures["spectrum"] = png_base64(spectrum_figure([("sim", where)]))
    if samples is not None and len(sample_labels):
        figures["samples"] = png_base64(samples_figure(samples, sample_labels))
    return figures
