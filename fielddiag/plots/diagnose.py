"""PNG plots of a diagnosis: where the linear model misses and how the findings fix it."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from fielddiag.diagnose.locate import residual_psd
from fielddiag.plots.identify import _save


def _runs(fit) -> list[tuple[str, np.ndarray, np.ndarray, np.ndarray]]:
    """(label, time, measured, simulated) per drive on held-out data."""
    out = []
    for sf, measured, residual, t in fit.runs:
        out.append((sf.name, t, measured, measured - residual))
    return out


def plot_worst_windows(diag, path: str | os.PathLike) -> Path:
    """Recorded and simulated body acceleration over the worst held-out windows."""
    wins = diag.windows[:3]
    # validation runs are named like "before[105.0-150.0 s]": key them by drive label
    base_runs = {lab.split("[")[0]: (t, m, s) for lab, t, m, s in _runs(diag.baseline)}
    aug_runs = {lab.split("[")[0]: (t, m, s) for lab, t, m, s in _runs(diag.described)}
    spread = not wins
    if spread:  # residual spread evenly: show the first 6 s of each held-out part
        wins = [
            {"session": lab, "start_s": float(t[0]), "end_s": float(t[0]) + 6.0, "rms_ratio": 1.0}
            for lab, (t, _, _) in base_runs.items()
        ]
    # per window a fit axis and, under it, the residual (recording minus model): where
    # recording and model overlap, the miss is only visible there
    fig = Figure(figsize=(10, 4.2 * len(wins) + 1.0), layout="constrained")
    grid = fig.subplots(2 * len(wins), 1, squeeze=False,
                        gridspec_kw={"height_ratios": [3, 1.3] * len(wins)})[:, 0]
    axes, res_axes = grid[0::2], grid[1::2]
    labels = {d.label: d for d in diag.drives}
    for ax, rax, w in zip(axes, res_axes, wins, strict=False):
        lab = w["session"]
        t, m, s = base_runs[lab]
        sel = (t >= w["start_s"]) & (t <= w["end_s"])
        ax.plot(t[sel], m[sel], color="k", lw=1.2, label="recorded")
        ax.plot(t[sel], s[sel], color="tab:orange", lw=1.0, label="linear model")
        rax.plot(t[sel], (m - s)[sel], color="tab:orange", lw=1.0, label="linear model")
        if diag.described is not diag.baseline:
            ta, ma, sa = aug_runs[lab]
            sel_a = (ta >= w["start_s"]) & (ta <= w["end_s"])
            name = (" + ".join(diag.described.effects).replace("force_surface", "force surface")
                    .replace("memory_surface", "a force remembering reversals"))
            ax.plot(ta[sel_a], sa[sel_a], color="tab:green", lw=1.0, ls="--", label=f"with {name}")
            rax.plot(ta[sel_a], (ma - sa)[sel_a], color="tab:green", lw=1.0, ls="--",
                     label=f"with {name}")
        rax.axhline(0.0, color="k", lw=0.6)
        rax.set_ylabel("residual (m/s²)")
        rax.grid(alpha=0.3)
        rax.legend(loc="upper right", fontsize=7)
        added = labels[lab].added_mass_kg if lab in labels else 0.0
        what = (
            "the mismatch is spread evenly, no window stands out"
            if spread
            else f"residual {w['rms_ratio']:.1f}x its typical level"
        )
        ax.set_title(
            f"{lab} drive (+{added:g} kg), held-out data, {w['start_s']:.1f}-"
            f"{w['end_s']:.1f} s: {what}"
        )
        ax.set_ylabel("body accel. (m/s²)")
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
        rax.set_xlabel("time in the drive (s)")
    out = diag.to_dict()
    fig.suptitle(
        f"Verdict: {out['verdict']} — held-out NRMSE linear "
        f"{out['baseline']['nrmse_validation']:.3f}"
        f" → {out['augmented']['nrmse_validation']:.3f}"
    )
    return _save(fig, path)


def plot_residual_spectrum(diag, path: str | os.PathLike) -> Path:
    """Spectrum of the held-out residual, linear model vs with the findings."""
    fig = Figure(figsize=(9, 5), layout="constrained")
    ax = fig.subplots()
    for fit, colour, name in (
        (diag.baseline, "tab:orange", "linear model"),
        (diag.described, "tab:green", "with findings"),
    ):
        if name == "with findings" and diag.described is diag.baseline:
            continue
        res = np.concatenate([r[2] for r in fit.runs])
        fs = fit.runs[0][0].sample_rate_hz
        f, p = residual_psd(res, fs)
        ax.semilogy(f, p, color=colour, label=f"residual, {name}")
    meas = np.concatenate([r[1] for r in diag.baseline.runs])
    f, p = residual_psd(meas, diag.baseline.runs[0][0].sample_rate_hz)
    ax.semilogy(f, p, color="k", lw=0.8, alpha=0.6, label="recorded body acceleration")
    lo, hi = diag.band_hz
    ax.axvspan(0, lo, color="0.9")
    ax.axvspan(hi, f[-1], color="0.9")
    if diag.excess_band_hz:
        a, b = diag.excess_band_hz
        ax.axvspan(a, b, color="tab:red", alpha=0.12, label=f"mismatch band {a:.1f}-{b:.1f} Hz")
    ax.set_xlim(0, min(f[-1], 1.3 * hi))
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("PSD ((m/s²)²/Hz)")
    ax.set_title("Where in frequency the model misses (grey: outside the valid band)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    return _save(fig, path)


def plot_departure_map(
    dmap,
    region: dict | None,
    path: str | os.PathLike,
    *,
    title: str,
    r_label: str = "suspension extension r (mm)",
    v_label: str = "rate ṙ (m/s)",
    unit: str = "N",
) -> Path:
    """Mean departure of the force from the fitted model over (r, rdot)."""
    fig = Figure(figsize=(7.5, 6), layout="constrained")
    ax = fig.subplots()
    m = np.ma.masked_invalid(np.where(dmap.count >= 20, dmap.mean, np.nan))
    lim = float(np.nanmax(np.abs(m))) if m.count() else 1.0
    extent = (
        1000 * dmap.r_edges_m[0],
        1000 * dmap.r_edges_m[-1],
        dmap.rdot_edges_mps[0],
        dmap.rdot_edges_mps[-1],
    )
    im = ax.imshow(
        m.T, origin="lower", aspect="auto", extent=extent, cmap="RdBu_r", vmin=-lim, vmax=lim
    )
    fig.colorbar(im, ax=ax, label=f"mean force departure ({unit})")
    if region:
        r0, r1 = (1000 * v for v in region["r_m"])
        v0, v1 = region["rdot_mps"]
        ax.add_patch(
            Rectangle(
                (r0, v0),
                r1 - r0,
                v1 - v0,
                fill=False,
                ec="k",
                lw=2,
                label="where the departure concentrates",
            )
        )
        ax.legend(loc="upper right", fontsize=8)
    ax.set_xlabel(r_label)
    ax.set_ylabel(v_label)
    ax.set_title(title)
    return _save(fig, path)


def write_diagnosis_plots(diag, folder: str | os.PathLike) -> list[Path]:
    """Write the diagnosis PNGs into ``folder``; returns their paths."""
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    paths = [
        plot_worst_windows(diag, out / "diagnosis_windows.png"),
        plot_residual_spectrum(diag, out / "diagnosis_residual_spectrum.png"),
    ]
    # the departure map only where a finding locates something (on a car judged adequate
    # an outlined region reads as a fault)
    if diag.departure is not None and diag.to_dict()["findings"]:
        unit = "N" if diag.mode == "pair" else "N/kg"
        paths.append(
            plot_departure_map(
                diag.departure,
                diag.region,
                out / "diagnosis_departure_map.png",
                title="Restoring force minus the fitted model, over travel and rate",
                unit=unit,
            )
        )
    return paths


def write_rig_plots(result, folder: str | os.PathLike) -> list[Path]:
    """Rig mode: measured vs model force on held-out data, and the departure map."""
    from fielddiag.diagnose.locate import departure_map

    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    sel = result.selection
    data = result.data
    val = data.part(result.split_index, data.n)
    fig = Figure(figsize=(10, 6.5), layout="constrained")
    ax, rax = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [3, 1.3]})
    n = min(val.n, int(5 * data.sample_rate_hz))
    t = val.time_s[:n]
    ax.plot(t, val.force[:n], "k", lw=1.2, label="measured force")
    ax.plot(
        t,
        (val.force - sel.baseline.residual_validation)[:n],
        color="tab:orange",
        label="linear model",
    )
    rax.plot(t, sel.baseline.residual_validation[:n], color="tab:orange", label="linear model")
    if sel.chosen is not sel.baseline:
        name = "with " + " + ".join(sel.chosen.effects)
        ax.plot(t, (val.force - sel.chosen.residual_validation)[:n], "--", color="tab:green",
                label=name)
        rax.plot(t, sel.chosen.residual_validation[:n], "--", color="tab:green", label=name)
    rax.axhline(0.0, color="k", lw=0.6)
    rax.set_xlabel("time (s)")
    rax.set_ylabel(f"residual ({data.force_unit})")
    rax.grid(alpha=0.3)
    rax.legend(fontsize=8)
    ax.set_ylabel(f"force ({data.force_unit})")
    ax.legend()
    ax.grid(alpha=0.3)
    ax.set_title("Rig test, held-out data")
    paths = [_save(fig, out / "rig_force.png")]
    if not result.to_dict()["findings"]:  # nothing located: no map that reads as a fault
        return paths
    dmap = departure_map(val.displacement, val.velocity, sel.baseline.residual_validation)
    paths.append(
        plot_departure_map(
            dmap,
            dmap.region(),
            out / "rig_departure_map.png",
            title="Force the linear model leaves, over displacement and velocity",
            r_label=f"displacement (m{'' if data.displacement_unit == 'm' else ''} x1000)",
            v_label="velocity",
            unit=data.force_unit,
        )
    )
    return paths
