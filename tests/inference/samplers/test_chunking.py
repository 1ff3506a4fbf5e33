"""Chunking does not matter: given the same random numbers, one run of n iterations and the same n split into
chunks (adaptation and warm-up boundaries included) end in the same chain state and keep the same draws. Only
the count of exact likelihood evaluations (work done, not part of the chain) may differ.

(The random numbers themselves are drawn per chunk from the generator, so the driver's fixed chunk size is part
of a chain's result; that is why this test feeds one stream of random numbers to both runs.)
"""

import dataclasses
from typing import Any

import numpy as np
import pytest

from pbicrl.inference.codes import C_EVALS
from pbicrl.inference.likelihood import PreferenceLikelihood
from pbicrl.inference.samplers import build_kernel
from pbicrl.inference.samplers.kernels import Kernel


@dataclasses.dataclass(frozen=True, eq=False)
class _Fed(Kernel):
    """A kernel whose chunks take consecutive slices of random numbers drawn once, in advance."""

    randoms: tuple[np.ndarray, ...] = ()
    cursor: list[int] = dataclasses.field(default_factory=lambda: [0])

    def draw_randoms(self, rng: Any, n: int) -> tuple[np.ndarray, ...]:
        i, total = self.cursor[0], len(self.randoms[0])
        self.cursor[0] += n
        # per-iteration arrays are sliced; a placeholder (a move type that is off) passes as it is
        return tuple(r[i:i + n] if len(r) == total else r for r in self.randoms)


def _fed(kernel: Kernel, randoms: tuple[np.ndarray, ...]) -> _Fed:
    base = {f.name: getattr(kernel, f.name) for f in dataclasses.fields(kernel) if f.init}
    return _Fed(**base, randoms=randoms)


def _leaves(x: Any) -> list[np.ndarray]:
    """Every array and number of a (nested) chain state, in a fixed order."""
    if isinstance(x, np.ndarray):
        return [x]
    if isinstance(x, (int, float, np.integer, np.floating, bool)):
        return [np.asarray(x)]
    if isinstance(x, tuple):
        return [a for item in x for a in _leaves(item)]
    if dataclasses.is_dataclass(x):
        return [a for f in dataclasses.fields(x) for a in _leaves(getattr(x, f.name))]
    return []


@pytest.mark.parametrize("method", ["paper", "bpl", "pbicrl"])
def test_one_run_and_the_same_iterations_in_chunks_give_the_same_chain(ranked_problem, method):
    lik = PreferenceLikelihood.from_dataset(ranked_problem.dataset, margins=[0.5, 1.0])
    n, burn_in = 3000, 700  # warm-up ends inside a chunk; adaptation (every 100 or so) crosses chunk ends
    kernel = build_kernel(lik, method=method, n_iterations=n, burn_in=burn_in, thin=1)
    start = kernel.init(2)
    randoms = kernel.draw_randoms(np.random.default_rng(11), n)
    assert sum(len(r) == n for r in randoms) >= 4  # feature, move, normal, acceptance: one per iteration

    whole_out = kernel.new_buffers(n - burn_in)
    whole = _fed(kernel, randoms).run(None, start, n, whole_out)

    chunked_kernel = _fed(kernel, randoms)
    chunked_out = kernel.new_buffers(n - burn_in)  # one buffer: each chunk appends its kept draws
    state = start
    for size in (450, 1000, 1, 1549):  # uneven on purpose; they add up to n
        state = chunked_kernel.run(None, state, size, chunked_out)
    assert chunked_kernel.cursor[0] == n and state.iteration == whole.iteration == start.iteration + n

    a, b = _leaves(whole._replace(counts=None)), _leaves(state._replace(counts=None))
    assert len(a) == len(b) > 5
    for x, y in zip(a, b):  # position, adaptation, MAP tracker: the chain
        np.testing.assert_array_equal(x, y)
    # the counters too, except the exact likelihood evaluations: work, not chain (a chunk starts afresh)
    keep = np.arange(whole.counts.size) != C_EVALS
    np.testing.assert_array_equal(whole.counts[keep], state.counts[keep])
    assert whole.counts[keep].sum() > 0
    assert int(whole_out[-1][0]) == int(chunked_out[-1][0]) == n - burn_in  # every kept draw was stored
    for x, y in zip(whole_out, chunked_out):
        np.testing.assert_array_equal(x, y)
    # the chain moved: the test compares a real run, not two copies of the start
    assert any(not np.array_equal(x, y) for x, y in zip(_leaves(start._replace(counts=None)), a))


def test_the_comparison_can_fail(ranked_problem):
    """Other random numbers give another chain, so the equality above is not trivially true."""
    lik = PreferenceLikelihood.from_dataset(ranked_problem.dataset, margins=[0.5, 1.0])
    kernel = build_kernel(lik, method="pbicrl", n_iterations=2000, burn_in=0, thin=1)
    start = kernel.init(2)
    one = _fed(kernel, kernel.draw_randoms(np.random.default_rng(11), 2000)).run(None, start, 2000)
    two = _fed(kernel, kernel.draw_randoms(np.random.default_rng(12), 2000)).run(None, start, 2000)
    assert any(not np.array_equal(x, y) for x, y in zip(_leaves(one), _leaves(two)))
