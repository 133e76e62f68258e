"""scripts/export.py: the exported policy acts as the TorchRL actor, in ONNX and as a .pt2."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from tensordict import TensorDict
from torchrl.envs import ExplorationType, set_exploration_type

from tests.conftest import CONFIG_DIR, SMOKE_OVERRIDES, run_script_in_process
from trl_cartpole.cli.commands import export as export_command
from trl_cartpole.config.compose import compose_config
from trl_cartpole.config.schema import Config, NetworkConfig
from trl_cartpole.errors import ConfigError
from trl_cartpole.parts.env import make_env
from trl_cartpole.parts.models import expected_action_values
from trl_cartpole.policy.export import (
    export_onnx,
    export_program,
    greedy_q_network,
    greedy_q_network_of,
)
from trl_cartpole.policy.load import evaluate_checkpoint, load_trained_policy
from trl_cartpole.run.from_config import build_actor
from trl_cartpole.store.checkpoint import read_observation_norm

ort = pytest.importorskip("onnxruntime")
pytest.importorskip("onnxscript")

EPISODES = 20


def _export_script(*args: str) -> None:
    """Run ``trl-cartpole export``'s ``main`` in this process (no interpreter start-up)."""
    export_command.main(list(args))


def _play_onnx(path, env_id: str, seed: int, episodes: int) -> tuple[list[float], np.ndarray]:
    """Greedy episodes of the ONNX policy: returns, and every observation ``[N, obs_dim]``.

    Episode i starts where ``scripts/evaluate.py``'s env i does: TorchRL's ``set_seed`` resets
    the vector env with ``seed`` (env i gets ``seed + i``), then the rollout resets it again.
    """
    session = ort.InferenceSession(str(path))
    returns, observations = [], []
    for i in range(episodes):
        env = gym.make(env_id)
        env.reset(seed=seed + i)
        observation, _ = env.reset()
        total, done = 0.0, False
        while not done:
            batch = observation[np.newaxis].astype(np.float32)  # [1, obs_dim]
            values = session.run(["action_values"], {"observation": batch})[0]  # [1, A]
            observations.append(batch[0])
            observation, reward, terminated, truncated, _ = env.step(int(values[0].argmax()))
            total += float(reward)
            done = terminated or truncated
        env.close()
        returns.append(total)
    return returns, np.stack(observations)


def _actor_values(
    actor, observations: torch.Tensor, exploration: ExplorationType = ExplorationType.DETERMINISTIC
) -> tuple[torch.Tensor, torch.Tensor]:
    """The TorchRL actor's values ``[N, A]`` and actions ``[N]`` for ``[N, obs_dim]``."""
    td = TensorDict({"observation": observations}, batch_size=[len(observations)])
    with torch.no_grad(), set_exploration_type(exploration):
        out = actor(td)
    action = out["action"]  # one-hot [N, A] (or an index [N])
    return expected_action_values(actor, out["action_value"]), (
        action.argmax(-1) if action.ndim == 2 else action
    )


def _onnx_values(path, observations: np.ndarray) -> torch.Tensor:
    session = ort.InferenceSession(str(path))
    return torch.from_numpy(session.run(None, {"observation": observations})[0])  # [N, A]


@pytest.fixture(scope="module")
def normalized_run(tmp_path_factory):
    """A 300-frame run with ``env.normalize_observations=true`` (its run directory)."""
    from trl_cartpole.run.training import train

    run_dir = tmp_path_factory.mktemp("normalized-run")
    overrides = ["env.normalize_observations=true", "env.normalization_frames=300"]
    train(
        compose_config(
            CONFIG_DIR,
            [*SMOKE_OVERRIDES, *overrides, f"run_dir={run_dir}", "logger.plots=false"],
        )
    )
    return run_dir


def test_onnx_policy_acts_as_the_actor_and_scores_what_evaluate_reports(smoke_checkpoint, tmp_path):
    path = tmp_path / "policy.onnx"
    _export_script(f"checkpoint={smoke_checkpoint}", f"output={path}")
    assert [p.name for p in tmp_path.iterdir()] == ["policy.onnx"]  # no temporary left
    trained = load_trained_policy(smoke_checkpoint)
    cfg = trained.cfg
    seed = cfg.seed + 2 * cfg.eval.seed_offset  # the seeds of evaluate.py's default
    returns, observations = _play_onnx(path, cfg.env.id, seed, EPISODES)

    onnx_values = _onnx_values(path, observations)  # [N, A]
    values, actions = _actor_values(trained.actor, torch.from_numpy(observations))
    assert torch.equal(onnx_values.argmax(-1), actions)  # every step's greedy action
    torch.testing.assert_close(onnx_values, values, atol=1e-4, rtol=0)

    evaluation, _ = evaluate_checkpoint(smoke_checkpoint, episodes=EPISODES)
    assert returns == evaluation.returns  # episode for episode


def test_pt2_program_gives_the_actor_values(smoke_checkpoint, tmp_path):
    path = tmp_path / "policy.pt2"
    _export_script(f"checkpoint={smoke_checkpoint}", f"output={path}")
    program = torch.export.load(str(path)).module()
    observations = torch.randn(64, 4, generator=torch.Generator().manual_seed(0))  # [64, 4]
    values, _ = _actor_values(load_trained_policy(smoke_checkpoint).actor, observations)
    torch.testing.assert_close(program(observations), values, atol=1e-5, rtol=0)
    torch.testing.assert_close(program(observations[:1]), values[:1], atol=1e-5, rtol=0)


@pytest.mark.slow  # a run, then its export
def test_observation_normalisation_is_folded_in(normalized_run, tmp_path):
    path = tmp_path / "policy.onnx"
    _export_script(f"checkpoint={normalized_run}", f"output={path}")
    trained = load_trained_policy(normalized_run)
    norm = read_observation_norm(trained.checkpoint)
    loc, scale = torch.tensor(norm["loc"]), torch.tensor(norm["scale"])  # [obs_dim]
    _, raw = _play_onnx(path, trained.cfg.env.id, seed=7, episodes=5)  # raw observations

    onnx_values = _onnx_values(path, raw)
    values, actions = _actor_values(trained.actor, (torch.from_numpy(raw) - loc) / scale)
    torch.testing.assert_close(onnx_values, values, atol=1e-4, rtol=0)
    assert torch.equal(onnx_values.argmax(-1), actions)
    unnormalised, _ = _actor_values(trained.actor, torch.from_numpy(raw))
    assert not torch.allclose(onnx_values, unnormalised, atol=1e-2)  # the statistics matter


@pytest.mark.slow  # a noisy C51 run, then its export
def test_noisy_distributional_network_exports_its_mean_expected_values(tmp_path):
    norm = {"loc": [0.1, -0.2, 0.0, 0.3], "scale": [2.0, 1.5, 0.2, 1.0]}
    env = make_env("CartPole-v1", observation_norm=norm)
    network = NetworkConfig(
        head="dueling", num_cells=[16, 16], noisy=True, distributional=True, atoms=11
    )
    torch.manual_seed(0)
    actor = build_actor(Config(network=network), env)
    module = greedy_q_network_of(actor, env)
    raw = torch.randn(32, 4, generator=torch.Generator().manual_seed(1))  # [32, 4]
    normalised = (raw - torch.tensor(norm["loc"])) / torch.tensor(norm["scale"])
    values, actions = _actor_values(actor, normalised)  # noise off, as in evaluation
    assert values.abs().max() > 1  # values of the order of the support, [0, 200]
    torch.testing.assert_close(module(raw), values, atol=1e-4, rtol=0)
    noisy_values, _ = _actor_values(actor, normalised, ExplorationType.RANDOM)  # noise on
    assert not torch.allclose(module(raw), noisy_values, atol=1e-2)

    path = export_onnx(module, module.obs_dim, tmp_path / "c51.onnx")
    onnx_values = _onnx_values(path, raw.numpy())
    torch.testing.assert_close(onnx_values, values, atol=1e-4, rtol=0)
    assert torch.equal(onnx_values.argmax(-1), actions)
    env.close()


def test_missing_onnx_packages_and_a_failed_write_leave_no_file(
    smoke_checkpoint, tmp_path, monkeypatch
):
    module = greedy_q_network(smoke_checkpoint)
    with monkeypatch.context() as patch:
        patch.setitem(sys.modules, "onnxscript", None)  # as if not installed
        with pytest.raises(ConfigError, match=re.escape('-e ".[export]" -c constraints.txt')):
            export_onnx(module, module.obs_dim, tmp_path / "policy.onnx")

    def broken_save(program, path):
        Path(path).write_bytes(b"half")  # a partial file
        raise RuntimeError("disk full")

    monkeypatch.setattr(torch.export, "save", broken_save)
    with pytest.raises(RuntimeError, match="disk full"):
        export_program(module, module.obs_dim, tmp_path / "policy.pt2")
    assert list(tmp_path.iterdir()) == []


def test_bad_suffix_exits_2_with_one_line(smoke_checkpoint, tmp_path):
    result = run_script_in_process(
        "export.py", f"checkpoint={smoke_checkpoint}", f"output={tmp_path / 'policy.txt'}"
    )
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and ".onnx" in lines[0] and ".pt2" in lines[0], result.stderr
    assert list(tmp_path.iterdir()) == []
