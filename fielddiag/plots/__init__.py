"""PNG figures for people to look at (matplotlib, Agg canvas; no pyplot global state)."""

from fielddiag.plots.identify import (
    plot_hysteresis,
    plot_restoring_force,
    plot_ride,
    plot_transmissibility,
    write_identify_plots,
)

__all__ = [
    "plot_hysteresis",
    "plot_restoring_force",
    "plot_ride",
    "plot_transmissibility",
    "write_identify_plots",
]
