"""Output-only identification of a suspension corner.

* :mod:`~fielddiag.identify.transmissibility`: H1/H2/H-v, coherence, noise floors, band.
* :mod:`~fielddiag.identify.boundary`: added-mass (boundary perturbation) identification,
  frequency and time routes, jackknife standard deviations.
* :mod:`~fielddiag.identify.restoring_force`: restoring-force surface, slopes and loops.
* :mod:`~fielddiag.identify.ride`: what a body accelerometer alone can say.
* :mod:`~fielddiag.identify.pipeline`: sessions or arrays to an IdentificationResult.
* :mod:`~fielddiag.identify.results`: the JSON-serialisable result dataclasses.
"""

from fielddiag.identify.pipeline import (
    IdentifyConfig,
    Recording,
    identify_recordings,
    identify_sessions,
    read_recording,
)
from fielddiag.identify.results import (
    Band,
    ComplexSeries,
    Estimate,
    HysteresisLoop,
    IdentificationResult,
    NoiseResult,
    Peak,
    RestoringForceSurface,
    RouteResult,
    SessionSummary,
    TransmissibilityResult,
)
from fielddiag.identify.ride import RideAnalysis, analyse_ride

__all__ = [
    "Band",
    "ComplexSeries",
    "Estimate",
    "HysteresisLoop",
    "IdentificationResult",
    "IdentifyConfig",
    "NoiseResult",
    "Peak",
    "Recording",
    "RestoringForceSurface",
    "RideAnalysis",
    "RouteResult",
    "SessionSummary",
    "TransmissibilityResult",
    "analyse_ride",
    "identify_recordings",
    "identify_sessions",
    "read_recording",
]
