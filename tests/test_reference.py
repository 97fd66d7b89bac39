"""Reference evaluation (fastrl.tools.reference, ``python -m fastrl.evaluate RUN_DIR --reference``).

Short horizons (the debug config's 20-step episodes): a contact-free env and a contact env are
trained in-process for a few hundred steps, then scored by fastrl and by MuJoCo C from the same
initial states. Over 20 steps the two simulators stay on the same trajectory, so the scores
agree closely; over long horizons closed-loop trajectories part (see
tests/physics/test_long_horizon.py), and only their statistics can be compared.
"""

import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hydra import compose, initialize_config_dir

from fastrl import envs
from fastrl.cli.conf import CONF_DIR
from fastrl.cli.train import run
from fastrl.tools import evaluate, reference


def _train(tmp_path, overrides):
    with initialize_config_dir(config_dir=CONF_DIR, version_base=None):
        cfg = compose("train", overrides=[*overrides, "debug=quick", "logger=quiet", f"run_dir={tmp_path}"])
    run(cfg)
    return tmp_path


def _rows(out: str) -> dict[str, float]:
    """Mean return of each row of the side-by-side table, by its label."""
    rows = {}
    for line in out.splitlines():
        m = re.match(r"((?:fastrl|MuJoCo C|reference) \(.*?\))\s+(-?[\d.]+) \+- ", line)
        if m:
            rows[m[1]] = float(m[2])
    return rows


def _one(rows: dict[str, float], *words: str) -> float:
    found = [v for k, v in rows.items() if all(w in k for w in words)]
    assert len(found) == 1, (words, rows)
    return found[0]


@pytest.mark.parametrize(
    "overrides",
    # a run at other physics on the inverted pendulum in the default suite, on the hopper (a contact
    # scene, ~70 s) under the slow marker
    [
        ["env=inverted_pendulum", "algo=ppo"],
        ["env=inverted_pendulum", "algo=ppo", "env.integrator=euler"],
        # the same 0.04 s control step in 4 substeps instead of the asset's 2
        ["env=inverted_pendulum", "algo=ppo", "env.timestep=0.01", "env.frame_skip=4"],
        pytest.param(["env=hopper", "algo=ppo", "env.integrator=euler"], marks=pytest.mark.slow),
    ],
    ids=["inverted_pendulum", "inverted_pendulum_euler", "inverted_pendulum_substeps", "hopper_euler"],
)
def test_reference_flag_prints_both_scores(tmp_path, capsys, overrides):
    """An env at its asset's physics, and envs trained at other physics (RK4 assets, Euler runs)."""
    run_dir = _train(tmp_path, overrides)
    trained = capsys.readouterr().out
    # a run at non-asset physics says so when it starts, and how to get the reference score
    assert ("evaluation returns are at this run's physics (euler" in trained) == (
        "env.integrator=euler" in overrides
    )
    substeps = "env.frame_skip=4" in overrides
    assert ("this run's physics (rk4 at 0.01 s x 4" in trained) == substeps
    assert evaluate.run([str(run_dir), "--reference", "--episodes", "4"]) == 0
    out = capsys.readouterr().out
    rows = _rows(out)
    ours, ref = _one(rows, "fastrl", "the run's"), _one(rows, "reference (Gymnasium")
    assert "fastrl / reference" in out
    if substeps:  # scored at the asset's 0.02 s x 2 in Gymnasium, and by MuJoCo C at the run's
        assert len(rows) == 4, out
        assert _one(rows, "MuJoCo C", "rk4 at 0.01 s x 4") == pytest.approx(ours, rel=1e-6)
        assert _one(rows, "fastrl", "the asset's") == pytest.approx(ref, rel=1e-6)
        assert not [k for k in rows if k.startswith("reference") and " at 0." in k], out
        return
    if "env.integrator=euler" not in overrides:
        assert len(rows) == 2, out
        assert ours == pytest.approx(ref, rel=1e-6)  # 20 steps, no contacts: the same survival
        return
    # Trained with Euler where the asset has RK4: each simulator at the other's physics too.
    assert len(rows) == 4, out
    assert _one(rows, "MuJoCo C", "euler") == pytest.approx(ours, rel=0.02)
    assert _one(rows, "fastrl", "rk4", "the asset's") == pytest.approx(ref, rel=0.02)


def _linear_policy(env, scale=0.3, seed=0):
    w = np.random.default_rng(seed).normal(size=(env.observation_size, env.action_size))
    w = jnp.asarray(w * scale / np.sqrt(env.observation_size), jnp.float32)
    return lambda obs: jnp.tanh(obs @ w)


@pytest.mark.parametrize("name", ["reacher", "ant_goal"])
def test_reference_simulators_score_short_episodes_as_fastrl_does(name):
    """Each simulator the env supports, from fastrl's initial states, with a fixed policy: both
    for a contact-free arm, MuJoCo C with fastrl's obs/reward for a contact scene (the hopper's
    Gymnasium and MuJoCo C scores are checked through the command line above)."""
    env = envs.make(name, episode_length=15)
    policy = _linear_policy(env)
    key = jax.random.PRNGKey(1)
    ours = reference.fastrl_evaluate(env, policy, 3, key)
    sims = ["gymnasium", "mujoco"] if name in reference.GYMNASIUM else ["mujoco"]
    for sim in sims:
        ref = reference.evaluate(env, policy, 3, key, sim)
        np.testing.assert_array_equal(ref.lengths, ours.lengths, err_msg=sim)
        np.testing.assert_allclose(ref.returns, ours.returns, rtol=2e-3, atol=2e-3, err_msg=sim)


def test_gymnasium_kwargs_carry_the_env_options():
    env = envs.make(
        "ant", include_cfrc_ext_in_observation=False, reward_weights={"ctrl": 0.1}, episode_length=7
    )
    kwargs = reference.gymnasium_kwargs(env)
    assert kwargs["include_cfrc_ext_in_observation"] is False
    assert kwargs["ctrl_cost_weight"] == 0.1 and kwargs["max_episode_steps"] == 7
    with pytest.raises(ValueError, match="no weight for the reward term 'upright'"):
        reference.gymnasium_kwargs(envs.make("inverted_pendulum", reward_weights={"upright": 1.0}))
    with pytest.raises(ValueError, match="no Gymnasium counterpart"):
        reference.gymnasium_kwargs(envs.make("arm_reach"))
    reacher = envs.make("reacher", timestep=0.005)
    with pytest.raises(ValueError, match="cannot take a timestep override"):
        reference.evaluate(reacher, _linear_policy(reacher), 1, jax.random.PRNGKey(0), "gymnasium")
