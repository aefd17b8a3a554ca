"""Pattern geometry: ordering, edges, keys and probes (analytic checks)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from shipstar.identify import _patterns as pat


def test_ordered_combinations_is_breadth_first_and_complete():
    c = pat.ordered_combinations(9)
    assert c.shape == (126, 4)
    assert {tuple(r) for r in c} == set(itertools.combinations(range(9), 4))
    # every pattern of the brightest m stars comes before any pattern using star m
    assert np.all(np.diff(c[:, 3]) >= 0)
    assert np.all(np.diff(c, axis=1) > 0)
    assert tuple(c[0]) == (0, 1, 2, 3) and tuple(c[1]) == (0, 1, 2, 4)
    assert pat.ordered_combinations(3).shape == (0, 4)


def test_combination_edges_index_the_pair_angles():
    rng = np.random.default_rng(1)
    m = rng.normal(size=(7, 7))
    idx = pat.combination_edges(7)
    c = pat.ordered_combinations(7)
    expect = np.stack([m[c[:, a], c[:, b]] for a, b in zip(pat.PAIR_A, pat.PAIR_B)], axis=1)
    np.testing.assert_array_equal(m.ravel()[idx], expect)


def test_permutation_edges_relabel_the_edges():
    rng = np.random.default_rng(2)
    u = rng.normal(size=(4, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    e = pat.pattern_edges_rad(u[None])[0]
    for p, perm in enumerate(pat.PERMUTATIONS):
        ep = pat.pattern_edges_rad(u[perm][None])[0]
        np.testing.assert_allclose(e[pat.PERMUTATION_EDGES[p]], ep, rtol=0, atol=1e-15)


def test_edges_are_angles_and_ratios_sorted():
    # a right isoceles triangle plus its centre on the equator (small angles ~ plane)
    d = 0.01
    pts = np.array([[0, 0], [d, 0], [0, d], [d / 3, d / 3]])
    u = np.stack([np.cos(pts[:, 0]) * np.cos(pts[:, 1]), np.sin(pts[:, 0]) * np.cos(pts[:, 1]),
                  np.sin(pts[:, 1])], axis=1)
    e = pat.pattern_edges_rad(u[None])
    r, largest = pat.edge_ratios(e)
    assert largest[0] == pytest.approx(np.sqrt(2) * d, rel=1e-4)
    assert np.all(np.diff(r[0]) >= 0) and r[0, -1] <= 1.0
    assert r[0, 3] == pytest.approx(1 / np.sqrt(2), rel=1e-4)     # the two legs


def test_probe_keys_cover_every_key_within_the_tolerance():
    rng = np.random.default_rng(3)
    bins = 50
    ratios = np.sort(rng.uniform(0.05, 0.99, size=(400, 5)), axis=1)
    tol = rng.uniform(0.001, 0.02, size=(400, 5))
    keys, owner = pat.probe_keys(ratios, tol, bins)
    probes = {}
    for k, o in zip(keys.tolist(), owner.tolist()):
        probes.setdefault(o, set()).add(k)
    for _ in range(5):
        shifted = ratios + rng.uniform(-1, 1, size=ratios.shape) * tol
        true_keys = pat.pattern_keys(shifted, bins)
        for i, k in enumerate(true_keys.tolist()):
            assert k in probes[i]


def test_probe_keys_narrow_very_loose_intervals_to_the_centre():
    ratios = np.array([[0.2, 0.3, 0.5, 0.7, 0.9]])
    keys, owner = pat.probe_keys(ratios, np.full((1, 5), 0.2), 50, max_span=3)
    assert keys.size == 3 ** 5 and np.all(owner == 0)
    assert pat.pattern_keys(ratios, 50)[0] in set(keys.tolist())
