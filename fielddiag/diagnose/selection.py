"""Choosing between a baseline model and models augmented with candidate effects.

The rule is the same for the vehicle diagnosis and the rig mode: every model is fitted on
one part of the data and scored on a part it has not seen. An augmented model wins only
if it lowers the held-out error *significantly* (a paired test over time blocks, which
stays honest when residuals are correlated in time) and by a margin worth its extra
parameters, and only if its parameters are physical (not pinned at a bound such as a zero
friction force or a zero stiffness). Otherwise the simpler model stands: a false alarm is
as bad as a miss.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from fielddiag.identify.greybox_results import nrmse

__all__ = [
    "CandidateFit",
    "Comparison",
    "Selection",
    "compare",
    "confidence",
    "nrmse",
    "paired_block_t",
    "select_model",
]

#: Blocks for the paired test on held-out residuals.
N_BLOCKS = 30
#: t statistic an improvement must reach (about 3 sigma, one-sided).
MIN_T = 3.0
#: Minimum relative reduction of held-out mean-square error per added parameter.
MIN_GAIN_PER_PARAM = 0.02


def paired_block_t(
    residual_a: np.ndarray, residual_b: np.ndarray, n_blocks: int = N_BLOCKS
) -> float:
    """t statistic that model b has a smaller mean-square error than model a.

    The held-out residuals (same samples) are cut into ``n_blocks`` contiguous blocks and
    the per-block log ratios of mean squares, log(MSE_a / MSE_b), are treated as
    independent samples. Log ratios make the test fair to effects that act in a few
    events only (a bump stop): their gain is large where they act and nil elsewhere, which
    in raw differences would look like noise. Positive t favours b.

    Parameters
    ----------
    residual_a, residual_b : ndarray
        Held-out residuals of the two models on the same samples, in the data's unit (body
        acceleration [m/s^2] in the vehicle diagnosis, force [N] in the rig mode).
    n_blocks : int
        Number of blocks; fewer when there are less than 50 samples per block (at least 2).

    Returns
    -------
    float
        Mean over standard error of the block log ratios (dimensionless); ``inf`` when every
        block favours b equally, 0 when none does.

    Examples
    --------
    ::

        t = paired_block_t(linear.residual_validation, friction.residual_validation)
        t >= MIN_T   # friction predicts the held-out data significantly better
    """
    return _block_t(block_log_ratios(residual_a, residual_b, n_blocks))


def _block_t(d: np.ndarray) -> float:
    """Mean over standard error of the block log ratios ``d`` (see :func:`paired_block_t`)."""
    sd = float(d.std(ddof=1))
    # equal log ratios give sd of a few ulp (the mean of equal numbers is not exact)
    if sd <= 1e-12 * abs(float(d.mean())) or sd == 0.0:
        return np.inf if d.mean() > 0 else 0.0
    return float(d.mean() / (sd / np.sqrt(d.size)))


def block_log_ratios(
    residual_a: np.ndarray, residual_b: np.ndarray, n_blocks: int = N_BLOCKS
) -> np.ndarray:
    """Per-block log(MSE_a / MSE_b) of two residuals on the same samples.

    The samples are cut into ``n_blocks`` contiguous blocks (fewer when there are less
    than 50 samples a block, at least 2); positive entries favour b. The sample
    :func:`paired_block_t` tests.
    """
    a = np.asarray(residual_a, float) ** 2
    b = np.asarray(residual_b, float) ** 2
    n = min(a.size, b.size)
    k = max(2, min(n_blocks, n // 50))
    edges = np.linspace(0, n, k + 1).astype(int)
    tiny = 1e-300
    return np.array(
        [
            np.log((a[i:j].mean() + tiny) / (b[i:j].mean() + tiny))
            for i, j in zip(edges[:-1], edges[1:], strict=True)
        ]
    )


@dataclass
class CandidateFit:
    """One fitted model and how well it predicts data it was not fitted to.

    ``residual_validation`` holds the held-out residuals (concatenated over sessions, in a
    fixed order shared by all candidates) for the paired test.

    Parameters
    ----------
    effects : tuple of str
        The effects added to the linear model (empty for the baseline).
    values, std : dict
        Fitted parameter values and standard deviations by name (SI units as named).
    nrmse_fit, nrmse_validation : float
        Normalised RMS error on the fitted and on the held-out data (dimensionless).
    residual_validation : ndarray
        Held-out residuals (body acceleration [m/s^2], or force [N] in the rig mode).
    n_params : int
        Number of fitted parameters.
    at_bound : tuple of str
        Parameters pinned at a bound or otherwise unphysical (then the candidate is never
        chosen).
    extra : dict
        What the caller wants to keep with the fit (the model, the data hypothesis).
    corrections : tuple of str
        The names in ``effects`` that correct the recording rather than model the
        suspension (a late channel, a gain change): they act alike on every block.
    """

    effects: tuple[str, ...]
    values: dict[str, float]
    std: dict[str, float]
    nrmse_fit: float
    nrmse_validation: float
    residual_validation: np.ndarray = field(repr=False)
    n_params: int
    at_bound: tuple[str, ...] = ()
    extra: dict = field(default_factory=dict)
    corrections: tuple[str, ...] = ()

    def adds_corrections_only(self, reference: CandidateFit) -> bool:
        """True if all this model adds to ``reference`` are corrections of the recording."""
        added = set(self.effects) - set(reference.effects)
        return bool(added) and added <= set(self.corrections)

    @property
    def mse_validation(self) -> float:
        """Mean square of the held-out residuals (in the residual's unit squared, e.g. m^2/s^4)."""
        return float(np.mean(self.residual_validation**2))

    @property
    def physical(self) -> bool:
        """True if no parameter is pinned at a bound (``at_bound`` empty)."""
        return not self.at_bound


@dataclass(frozen=True)
class Comparison:
    """How a candidate compares with a reference model on held-out data.

    Parameters
    ----------
    t : float
        :func:`paired_block_t` of the candidate against the reference (positive favours the
        candidate).
    relative_gain : float
        Reduction of held-out mean-square error as a fraction of the reference's.
    typical_gain : float
        Reduction of the typical block's mean-square error: one minus the geometric mean of
        the blocks' MSE ratios (candidate over reference).
    """

    t: float
    relative_gain: float  # reduction of held-out MSE, fraction of the reference's
    typical_gain: float = 0.0  # the same in the typical block (geometric mean of ratios)

    def gain(self, everywhere: bool = False) -> float:
        """The reduction of held-out MSE that fits what the candidate adds.

        Physics acts where the suspension goes (a bump stop in a few events, which then
        dominate the held-out MSE): its gain is the whole MSE's. A correction of the
        recording (a late channel, a gain change: ``everywhere``) acts alike in every block:
        its gain is the typical block's, which a few events the model still misfits (and
        the correction moves a little either way) do not swamp.
        """
        return self.typical_gain if everywhere else self.relative_gain

    def beats(self, extra_params: int, everywhere: bool = False) -> bool:
        """True if the candidate is significantly and usefully better than the reference.

        Parameters
        ----------
        extra_params : int
            Parameters the candidate has beyond the reference.
        everywhere : bool
            What it adds acts alike in every block (a data problem's correction): judged
            by the typical block's gain (:meth:`gain`).

        Returns
        -------
        bool
            ``t >= MIN_T`` and ``gain >= MIN_GAIN_PER_PARAM * max(1, extra_params)``.
        """
        return self.t >= MIN_T and self.gain(everywhere) >= MIN_GAIN_PER_PARAM * max(
            1, extra_params)


def compare(reference: CandidateFit, candidate: CandidateFit) -> Comparison:
    """Compare ``candidate`` against ``reference`` on their held-out residuals.

    Parameters
    ----------
    reference, candidate : CandidateFit
        Fits whose ``residual_validation`` cover the same samples.

    Returns
    -------
    Comparison
        The paired-block t statistic and the relative reduction of held-out MSE.
    """
    d = block_log_ratios(reference.residual_validation, candidate.residual_validation)
    gain = 1.0 - candidate.mse_validation / reference.mse_validation
    return Comparison(_block_t(d), gain, 1.0 - float(np.exp(-d.mean())))


@dataclass
class Selection:
    """The outcome: the chosen model and the evidence for it.

    Parameters
    ----------
    chosen : CandidateFit
        The model selected (``baseline`` when no candidate beats it).
    baseline : CandidateFit
        The linear model.
    comparison : Comparison or None
        ``chosen`` against the baseline (None when the baseline stands).
    ranking : list of (CandidateFit, Comparison)
        All candidates against the baseline, lowest held-out MSE first.
    rejected_unphysical : list of CandidateFit
        Candidates left out because a parameter was pinned at a bound.
    """

    chosen: CandidateFit
    baseline: CandidateFit
    comparison: Comparison | None  # chosen vs baseline (None when the baseline stands)
    ranking: list[tuple[CandidateFit, Comparison]]  # all candidates vs baseline, best first
    rejected_unphysical: list[CandidateFit]


def select_model(baseline: CandidateFit, candidates: Sequence[CandidateFit], *,
                 simplest_alike: bool = True,
                 data_twins: frozenset[str] = frozenset()) -> Selection:
    """Pick the simplest model that predicts held-out data significantly better.

    Single effects are compared with the baseline; a pair of effects must also beat the
    best single effect it contains, and a pair without the chosen single must beat that
    single and each of its own parts. What corrects the recording only is judged by its gain
    in the typical block (:meth:`Comparison.gain`). Candidates with a parameter pinned at
    a bound are unphysical and never chosen. The model chosen must also beat every
    simpler candidate that would be chosen in its own right (``simplest_alike``).

    Parameters
    ----------
    baseline : CandidateFit
        The linear model.
    candidates : sequence of CandidateFit
        Augmented models (one or two effects each), scored on the same held-out samples.
    simplest_alike : bool
        The chosen model must also beat every simpler candidate that would be chosen in
        its own right, else that one is chosen (:func:`_simpler_alike`). Off for the rig,
        where one periodic record is held out from itself: the real MR damper's build-up
        law, which predicts a neighbouring record as well and a shorter stroke 40 % better
        than Dahl friction, does not beat it by the per-parameter gain on its own record.
    data_twins : frozenset of str
        Effects that look like a data problem (a top mount's lag and a late channel): a
        simpler model does not bring one in by the ``simplest_alike`` rule. Whether its
        lag is physics or the recording's is weighed where the data problem is, on top of
        the chosen physics; taken in here by one parameter fewer, it stood in for a
        hysteresis beside which the lag was then told a late channel (seed 1795938617).

    Returns
    -------
    Selection

    Examples
    --------
    ::

        sel = select_model(linear_fit, [friction_fit, bump_fit, friction_bump_fit])
        sel.chosen.effects          # () when the linear model stands
    """
    ranking = sorted(
        ((c, compare(baseline, c)) for c in candidates), key=lambda cc: cc[0].mse_validation
    )
    unphysical = [c for c, _ in ranking if not c.physical]
    ok = [(c, cmp) for c, cmp in ranking if c.physical]
    chosen, chosen_cmp = baseline, None
    singles = [
        (c, cmp)
        for c, cmp in ok
        if len(c.effects) == 1
        and cmp.beats(c.n_params - baseline.n_params, c.adds_corrections_only(baseline))
    ]
    if singles:
        chosen, chosen_cmp = singles[0]
    for c, cmp in ok:
        if len(c.effects) < 2 or not cmp.beats(
            c.n_params - baseline.n_params, c.adds_corrections_only(baseline)
        ):
            continue
        if chosen is baseline:
            chosen, chosen_cmp = c, cmp
            break
        if set(chosen.effects) <= set(c.effects) and compare(chosen, c).beats(
            c.n_params - chosen.n_params, c.adds_corrections_only(chosen)
        ):
            chosen, chosen_cmp = c, cmp
            break
        if not set(chosen.effects) <= set(c.effects) and _beats_apart(c, chosen, candidates):
            chosen, chosen_cmp = c, cmp
            break
    if simplest_alike and chosen is not baseline:
        simpler = _simpler_alike(chosen, baseline, ok, candidates, data_twins)
        if simpler is not None:
            chosen, chosen_cmp = simpler
    return Selection(chosen, baseline, chosen_cmp, ranking, unphysical)


def _simpler_alike(chosen: CandidateFit, baseline: CandidateFit,
                   ok: Sequence[tuple[CandidateFit, Comparison]],
                   candidates: Sequence[CandidateFit],
                   data_twins: frozenset[str] = frozenset()
                   ) -> tuple[CandidateFit, Comparison] | None:
    """The best-predicting physical candidate with fewer parameters than ``chosen`` that
    ``chosen`` does not beat by the selection's rule for its extra parameters, and that
    would be chosen in its own right (it beats the baseline and, a pair, each of its
    parts); None where there is none. Only candidates with the same corrections of the
    recording as ``chosen`` (the data problems are judged apart).

    The chosen model earns its parameters against every simpler model, not only against
    the baseline and its own parts: a digressive damper (four parameters), whose
    per-direction drops and low knees stand for dry friction and asymmetric damping
    together, predicted as well as the two (three parameters) and was named for them
    (seed 1795922758). A candidate that holds an effect of ``data_twins`` the chosen one
    does not hold is not taken."""
    for c, cmp in ok:  # best held-out error first
        if (c is chosen or c.n_params >= chosen.n_params
                or set(c.corrections) != set(chosen.corrections)
                or set(c.effects) <= set(chosen.effects)
                or (set(c.effects) - set(chosen.effects)) & data_twins
                or not cmp.beats(c.n_params - baseline.n_params,
                                 c.adds_corrections_only(baseline))
                or compare(c, chosen).beats(chosen.n_params - c.n_params,
                                            chosen.adds_corrections_only(c))):
            continue
        parts = [p for p in candidates if p is not c and set(p.effects) < set(c.effects)
                 and set(p.corrections) == set(c.corrections)]
        if all(compare(p, c).beats(c.n_params - p.n_params) for p in parts):
            return c, cmp
    return None


def _beats_apart(pair: CandidateFit, single: CandidateFit,
                 candidates: Sequence[CandidateFit]) -> bool:
    """Whether ``pair``, which does not hold the chosen ``single``, replaces it: each of
    its effects was fitted alone too, and it beats the single and every candidate made of
    a part of it, each by the selection's rule for the parameters it adds (a hysteresis
    beside a late channel against the top mount whose lag takes up both on the drives as
    recorded). Where a part was never fitted alone, nothing says the pair needs both."""
    parts = [c for c in candidates if c is not pair and set(c.effects) < set(pair.effects)]
    if {e for c in parts for e in c.effects} != set(pair.effects):
        return False
    return all(compare(ref, pair).beats(pair.n_params - ref.n_params,
                                        pair.adds_corrections_only(ref))
               for ref in [single, *parts])


def confidence(cmp: Comparison | None, explained_fraction: float) -> float:
    """A 0..1 confidence from the test statistic and how much of the excess is explained.

    Parameters
    ----------
    cmp : Comparison or None
        The chosen model against the baseline (None: the baseline stands).
    explained_fraction : float
        Share of the baseline's excess residual the chosen model removes (clipped to 0..1).

    Returns
    -------
    float
        ``(0.5 + 0.5 (1 - exp(-(t - MIN_T) / 3))) * explained_fraction``; 0 without a
        comparison.
    """
    if cmp is None:
        return 0.0
    sig = 1.0 - np.exp(-max(cmp.t - MIN_T, 0.0) / 3.0)
    return float(np.clip(0.5 + 0.5 * sig, 0, 1) * np.clip(explained_fraction, 0.0, 1.0))
