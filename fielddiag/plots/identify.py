"""PNG plots of an identification and of a body-only ride analysis.

Figures are drawn on matplotlib's Agg canvas directly (no pyplot, no global backend
change), so this works on a headless machine and next to a web server.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from fielddiag.identify.results import IdentificationResult

COLOURS = {"before": "tab:blue", "after": "tab:red"}


def _save(fig: Figure, path: str | os.PathLike) -> Path:
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=110)
    return Path(path)


def _colour(label: str, i: int) -> str:
    return COLOURS.get(label, f"C{i}")


def plot_transmissibility(result: IdentificationResult, path: str | os.PathLike) -> Path:
    """|T|, phase and coherence before/after: H-v points, H1/H2 lines, fitted model."""
    fig = Figure(figsize=(9, 9), layout="constrained")
    ax_m, ax_p, ax_c = fig.subplots(3, 1, sharex=True, height_ratios=[3, 1.5, 1.2])
    band = result.band_hz
    for i, tr in enumerate(result.transmissibility):
        c = _colour(tr.label, i)
        f = np.asarray(tr.freq_hz)
        hv, h1, h2, mod = (tr.hv.array(), tr.h1.array(), tr.h2.array(), tr.model.array())
        lab = f"{tr.label} (+{tr.added_mass_kg:g} kg)"
        ax_m.loglog(f, np.abs(h1), color=c, lw=0.6, alpha=0.4, ls=":")
        ax_m.loglog(f, np.abs(h2), color=c, lw=0.6, alpha=0.4, ls="--")
        ax_m.loglog(f, np.abs(hv), "o", color=c, ms=2.5, alpha=0.7, label=f"{lab}: H-v")
        ax_m.loglog(f, np.abs(mod), "-", color=c, lw=1.6, label=f"{lab}: fitted model")
        ax_p.semilogx(f, np.degrees(np.angle(hv)), "o", color=c, ms=2)
        ax_p.semilogx(f, np.degrees(np.angle(mod)), "-", color=c, lw=1.3)
        ax_c.semilogx(f, tr.coherence, "-", color=c, lw=1, label=tr.label)
    ax_m.plot([], [], "k:", lw=0.8, label="H1 (biased low by wheel noise)")
    ax_m.plot([], [], "k--", lw=0.8, label="H2 (biased high by body noise)")
    for ax in (ax_m, ax_p, ax_c):
        ax.axvspan(band.low_hz, band.high_hz, color="0.92", zorder=0)
        ax.grid(True, which="both", lw=0.3)
    m2, k2, c2 = (result.sprung_mass_kg, result.suspension_stiffness_n_per_m,
                  result.suspension_damping_ns_per_m)
    ax_m.set_title(
        f"Body/wheel transmissibility   M2 = {m2.value:.1f} ± {m2.std:.1f} kg, "
        f"K2 = {k2.value / 1e3:.2f} ± {k2.std / 1e3:.2f} kN/m, C2 = {c2.value:.0f} ± "
        f"{c2.std:.0f} N s/m\nband {band.low_hz:.2f}-{band.high_hz:.1f} Hz (shaded)",
        fontsize=10)
    ax_m.set_ylabel("|T| = |A2/A1|")
    ax_m.legend(fontsize=7, loc="lower left")
    ax_p.set_ylabel("phase (deg)")
    ax_c.set_ylabel("coherence")
    ax_c.set_ylim(0, 1.02)
    ax_c.set_xlabel("frequency (Hz)")
    ax_c.legend(fontsize=7, loc="lower left")
    return _save(fig, path)


def plot_restoring_force(result: IdentificationResult, path: str | os.PathLike) -> Path:
    """Restoring-force surfaces over (r, rdot), one panel per session, with the plane fit."""
    surfs = result.restoring_force
    fig = Figure(figsize=(5.2 * max(len(surfs), 1), 4.6), layout="constrained")
    axes = np.atleast_1d(fig.subplots(1, max(len(surfs), 1)))
    for ax, s in zip(axes, surfs, strict=False):
        grid = np.array([[np.nan if v is None else v for v in row]
                         for row in s.force_per_mass_mps2], float)
        scale, unit = (s.mass_kg / 1e3, "kN") if s.mass_kg else (1.0, "N/kg")
        r = np.asarray(s.r_centers_m) * 1e3
        v = np.asarray(s.rdot_centers_mps)
        mesh = ax.pcolormesh(v, r, grid * scale, shading="nearest", cmap="coolwarm")
        fig.colorbar(mesh, ax=ax, label=f"restoring force ({unit})")
        ok = np.isfinite(grid)
        if ok.sum() > 6:
            ax.contour(v, r, np.where(ok, grid * scale, np.nan), colors="k", linewidths=0.5)
        txt = (f"k/M = {s.stiffness_per_mass.value:.1f} ± {s.stiffness_per_mass.std:.1f} 1/s²\n"
               f"c/M = {s.damping_per_mass.value:.3f} ± {s.damping_per_mass.std:.3f} 1/s")
        if s.stiffness_n_per_m is not None and s.damping_ns_per_m is not None:
            txt += (f"\nK2 ≈ {s.stiffness_n_per_m.value / 1e3:.2f} kN/m, "
                    f"C2 ≈ {s.damping_ns_per_m.value:.0f} N s/m")
        ax.text(0.02, 0.02, txt, transform=ax.transAxes, fontsize=7,
                bbox={"fc": "white", "alpha": 0.8, "lw": 0})
        ax.set_xlabel("suspension rate rdot (m/s)")
        ax.set_ylabel("suspension travel r (mm)")
        ax.set_title(f"{s.label}: band {s.band_hz[0]:.2f}-{s.band_hz[1]:.1f} Hz"
                     + (f", mass {s.mass_kg:.0f} kg" if s.mass_kg else ""), fontsize=9)
    fig.suptitle("Restoring force over travel and rate (a plane for a linear suspension)",
                 fontsize=10)
    return _save(fig, path)


def plot_hysteresis(result: IdentificationResult, path: str | os.PathLike) -> Path:
    """Loops of restoring force against r and rdot at each chosen frequency."""
    freqs = sorted({round(lp.freq_hz, 6) for lp in result.hysteresis})
    n = max(len(freqs), 1)
    fig = Figure(figsize=(8, 2.6 * n + 0.6), layout="constrained")
    axes = np.atleast_2d(fig.subplots(n, 2))
    for row, f0 in enumerate(freqs):
        for i, lp in enumerate(lp for lp in result.hysteresis if round(lp.freq_hz, 6) == f0):
            c = _colour(lp.label, i)
            scale, unit = (lp.mass_kg / 1e3, "kN") if lp.mass_kg else (1.0, "N/kg")
            force = np.asarray(lp.force_per_mass_mps2) * scale
            axes[row, 0].plot(np.asarray(lp.r_m) * 1e3, force, color=c, lw=0.9, label=lp.label)
            axes[row, 1].plot(lp.rdot_mps, force, color=c, lw=0.9, label=lp.label)
            axes[row, 0].set_ylabel(f"force ({unit})")
        axes[row, 0].set_title(f"{f0:.2f} Hz: force vs travel (area = damping)", fontsize=9)
        axes[row, 1].set_title(f"{f0:.2f} Hz: force vs rate (area = stiffness)", fontsize=9)
        for ax in axes[row]:
            ax.grid(True, lw=0.3)
        axes[row, 0].legend(fontsize=7)
    axes[-1, 0].set_xlabel("suspension travel r (mm)")
    axes[-1, 1].set_xlabel("suspension rate rdot (m/s)")
    return _save(fig, path)


def write_identify_plots(result: IdentificationResult, folder: str | os.PathLike
                         ) -> list[Path]:
    """Write transmissibility.png, restoring_force.png and hysteresis.png into ``folder``."""
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    return [plot_transmissibility(result, out / "transmissibility.png"),
            plot_restoring_force(result, out / "restoring_force.png"),
            plot_hysteresis(result, out / "hysteresis.png")]


def plot_ride(analysis, folder: str | os.PathLike, *, title: str = "") -> list[Path]:
    """Body-only ride analysis: spectrum, spectrogram with speed, dominant frequency vs speed.

    Parameters
    ----------
    analysis : fielddiag.identify.ride.RideAnalysis
    folder : path
        Writes ``ride_spectrum.png`` and ``ride_vs_speed.png``.
    """
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    a = analysis
    fig = Figure(figsize=(9, 4.5), layout="constrained")
    ax = fig.subplots()
    f = np.asarray(a.freq_hz)
    ax.semilogy(f, a.psd_mps2_per_hz, "k-", lw=0.9, label="whole drive")
    for b in a.speed_bins:
        ax.semilogy(b.freq_hz, b.psd_mps2_per_hz, lw=0.8, alpha=0.8,
                    label=f"{3.6 * b.speed_low_mps:.0f}-{3.6 * b.speed_high_mps:.0f} km/h "
                          f"({b.n_windows} windows)")
    ax.axhline(a.noise_psd_per_hz, color="0.5", ls="--", lw=0.8,
               label="noise floor" + ("" if a.noise_floor_found else " (upper bound)"))
    for pk in a.peaks:
        ax.annotate(f"{pk.freq_hz:.2f} Hz", (pk.freq_hz, np.interp(pk.freq_hz, f,
                                                                   a.psd_mps2_per_hz)),
                    textcoords="offset points", xytext=(0, 6), ha="center", fontsize=7)
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("PSD of vertical body acceleration ((m/s²)²/Hz)")
    ax.set_xlim(0, 0.5 * a.sample_rate_hz)
    ax.grid(True, which="both", lw=0.3)
    ax.legend(fontsize=7)
    ax.set_title(title or "Vertical body acceleration spectrum", fontsize=10)
    paths = [_save(fig, out / "ride_spectrum.png")]

    fig = Figure(figsize=(9, 7), layout="constrained")
    ax_s, ax_v = fig.subplots(2, 1, height_ratios=[1.3, 1])
    if a.spectrogram_db:
        sg = np.array(a.spectrogram_db).T
        mesh = ax_s.pcolormesh(a.spectrogram_time_s, a.spectrogram_freq_hz, sg, shading="nearest",
                               cmap="magma")
        fig.colorbar(mesh, ax=ax_s, label="dB re 1 (m/s²)²/Hz")
        if a.speed_time_s:
            tw = ax_s.twinx()
            tw.plot(a.speed_time_s, np.asarray(a.speed_mps) * 3.6, "c-", lw=1.2)
            tw.set_ylabel("speed (km/h)", color="c")
    ax_s.set_xlabel("time (s)")
    ax_s.set_ylabel("frequency (Hz)")
    ax_s.set_title("Spectrogram of vertical body acceleration with vehicle speed", fontsize=10)
    v = np.array([w.speed_mps for w in a.windows]) * 3.6
    for k, tr in enumerate(a.tracks):
        c = f"C{k}"
        lab = (f"peak near {tr.mean_freq_hz:.2f} Hz: slope {tr.slope_hz_per_mps:+.3f} ± "
               f"{tr.slope_std_hz_per_mps:.3f} Hz/(m/s)")
        ax_v.axhspan(*tr.search_band_hz, color=c, alpha=0.07)
        if len(tr.window_freq_hz) == v.size:
            ax_v.plot(v, tr.window_freq_hz, "o", color=c, ms=4, label=lab)
        if np.isfinite(tr.slope_hz_per_mps) and v.size:
            vv = np.linspace(v.min(), v.max(), 10)
            ax_v.plot(vv, tr.intercept_hz + tr.slope_hz_per_mps * vv / 3.6, "-", color=c, lw=0.8)
    if v.size and np.all(np.isfinite(v)):
        vv = np.linspace(max(v.min() - 5, 1), v.max() + 5, 50)
        for h in (1, 2):
            ax_v.plot(vv, h * vv / 3.6 / (2 * np.pi * 0.35), "k:", lw=0.8)
        ax_v.plot([], [], "k:", label="wheel rotation ×1, ×2 (rolling radius 0.35 m assumed)")
    ax_v.set_title("Peaks tracked window by window against speed (lines: regressions); a "
                   "resonance stays flat, rotation-tied lines rise", fontsize=9)
    ax_v.set_xlabel("speed (km/h)")
    ax_v.set_ylabel("frequency (Hz)")
    top = max([tr.search_band_hz[1] for tr in a.tracks] + [5.0])
    ax_v.set_ylim(0, 1.45 * top)
    ax_v.grid(True, lw=0.3)
    ax_v.legend(fontsize=7, loc="upper left", ncols=2)
    paths.append(_save(fig, out / "ride_vs_speed.png"))
    return paths
