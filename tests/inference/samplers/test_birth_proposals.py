"""Birth proposals that find what the data require, under any prior (issue 27, item 3).

With ``--prior flat --prior-bounds=-1000,0`` the old flip proposal started at N(-500, 50) and adapted only from
draws where the feature was already on, so on the shipped point mass in_orange (required: min_penalty 56.25)
stayed off (P(c=1) = 0.000). The log-magnitude birth proposal is a mixture of a component just above the
separation scale and one over the prior's range.
"""

from __future__ import annotations

import numpy as np
import pytest

import pbicrl
from pbicrl.inference.likelihood import PreferenceLikelihood
from pbicrl.inference.samplers import build_kernel


@pytest.mark.parametrize("prior", [{}, {"prior": "flat", "prior_low": -1000.0, "prior_high": 0.0}],
                         ids=["default half-t", "flat [-1000, 0]"])
def test_required_constraints_are_selected_under_any_prior(prior):
    ds = pbicrl.load_dataset("point_mass")
    post = pbicrl.infer(ds, iterations=3_000, chains=2, seed=0, progress=False, **prior)
    assert post.selected() == ["in_orange", "in_red"]
    assert post.p_constraint[1] > 0.95 and post.p_constraint[2] > 0.95


def test_birth_proposal_starts_above_the_separation_scale():
    ds = pbicrl.load_dataset("point_mass")
    lik = PreferenceLikelihood.from_dataset(ds, likelihood="grouped")
    mp = [0.0, 56.25, 455.9, 0.0]
    k = build_kernel(lik, min_penalty=mp)
    lsg, bound, mu_a, s_a = k._log_proposals
    assert lsg.tolist() == [-1, -1, -1, -1]
    np.testing.assert_allclose(mu_a[1:3], np.log([56.25, 455.9]) + 0.5)
    med = np.abs(k.resolved_prior.ppf(0.5))
    np.testing.assert_allclose(mu_a[[0, 3]], np.log(med[[0, 3]]))  # not required: the prior's median
    q = np.abs(k.resolved_prior.ppf(np.array([0.01, 0.99])))  # on (-inf, 0] the 1% quantile is the largest |w|
    np.testing.assert_allclose(bound, q.max(axis=0))
    st = k.init(0)
    np.testing.assert_allclose(st.adaptation.q_mean, mu_a)
