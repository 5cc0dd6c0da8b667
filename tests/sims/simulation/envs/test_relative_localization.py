"""The PettingZoo env: API and seed conformance, spaces, observations, infos, faults and rendering."""

from __future__ import annotations

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test, parallel_seed_test

from decentral.errors import InputError
from protocols.network import Crash
from sims.simulation.envs import relative_localization_v0

SMALL = dict(n_robots=4, arena=3.0)


def test_passes_parallel_api_test():
    """PettingZoo's parallel_api_test passes (spaces cached, reset(seed, options), agents leave when done)."""
    parallel_api_test(relative_localization_v0.parallel_env(**SMALL), num_cycles=25)


def test_passes_parallel_seed_test():
    """PettingZoo's parallel_seed_test passes: same seed, same observations, rewards and infos."""
    parallel_seed_test(lambda: relative_localization_v0.parallel_env(**SMALL), num_cycles=15)


def test_same_seed_same_episode_over_many_steps():
    """Two envs reset with one seed give identical observations for 30 steps of the same actions."""
    envs = [relative_localization_v0.parallel_env(**SMALL) for _ in range(2)]
    outs = [e.reset(seed=9)[0] for e in envs]
    for k in range(30):
        acts = {a: np.array([0.2, 0.3 * np.sin(k)], np.float32) for a in envs[0].agents}
        outs = [e.step(acts)[0] for e in envs]
    for a in outs[0]:
        for key in outs[0][a]:
            assert np.array_equal(outs[0][a][key], outs[1][a][key])


def test_observations_lie_in_their_spaces():
    """Every observation is contained in the agent's (cached, identical) observation space."""
    env = relative_localization_v0.parallel_env(**SMALL)
    obs, _ = env.reset(seed=0)
    for _ in range(10):
        obs, *_ = env.step({a: env.action_space(a).sample() for a in env.agents})
    for a, o in obs.items():
        assert env.observation_space(a) is env.observation_space(a)
        assert env.observation_space(a).contains(o)


def test_agents_come_to_know_each_other():
    """Driving in a small arena, agents' estimates cover their peers with errors below 20 cm."""
    env = relative_localization_v0.parallel_env(**SMALL, max_cycles=60)
    env.reset(seed=2)
    while env.agents:
        acts = {a: np.array([0.2, 0.4], np.float32) for a in env.agents}
        obs, rew, term, trunc, info = env.step(acts)
    tracked = [o["estimates"][:, 0].mean() for o in obs.values()]
    assert np.mean(tracked) >= 0.75
    errs = [i["mean_position_error"] for i in info.values() if i["mean_position_error"] is not None]
    assert errs and np.median(errs) < 0.2


def test_estimates_in_observations_match_infos():
    """The tracked flags in observations are exactly the peers that infos score."""
    env = relative_localization_v0.parallel_env(**SMALL)
    env.reset(seed=1)
    for _ in range(15):
        obs, _, _, _, info = env.step({a: np.array([0.2, 0.5], np.float32) for a in env.agents})
    for a in env.agents:
        peers = [p for p in env.possible_agents if p != a]
        flagged = {p for p, row in zip(peers, obs[a]["estimates"]) if row[0] == 1.0}
        assert flagged == set(info[a]["position_error"])


def test_truncation_removes_all_agents():
    """After max_cycles steps every agent is truncated and agents is empty."""
    env = relative_localization_v0.parallel_env(**SMALL, max_cycles=3)
    env.reset(seed=0)
    for _ in range(3):
        _, _, term, trunc, _ = env.step({a: np.zeros(2, np.float32) for a in env.agents})
    assert all(trunc.values()) and not any(term.values()) and env.agents == []


def test_loss_shows_in_the_inbox():
    """With 50 % radio loss the inbox summary reports missing peers' messages."""
    env = relative_localization_v0.parallel_env(**SMALL, loss=0.5)
    env.reset(seed=0)
    heard = []
    for _ in range(10):
        obs, *_ = env.step({a: np.zeros(2, np.float32) for a in env.agents})
        heard += [o["inbox"][:, 0].mean() for o in obs.values()]
    assert 0.3 < np.mean(heard) < 0.7


def test_crashed_agent_inbox_is_empty_while_down():
    """A crashed agent hears no step report sent during its down interval, and hears everyone after."""
    env = relative_localization_v0.parallel_env(**SMALL, crashes=(Crash("R2", 0.5, 1.5),))
    env.reset(seed=0)
    for k in range(1, 10):
        obs, *_ = env.step({a: np.zeros(2, np.float32) for a in env.agents})
        if 0.5 <= k * 0.2 < 1.5:
            assert obs["R2"]["inbox"][:, :2].sum() == 0  # phase A is sent at k * dt
    assert obs["R2"]["inbox"][:, 0].sum() == 3


def test_render_returns_an_rgb_frame():
    """render() gives a uint8 (H, W, 3) frame that changes as robots move; None without a render mode."""
    env = relative_localization_v0.parallel_env(**SMALL, render_mode="rgb_array")
    env.reset(seed=0)
    a = env.render()
    for _ in range(5):
        env.step({ag: np.array([0.3, 0.0], np.float32) for ag in env.agents})
    b = env.render()
    assert a.dtype == np.uint8 and a.ndim == 3 and a.shape[2] == 3 and not np.array_equal(a, b)
    quiet = relative_localization_v0.parallel_env(**SMALL)
    quiet.reset(seed=0)
    assert quiet.render() is None


@pytest.mark.parametrize("kw", [dict(scenario="nope"), dict(bogus=1), dict(render_mode="human"), dict(max_cycles=0),
                                dict(n_robots=0)])
def test_bad_parameters_raise_input_error(kw):
    """Unknown scenarios or parameters and invalid values raise InputError."""
    with pytest.raises(InputError):
        relative_localization_v0.parallel_env(**kw)


def test_env_name_is_versioned():
    """The env's metadata name carries the _v0 version."""
    assert relative_localization_v0.parallel_env().metadata["name"] == "relative_localization_v0"


ASM = dict(scenario="assemblies", n_assemblies=3, admm_rounds=4)


def test_assemblies_pass_parallel_api_test():
    """The FreeSN-like assemblies scenario (ADMM assembly agents) passes parallel_api_test."""
    parallel_api_test(relative_localization_v0.parallel_env(**ASM), num_cycles=5)


def test_assemblies_pass_parallel_seed_test():
    """The assemblies scenario is deterministic under a seed."""
    parallel_seed_test(lambda: relative_localization_v0.parallel_env(**ASM), num_cycles=4)


def test_assembly_agents_place_each_other():
    """After 8 steps every assembly agent places every other within 10 cm (errors from infos)."""
    env = relative_localization_v0.parallel_env(**ASM, max_cycles=8)
    env.reset(seed=1)
    while env.agents:
        obs, _, _, _, info = env.step({a: np.array([0.05, 0.1], np.float32) for a in env.agents})
    for a, i in info.items():
        assert i["tracked"] == 2 and i["mean_position_error"] < 0.10
        assert obs[a]["estimates"][:, 0].sum() == 2
        assert env.observation_space(a).contains(obs[a])


def test_assemblies_render():
    """The assemblies scenario renders an RGB frame with its camera views."""
    env = relative_localization_v0.parallel_env(**ASM, render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.shape[2] == 3


def test_assemblies_reject_swarm_parameters():
    """A swarm-only parameter given to the assemblies scenario raises InputError naming it."""
    with pytest.raises(InputError, match="n_robots"):
        relative_localization_v0.parallel_env(scenario="assemblies", n_robots=3)


def test_render_fills_its_canvas_and_draws_a_scale_bar():
    """The camera grid spans the top view's full height, and the bottom-right scale bar is drawn (dark pixels)."""
    env = relative_localization_v0.parallel_env(**SMALL, render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    h = frame.shape[0]
    right = frame[:, h:]  # the top view is square (h x h); cameras fill the rest
    assert right.shape[1] > 0 and (right[-3:] != 255).any(axis=2).all()
    corner = frame[h - 30:h - 5, h - 140:h - 10]
    assert (corner.max(axis=2) < 60).sum() > 50
