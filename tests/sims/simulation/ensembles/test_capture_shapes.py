"""Tests of the shape-capture containers (Funiak et al. 2008 §VI-A, Fig. 5 read as slices of shape capture)."""

from functools import lru_cache

import numpy as np
import pytest
from scipy import ndimage, sparse
from scipy.sparse.csgraph import connected_components

from sims.simulation.ensembles import EnsembleSpec, generate
from sims.simulation.ensembles.containers import make_container

N = 600
CAPTURE = ["capture-triple", "capture-sparse", "capture-open"]


@lru_cache(maxsize=None)
def scene(shape):
    """(shape, ensemble, container, obstacle points) at N modules, generator seed 0."""
    ens = generate(EnsembleSpec(shape=shape, n=N), np.random.default_rng(0))
    container = make_container(shape, N, ens.radius, np.random.default_rng(0))
    return shape, ens, container, obstacles(container)


def obstacles(container):
    """One world point (2,) per obstacle: the centroid of each group of wall cells that lies inside
    the bounding box of the container's free cells (the box walls lie outside it)."""
    inside = container.sdf > 0
    rows, cols = np.nonzero(inside)
    window = np.zeros_like(inside)
    window[rows.min() : rows.max() + 1, cols.min() : cols.max() + 1] = True
    labels, count = ndimage.label(window & ~inside)
    points = []
    for k in range(1, count + 1):
        r, c = np.nonzero(labels == k)
        if len(r) > 20:  # raster specks at the free surface are not objects
            points.append(container.origin + container.cell * np.array([c.mean(), r.mean()]))
    return points


def encloses(position, i, j, point) -> bool:
    """True when some cycle of observation pairs winds an odd number of times around ``point``.

    Double cover of the contact graph: a pair whose segment crosses the upward ray from ``point``
    switches sheets; a module's two copies are connected exactly when such a cycle exists.
    """
    n = len(position)
    a, b = position[i] - point, position[j] - point
    straddle = (a[:, 0] * b[:, 0]) < 0
    t = a[:, 0] / np.where(straddle, a[:, 0] - b[:, 0], 1.0)
    crosses = straddle & (a[:, 1] + t * (b[:, 1] - a[:, 1]) > 0)
    src = np.r_[i, i + n]
    dst = np.r_[np.where(crosses, j + n, j), np.where(crosses, j, j + n)]
    adj = sparse.coo_matrix((np.ones(len(src)), (src, dst)), shape=(2 * n, 2 * n))
    _, label = connected_components(adj, directed=False)
    return bool(label[0] == label[n])


@pytest.mark.parametrize("shape", CAPTURE)
def test_every_capture_shape_gives_one_connected_ensemble(shape):
    """Each shape-capture scene keeps all but 1 % of its modules in one connected observation graph."""
    _, ens, _, _ = scene(shape)
    adj = sparse.coo_matrix((np.ones(len(ens.i)), (ens.i, ens.j)), shape=(ens.n, ens.n))
    assert connected_components(adj, directed=False)[0] == 1
    assert ens.dropped <= 0.01 * N


@pytest.mark.parametrize("shape", CAPTURE)
def test_no_module_inside_an_obstacle_or_a_wall(shape):
    """Every settled module's disc stays clear of the walls and the objects (to 5 % of a radius)."""
    _, ens, container, _ = scene(shape)
    assert container.distance(ens.position).min() >= 0.95 * ens.radius


@pytest.mark.parametrize("shape", CAPTURE)
def test_the_scene_has_its_objects(shape):
    """capture-triple and capture-sparse hold three objects, capture-open one."""
    _, _, _, points = scene(shape)
    assert len(points) == (1 if shape == "capture-open" else 3)


@pytest.mark.parametrize("shape", ["capture-triple", "capture-sparse"])
def test_triple_and_sparse_enclose_each_object(shape):
    """In capture-triple and capture-sparse a loop of contacts goes around every object."""
    _, ens, _, points = scene(shape)
    assert all(encloses(ens.position, ens.i, ens.j, p) for p in points)


def test_open_wraps_its_object_without_closing_the_loop():
    """capture-open: no contact loop goes around the object, yet modules rise above its centre on both sides."""
    _, ens, _, points = scene("capture-open")
    (p,) = points
    assert not encloses(ens.position, ens.i, ens.j, p)
    x, y = ens.position[:, 0], ens.position[:, 1]
    assert y[x < p[0]].max() > p[1] and y[x > p[0]].max() > p[1]


def test_loop_test_sees_a_ring_and_not_a_chain():
    """The winding test finds the loop of a ring of contacts and none when one contact is removed."""
    k = 12
    ang = 2 * np.pi * np.arange(k) / k
    pos = np.column_stack([np.cos(ang), np.sin(ang)])
    i = np.arange(k)
    j = (i + 1) % k
    ring_i, ring_j = np.r_[i, j], np.r_[j, i]
    assert encloses(pos, ring_i, ring_j, np.zeros(2))
    assert not encloses(pos, ring_i[1:k], ring_j[1:k], np.zeros(2))
    assert not encloses(pos, ring_i, ring_j, np.array([3.0, 0.0]))
