r"""Typed bundles of the compiled sampler loop (:func:`pbicrl.inference.samplers._mcmc.advance`).

NamedTuples of arrays and scalars: Numba passes them to nopython code field by field, so a bundle costs
nothing in the loop, and a field is found by its name instead of its place in a list of 76 arguments.

The chain's state is three of them plus the counters (:class:`pbicrl.inference.samplers.ChainState`):

* :class:`Position` - where the chain is: :math:`c`, :math:`w_p`, :math:`\vartheta` and the caches the next step
  needs (returns :math:`a`, the feature rows :math:`\beta\bar\Phi^\top` at :math:`\vartheta`, the log-densities);
* :class:`Adaptation` - proposal scales and warm-up accumulators (adaptation stops after warm-up);
* :class:`MapTracker` - the best state visited (highest log-posterior).

The others are inputs of one call: :class:`Schedule` (which iterations), :class:`Moves` (proposal settings),
:class:`Model` (prior and tempering), :class:`ConstraintArrays` (parametric constraints), :class:`Randoms`
(per-iteration random numbers), :class:`Draws` (kept-draw buffers) and :class:`Scratch`. The likelihood's
arrays are :class:`pbicrl.inference.likelihood_kernels.LikelihoodArrays`. :class:`Context` gathers what every
move of the loop reads and updates, so that a move names the bundles it uses instead of taking them one by one.

Arrays are mutated in place by the loop; :class:`pbicrl.inference.samplers.Kernel` copies the state first, so its
``init``/``step``/``run`` stay pure. Scalars that the loop updates live in small arrays (``log_density``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from pbicrl.inference.likelihood_kernels import LikelihoodArrays

__all__ = ["Position", "Adaptation", "MapTracker", "Schedule", "Moves", "Model", "ConstraintArrays", "Randoms",
           "Draws", "Scratch", "Context"]


class Position(NamedTuple):
    r"""Where the chain is.

    Attributes
    ----------
    indicators : ndarray (d,) int8
        :math:`c` (known features first, then parametric constraints).
    penalty_weights : ndarray (d,)
        :math:`w_p` (0 for inactive features in ``pbicrl`` mode; latent in ``paper`` mode).
    parameters : ndarray (P,)
        :math:`\vartheta` of all parametric constraints (meaningless where inactive in ``pbicrl`` mode).
    scaled_returns : ndarray (N,)
        :math:`a = \beta \bar\Phi (w_n + c \circ w_p)`.
    features_T : ndarray (d, N)
        :math:`\beta \bar\Phi^\top`, parametric rows at the current :math:`\vartheta`.
    log_density : ndarray (2,)
        [log-likelihood, log-prior] at this position.
    """

    indicators: NDArray[np.int8]
    penalty_weights: NDArray[np.float64]
    parameters: NDArray[np.float64]
    scaled_returns: NDArray[np.float64]
    features_T: NDArray[np.float64]
    log_density: NDArray[np.float64]


class Adaptation(NamedTuple):
    """Proposal scales and their warm-up statistics.

    Attributes
    ----------
    sigma, q_mean, q_scale : ndarray (d,)
        Weight random-walk scales :math:`\\sigma_j` and flip-and-draw proposals :math:`q_j = N(\\mu_j, s_j^2)`.
    sigma_theta, q_theta_mean, q_theta_scale : ndarray (P,)
        The same for the parameters :math:`\\vartheta`.
    stats : ndarray (5, d); theta_stats : ndarray (5, P)
        Warm-up accumulators: active count, sum, sum of squares; proposals, accepts in the window.
    joint_cov : ndarray (d, d); joint_stats : ndarray (3, d, d); joint_scale : ndarray (3,)
        The joint weight move (``SamplerSettings.p_joint``): adapted covariance, warm-up accumulators, and
        [scale, proposals, accepts in the current adaptation window].
    """

    sigma: NDArray[np.float64]
    q_mean: NDArray[np.float64]
    q_scale: NDArray[np.float64]
    sigma_theta: NDArray[np.float64]
    q_theta_mean: NDArray[np.float64]
    q_theta_scale: NDArray[np.float64]
    stats: NDArray[np.float64]
    theta_stats: NDArray[np.float64]
    joint_cov: NDArray[np.float64]
    joint_stats: NDArray[np.float64]
    joint_scale: NDArray[np.float64]


class MapTracker(NamedTuple):
    """The best state visited (highest log-posterior, every iteration counts).

    Attributes
    ----------
    indicators, penalty_weights, parameters : ndarray
    log_density : ndarray (2,)
        [log-posterior, log-likelihood] of that state.
    """

    indicators: NDArray[np.int8]
    penalty_weights: NDArray[np.float64]
    parameters: NDArray[np.float64]
    log_density: NDArray[np.float64]


class Schedule(NamedTuple):
    """Which iterations one call runs and what each does: global iterations ``it0 .. it0+n-1`` (0-based), the
    first ``burn_in`` of the chain warm up (and adapt every ``adapt_every``, 0: never), then every ``thin``-th is
    stored. ``mode``: ``MODE_*`` of :mod:`pbicrl.inference.codes`."""

    mode: int
    n: int
    it0: int
    burn_in: int
    thin: int
    adapt_every: int


class Moves(NamedTuple):
    r"""Proposal settings.

    ``d_known`` known features come first (the rest are parametric constraints); ``cand`` are the features
    that may be constraints; ``p_flip``, ``p_theta``, ``p_joint``: move probabilities; ``f_s``: Algorithm 1's
    sampling frequency; ``naive``: recount every state on a parameter move (benchmark only).

    ``log_sign`` (d,): ``pbicrl`` only, the sign of a feature whose weight moves on the log-magnitude scale
    :math:`\eta = \log|w|` (-1 or +1, where the prior's support is one-signed and log moves are on; 0: moves on
    :math:`w` itself). For such a feature the flip-and-draw proposal is an equal mixture of the adapted
    :math:`\log|w| \sim \mathcal{N}(\mu_j, s_j^2)` of :class:`Adaptation` and a fixed defensive
    :math:`|w| \sim U(0, b_j)` (``birth_bound``: the prior's 99% quantile of :math:`|w|`), which has the prior's
    shape near 0, where a feature the data do not want puts its conditional posterior.
    """

    d_known: int
    naive: bool
    cand: NDArray[np.int64]
    p_flip: float
    p_theta: float
    f_s: int
    p_joint: float
    log_sign: NDArray[np.int64]
    birth_bound: NDArray[np.float64]


class Model(NamedTuple):
    r"""The target besides the likelihood's data: :math:`\beta` (scales the parametric rows), the likelihood
    power :math:`\gamma`, the indicator prior's :math:`\log\frac{\pi}{1-\pi}`, and the weight prior as kind codes
    (``PRIOR_*``, shape (d,)) and parameters (d, 6) (:meth:`pbicrl.inference.priors.ResolvedWeightPrior.as_arrays`)."""

    beta: float
    power: float
    log_odds: float
    prior_kind: NDArray[np.int64]
    prior_params: NDArray[np.float64]


class ConstraintArrays(NamedTuple):
    """Parametric constraints as flat arrays (:meth:`pbicrl.inference.constraints.ConstraintSet.compiled_arrays`):
    family codes (``FAM_*``), signs, parameter and dimension offsets, per-constraint sorted values, states,
    trajectory offsets, inverse lengths and the parameters' box bounds ``lo``, ``hi``."""

    fam: NDArray[np.int64]
    sign: NDArray[np.int64]
    poff: NDArray[np.int64]
    dims_off: NDArray[np.int64]
    dims: NDArray[np.int64]
    sorted_vals: NDArray[np.float64]
    states: NDArray[np.float64]
    offsets: NDArray[np.int64]
    inv_len: NDArray[np.float64]
    lo: NDArray[np.float64]
    hi: NDArray[np.float64]


class Randoms(NamedTuple):
    """One row per iteration: feature choice ``u_j``, move choice ``u_mv``, normal ``z``, acceptance uniform
    ``u_acc``, parameter normals ``zt`` (n, max parameters) and the joint move's normals ``zj`` (n, d), or a
    (1, 1) placeholder when joint moves are off (then they are not drawn: the stream stays the same)."""

    u_j: NDArray[np.float64]
    u_mv: NDArray[np.float64]
    z: NDArray[np.float64]
    u_acc: NDArray[np.float64]
    zt: NDArray[np.float64]
    zj: NDArray[np.float64]


class Draws(NamedTuple):
    """Kept-draw buffers: rows of :math:`c`, :math:`w_p`, :math:`\\vartheta`, log-likelihood, log-prior, and
    ``n`` = [rows filled]."""

    indicators: NDArray[np.int8]
    penalty_weights: NDArray[np.float64]
    parameters: NDArray[np.float64]
    log_likelihood: NDArray[np.float64]
    log_prior: NDArray[np.float64]
    n: NDArray[np.int64]


class Scratch(NamedTuple):
    """Per-call work space: proposed returns, column and parameters; the memo of likelihoods with one feature
    flipped (``memo_valid``, ``memo_ll``); and ``last`` = [move code, accepted] of the call's last iteration
    (``MOVE_*``; read by :meth:`pbicrl.inference.samplers.Kernel.step`)."""

    a_new: NDArray[np.float64]
    col_new: NDArray[np.float64]
    theta_new: NDArray[np.float64]
    memo_valid: NDArray[np.bool_]
    memo_ll: NDArray[np.float64]
    last: NDArray[np.int64]


class Context(NamedTuple):
    """What the moves of one :func:`pbicrl.inference.samplers._mcmc.advance` call share: the sampler ``mode``
    (``MODE_*``), ``screen`` (whether :func:`pbicrl.inference.samplers._mcmc.mh_accept` may reject on the cheap
    bound of explicit pairs, or of the grouped likelihood for death moves), and the call's bundles. Built once per
    call; the moves are inlined into the loop, so reading a field through it costs nothing."""

    mode: int
    screen: bool
    pos: Position
    lik: LikelihoodArrays
    cons: ConstraintArrays
    moves: Moves
    model: Model
    rnd: Randoms
    adaptation: Adaptation
    counts: NDArray[np.int64]
    scratch: Scratch
