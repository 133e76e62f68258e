"""Load a trained policy from a checkpoint: its env, observation normalisation and network.

Evaluation, rendering and the notebook all load a policy through :func:`load_trained_policy`,
which rebuilds the env and the Q-actor from the config stored in the checkpoint (imports of
custom envs included, through ``env.imports``) with :mod:`trl_cartpole.run.build`, applies the
run's observation statistics and loads the weights.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from omegaconf import OmegaConf
from torchrl.envs import TransformedEnv
from torchrl.modules import DistributionalQValueActor, QValueActor

from trl_cartpole.config.schema import Config
from trl_cartpole.errors import ConfigError
from trl_cartpole.report.console import quiet_libraries
from trl_cartpole.run.env_kind import EnvKind
from trl_cartpole.run.eval_protocol import EvalProtocol
from trl_cartpole.run.evaluation import EvalResult
from trl_cartpole.run.from_config import build_actor, build_env
from trl_cartpole.store.checkpoint import (
    load_policy,
    newest_policy,
    read_checkpoint_config,
    read_observation_norm,
    verify_checkpoint,
)

__all__ = ["TrainedPolicy", "evaluate_checkpoint", "load_trained_policy", "policy_checkpoint"]


@dataclass
class TrainedPolicy:
    """A trained Q-actor with the env it acts in and the config it was trained with."""

    actor: QValueActor | DistributionalQValueActor
    env: TransformedEnv
    cfg: Config
    checkpoint: Path


def policy_checkpoint(path: str | Path) -> Path:
    """``path`` if it is a checkpoint; for a run directory, its best policy, or before its
    first evaluation the policy of its newest training state (:func:`newest_policy`).

    Raises a one-line ``ConfigError`` for a directory that is neither.
    """
    path = Path(path)
    if not path.is_dir() or (path / "manifest.json").is_file():
        return path  # a checkpoint, or a path whose reading says what is wrong with it
    policy = newest_policy(path)
    if policy is None:
        raise ConfigError(
            f"checkpoint={str(path)!r} is neither a checkpoint nor a run directory with "
            "checkpoints; pass the directory training printed"
        )
    return policy


def load_trained_policy(
    checkpoint: str | Path,
    num_envs: int = 1,
    seed: int | None = None,
    render_mode: str | None = None,
) -> TrainedPolicy:
    """Rebuild and load the policy of ``checkpoint`` (a checkpoint or a run directory).

    ``seed`` defaults to the training seed plus twice the eval seed offset (the seeds of the
    run's final evaluation); ``num_envs`` envs are stepped together (``render_mode`` needs 1).
    A pixel policy plays on Gymnasium's own picture, whichever renderer it trained on: a drawn
    run's vector env with every frame painted by Gymnasium's calls, or with ``render_mode`` (a
    video) Gymnasium's ``render()``.
    Raises a one-line ``ConfigError`` for a path that is not a checkpoint of this project.
    """
    path = policy_checkpoint(checkpoint)
    verify_checkpoint(path)  # before its config names modules to import and envs to build
    cfg = read_checkpoint_config(path)
    if seed is None:  # the final evaluation's episodes
        seed = EvalProtocol.from_config(cfg).seed_for("final")
    cfg.device = "cpu"  # a policy trained on a GPU is loaded for this machine's CPU
    kind = EnvKind(cfg.env)
    # a trained policy plays on Gymnasium's own picture; a video records its own render()
    cfg.env = kind.evaluation_env() if render_mode is None else kind.recorded()
    with quiet_libraries():  # no TorchRL INFO lines (spec checks) from a library call
        env = build_env(cfg, seed, num_envs, read_observation_norm(path), render_mode)
    actor = load_policy(path, build_actor(cfg, env))
    return TrainedPolicy(actor, env, cfg, path)


def evaluate_checkpoint(
    checkpoint: str | Path,
    episodes: int = 100,
    seed: int | None = None,
    epsilon: float = 0.0,
    on_turn: Callable[[int], None] | None = None,
) -> tuple[EvalResult, dict]:
    """Evaluate the policy of ``checkpoint`` greedily (or epsilon-greedily) over ``episodes``.

    Returns the result and the stored config as a dict.
    """
    trained = load_trained_policy(checkpoint, num_envs=1, seed=seed)  # the actor, its config
    trained.env.close()
    cfg = trained.cfg
    protocol = EvalProtocol.from_config(cfg, read_observation_norm(trained.checkpoint))
    seed = protocol.seed_for("final") if seed is None else seed
    with quiet_libraries():
        result = protocol.play(trained.actor, seed, episodes, epsilon, on_turn=on_turn)
    return result, OmegaConf.to_container(OmegaConf.structured(cfg))
