"""Learning thresholds set in advance (``pytest -m slow``): each learner on the envs it suits.

Each case trains with the shipped ``experiment/<env>_<algo>`` settings (budget included), its
seeds as one batch of agents in one program (``train.num_seeds``), and stops once every agent's
deterministic evaluation return has reached the threshold (``train.stop_at_return``); it fails
when the budget runs out first. Thresholds were fixed before running: inverted_pendulum 950 (of
1000); halfcheetah 2000 (SAC, PPO) and 1000 (ES); hopper 1000; swimmer 100; reacher -10, raised
to -5 in session 10 (before that run) because a motionless arm scores -11.8. Swimmer's ES
settings changed to a linear policy after the 2x32 MLP plateaued near 50 (conf/experiment/
swimmer_es.yaml); the threshold did not change.
"""

import pytest

from experiments import joystick_commands, reference_scores

from .test_front_door import compose_cfg, run

CASES = [
    ("inverted_pendulum", "ppo", 950.0, 1),
    ("halfcheetah", "ppo", 2000.0, 1),
    ("hopper", "ppo", 1000.0, 1),
    ("hopper", "sac", 1000.0, 3),
    ("halfcheetah", "sac", 2000.0, 3),
    ("swimmer", "es", 100.0, 3),
    ("halfcheetah", "es", 1000.0, 3),
    ("inverted_pendulum", "apg", 950.0, 3),
    ("reacher", "apg", -5.0, 3),
]


@pytest.mark.slow
@pytest.mark.parametrize("env_name,algo,threshold,seeds", CASES, ids=[f"{e}-{a}" for e, a, *_ in CASES])
def test_reaches_threshold(tmp_path, env_name, algo, threshold, seeds):
    overrides = [f"env={env_name}", f"algo={algo}", "seed=0", f"train.num_seeds={seeds}", "logger=quiet"]
    overrides += [f"train.stop_at_return={threshold}", f"run_dir={tmp_path}"]
    out = run(compose_cfg(overrides))
    reached = out["reached"] if seeds > 1 else [out["reached"]]
    best = out["best_eval_return"] if seeds > 1 else [out["best_eval_return"]]
    took = f"{out['wall_s']:.0f}s (+{out['compile_s']:.0f}s compile)"
    print(f"{env_name}/{algo}, {seeds} seed(s) in one program: {out['status']} after {out['chunks']} chunks, "
          f"{out['env_steps']:,d} env steps per agent, {took}")  # fmt: skip
    for seed, (r, b) in enumerate(zip(reached, best, strict=True)):
        at = None if r is None else f"{r['eval_return']:.1f} at {r['env_steps']:,d} steps, {r['wall_s']:.0f}s"
        where = at or "never"
        print(f"  seed {seed}: reached {threshold}: {where}; best {b:.1f}")
    assert all(r is not None for r in reached), f"best returns {best} vs threshold {threshold}"


@pytest.mark.slow
def test_humanoid_ppo_scores_5000_in_gymnasiums_humanoid_v5_within_two_hours(tmp_path):
    """Humanoid: the shipped settings and budget (10.2M steps, one seed), then the final
    deterministic policy scored in Gymnasium's own Humanoid-v5 (MuJoCo C, 16 episodes) averages
    5000 or more (a policy that stays up all 1000 steps and stands still scores ~5000), and the
    whole run takes under 2 hours. The bar is the one the issue set before any run."""
    out = run(compose_cfg(["env=humanoid", "algo=ppo", "logger=quiet", f"run_dir={tmp_path}"]))
    row = reference_scores.score_run(str(tmp_path), 16)
    score, took = row["reference"]["mean"], out["wall_s"] + out["compile_s"]
    print(f"humanoid/ppo: {score:.0f} in Humanoid-v5 after {out['env_steps']:,d} steps, {took:.0f}s")
    assert took < 7200, took
    assert score >= 5000, row["reference"]


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


@pytest.mark.slow
def test_panda_pick_cube_ppo_lifts_the_cube_to_its_target_in_half_the_episodes(tmp_path):
    """panda_pick_cube success: the cube's centre within 5 cm of its target (0.2-0.4 m above its
    start) at the episode's end, over 64 deterministic evaluation episodes with domain
    randomisation; the shipped settings and budget, one seed. The bar (50%) was set before the
    first training run."""
    overrides = ["env=panda_pick_cube", "algo=ppo", "logger=quiet", f"run_dir={tmp_path}"]
    out = run(compose_cfg(overrides))
    success = out["last"]["eval/success"]
    took = f"{out['wall_s']:.0f}s (+{out['compile_s']:.0f}s compile)"
    print(f"panda_pick_cube/ppo: success {success} in {took}")
    assert success >= 0.5, success


@pytest.mark.slow
def test_go1_joystick_ppo_walks_forward_on_command(tmp_path):
    """go1_joystick: after the shipped settings and budget (120M steps, ~2 h on this 2-core CPU;
    one seed), the deterministic policy under a held forward command of 0.5 m/s (6 s from reset,
    32 envs, no observation noise, nominal physics; ``experiments.joystick_commands``) moves
    forward at 0.25 m/s or more on average. A robot that stands, or only turns on command,
    scores ~0. The bar was set on 2026-11-28, before any run with a privileged critic had
    finished."""
    out = run(compose_cfg(["env=go1_joystick", "algo=ppo", "logger=quiet", f"run_dir={tmp_path}"]))
    _, rows = joystick_commands.measure(str(tmp_path), [(0.5, 0.0, 0.0)], n=32, runs=1, seconds=6.0)
    forward = rows[0]["fastrl"]["velocity"][0]
    print(f"go1_joystick/ppo: {forward:.2f} m/s under 0.5 m/s after {out['env_steps']:,d} steps")
    assert forward >= 0.25, forward


@pytest.mark.slow
def test_go1_joystick_rough_ppo_from_the_flat_walker_walks_forward_on_rough_ground(tmp_path):
    """go1_joystick_rough, fine-tuned: go1_joystick's shipped run (120M steps, ~2 h), then the
    shipped rough-ground run started from its weights (``init_from``, 20M steps, ~75 min; one
    seed). The rough-ground policy's deterministic evaluation return (64 episodes, commands drawn
    as in training) reaches 20, and under a held forward command of 0.5 m/s (6 s from reset,
    32 envs, nominal physics) it moves forward at 0.25 m/s or more. The flat walker itself
    scores 13.5 on rough ground (it falls in half its episodes; 28.9 on flat ground). The bars
    were set on 2026-11-28 before the first rough-ground run's first evaluation."""
    flat, rough = tmp_path / "flat", tmp_path / "rough"
    run(compose_cfg(["env=go1_joystick", "algo=ppo", "logger=quiet", f"run_dir={flat}"]))
    overrides = ["env=go1_joystick_rough", "algo=ppo", "logger=quiet", f"init_from={flat}"]
    out = run(compose_cfg([*overrides, f"run_dir={rough}"]))
    _, rows = joystick_commands.measure(str(rough), [(0.5, 0.0, 0.0)], n=32, runs=1, seconds=6.0)
    forward, ret = rows[0]["fastrl"]["velocity"][0], out["last"]["eval/episode_return"]
    print(f"go1_joystick_rough/ppo: return {ret:.1f}, {forward:.2f} m/s under 0.5 m/s")
    assert ret >= 20 and forward >= 0.25, (ret, forward)


@pytest.mark.slow
def test_humanoid_joystick_ppo_tracks_commands_to_an_eval_return_of_10(tmp_path):
    """humanoid_joystick: the mean deterministic evaluation return (64 episodes of up to 1000
    steps, commands drawn as in training, pushes and domain randomisation on) reaches 10 within
    the shipped budget (20M steps). Playground's Brax PPO, 8192 envs and a privileged critic,
    averages 11.2 at 21.6M steps (a standing robot that never falls scores ~3-5). The bar was
    set before the first training run."""
    overrides = ["env=humanoid_joystick", "algo=ppo", "logger=quiet", "train.stop_at_return=10"]
    out = run(compose_cfg([*overrides, f"run_dir={tmp_path}"]))
    took = f"{out['wall_s']:.0f}s (+{out['compile_s']:.0f}s compile)"
    best = out["best_eval_return"]
    print(f"humanoid_joystick/ppo: best {best:.1f} after {out['env_steps']:,d} steps, {took}")
    assert out["reached"] is not None, out["best_eval_return"]


@pytest.mark.slow
def test_leap_cube_reorient_ppo_reaches_a_target_per_episode(tmp_path):
    """leap_cube_reorient: over 16 deterministic evaluation episodes (1000 steps, 50 s), the hand
    turns the cube to at least one target per episode on average, within 20M steps of the
    shipped settings. The bar was set before the first training run."""
    overrides = ["env=leap_cube_reorient", "algo=ppo", "logger=quiet", "train.total_env_steps=20_000_000"]
    out = run(compose_cfg([*overrides, f"run_dir={tmp_path}"]))
    reached = out["last"]["eval/targets_reached"]
    print(f"leap_cube_reorient/ppo: {reached} targets per episode in {out['wall_s']:.0f}s")
    assert reached >= 1.0, reached
