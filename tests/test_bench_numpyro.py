"""benchmarks/bench_numpyro.py: the hand-written JAX grouped likelihood agrees with pbicrl's exact kernel, and
the diagnostics treat constant quantities and inactive penalties as the report says (needs ``pbicrl[bench]``)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.slow  # JAX compiles: about 30 s of CPU

pytest.importorskip("numpyro")
pytest.importorskip("jax")
pytest.importorskip("arviz")

from pbicrl.inference.likelihood import PreferenceLikelihood  # noqa: E402
from pbicrl.inference.synthetic import make_problem  # noqa: E402

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_numpyro.py"


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("bench_numpyro", _PATH)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_jax_grouped_likelihood_matches_exact_kernel(bench) -> None:
    import jax.numpy as jnp

    ds = make_problem(40, seed=3).dataset
    exact = PreferenceLikelihood.from_dataset(ds, likelihood="grouped")
    lik = bench.GroupedPL(ds.group)
    rng = np.random.default_rng(0)
    scale = bench.prior_scales(ds)
    for shrink in (1.0, 20.0):
        for _ in range(4):
            c = rng.integers(0, 2, ds.n_features).astype(float)
            w = -np.abs(rng.standard_t(3.0, ds.n_features)) * scale / shrink
            a = ds.mean_features @ exact.weights(w, c)
            ref = exact.from_scaled_returns(a)
            assert float(lik(jnp.asarray(a))) == pytest.approx(ref, rel=1e-9)


def test_prior_scales_follow_pbicrl(bench) -> None:
    ds = make_problem(20, seed=1).dataset
    sd = ds.mean_features.std(axis=0)
    expected = 2.5 / np.where(sd > 0, sd, 1.0)
    np.testing.assert_allclose(bench.prior_scales(ds), expected, rtol=1e-12)


def test_summarise_constant_and_inactive(bench) -> None:
    rng = np.random.default_rng(0)
    chains, draws = 4, 300
    c = np.zeros((chains, draws, 2), dtype=int)
    c[:, :, 0] = 1  # always on: constant, converged
    c[:, :5, 1] = 1  # on 5 times per chain: too few to assess its penalty
    w = -np.exp(rng.standard_normal((chains, draws, 2)))
    ll = rng.standard_normal((chains, draws))
    out = bench.summarise(c, w, ll, ("a", "b"), min_active=50)
    q = out["quantities"]
    assert q["c[a]"]["constant"] and q["c[a]"]["rhat"] == 1.0 and q["c[a]"]["ess_bulk"] is None
    assert q["log|w|[b] | c=1"]["assessed"] is False
    assert q["log|w|[a] | c=1"]["draws_per_chain_used"] == draws
    assert out["min_ess"] == pytest.approx(min(q[k][s] for k in ("c[b]", "log|w|[a] | c=1", "loglik")
                                               for s in ("ess_bulk", "ess_tail")))
    assert out["max_rhat"] < 1.05  # independent draws
