"""Atari outside the project: an exported policy in a plain Gymnasium loop, and env speeds.

    python -m benchmarks atari --checkpoint RUN_DIR [RUN_DIR ...] [--games 30] [--seeds 0]
        [--record docs/results/atari_breakout.json]
    python -m benchmarks atari --env-speed [--steps 2000] [env.id=ALE/Breakout-v5]

``--checkpoint``: the run's best policy, exported as ``scripts/export.py`` does to
``OUT/policy.pt2`` (``torch.export``), plays ``--games`` whole games (game i seeded
``--seeds``' first + i, the same games for every run) of the run's game in a loop of
Gymnasium's own: ``gymnasium.make(id, frameskip=1, <the run's env.make_kwargs>)``,
``AtariPreprocessing`` (30 NOOPs, frame skip 4, 84x84 gray) and ``FrameStackObservation(4)``;
the one rule of this project's preprocessing Gymnasium has no wrapper for, ``fire_steps`` FIRE
steps after a reset and after a lost life, is a few lines of the loop. The stacks then differ a
little from the project's for three steps after each FIRE: here the frames of the lost life and
of each FIRE step are pushed onto the stack, where the project's stack gets only the last FIRE
step's frame (four times after a reset), a difference that does not show in the scores
(docs/results/breakout.md, the games seeded 0 to 99). Prints the mean score over the games beside
the run's own final evaluation (``summary.json``); ``--record`` writes each run's summary with
its plain-loop scores (each game's, and the first game's seed), and where and when they were
measured, to a results file (docs/results/breakout.md is generated from it).

``--env-speed``: agent steps per second of random play (4 game frames each) through this
project's TorchRL env (one game; a ``SerialEnv`` of 4), Gymnasium's preprocessing wrappers,
and ALE's own C++ ``AtariVectorEnv`` (4 and 8 games, its threads), one after another.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from functools import partial
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from torchrl.envs.utils import step_mdp

from trl_cartpole.config.compose import compose_config
from trl_cartpole.envs.atari import ATARI_DEFAULTS
from trl_cartpole.envs.ids import register_atari_games

SEEDS = [0]
OUT = "runs/bench/atari"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--checkpoint", type=Path, nargs="+", help="run directories of a game")
    parser.add_argument("--record", type=Path, help="write the runs' results to this file")
    parser.add_argument("--games", type=int, default=30, help="whole games to play")
    parser.add_argument("--env-speed", action="store_true", help="time the env paths instead")
    parser.add_argument("--steps", type=int, default=2000, help="agent steps per env timed")


def _gymnasium_game(env_id: str, make_kwargs: dict, atari: dict | None = None) -> gym.Env:
    """Gymnasium's own preprocessing with the run's ``env.atari`` settings (the defaults
    without it)."""
    from gymnasium.wrappers import AtariPreprocessing, FrameStackObservation

    settings = {**ATARI_DEFAULTS, **(atari or {})}
    register_atari_games()
    base = gym.make(env_id, frameskip=1, **make_kwargs)
    preprocessed = AtariPreprocessing(
        base,
        noop_max=settings["noop_max"],
        frame_skip=settings["frame_skip"],
        screen_size=settings["screen_size"],
    )
    return FrameStackObservation(preprocessed, settings["frames"])


def play_in_gymnasium(program: Path, config: dict, games: int, seed: int) -> list[float]:
    """Scores of ``games`` whole games of the exported greedy network ``program``, in the game
    and preprocessing of the run's ``config``."""
    network = torch.export.load(program).module()
    env_cfg = config["env"]
    atari = env_cfg.get("atari", {})
    env = _gymnasium_game(env_cfg["id"], env_cfg.get("make_kwargs", {}), atari)
    meanings = env.unwrapped.get_action_meanings()
    fires = atari.get("fire_on_reset", True) and "FIRE" in meanings
    fire = meanings.index("FIRE") if fires else None
    fire_steps = atari.get("fire_steps", ATARI_DEFAULTS["fire_steps"])
    scores = []
    for game in range(games):
        observation, info = env.reset(seed=seed + game)
        score, lives, over, fire_due = 0.0, info["lives"], False, fire is not None
        while not over:
            firing = fire_due
            if firing:  # FIRE after the reset and after a lost life, as FireOnReset
                action, steps = fire, fire_steps
            else:
                with torch.no_grad():
                    values = network(torch.from_numpy(np.asarray(observation))[None])  # [1, A]
                action, steps = int(values.argmax()), 1
            for _ in range(steps):
                observation, reward, terminated, truncated, info = env.step(action)
                score, over = score + reward, terminated or truncated
                if over:
                    break
            fire_due = fire is not None and not firing and not over and info["lives"] < lives
            lives = info["lives"]
        scores.append(score)
    env.close()
    return scores


def _plain_loop(args: argparse.Namespace) -> None:
    from benchmarks.harness import provenance
    from trl_cartpole.policy.export import export_program, greedy_q_network

    torch.set_num_threads(1)  # one game, one observation a step: a second thread only waits
    runs = []
    for number, run_dir in enumerate(args.checkpoint):
        config = _run_config(run_dir)
        args.out.mkdir(parents=True, exist_ok=True)
        network = greedy_q_network(run_dir)  # what scripts/export.py writes
        program = export_program(network, network.obs_dim, args.out / f"policy-{number}.pt2")
        env_id = config["env"]["id"]
        scores = play_in_gymnasium(program, config, args.games, args.seeds[0])
        summary = json.loads((run_dir / "summary.json").read_text())
        print(f"{env_id}, {run_dir}: {args.games} games in Gymnasium's own loop")
        print(
            f"  exported policy, Gymnasium's preprocessing: mean {statistics.mean(scores):.2f} "
            f"+/- {statistics.pstdev(scores):.2f} (min {min(scores):g}, max {max(scores):g})"
        )
        print(
            f"  the run's final evaluation ({summary['final_eval_episodes']} games): mean "
            f"{summary['final_eval_return_mean']:.2f} +/- {summary['final_eval_return_std']:.2f}"
        )
        plain = {"games": len(scores), "mean": statistics.mean(scores)}
        plain |= {"std": statistics.pstdev(scores), "first_seed": args.seeds[0], "scores": scores}
        runs.append({**summary, "plain_loop": plain})
    if args.record:
        command = f"python -m benchmarks atari --checkpoint RUN_DIR --games {args.games}"
        command += f" --seeds {args.seeds[0]}" if args.seeds[0] != SEEDS[0] else ""
        record = _merged_record(args.record, runs, command, provenance())
        args.record.write_text(json.dumps(record, indent=2) + "\n")


def _merged_record(path: Path, runs: list[dict], command: str, measured: dict) -> dict:
    """The results file at ``path`` with ``runs`` added: a game and seed measured again
    replaces its old run, the others stay (seeds trained on other days, or other games of one
    seed, land in one table), and each run keeps where and when it was measured (``measured``:
    date, commit, machine). A run recorded without its game is taken for any game."""
    kept, commands = [], [command]
    if path.is_file():
        previous = json.loads(path.read_text())
        where = {key: previous[key] for key in ("date", "commit", "machine")}
        kept = [
            {"measured": where, **run}
            for run in previous["runs"]
            if not any(_same_run(run, new) for new in runs)
        ]
        commands = [line for line in previous["command"].splitlines() if line != command]
        commands.append(command)
    merged = kept + [{**run, "measured": measured} for run in runs]
    merged.sort(key=lambda run: (run["seed"], run.get("env_id", "")))
    return {**measured, "command": "\n".join(commands), "runs": merged}


def _same_run(old: dict, new: dict) -> bool:
    """Whether ``new`` measures ``old`` again: the same seed, and the same game where both name
    theirs."""
    games = {old.get("env_id"), new.get("env_id")} - {None}
    return old["seed"] == new["seed"] and len(games) <= 1


def _run_config(run_dir: Path) -> dict:
    from omegaconf import OmegaConf

    return OmegaConf.to_container(OmegaConf.load(run_dir / "config.yaml"), resolve=False)


def _steps_per_second(step, steps: int, batch: int) -> float:
    step()  # warm-up
    start = time.perf_counter()
    for _ in range(steps // batch):
        step()
    return (steps // batch) * batch / (time.perf_counter() - start)


def _torchrl_stepper(env):
    state = [env.reset()]

    def step() -> None:
        state[0] = step_mdp(env.rand_step(state[0]))

    return step


def _gymnasium_stepper(game: gym.Env):
    game.reset(seed=0)

    def step() -> None:
        _, _, terminated, truncated, _ = game.step(game.action_space.sample())
        if terminated or truncated:
            game.reset()

    return step


def _random_vector_step(vector: Any) -> None:
    vector.step(vector.action_space.sample())


def _env_speed(args: argparse.Namespace) -> None:
    import ale_py
    from torchrl.envs import SerialEnv

    from trl_cartpole.envs.atari import make_atari_env

    env_id = str(compose_config("configs", ["env=breakout", *args.overrides]).env.id)
    register_atari_games()
    rows = []
    for count in (1, 4):
        env = (
            make_atari_env(env_id, seed=0)
            if count == 1
            else SerialEnv(count, partial(make_atari_env, env_id))
        )
        env.set_seed(0)
        rate = _steps_per_second(_torchrl_stepper(env), args.steps, count)
        rows.append((f"TorchRL env, this project's transforms, {count} game(s)", rate))
        env.close()
    game = _gymnasium_game(env_id, {})
    rate = _steps_per_second(_gymnasium_stepper(game), args.steps, 1)
    rows.append(("Gymnasium AtariPreprocessing + FrameStackObservation, 1 game", rate))
    game.close()
    name = env_id.split("/")[-1].split("-")[0].lower()
    for count in (4, 8):
        vector = ale_py.AtariVectorEnv(name, count, repeat_action_probability=0.25)
        vector.reset(seed=0)
        rate = _steps_per_second(partial(_random_vector_step, vector), args.steps, count)
        rows.append((f"ALE AtariVectorEnv (C++ threads), {count} games", rate))
        vector.close()
    print("| env path | agent steps / s |\n| --- | --- |")
    for label, rate in rows:
        print(f"| {label} | {rate:.0f} |")


def main(args: argparse.Namespace) -> None:
    if args.env_speed:
        _env_speed(args)
    elif args.checkpoint is None:
        raise SystemExit("give --checkpoint RUN_DIR (an Atari run) or --env-speed")
    else:
        _plain_loop(args)
