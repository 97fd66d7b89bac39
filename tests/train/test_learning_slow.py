"""Learning thresholds set in advance (``pytest -m slow``): each learner on the envs it suits.

Each case trains with the shipped ``experiment/<env>_<algo>`` settings (budget included) and
asserts the final deterministic evaluation return. Thresholds were fixed before running:
inverted_pendulum 950 (of 1000); halfcheetah 2000; hopper 1000; swimmer 100; reacher -10.
"""

import pytest

from .test_front_door import compose_cfg, run

CASES = [
    ("inverted_pendulum", "ppo", 950.0, (0,)),
    ("halfcheetah", "ppo", 2000.0, (0,)),
    ("hopper", "ppo", 1000.0, (0,)),
    ("hopper", "sac", 1000.0, (0, 1, 2)),
    ("halfcheetah", "sac", 2000.0, (0, 1, 2)),
    ("swimmer", "es", 100.0, (0, 1, 2)),
    ("halfcheetah", "es", 1000.0, (0, 1, 2)),
    ("inverted_pendulum", "apg", 950.0, (0, 1, 2)),
    ("reacher", "apg", -10.0, (0, 1, 2)),
]


@pytest.mark.slow
@pytest.mark.parametrize("env_name,algo,threshold,seeds", CASES, ids=[f"{e}-{a}" for e, a, *_ in CASES])
def test_reaches_threshold(tmp_path, env_name, algo, threshold, seeds):
    for seed in seeds:
        overrides = [f"env={env_name}", f"algo={algo}", f"seed={seed}", "logger=quiet"]
        overrides.append(f"run_dir={tmp_path}/{seed}")
        out = run(compose_cfg(overrides))
        ret = out["last"]["eval/episode_return"]
        took = f"{out['wall_s']:.0f}s (+{out['compile_s']:.0f}s compile)"
        print(f"{env_name}/{algo} seed {seed}: return {ret:.1f} in {took}")
        assert ret >= threshold, f"seed {seed}: {ret:.1f} < {threshold}"


@pytest.mark.slow
def test_arm_reach_ppo_succeeds_in_80_percent_of_episodes_for_3_seeds_in_one_program(tmp_path):
    """arm_reach success: flange within 5 cm of the target at the episode's end, over 64
    deterministic evaluation episodes per agent; the bar (80%) was set before training."""
    overrides = ["env=arm_reach", "algo=ppo", "logger=quiet", "train.num_seeds=3", f"run_dir={tmp_path}"]
    out = run(compose_cfg(overrides))
    success = [agent["eval/success"] for agent in out["last"]["agents"]]
    print(
        f"arm_reach/ppo 3 seeds: success {success} in {out['wall_s']:.0f}s (+{out['compile_s']:.0f}s compile)"
    )
    assert min(success) >= 0.8, success
