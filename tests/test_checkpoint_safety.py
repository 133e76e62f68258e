"""No code from a checkpoint: pickles are refused before loading, env state is stored as data.

A planted pickle payload would write a marker file; ``resume=``, ``evaluate.py``,
``render.py`` and ``export.py`` must refuse the checkpoint in one line and never run it.
"""

from __future__ import annotations

import base64
import hashlib
import json
import os
import pickle
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch
from torchrl.checkpoint import Checkpoint

from trl_cartpole.compat import gym_env
from trl_cartpole.parts.env import make_env
from trl_cartpole.policy.load import evaluate_checkpoint
from trl_cartpole.store.env_state import env_snapshot, restore_env_snapshot
from trl_cartpole.store.pickle_scan import executable_opcode

from .conftest import ROOT, run_script, run_script_in_process


class _WritesAFile:
    """Unpickled, it writes ``path``: the payload an altered checkpoint would carry."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def __reduce__(self):
        return (exec, (f"open({str(self.path)!r}, 'w').write('ran')",))


def test_plain_data_pickles_pass_and_any_callable_is_named(tmp_path):
    assert executable_opcode(pickle.dumps({"a": [1, 2.5, "x", (None, True)], "b": b"\x00"})) is None
    # TorchRL's replay buffer writes this prefetch state without prefetching.
    assert executable_opcode(pickle.dumps({"version": 1, "capacity": 0, "queue": ()})) is None
    assert executable_opcode(pickle.dumps(_WritesAFile(tmp_path / "x"))) == "builtins.exec"
    assert executable_opcode(pickle.dumps(os.system, protocol=0)) == "posix.system"
    assert executable_opcode(pickle.dumps(torch.zeros(2))).startswith("torch.")
    assert executable_opcode(b"\x80\x04not a pickle").startswith("an unparsable pickle")
    assert not (tmp_path / "x").exists()  # scanning never runs anything


def _rewrite_integrity(checkpoint: Path) -> None:
    """Record the altered files as whoever altered them would (the integrity check passes)."""
    digests = {
        str(f.relative_to(checkpoint)): hashlib.sha256(f.read_bytes()).hexdigest()
        for f in sorted(checkpoint.rglob("*"))
        if f.is_file() and f.name != "integrity.json"
    }
    (checkpoint / "integrity.json").write_text(json.dumps(digests))


def _plant_in_policy(checkpoint: Path, payload: bytes) -> None:
    """A non-tensor leaf whose ``other.pickle`` tensordict 0.14 unpickles (with a warning)."""
    state = next(checkpoint.glob("components/*-policy/state"))
    leaf = state / "note"
    leaf.mkdir()
    (leaf / "meta.json").write_text(
        json.dumps(
            {
                "_type": "<class 'tensordict.tensorclass.NonTensorData'>",
                "_is_non_tensor": True,
                "_metadata": None,
            }
        )
    )
    (leaf / "other.pickle").write_bytes(pickle.dumps({"data": payload}))
    meta = json.loads((state / "meta.json").read_text())
    meta["note"] = {"type": "NonTensorData"}
    (state / "meta.json").write_text(json.dumps(meta))
    _rewrite_integrity(checkpoint)


def _plant_env_pickle(checkpoint: Path, payload: bytes) -> None:
    """The training env's state replaced by a pickled snapshot (``{"pickle": bytes}``)."""
    schema_file = next(checkpoint.glob("components/*-envs/state.json"))
    schema = json.loads(schema_file.read_text())
    for key, value in schema["items"]:
        if key["value"] == "env":
            value.clear()
            pickled = {"kind": "bytes", "value": base64.b64encode(payload).decode("ascii")}
            value.update(kind="dict", items=[[{"kind": "value", "value": "pickle"}, pickled]])
    schema_file.write_text(json.dumps(schema))
    _rewrite_integrity(checkpoint)


@pytest.fixture
def planted(tmp_path, smoke_checkpoint):
    """A copy of a finished run, and the file its payloads would write."""
    run_dir = tmp_path / "run"
    shutil.copytree(smoke_checkpoint.parent.parent, run_dir)
    return run_dir, tmp_path / "payload-ran"


def test_a_policy_saved_on_a_gpu_plays_on_a_machine_without_one(planted):
    """A GPU run's policy records its tensors as ``cuda:0``; ``evaluate`` (as ``render`` and
    ``export``) reads them onto the CPU actor it builds. Loaded where they were saved, they
    raised "Torch not compiled with CUDA enabled" on a CPU-only torch."""
    run_dir, _ = planted
    best = run_dir / "checkpoints" / "best"
    (component,) = (best / "components").glob("*-policy")
    for record in (component / "state.json", component / "state" / "meta.json"):
        text = record.read_text()
        assert '"device":"cpu"' in text  # what is rewritten below
        record.write_text(text.replace('"device":"cpu"', '"device":"cuda:0"'))
    _rewrite_integrity(best)
    result, loaded = evaluate_checkpoint(best, episodes=2)
    assert loaded["device"] == "cpu" and len(result.returns) == 2


@pytest.mark.parametrize("script", ["evaluate.py", "render.py", "export.py"])
def test_a_policy_checkpoint_with_a_pickle_payload_is_refused_unrun(planted, script):
    run_dir, marker = planted
    payload = _WritesAFile(marker)
    _plant_in_policy(run_dir / "checkpoints" / "best", payload)
    output = run_dir / ("policy.pt2" if script == "export.py" else "agent.gif")
    proc = run_script_in_process(script, f"checkpoint={run_dir}", f"output={output}")
    errors = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert proc.returncode == 2 and len(errors) == 1, proc.stderr[-1500:]
    assert "other.pickle would run code (builtins.exec)" in errors[0]
    assert not marker.exists() and not output.exists()


def test_a_training_state_with_a_pickle_payload_is_refused_unrun(planted):
    run_dir, marker = planted
    last = run_dir / "checkpoints" / "last"
    # TorchRL's replay buffer unpickles prefetch.pkl when it loads.
    prefetch = next(last.glob("components/*-replay_buffer/prefetch.pkl"))
    prefetch.write_bytes(pickle.dumps(_WritesAFile(marker)))
    _rewrite_integrity(last)
    proc = run_script_in_process("train.py", f"resume={run_dir}", "collector.total_frames=400")
    errors = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert proc.returncode == 2 and len(errors) == 1, proc.stderr[-1500:]
    assert "prefetch.pkl would run code (builtins.exec)" in errors[0]
    assert not marker.exists()


def _archive_with_payload(path: Path, payload: bytes) -> None:
    """A tensordict archive whose non-tensor leaf's ``other.pickle`` is ``payload``.

    (Built from a harmless leaf, then the pickle swapped: the payload object itself would run
    when copied, so it never exists here as an object.)
    """
    from tensordict import NonTensorData, TensorDict

    TensorDict({"note": NonTensorData(b"harmless")}, batch_size=[]).save(path, archive=True)
    with zipfile.ZipFile(path) as archive:
        members = {info.filename: archive.read(info) for info in archive.infolist()}
    swapped = [name for name in members if name.endswith("other.pickle")]
    assert swapped, sorted(members)
    with zipfile.ZipFile(path, "w") as archive:
        for name, data in members.items():
            archive.writestr(name, payload if name in swapped else data)


def test_a_zip_archive_or_a_symbolic_link_in_a_checkpoint_is_refused_unrun(planted, tmp_path):
    from trl_cartpole.errors import ConfigError
    from trl_cartpole.store.checkpoint import load_policy

    run_dir, marker = planted
    best = run_dir / "checkpoints" / "best"
    component = next(best.glob("components/*-policy"))
    # tensordict's archive format: the adapter loads state.tdz when state/ is absent, and
    # unpickles the non-tensor leaf inside it.
    shutil.move(component / "state", tmp_path / "state-moved")
    _archive_with_payload(component / "state.tdz", pickle.dumps({"data": _WritesAFile(marker)}))
    _rewrite_integrity(best)
    proc = run_script_in_process("evaluate.py", f"checkpoint={run_dir}", "episodes=2")
    errors = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert proc.returncode == 2 and len(errors) == 1, proc.stderr[-1500:]
    assert "state.tdz would run code (a zip archive" in errors[0]
    # A symbolic link a loader would follow out of the checkpoint.
    (component / "state.tdz").unlink()
    (component / "state").symlink_to(tmp_path / "state-moved", target_is_directory=True)
    _rewrite_integrity(best)
    with pytest.raises(ConfigError, match="would run code \\(a symbolic link to"):
        load_policy(best, None)
    assert not marker.exists()


def test_unpickling_during_a_load_is_refused_whatever_path_led_there(tmp_path):
    from tensordict import NonTensorData, TensorDict, load

    from trl_cartpole.errors import ConfigError
    from trl_cartpole.store.pickle_scan import no_unpickling

    marker = tmp_path / "payload-ran"
    TensorDict({"note": NonTensorData(b"harmless")}, batch_size=[]).memmap(
        tmp_path / "td"
    )  # pickled
    (tmp_path / "td" / "note" / "other.pickle").write_bytes(
        pickle.dumps({"data": _WritesAFile(marker)})
    )
    with (
        pytest.raises(ConfigError, match="a pickle tensordict was about to load"),
        no_unpickling(tmp_path / "td"),
    ):
        load(tmp_path / "td")
    assert not marker.exists()


@pytest.mark.slow  # a run resumed twice
def test_pickled_env_state_is_not_loaded_unless_the_resuming_command_trusts_it(planted):
    run_dir, marker = planted
    last = run_dir / "checkpoints" / "last"
    _plant_env_pickle(last, pickle.dumps(_WritesAFile(marker)))
    # The checkpoint's own config saying it trusts pickles is ignored.
    manifest = json.loads((last / "manifest.json").read_text())
    manifest["metadata"]["config"]["checkpoint"]["trust_pickled_envs"] = True
    (last / "manifest.json").write_text(json.dumps(manifest))
    _rewrite_integrity(last)
    args = (f"resume={run_dir}", "collector.total_frames=400")
    proc = run_script("train.py", *args, "logger.plots=false")
    assert proc.returncode == 0, proc.stderr[-1500:]
    assert not marker.exists()  # reset instead: new episodes
    assert json.loads((run_dir / "summary.json").read_text())["frames"] == 400
    assert "pass checkpoint.trust_pickled_envs=true to load it" in proc.stderr


def _walk(value):
    yield value
    if isinstance(value, dict):
        for item in value.values():
            yield from _walk(item)
    elif isinstance(value, (list, tuple)):
        for item in value:
            yield from _walk(item)


class _Holder:
    """A checkpoint component around one env's snapshot."""

    def __init__(self, env) -> None:
        self.env = env

    def state_dict(self):
        return env_snapshot(self.env)

    def load_state_dict(self, state):
        assert restore_env_snapshot(self.env, state)


def _steps(gymnasium_env, actions) -> list:
    """Step through ``actions``; a single env is reset at its episode's end (the vector env
    resets itself), its start state drawn from its RNG."""
    out = []
    for action in actions:
        obs, reward, terminated, truncated, _ = gymnasium_env.step(action)
        out.append((obs, reward, terminated, truncated))
        if np.ndim(terminated) == 0 and (terminated or truncated):
            out.append((gymnasium_env.reset()[0],))
    return out


@pytest.mark.parametrize("num_envs", [1, 3])
@pytest.mark.parametrize("env_id", ["CartPole-v1", "Acrobot-v1", "MountainCar-v0"])
def test_a_classic_control_env_continues_exactly_from_its_stored_data(tmp_path, env_id, num_envs):
    env = make_env(env_id, seed=0, num_envs=num_envs)
    g = gym_env(env)
    g.reset(seed=0)
    n = g.action_space.n if num_envs == 1 else g.single_action_space.n
    rng = np.random.default_rng(0)
    shape = () if num_envs == 1 else (num_envs,)
    _steps(g, [rng.integers(n, size=shape) for _ in range(37)])
    snapshot = env_snapshot(env)
    assert not any(isinstance(v, (bytes, bytearray)) for v in _walk(snapshot))  # no pickle
    Checkpoint(envs=_Holder(env)).save(tmp_path / "ck")

    other = make_env(env_id, seed=123, num_envs=num_envs)  # another seed, another episode
    gym_env(other).reset(seed=123)
    Checkpoint(envs=_Holder(other)).load(tmp_path / "ck")
    # 200 steps cross episode ends (CartPole's), so resets draw from the restored RNG too.
    actions = [rng.integers(n, size=shape) for _ in range(200)]
    expected, resumed = _steps(g, actions), _steps(gym_env(other), actions)
    for a, b in zip(expected, resumed, strict=True):
        for x, y in zip(a, b, strict=True):
            np.testing.assert_array_equal(x, y)


def test_an_env_that_is_not_data_is_replayed_or_else_pickled_only_when_trusted(monkeypatch):
    from trl_cartpole.envs import episode_log

    monkeypatch.syspath_prepend(str(ROOT / "examples"))
    env = make_env("corridor:Corridor", seed=0)
    assert set(env_snapshot(env)) == {"replay"}  # its episode under way, to play again
    monkeypatch.setattr(episode_log, "MAX_LOGGED_STEPS", 0)
    env.rand_step(env.reset())  # an episode longer than its log holds: none to play again
    assert env_snapshot(env) is None  # reset on resume
    snapshot = env_snapshot(env, trust_pickle=True)
    assert set(snapshot) == {"pickle"}
    assert not restore_env_snapshot(make_env("corridor:Corridor"), snapshot)
    assert restore_env_snapshot(make_env("corridor:Corridor"), snapshot, trust_pickle=True)
