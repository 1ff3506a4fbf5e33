"""Named integer codes shared by the compiled sampler and Python: the one place each code is defined.

Numba freezes a module global into the machine code when it compiles a function, so every code is a plain
``int`` constant (an ``IntEnum`` member would be frozen too, but plain ints keep the compiled comparisons
trivially integer). Python code maps names to codes with the dictionaries below; compiled code compares with
the constants. Renumbering a code here changes both sides together; reordering a tuple elsewhere no longer
changes results silently. Editing this file invalidates every cached compiled function that uses it
(:mod:`pbicrl.inference.samplers._cache`).

Families
--------
``MODE_*``
    The sampler (:attr:`pbicrl.inference.samplers.SamplerSettings.sampler`): :data:`MODES`.
``MOVE_*``
    The move of one iteration. ``MOVE_NONE`` .. ``MOVE_PARAMETER`` are also the per-draw codes of
    ``Posterior.move`` (:data:`MOVES`); ``MOVE_JOINT`` (all active weights at once) is recorded per draw and in
    :class:`pbicrl.inference.samplers.StepInfo` as a weight move.
``C_*``
    Indices of the per-chain counters (``ChainState.counts``, ``Posterior.counts``): :data:`COUNTERS`.
``PRIOR_*``
    Kinds of the weight prior :math:`p(w)` of the compiled density: :data:`PRIOR_KINDS`.
``FAM_*``
    Families of parametric constraints :math:`\\vartheta`: :data:`FAMILY_CODES`.
``LIK_*``
    Layouts of the compiled log-likelihood :math:`\\mathcal{L}`: :data:`LIKELIHOODS`.
"""

from __future__ import annotations

__all__ = [
    "MODE_PBICRL", "MODE_PAPER", "MODE_BPL", "MODE_AUTHORS", "MODES",
    "MOVE_NONE", "MOVE_FLIP", "MOVE_WEIGHT", "MOVE_PARAMETER", "MOVE_JOINT", "MOVES", "MOVE_NAMES",
    "C_FLIP_PROP", "C_FLIP_ACC", "C_W_PROP", "C_W_ACC", "C_EVALS", "C_T_PROP", "C_T_ACC", "N_COUNTS", "COUNTERS",
    "PRIOR_FLAT", "PRIOR_NORMAL", "PRIOR_IMPROPER", "PRIOR_STUDENT_T", "PRIOR_KINDS",
    "FAM_AXIS", "FAM_HALFSPACE", "FAM_BOX", "FAM_BALL", "FAMILY_CODES",
    "LIK_PAIRWISE", "LIK_GROUPED", "LIK_RANKED", "LIKELIHOODS",
]

# ------------------------------------------------------------------------------------------------ samplers
MODE_PBICRL = 0  # flip-and-draw moves (reversible jump), valid for the stated prior
MODE_PAPER = 1  # the paper's Algorithm 1 (2 with a schedule that does propose theta)
MODE_BPL = 2  # Algorithm 3: weights only, every feature on
MODE_AUTHORS = 3  # Algorithm 1 as the authors' public code runs it: switching c_j off resets w_j to 0
#: Sampler name -> mode code.
MODES: dict[str, int] = {"pbicrl": MODE_PBICRL, "paper": MODE_PAPER, "bpl": MODE_BPL, "authors": MODE_AUTHORS}

# ------------------------------------------------------------------------------------------------ moves
MOVE_NONE = 0  # nothing proposed (a pbicrl weight step with no active weight)
MOVE_FLIP = 1  # flip c_j (pbicrl: reversible jump on/off)
MOVE_WEIGHT = 2  # random walk on one weight w_j
MOVE_PARAMETER = 3  # random walk on one constraint's parameters vartheta
MOVE_JOINT = 4  # all active weights together (SamplerSettings.p_joint); a weight move to the outside
#: Per-draw move code -> name (``Posterior.move``, ``StepInfo.move``).
MOVES: dict[int, str] = {MOVE_NONE: "none", MOVE_FLIP: "flip", MOVE_WEIGHT: "weight", MOVE_PARAMETER: "parameter"}
#: Every move code of the compiled loop -> the name it is reported under.
MOVE_NAMES: dict[int, str] = MOVES | {MOVE_JOINT: "weight"}

# ------------------------------------------------------------------------------------------------ counters
C_FLIP_PROP = 0  # flip proposals
C_FLIP_ACC = 1  # flip acceptances
C_W_PROP = 2  # weight proposals (single and joint)
C_W_ACC = 3  # weight acceptances (single and joint)
C_EVALS = 4  # exact likelihood evaluations (work, not part of the chain)
C_T_PROP = 5  # parameter proposals
C_T_ACC = 6  # parameter acceptances
N_COUNTS = 7
#: Counter names in index order (``counts[C_*]``).
COUNTERS: tuple[str, ...] = ("flip_proposals", "flip_accepts", "weight_proposals", "weight_accepts",
                             "likelihood_evaluations", "parameter_proposals", "parameter_accepts")

# ------------------------------------------------------------------------------------------------ priors
PRIOR_FLAT = 0
PRIOR_NORMAL = 1
PRIOR_IMPROPER = 2
PRIOR_STUDENT_T = 3
#: Weight prior kind -> code of the compiled density.
PRIOR_KINDS: dict[str, int] = {"flat": PRIOR_FLAT, "normal": PRIOR_NORMAL, "improper": PRIOR_IMPROPER,
                               "student_t": PRIOR_STUDENT_T}

# ------------------------------------------------------------------------------------------------ constraints
FAM_AXIS = 0  # x_k >= t or x_k <= t
FAM_HALFSPACE = 1  # n(angles) . x >= b
FAM_BOX = 2  # lo <= x <= hi
FAM_BALL = 3  # |x - centre| < radius
#: Constraint family name -> code.
FAMILY_CODES: dict[str, int] = {"axis_halfspace": FAM_AXIS, "halfspace": FAM_HALFSPACE, "box": FAM_BOX,
                                "ball": FAM_BALL}

# ------------------------------------------------------------------------------------------------ likelihoods
LIK_PAIRWISE = 0  # paper Eq. 7 over blocks and explicit pairs
LIK_GROUPED = 1  # grouped Plackett-Luce
LIK_RANKED = 2  # paper Eq. 7 over a ranking's every cross-group pair (Preferences.ranked)
#: Compiled likelihood layout name -> code.
LIKELIHOODS: dict[str, int] = {"pairwise": LIK_PAIRWISE, "grouped": LIK_GROUPED, "ranked": LIK_RANKED}
