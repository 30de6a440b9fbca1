"""Hierarchical potential-based shaping (reward_mode="potential")."""

import math

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import tl_gym  # noqa: F401 - registers TLCarNav-v0
from tl_gym import TLTLRewardWrapper, parse
from tl_gym.shaping import HierarchicalPotential
from tl_gym.tltl.online import PrefixMonitor

from .test_online import fragment
from .test_wrapper import Scripted

values = st.floats(-3, 3, allow_nan=False, width=32)
episodes = st.integers(1, 8).flatmap(lambda n: st.lists(st.tuples(values, values, values), min_size=n + 1,
                                                         max_size=n + 1))


@settings(max_examples=100, deadline=None)
@given(fragment, episodes, st.sampled_from([1.0, 0.9]))
def test_episode_sum_is_the_clipped_robustness_minus_the_start_potential(formula, rows, gamma):
    """Discounted with the wrapper's γ, an episode's rewards add up to γ^(T-1) clip(ρ) − Φ(s_0)."""
    env = TLTLRewardWrapper(Scripted(rows), formula, signals={"a": 0, "b": 1}, reward_mode="potential",
                            observe_monitor=True, gamma=gamma, clip=50.0, rho_max=20.0)
    env.reset(seed=0)
    potential = HierarchicalPotential(formula, 20.0, 1.0)
    phi_start = potential.update({"a": rows[0][0], "b": rows[0][1]})
    total = 0.0
    for t in range(1, len(rows)):
        _, reward, _, truncated, info = env.step(np.zeros(1, dtype=np.float32))
        total += gamma ** (t - 1) * reward
    assert truncated
    rho = min(max(info["robustness"], -50.0), 50.0)
    assert total == pytest.approx(gamma ** (len(rows) - 2) * rho - phi_start, abs=1e-9)


def test_conjuncts_are_sorted_into_safety_and_targets():
    from tl_gym.envs.tasks import task_formula

    potential = HierarchicalPotential(task_formula(2), scale=100.0)
    assert len(potential.safety) == 4 and all(text.startswith("G") for text in potential.safety)
    assert len(potential.targets) == 3 and " T " in potential.targets[0] and " U " in potential.targets[1]


def test_a_chain_scores_its_stages_in_order():
    phi = HierarchicalPotential(parse("a > 0 T b > 0"), scale=1.0)
    assert phi.update({"a": -1.0, "b": 5.0}) == pytest.approx(math.exp(-1.0) / 2)  # b first does not count
    assert phi.update({"a": 1.0, "b": -2.0}) == pytest.approx((1 + math.exp(-2.0)) / 2)  # a met; b is next
    assert phi.update({"a": -1.0, "b": 1.0}) == 1.0  # then b


def test_until_scores_zero_once_its_left_side_failed_first():
    phi = HierarchicalPotential(parse("a > 0 U b > 0"), scale=1.0)
    assert phi.update({"a": 1.0, "b": -1.0}) == pytest.approx(math.exp(-1.0))
    assert phi.update({"a": -1.0, "b": -0.5}) == 0.0  # a failed with b unmet: no later b can count
    assert phi.update({"a": 1.0, "b": 0.5}) == 0.0
    met = HierarchicalPotential(parse("a > 0 U b > 0"), scale=1.0)
    met.update({"a": 1.0, "b": -1.0})
    assert met.update({"a": -1.0, "b": 0.5}) == 1.0  # b met where a fails: a had held before it


def test_until_potential_is_a_function_of_the_monitor_state():
    """Two histories with one monitor state and one current state get one Φ (the review's counterexample)."""
    spec = parse("a > 0 U b > 0")
    values = []
    for first in ({"a": 0.1, "b": -5.0}, {"a": -0.05, "b": -5.0}):
        phi, monitor = HierarchicalPotential(spec, scale=1.0), PrefixMonitor(spec)
        for state in (first, {"a": -1.0, "b": -0.05}):
            value = phi.update(state)
            monitor.update(state)
        values.append((monitor.state(), value))
    assert values[0][0] == values[1][0] and values[0][1] == values[1][1]


def test_eventually_of_temporal_operands_is_a_target():
    phi = HierarchicalPotential(parse("F(x > 1 & X(x > 2)) & F(y > 0) & G(y < 10)"), scale=1.0)
    assert len(phi.targets) == 2 and phi.safety == ["G y < 10"]
    # the unmet F(x ...) no longer blocks the shaping of F(y > 0)
    values = [phi.update({"x": 0.0, "y": y}) for y in (-3.0, -1.0, -0.1)]
    assert values[0] < values[1] < values[2]
    chain = HierarchicalPotential(parse("F(a > 0 T b > 0)"), scale=1.0)
    assert chain.update({"a": 1.0, "b": -2.0}) == pytest.approx((1 + math.exp(-2.0)) / 2)  # F of a chain: the chain


def test_targets_count_only_while_safe():
    phi = HierarchicalPotential(parse("F(a > 0) & G(b < 1)"), scale=2.0)
    assert phi.update({"a": 1.0, "b": 0.0}) == 4.0  # 2 · (1 safe + 1 target)
    assert phi.update({"a": 1.0, "b": 2.0}) == 0.0


def test_bad_arguments():
    with pytest.raises(ValueError, match="scale must be a finite number > 0"):
        HierarchicalPotential(parse("F(a > 0)"), scale=-1.0)
    with pytest.raises(ValueError, match="gamma must lie in"):
        TLTLRewardWrapper(Scripted(), "F(a > 0)", signals={"a": 0}, reward_mode="potential", gamma=0.0)
    with pytest.raises(ValueError, match="pays exact robustness increments"):
        TLTLRewardWrapper(Scripted(), "F(a > 0)", signals={"a": 0}, reward_mode="potential", reward="smooth")


@pytest.mark.parametrize("reward_mode", ["potential", "dense"])
def test_car_batched_env_pays_the_single_env_rewards(reward_mode):
    kwargs = {"task": 2, "observe_monitor": True, "reward_mode": reward_mode, "gamma": 0.99, "horizon": 25}
    envs = gym.make_vec("TLCarNav-v0", num_envs=2, vectorization_mode="vector_entry_point", **kwargs)
    singles = [gym.make("TLCarNav-v0", **kwargs) for _ in range(2)]
    envs.reset(seed=1)
    for i, env in enumerate(singles):
        env.reset(seed=1 + i)
    rng = np.random.default_rng(0)
    for _ in range(25):
        actions = rng.uniform(-1, 1, (2, 2)).astype(np.float32)
        _, rewards, _, truncated, _ = envs.step(actions)
        assert np.allclose(rewards, [env.step(a)[1] for env, a in zip(singles, actions)])
    assert truncated.all()
    _, rewards, *_ = envs.step(np.zeros((2, 2), dtype=np.float32))  # the autoreset step pays 0
    assert (rewards == 0).all()
