"""Tests of the ensemble generator: settling, lattices, IR sensors, files."""

import numpy as np
import pytest

from sims.simulation.ensembles import EnsembleSpec, SensorModel, generate, save_observations, save_truth
from sims.io.ensemble_npz import read_ensemble_truth
from sims.simulation.ensembles.lattices import lattice_sites
from sims.simulation.ensembles.sensors import observe_contacts, rotation_matrices, sensor_layout
from decentral.errors import InputError

SHAPES_2D = ["triple", "sparse", "open", "twin", "funnel", "ring", "blobs", "capture-triple", "capture-sparse", "capture-open"]
SHAPES_3D = ["sphere", "box", "torus", "dumbbell", "triple3d"]


@pytest.fixture(scope="module")
def triple():
    return generate(EnsembleSpec(shape="triple", n=600, radius=0.05), np.random.default_rng(3))


@pytest.mark.parametrize("shape", SHAPES_2D + SHAPES_3D)
def test_every_shape_gives_connected_symmetric_observations(shape):
    """Every shape yields (almost) all requested modules with symmetric pairs and no self-pairs."""
    ens = generate(EnsembleSpec(shape=shape, n=400), np.random.default_rng(0))
    assert ens.n >= 390 and ens.n + ens.dropped == 400
    pairs = set(zip(ens.i.tolist(), ens.j.tolist()))
    assert all((b, a) in pairs for a, b in pairs)
    assert np.all(ens.i != ens.j)
    assert np.unique(ens.i).size == ens.n  # nobody is left without an observation


def test_settled_modules_barely_overlap(triple):
    """Settled 2D modules overlap by under a fifth of a radius at worst and 3 % at the median."""
    from scipy.spatial import cKDTree

    x, r = triple.position, triple.radius
    p = cKDTree(x).query_pairs(2 * r, output_type="ndarray")
    ov = (2 * r - np.linalg.norm(x[p[:, 0]] - x[p[:, 1]], axis=1)) / r
    assert ov.max() < 0.2 and np.median(ov) < 0.03


def test_gravity_leaves_a_free_surface_at_the_top(triple):
    """Modules settle to the floor: the lowest modules rest on it, the top of each chamber has head room."""
    y = triple.position[:, 1]
    height = y.max() - y.min()
    # chambers are about as tall as wide; 3 chambers side by side: the pile is under a third as tall as wide
    width = np.ptp(triple.position[:, 0])
    assert height < width / 3.0
    assert np.mean(y < y.min() + 0.5 * triple.radius) > 0.02  # a full bottom row


def test_observed_pairs_are_near_and_touching_pairs_are_seen(triple):
    """Observed pairs are within sensing reach; every touching pair (gap < 5 % radius) is observed."""
    from scipy.spatial import cKDTree

    x, r = triple.position, triple.radius
    d = np.linalg.norm(x[triple.i] - x[triple.j], axis=1)
    assert d.max() <= SensorModel(depth=0.2).reach(r) + 1e-12
    touching = cKDTree(x).query_pairs(2.1 * r, output_type="ndarray")
    seen = set(zip(triple.i.tolist(), triple.j.tolist()))
    assert all((a, b) in seen for a, b in touching.tolist())


def test_observations_are_quantized_sensor_positions_on_the_perimeter(triple):
    """Each z_ij is one of the 12 transceiver directions, scaled to the module radius."""
    layout = sensor_layout(2, 12) * triple.radius
    dist = np.linalg.norm(triple.z[:, None, :] - layout[None], axis=2).min(axis=1)
    assert np.allclose(dist, 0.0, atol=1e-12)


def test_observation_points_towards_the_neighbour(triple):
    """z_ij, rotated to the world, points from i towards j within half the sensor spacing plus slack."""
    R = rotation_matrices(triple.orientation)
    zw = np.einsum("mij,mj->mi", R[triple.i], triple.z)
    d = triple.position[triple.j] - triple.position[triple.i]
    cos = np.sum(zw * d, axis=1) / np.linalg.norm(zw, axis=1) / np.linalg.norm(d, axis=1)
    assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() < 60.0
    assert np.median(np.degrees(np.arccos(np.clip(cos, -1, 1)))) < 15.0


def test_same_seed_same_ensemble_different_seed_different():
    """Generation is reproducible from the seed and changes with it."""
    spec = EnsembleSpec(shape="blobs", n=300)
    a, b = generate(spec, np.random.default_rng(7)), generate(spec, np.random.default_rng(7))
    c = generate(spec, np.random.default_rng(8))
    assert np.array_equal(a.position, b.position) and np.array_equal(a.z, b.z)
    assert not np.array_equal(a.position[: min(a.n, c.n)], c.position[: min(a.n, c.n)])


def test_global_rng_untouched():
    """The generator neither reads nor advances numpy's global random state."""
    np.random.seed(123)
    before = np.random.get_state()[1].copy()
    generate(EnsembleSpec(shape="sphere", n=200), np.random.default_rng(0))
    assert np.array_equal(before, np.random.get_state()[1])


@pytest.mark.parametrize("kind,coordination", [("cubic", 6), ("hcp", 12)])
def test_lattice_spacing_and_coordination(kind, coordination):
    """Lattice sites are one spacing apart with the lattice's coordination number inside."""
    from scipy.spatial import cKDTree

    sites = lattice_sites(kind, 2.0, np.array([6.0, 6.0, 6.0]))
    tree = cKDTree(sites)
    d, _ = tree.query(sites, k=2)
    assert np.allclose(d[:, 1], 2.0)
    centre = np.argmin(np.linalg.norm(sites, axis=1))
    assert len(tree.query_ball_point(sites[centre], 2.0 + 1e-9)) - 1 == coordination


def test_3d_orientations_are_unit_quaternions():
    """3D orientations are unit quaternions (w >= 0) and give proper rotations."""
    ens = generate(EnsembleSpec(shape="torus", n=300, lattice="cubic"), np.random.default_rng(1))
    assert ens.orientation.shape == (ens.n, 4)
    assert np.allclose(np.linalg.norm(ens.orientation, axis=1), 1.0)
    R = rotation_matrices(ens.orientation)
    assert np.allclose(np.linalg.det(R), 1.0)
    assert np.allclose(np.einsum("mji,mjk->mik", R, R), np.eye(3), atol=1e-12)


def test_pairs_beyond_reach_are_never_seen():
    """Two modules farther apart than the sensing reach make no observation, in any orientation."""
    model = SensorModel()
    rng = np.random.default_rng(0)
    for _ in range(20):
        pos = np.array([[0.0, 0.0], [model.reach(1.0) * 1.01, 0.0]])
        i, _, _ = observe_contacts(pos, rng.uniform(-np.pi, np.pi, 2), 1.0, model)
        assert len(i) == 0


def test_files_round_trip_with_contract_fields(tmp_path, triple):
    """The observation file has exactly the fields docs/formats.md lists and the truth file reads back."""
    obs, truth = tmp_path / "obs.npz", tmp_path / "truth.npz"
    save_observations(obs, triple)
    save_truth(truth, triple, seed=3)
    with np.load(obs, allow_pickle=False) as f:
        assert set(f.files) == {"format", "dim", "n", "radius", "i", "j", "z"}
        assert str(f["format"]) == "decentral.ensemble/1" and int(f["n"]) == triple.n and int(f["dim"]) == 2
        assert np.array_equal(f["i"], triple.i) and np.array_equal(f["z"], triple.z)
    t = read_ensemble_truth(truth)
    assert np.array_equal(t.position, triple.position) and np.array_equal(t.orientation, triple.orientation)
    assert t.seed == 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["obs.npz", "truth.npz"]  # no leftovers


def test_bad_spec_is_refused():
    """Unknown shapes, too few modules and non-positive radii raise InputError naming the field."""
    with pytest.raises(InputError, match="shape"):
        EnsembleSpec(shape="teapot")
    with pytest.raises(InputError, match="n"):
        EnsembleSpec(n=1)
    with pytest.raises(InputError, match="radius"):
        EnsembleSpec(radius=0.0)


def test_twin_clusters_are_joined_only_by_a_few_observations():
    """Funiak et al. 2008 Fig. 3: the exact normalized cut of ``twin`` splits two halves linked by <= 6 pairs."""
    from decentral.ensemble import EnsembleProblem, normalized_cut

    ens = generate(EnsembleSpec(shape="twin", n=600), np.random.default_rng(0))
    prob = EnsembleProblem.create(2, ens.n, ens.radius, ens.i, ens.j, ens.z)
    a = normalized_cut(prob.adjacency()).in_a
    assert 1 <= np.count_nonzero(a[prob.i] & ~a[prob.j]) <= 6
    assert min(a.sum(), (~a).sum()) > 0.4 * ens.n


def _hinged_parts(ens):
    """Sizes of the parts left when the hinges of a 3D ensemble are cut, largest first."""
    from decentral.ensemble import EnsembleProblem
    from decentral.ensemble.observability import hinge_pairs, hinged_parts

    prob = EnsembleProblem(3, ens.n, ens.radius, ens.i, ens.j, ens.z)
    return np.bincount(hinged_parts(prob, hinge_pairs(prob)))


# sizes at which the rasterizer left the rods of hcp `triple3d` a single file of modules (2.2-radius floor)
@pytest.mark.parametrize("n", [2300, 2500, 4375, 6750, 7000, 7500, 8000])
def test_triple3d_rods_are_no_chain_of_hinges(n):
    """At every size the rods of hcp ``triple3d`` hold the cubes rigidly: the ensemble has no hinge."""
    ens = generate(EnsembleSpec(shape="triple3d", n=n), np.random.default_rng(0))
    assert len(_hinged_parts(ens)) == 1


@pytest.mark.slow
@pytest.mark.parametrize("lattice", ["hcp", "cubic"])
@pytest.mark.parametrize("shape", SHAPES_3D)
def test_no_3d_shape_turns_on_a_hinge_at_any_size(shape, lattice):
    """From 200 to 30,000 modules no 3D shape has more than a bump of a few modules hanging on a hinge.

    (The bumps are where ties at the deepest-site cut leave a partial outer layer of a cubic lattice.)
    """
    sizes = [*range(200, 3000, 100), *range(3000, 12001, 250), *range(13000, 30001, 1000)]
    for n in sizes:
        parts = _hinged_parts(generate(EnsembleSpec(shape=shape, n=n, lattice=lattice), np.random.default_rng(0)))
        assert parts[1:].max(initial=0) <= 5, (n, parts[:4])
