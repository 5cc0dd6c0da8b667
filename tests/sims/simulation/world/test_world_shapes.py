"""Properties of the configuration library in sims.simulation.world.shapes."""

import networkx as nx
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sims.simulation.world.shapes import LIBRARY, NODE_RADIUS, library_shape, random_lattice


def _check(shape):
    assert np.allclose(shape.centres[0], 0.0)
    d = np.linalg.norm(shape.centres[:, None] - shape.centres[None], axis=-1)
    assert np.all(d[~np.eye(len(d), dtype=bool)] > 2 * NODE_RADIUS)
    assert np.all(shape.centres[:, 2] >= 0)
    g = nx.Graph()
    g.add_nodes_from(shape.ids)
    g.add_edges_from(shape.struts)
    assert nx.is_connected(g)


@pytest.mark.parametrize("name", sorted(LIBRARY))
def test_library_shapes_are_valid_assemblies(name):
    """Every library shape has its root at the origin, non-overlapping nodes and connected struts."""
    _check(library_shape(name))


@settings(max_examples=30, deadline=None)
@given(st.integers(1, 12), st.integers(0, 2**32 - 1), st.floats(0, 0.5))
def test_random_lattice_shapes_are_valid_assemblies(n, seed, p_up):
    """Random lattice shapes have n nodes, the root at the origin, no overlap, and are connected."""
    shape = random_lattice(n, np.random.default_rng(seed), p_up=p_up)
    assert len(shape.ids) == n
    _check(shape)


def test_renaming_keeps_geometry():
    """with_ids renames nodes and struts without moving any centre."""
    base = library_shape("T")
    renamed = base.with_ids([40, 41, 42, 43])
    assert renamed.ids == (40, 41, 42, 43)
    assert np.array_equal(renamed.centres, base.centres)
    assert set(renamed.struts) == {(40 + a, 40 + b) for a, b in base.struts}
    assert renamed.as_config()[43].tolist() == base.centres[3].tolist()


def test_stacks_have_nodes_above_the_floor():
    """The 3D library shapes carry a node with a positive z offset."""
    for name in ("stack", "tower"):
        assert library_shape(name).centres[:, 2].max() > 0.1
