"""Consensus-ADMM math: exact splitting, the homogenized prox solve, penalty balancing."""

import numpy as np
import pytest

from decentral.admm import AdmmConfig, LocalProblem, balance_penalty, quadratic_form, solve_prox
from decentral.errors import InputError
from decentral.estimator import EstimatorConfig, solve_window
from decentral.factors import measure_log
from decentral.geometry import rot2
from decentral.window import build_window
from sims.simulation.scenarios import get_scenario, simulate


@pytest.fixture(scope="module")
def window():
    sim = simulate(get_scenario("multi", n_assemblies=4, steps=4), seed=1)
    ms = measure_log(sim.log)
    return ms, build_window(ms, range(1, 4), "A0")


def _cols(i, n):
    return [i, n + 2 * i, n + 2 * i + 1]


def test_pair_and_odometry_costs_sum_to_the_joint_window_form(window):
    """Directed-pair visual forms plus per-assembly odometry forms add up to build_window's M and b_z."""
    ms, wp = window
    idx, m = wp.index(), wp.m
    M, b = np.zeros_like(wp.M), np.zeros(m)
    steps = [k for k in range(1, 4)]

    def add(P):
        g = [idx[k] for k in P.keys]
        gc = np.array([c for i in g for c in _cols(i, m)])
        lc = np.array([c for i in range(P.n) for c in _cols(i, P.n)])
        M[np.ix_(gc, gc)] += P.M[np.ix_(lc, lc)]
        b[g] += P.b_z

    pairs = {(o, a) for k in steps for o, a in zip(ms[k].visual.observer, ms[k].visual.target)}
    for o, a in pairs:
        keys, rows = [], ([], [], [], [], [])
        for k in steps:
            v = ms[k].visual
            sel = [i for i in range(len(v)) if (v.observer[i], v.target[i]) == (o, a)]
            if sel:
                keys += [(o, k), (a, k)]
                for i in sel:
                    for lst, val in zip(rows, (len(keys) - 2, len(keys) - 1, v.q[i], v.t[i], v.weight[i])):
                        lst.append(val)
        add(quadratic_form(keys, visual=tuple(np.array(r) for r in rows)))
    for name in {key[0] for key in wp.variables}:
        odo = [(j - 1, j, ms[k].odometry[name]) for j, k in enumerate(steps) if j and name in ms[k].odometry]
        iv, iu, o = zip(*odo)
        add(quadratic_form([(name, k) for k in steps], odometry=(
            np.array(iv), np.array(iu), np.array([x.dp for x in o]), np.array([x.dtheta for x in o]),
            np.array([x.weight_p for x in o]), np.array([x.weight_R for x in o]))))
    assert np.abs(M - wp.M).max() <= 1e-12 * np.abs(wp.M).max()
    assert np.abs(b - wp.b_z).max() <= 1e-9 * max(np.abs(wp.b_z).max(), 1.0)


def test_prox_solve_with_a_pinned_variable_reproduces_the_centralized_window(window):
    """Without prox terms and one variable fixed at the joint optimum, solve_prox returns the joint optimum."""
    _, wp = window
    sol = solve_window(wp, ("A0", 3), EstimatorConfig())
    P = LocalProblem(wp.variables, wp.M, wp.b_z, wp.c_z)
    n, r = P.n, wp.index()[("A0", 1)]
    out = solve_prox(P, np.zeros((n, 2, 2)), np.zeros((n, 3)), np.zeros(n), np.zeros(n),
                     fixed={r: (sol.theta[r], sol.position[r])})
    assert out.certified
    assert np.abs(out.position - sol.position).max() < 1e-6
    assert np.abs(np.angle(np.exp(1j * (out.theta - sol.theta)))).max() < 1e-7


def test_strong_prox_returns_its_targets(window):
    """With overwhelming penalties the prox solution equals the prox targets."""
    _, wp = window
    P = LocalProblem(wp.variables, wp.M, wp.b_z, wp.c_z)
    rng = np.random.default_rng(0)
    th, p = rng.uniform(-3, 3, P.n), rng.normal(size=(P.n, 3))
    out = solve_prox(P, rot2(th), p, np.full(P.n, 1e12), np.full(P.n, 1e12))
    assert np.abs(out.position - p).max() < 1e-5
    assert np.abs(np.angle(np.exp(1j * (out.theta - th)))).max() < 1e-5


def test_prox_cost_is_no_worse_than_the_targets(window):
    """The returned point has a lower objective (cost + prox) than the prox targets themselves."""
    _, wp = window
    P = LocalProblem(wp.variables, wp.M, wp.b_z, wp.c_z)
    rng = np.random.default_rng(1)
    th, p = rng.uniform(-0.2, 0.2, P.n), rng.normal(scale=0.5, size=(P.n, 3))
    rho = np.full(P.n, 50.0)
    out = solve_prox(P, rot2(th), p, rho, rho)

    def objective(t, q):
        return P.cost(t, q) + np.sum(rho / 2 * np.sum((rot2(t) - rot2(th)) ** 2, axis=(1, 2))) + np.sum(
            rho / 2 * np.sum((q - p) ** 2, axis=1))

    assert objective(out.theta, out.position) <= objective(th, p) + 1e-9


def test_residual_balancing_moves_rho_towards_the_larger_residual():
    """rho grows when the primal residual dominates, shrinks when the dual one does, else stays."""
    c = AdmmConfig(mu=10.0, tau=2.0)
    assert balance_penalty(1.0, 100.0, 1.0, c, 1e-3, 1e3) == 2.0
    assert balance_penalty(1.0, 1.0, 100.0, c, 1e-3, 1e3) == 0.5
    assert balance_penalty(1.0, 1.0, 2.0, c, 1e-3, 1e3) == 1.0
    assert balance_penalty(1e3, 100.0, 1.0, c, 1e-3, 1e3) == 1e3


def test_admm_config_rejects_bad_parameters():
    """Non-positive penalties or tolerances are input errors."""
    with pytest.raises(InputError):
        AdmmConfig(rho0=0.0)
    with pytest.raises(InputError):
        AdmmConfig(eps_pos=-1.0)


def test_per_step_forms_give_the_window_forms_joint_solution():
    """The forms agents share (one per pair and step, one per odometry link) have the same joint solution
    as one form per pair over the window and the odometry chain (a window adds only its newest step)."""
    from agents.assembly import AssemblyAgent
    from decentral.admm import solve_joint
    from sims.runners.admm_run import AdmmRunConfig, _agent_config, own_step

    log = simulate(get_scenario("multi", n_assemblies=4, steps=4), seed=1).log
    whole, split = [], []
    for name in log.assemblies:
        agent = AssemblyAgent(_agent_config(log, name, "A0", AdmmRunConfig()))
        for k in range(4):
            agent.on_step(own_step(log, name, k))
        agent._configs.table.history = {m: [(0, dict(log.steps[0].config[m]))] for m in log.assemblies if m != name}
        agent._rebuild()
        chain = agent._consensus.odometry_problem()
        for target, pair in agent._pairs.items():
            parts = agent._shared[target]
            assert all(p.n == 2 for p in parts) and len(parts) == len({k for _, k in pair.problem.keys})
            whole.append(pair.problem)
            split += parts
        links = agent._consensus.odometry_links()
        assert sum(link.c_z for link in links) == pytest.approx(chain.c_z)
        whole.append(chain)
        split += links
    a, b = solve_joint(whole, ("A0", 0)), solve_joint(split, ("A0", 0))
    assert a.poses.keys() == b.poses.keys()
    for key in a.poses:
        assert np.allclose(a.poses[key][0], b.poses[key][0], atol=1e-9)
        assert np.allclose(a.poses[key][1], b.poses[key][1], atol=1e-9)
