"""Gymnasium env ids and spaces: resolve an id, its solve threshold, and whether DQN fits it.

Torch-free (Gymnasium only), so a command line's env is checked before torch and TorchRL are
imported. Env ids: any id Gymnasium has registered (``CartPole-v1``), ``module:Id`` (the
module's import registers ``Id``, Gymnasium's own convention), ``module:EnvClass`` (a
``gymnasium.Env`` subclass, registered here as ``module.EnvClass``), or an id registered by a
module listed in ``env.imports``. :func:`resolve_env_id` turns each into a registered id.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym

from trl_cartpole.errors import ConfigError, install_hint

__all__ = [
    "ATARI_NAMESPACE",
    "CARTPOLE_FRAME",
    "cartpole_crop_bounds",
    "check_builtin_env_fits",
    "check_env_fits",
    "is_atari_id",
    "missing_dependency",
    "register_atari_games",
    "resolve_env_id",
    "solve_threshold",
]

# CartPoleEnv.render()'s picture: rows, columns (screen_height, screen_width in Gymnasium)
CARTPOLE_FRAME = (400, 600)

# Gymnasium env families whose dependencies come with an extra of this project (pyproject.toml).
OPTIONAL_EXTRAS = {"gymnasium.envs.box2d": "box2d", "ale_py": "atari"}
# The namespace of the Atari games ale-py registers (ALE/Breakout-v5, ALE/Pong-v5...)
ATARI_NAMESPACE = "ALE/"


def is_atari_id(env_id: str) -> bool:
    """Whether ``env_id`` names an Atari game of ALE's: ``ALE/<Game>-v5``, or an id whose
    registered entry point is ale-py's (its ``Breakout-v4`` family, once ale-py has registered
    it: ``env.imports=[ale_py]``)."""
    if str(env_id).startswith(ATARI_NAMESPACE):
        return True
    spec = gym.registry.get(str(env_id))
    return spec is not None and str(spec.entry_point).startswith("ale_py")


def register_atari_games() -> None:
    """Register ale-py's games with Gymnasium (``gym.register_envs(ale_py)``: its wheel holds
    the ROMs) and keep ALE's C++ banner off the console.

    :raises ConfigError: when ale-py is not installed, naming the extra that brings it.
    """
    try:
        ale_py = importlib.import_module("ale_py")
    except ImportError:
        raise ConfigError(
            "Atari games need the atari extra (ale-py and OpenCV), which is not installed; "
            f"install it with {install_hint('atari')}"
        ) from None
    ale_py.ALEInterface.setLoggerMode(ale_py.LoggerMode.Error)
    gym.register_envs(ale_py)


def _import_module(name: str, field: str) -> Any:
    """Import ``name``; a module in the folder the command runs from is found too (as with
    ``python -m``), where a script's own folder, not that one, starts ``sys.path``."""
    top = name.split(".")[0]
    here = Path.cwd()
    if str(here) not in sys.path and ((here / f"{top}.py").is_file() or (here / top).is_dir()):
        sys.path.append(str(here))  # after every installed package: it shadows none
    try:
        return importlib.import_module(name)
    except ImportError as error:
        raise ConfigError(
            f"{field}: cannot import module {name!r} ({error}); install the package that "
            "provides it or add its folder to PYTHONPATH"
        ) from None


def resolve_env_id(
    env_id: str,
    imports: Sequence[str] = (),
    field: str = "env.id",
    imports_field: str = "env.imports",
) -> str:
    """Import ``imports``, register a ``module:EnvClass`` entry point; return the registered id.

    Raises :class:`ConfigError` (one line, naming ``field``: the config's key, or a factory's
    argument) for a module that cannot be imported, an attribute that is not a
    ``gymnasium.Env`` subclass, or an id Gymnasium does not know.
    """
    for module_name in imports:
        _import_module(module_name, imports_field)
    if str(env_id).startswith(ATARI_NAMESPACE) and env_id not in gym.registry:
        register_atari_games()
    if ":" in env_id:
        module_name, name = env_id.split(":", 1)
        module = _import_module(module_name, f"{field}={env_id!r}")
        if name in gym.registry:  # registered by the import (Gymnasium's module:Id)
            env_id = name
        else:  # an env class, registered under its qualified name so two modules' classes differ
            target = getattr(module, name, None)
            if not (isinstance(target, type) and issubclass(target, gym.Env)):
                raise ConfigError(
                    f"{field}={env_id!r}: module {module_name!r} neither registers {name!r} nor "
                    "defines a gymnasium.Env subclass of that name"
                )
            qualified = f"{module_name}.{name}"
            if qualified not in gym.registry:
                gym.register(id=qualified, entry_point=env_id)
            env_id = qualified
    try:
        gym.spec(env_id)
    except gym.error.Error as error:
        raise ConfigError(
            f"{field}={env_id!r} is not a registered Gymnasium env ({error}); check the spelling "
            "and version suffix (e.g. CartPole-v1), or "
            + (
                f"name the module that registers it in {imports_field}"
                if imports_field
                else "import the module that registers it first (or write 'module:Id')"
            )
        ) from None
    return env_id


def solve_threshold(env_id: str, override: float | None = None) -> float | None:
    """The return that counts as solved: ``override`` or Gymnasium's ``reward_threshold``."""
    if override is not None:
        return float(override)
    threshold = gym.spec(resolve_env_id(env_id)).reward_threshold
    return None if threshold is None else float(threshold)


def time_limit(env_id: str, override: int | None = None) -> int | None:
    """The steps after which an episode is truncated: ``override`` or Gymnasium's registered
    ``max_episode_steps`` (None for none)."""
    if override is not None:
        return int(override)
    return gym.spec(resolve_env_id(env_id)).max_episode_steps


def missing_dependency(env_id: str, error: Exception) -> ConfigError:
    """The one-line error for an env whose package is missing, naming the extra to install."""
    entry_point = str(gym.spec(env_id).entry_point)
    extra = next(
        (e for prefix, e in OPTIONAL_EXTRAS.items() if entry_point.startswith(prefix)), None
    )
    if extra:  # the project's extra: the command to type, with the README's torch pin
        return ConfigError(
            f"env {env_id!r} needs the {extra} extra, which is not installed; install it with "
            f"{install_hint(extra)}"
        )
    reason = str(error).splitlines()[0] if str(error) else type(error).__name__
    return ConfigError(
        f"env {env_id!r} needs a package that is not installed ({reason}); install the package "
        "the message names"
    )


def check_env_fits(
    observation_space: gym.Space, action_space: gym.Space, env_id: str, pixels: bool = False
) -> None:
    """Raise :class:`ConfigError` unless the spaces are one vector and one discrete action.

    Checked on the Gymnasium spaces (of one env, ``single_*_space`` for a vector env) before
    TorchRL wraps the env, so a space TorchRL cannot batch fails here in one line too. With
    ``pixels`` (the env is rendered to frames) only the action space is checked.
    """
    spaces = gym.spaces
    if not isinstance(action_space, spaces.Discrete):
        kind = "continuous" if isinstance(action_space, spaces.Box) else "multi-part"
        raise ConfigError(
            f"env {env_id!r} has {kind} actions (a Gymnasium {type(action_space).__name__}); "
            "DQN needs one discrete action (a Gymnasium Discrete space)"
        )
    if pixels:
        return
    if isinstance(observation_space, spaces.Dict | spaces.Tuple):
        parts = (
            list(observation_space.spaces)
            if isinstance(observation_space, spaces.Dict)
            else [type(part).__name__ for part in observation_space.spaces]
        )
        raise ConfigError(
            f"env {env_id!r} has observation entries {parts} (a Gymnasium "
            f"{type(observation_space).__name__} space); DQN here needs one vector observation "
            "(a Gymnasium Box of rank 1): flatten it (gymnasium.wrappers.FlattenObservation)"
        )
    if isinstance(observation_space, spaces.Discrete | spaces.MultiDiscrete | spaces.MultiBinary):
        raise ConfigError(
            f"env {env_id!r} has a discrete observation (a state index, e.g. Taxi or FrozenLake); "
            "DQN here needs a vector observation (a Gymnasium Box of rank 1)"
        )
    shape = tuple(observation_space.shape or ())
    if len(shape) == 3 and is_atari_id(env_id):
        raise ConfigError(
            f"env {env_id!r} is an Atari game: make_atari_env({str(env_id)!r}) from "
            "trl_cartpole.envs.atari builds it with the standard preprocessing (84x84 gray, "
            f"4 frames under 'pixels'); scripts/train.py env.id={env_id} trains on it"
        )
    if len(shape) == 3:
        raise ConfigError(
            f"env {env_id!r} has image observations of shape {shape}; DQN here needs one vector "
            "observation: use the env's vector-state version or flatten it in a Gymnasium wrapper"
        )
    if len(shape) != 1 or not isinstance(observation_space, spaces.Box):
        raise ConfigError(
            f"env {env_id!r} has an observation of shape {shape}; DQN here needs a vector "
            "(rank 1): flatten it (gymnasium.wrappers.FlattenObservation) or use a vector-state env"
        )


def check_builtin_env_fits(env_id: str, pixels: bool = False) -> None:
    """:func:`check_env_fits` on one env built by Gymnasium, for the envs Gymnasium itself
    ships (``gymnasium.envs``), before torch is imported: a continuous-action env or an image
    observation is refused in about a second instead of after the heavy imports. Envs of other
    packages are left to the build (making them may cost or do more); a missing dependency is
    left to it too, where it is reported with the extra to install."""
    spec = gym.spec(env_id)
    entry = spec.entry_point if isinstance(spec.entry_point, str) else ""
    if not entry.startswith("gymnasium.envs."):
        return
    try:
        env = gym.make(env_id)
    except (ImportError, gym.error.DependencyNotInstalled):
        return
    try:
        check_env_fits(env.observation_space, env.action_space, env_id, pixels=pixels)
    finally:
        env.close()


def cartpole_crop_bounds(crop: Sequence[int | None]) -> tuple[int, int, int, int]:
    """``(top, bottom, left, right)``: ``env.pixels_crop`` read as Python slices of
    :data:`CARTPOLE_FRAME` (``None``: up to the edge), as ``CropFrame`` reads it."""
    rows, columns = CARTPOLE_FRAME
    top, bottom, _ = slice(crop[0], crop[1]).indices(rows)
    left, right, _ = slice(crop[2], crop[3]).indices(columns)
    return top, bottom, left, right
