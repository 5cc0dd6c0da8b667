"""Tests of the hinges of a 3D ensemble: single observation pairs about which a part turns unseen."""

import numpy as np
from scipy.spatial import cKDTree

from decentral.ensemble.model import negative_log_likelihood
from decentral.ensemble.observability import hinge_pairs, hinged_parts
from decentral.ensemble.problem import EnsembleProblem
from decentral.ensemble.rotation import angle_to_matrix, matrix_to_angle, matrix_to_quat, so3_exp

R_MOD = 0.05


def _observe(x, R, rng, noise=0.1):
    """Noisy observations (Funiak et al. 2008 eq. 1) of every touching pair of centres ``x`` (n, d)."""
    pairs = cKDTree(x).query_pairs(2 * R_MOD * 1.01, output_type="ndarray")
    i = np.concatenate([pairs[:, 0], pairs[:, 1]])
    j = np.concatenate([pairs[:, 1], pairs[:, 0]])
    z = np.einsum("eba,eb->ea", R[i], (x[j] - x[i]) / 2)
    z = z + noise * R_MOD * rng.normal(size=z.shape)
    z = z / np.linalg.norm(z, axis=1, keepdims=True) * R_MOD
    return EnsembleProblem.create(x.shape[1], len(x), R_MOD, i, j, z)


def _blocks_on_a_file(dim=3, file_length=3, seed=0):
    """Two cubic blocks (3 modules a side) joined by a single file of ``file_length`` modules."""
    rng = np.random.default_rng(seed)
    g = np.stack(np.meshgrid(*[np.arange(3)] * dim, indexing="ij"), -1).reshape(-1, dim).astype(float)
    file_ = np.zeros((file_length, dim))
    file_[:, 0] = 3 + np.arange(file_length)
    file_[:, 1:] = 1.0  # leaves the first block at the centre of its face
    other = g + np.r_[3 + file_length, np.zeros(dim - 1)]
    x = np.concatenate([g, file_, other]) * 2 * R_MOD
    if dim == 3:
        R = so3_exp(rng.normal(size=(len(x), 3)))
    else:
        R = angle_to_matrix(rng.uniform(-np.pi, np.pi, len(x)))
    return _observe(x, R, rng), x, R, len(g)


def test_a_single_file_between_two_blocks_is_a_chain_of_hinges():
    """Every contact of a single file joining two 3D blocks is a hinge, and nothing else is."""
    prob, x, R, block = _blocks_on_a_file(file_length=3)
    pairs = prob.pairs()
    on_file = (pairs >= block) & (pairs < block + 3)
    expected = pairs[on_file.any(axis=1)]
    assert len(expected) == 4  # block - file, two inside the file, file - block
    assert hinge_pairs(prob).tolist() == sorted(expected.tolist())


def test_turning_a_part_about_a_hinge_leaves_the_likelihood_unchanged():
    """Rotating everything beyond a hinge about the line through its two centres changes no cost (noisy z)."""
    prob, x, R, block = _blocks_on_a_file(file_length=2, seed=3)
    rng = np.random.default_rng(1)
    # any configuration, not only the truth: the degeneracy holds everywhere
    c = x + 0.2 * R_MOD * rng.normal(size=x.shape)
    Rc = so3_exp(rng.normal(size=(len(x), 3)))
    i, j = hinge_pairs(prob)[1]  # the contact inside the file
    beyond = np.arange(j, prob.n)  # j and the second block
    axis = (c[i] - c[j]) / np.linalg.norm(c[i] - c[j])
    for angle in (0.3, 1.7, np.pi):
        Q = so3_exp((angle * axis)[None])[0]
        c2, R2 = c.copy(), Rc.copy()
        c2[beyond] = c[j] + (c[beyond] - c[j]) @ Q.T
        R2[beyond] = Q @ Rc[beyond]
        before = negative_log_likelihood(prob, c, matrix_to_quat(Rc))
        after = negative_log_likelihood(prob, c2, matrix_to_quat(R2))
        assert abs(after - before) <= 1e-12 * before
        assert np.linalg.norm(c2 - c, axis=1).max() > angle * R_MOD  # the far block really moves


def test_solid_blocks_and_dangling_modules_have_no_hinges():
    """A solid 3D block has no hinge; a single module hanging on one contact is not one either."""
    rng = np.random.default_rng(2)
    g = np.stack(np.meshgrid(*[np.arange(4)] * 3, indexing="ij"), -1).reshape(-1, 3) * 2 * R_MOD
    lone = np.array([[-2 * R_MOD, 0.0, 0.0]])  # touches only module 0
    x = np.concatenate([g, lone])
    prob = _observe(x, so3_exp(rng.normal(size=(len(x), 3))), rng)
    assert hinge_pairs(prob).shape == (0, 2)


def test_a_single_contact_fixes_the_relative_rotation_in_2d():
    """In 2D two blocks on a single file have no hinge: turning one about a contact costs likelihood."""
    prob, x, R, block = _blocks_on_a_file(dim=2, file_length=2)
    assert hinge_pairs(prob).shape == (0, 2)
    j = block + 1  # the second module of the file: turn it and the far block about its centre
    a = 0.3
    Q = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    c2, R2 = x.copy(), R.copy()
    c2[j:] = x[j] + (x[j:] - x[j]) @ Q.T
    R2[j:] = Q @ R[j:]
    before = negative_log_likelihood(prob, x, matrix_to_angle(R))
    assert negative_log_likelihood(prob, c2, matrix_to_angle(R2)) > before + 1e-3 * R_MOD**2


def test_cutting_the_hinges_leaves_the_blocks_and_the_file_modules_as_parts():
    """Cut at its hinges, two blocks on a file of three fall into the two blocks and three single modules."""
    prob, x, R, block = _blocks_on_a_file(file_length=3)
    label = hinged_parts(prob, hinge_pairs(prob))
    assert np.bincount(label).tolist() == [block, block, 1, 1, 1]
    assert np.unique(label[:block]).size == 1 and np.unique(label[block + 3:]).size == 1
