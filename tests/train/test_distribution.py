"""The policy networks: the squashed-Gaussian distribution (initial scale, entropy estimates) and widths."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fastrl.agents.networks import TanhGaussian


def _numeric_squashed_entropy(mean: float, std: float) -> float:
    """Entropy of tanh(u), u ~ N(mean, std^2), by quadrature in u: H = -int p(u) log(p(u) / tanh'(u))."""
    u = np.linspace(mean - 12 * std, mean + 12 * std, 200_001)
    p = np.exp(-0.5 * ((u - mean) / std) ** 2) / (std * np.sqrt(2 * np.pi))
    integrand = p * (np.log(p + 1e-300) - np.log(1 - np.tanh(u) ** 2 + 1e-300))
    return float(-np.trapezoid(integrand, u))


@pytest.mark.parametrize("mean,std", [(0.0, 0.3), (0.0, 1.5), (1.2, 0.7)])
def test_squashed_entropy_estimate_is_unbiased(mean, std):
    dist = TanhGaussian(jnp.array([-1.0]), jnp.array([1.0]), init_std=std)
    out = jnp.array([[mean, 0.0]])  # raw scale 0 gives exactly init_std
    keys = jax.random.split(jax.random.PRNGKey(0), 100_000)
    estimates = jax.vmap(lambda k: dist.squashed_entropy(out, k)[0])(keys)
    assert float(jnp.mean(estimates)) == pytest.approx(_numeric_squashed_entropy(mean, std), abs=0.01)
    # The Gaussian's entropy ignores squashing, so it is larger, and grows without bound in std.
    assert float(dist.entropy(out)[0]) > float(jnp.mean(estimates)) + 0.01


def test_init_std_sets_the_scale_at_a_zero_network_output_and_bad_values_are_refused():
    for init_std in (0.05, 0.3, 1.0):
        dist = TanhGaussian(-jnp.ones(3), jnp.ones(3), init_std=init_std)
        _, std = dist._split(jnp.zeros(6))
        np.testing.assert_allclose(np.asarray(std), init_std, rtol=1e-5)
    _, std = TanhGaussian(-jnp.ones(1), jnp.ones(1))._split(jnp.zeros(2))
    assert float(std[0]) == pytest.approx(np.log(2.0) + 1e-3, rel=1e-6)
    with pytest.raises(ValueError, match="init_std"):
        TanhGaussian(-jnp.ones(1), jnp.ones(1), init_std=0.0)


def test_empty_hidden_list_gives_a_linear_policy_and_bad_widths_are_refused():
    from fastrl.agents.networks import MLP, NetworkConfig

    assert NetworkConfig(policy_hidden=[]).policy_hidden == ()
    with pytest.raises(ValueError, match=r"network.policy_hidden=\[32, 0\] must be positive"):
        NetworkConfig(policy_hidden=[32, 0])
    net = MLP(hidden=(), out=4)
    x = jax.random.normal(jax.random.PRNGKey(1), (3, 8))
    params = net.init(jax.random.PRNGKey(0), x)
    assert jax.tree.reduce(lambda n, leaf: n + leaf.size, params, 0) == 8 * 4 + 4  # one Dense
    # linear: f(a x + b y) - f(0) = a (f(x) - f(0)) + b (f(y) - f(0))
    f = lambda v: net.apply(params, v)  # noqa: E731
    zero = jnp.zeros((1, 8))
    lhs = f(2.0 * x[:1] - 3.0 * x[1:2]) - f(zero)
    rhs = 2.0 * (f(x[:1]) - f(zero)) - 3.0 * (f(x[1:2]) - f(zero))
    np.testing.assert_allclose(lhs, rhs, rtol=1e-4, atol=1e-6)
