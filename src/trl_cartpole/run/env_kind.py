"""The kind of observation a run learns from, decided once from the config's ``env`` section.

Four kinds: the env's state vector; pixels drawn from CartPole's state
(``env.pixels_renderer=drawn``, a share of the envs painted by Gymnasium's own calls); pixels
Gymnasium renders; and an Atari game's screen (an ``ALE/...`` id, preprocessed as
``env.atari`` says: :mod:`trl_cartpole.envs.atari`). What differs between them is asked of
:class:`EnvKind`, nowhere else: the env a policy is evaluated on and the one a video records,
the run's title, whether the collector's own state is saved with a checkpoint, how many envs
one evaluation holds at once.
A new kind is one more case here.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from trl_cartpole.config.schema import EnvConfig
from trl_cartpole.envs.ids import is_atari_id

__all__ = ["KINDS", "EnvKind"]

KINDS = ("state", "drawn pixels", "rendered pixels", "atari frames")


@dataclass(frozen=True)
class EnvKind:
    """The kind of ``env``'s observation, and what follows from it."""

    env: EnvConfig

    @property
    def name(self) -> str:
        """One of :data:`KINDS`."""
        if is_atari_id(self.env.id):
            return "atari frames"
        if not self.env.from_pixels:
            return "state"
        return "drawn pixels" if self.env.pixels_renderer == "drawn" else "rendered pixels"

    @property
    def atari(self) -> bool:
        """Whether the env is an Atari game (``env.atari`` preprocesses its screen)."""
        return self.name == "atari frames"

    @property
    def pixels(self) -> bool:
        """Whether the policy sees frames (a CNN torso reads ``"pixels"``)."""
        return self.name != "state"

    @property
    def title(self) -> str:
        """The env as a run's title names it: ``CartPole-v1``, ``CartPole-v1 from pixels``,
        ``ALE/Breakout-v5`` (a game is always seen from its screen)."""
        if self.name in ("state", "atari frames"):
            return str(self.env.id)
        return f"{self.env.id} from pixels"

    @property
    def collector_state_saved(self) -> bool:
        """Whether a single-process collector's own state (its frame counter, its env's
        transforms) is saved with the run: a state env's is, and one Atari game's; a pixel
        env's (a ``SerialEnv`` or drawn frames, restarted with fresh transforms once the
        collector has closed it) is not: its frames are counted by the run, and its stacked
        frames are stored with the env's state (:mod:`trl_cartpole.store.env_state`)."""
        if self.atari:
            return self.env.num_envs == 1
        return not self.pixels

    def evaluation_env(self) -> EnvConfig:
        """The env a policy is evaluated on: a pixel policy on Gymnasium's own frames, whichever
        renderer it trained on (a drawn env with every frame painted by Gymnasium's calls: the
        same vector env, one renderer for the batch); any other env as it is."""
        if self.name == "drawn pixels":
            return replace(self.env, pixels_rendered_share=1.0)
        return self.env

    @property
    def video_scale(self) -> float:
        """A video's frame size relative to the env's render: an Atari game's 160x210 screen
        x3, a classic-control env's 600x400 picture halved."""
        return 3.0 if self.atari else 0.5

    def recorded(self) -> EnvConfig:
        """The env a video records: Gymnasium's own ``render()`` for every kind (a game's
        colour screen, for Atari)."""
        return replace(self.env, pixels_renderer="gymnasium", pixels_rendered_share=0.0)

    def envs_at_once(self, episodes: int, pixel_envs_at_once: int) -> int:
        """How many of ``episodes`` evaluation envs to build and play at a time: each Gymnasium
        renderer holds its own frames, so pixel envs come ``pixel_envs_at_once`` at a time."""
        return max(min(episodes, pixel_envs_at_once) if self.pixels else episodes, 1)
