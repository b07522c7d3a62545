"""What the classical policies share: SB3's ``predict`` over one observation or a batch.

Stable-baselines3 policies are called as ``predict(observation, state,
episode_start, deterministic)`` with one observation ``(n_obs,)`` or a batch
``(n_envs, n_obs)`` from a vectorised env. :class:`PerEnvPolicy` implements that
contract once for policies that keep an episode state per env index: it checks
the shape, resets the envs whose episode starts and asks :meth:`PerEnvPolicy.act`
for each row.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

__all__ = ["PerEnvPolicy", "as_batch", "episode_starts"]


def as_batch(observation: npt.ArrayLike, n_obs: int, what: str) -> tuple[FloatArray, bool]:
    """``(batch (n, n_obs), was_single)``; a ``ValueError`` naming ``what`` on a wrong shape
    or a non-finite value."""
    obs = np.asarray(observation, dtype=np.float64)
    single = obs.ndim == 1
    batch = obs[None] if single else obs
    if batch.ndim != 2 or batch.shape[1] != n_obs:
        raise ValueError(
            f"observation must have shape ({n_obs},) or (n_envs, {n_obs}) ({what}), got {obs.shape}"
        )
    if not np.all(np.isfinite(batch)):
        raise ValueError(f"observation must be finite ({what})")
    return batch, single


def episode_starts(episode_start: npt.ArrayLike | None, n: int) -> npt.NDArray[np.bool_]:
    """SB3's ``episode_start`` as a boolean array of ``n`` (none: no env starts)."""
    if episode_start is None:
        return np.zeros(n, dtype=bool)
    s = np.asarray(episode_start, dtype=bool).reshape(-1)
    return np.broadcast_to(s, (n,)) if s.size == 1 else s


class PerEnvPolicy:
    """SB3-style ``predict`` for policies with one episode state per env index.

    Subclasses set :attr:`n_obs`, :attr:`n_act` and :attr:`obs_what` (named in shape
    errors) and implement :meth:`act` and :meth:`reset`.
    """

    n_obs: int = 0
    n_act: int = 2
    obs_what: str = ""

    def act(self, env_index: int, observation: FloatArray) -> npt.ArrayLike:
        """The action for one observation row of env ``env_index``."""
        raise NotImplementedError

    def reset(self, env_index: int | None = None) -> None:
        """Forget the episode state of one env (or of all)."""
        raise NotImplementedError

    def predict(
        self,
        observation: npt.ArrayLike,
        state: Any = None,
        episode_start: npt.ArrayLike | None = None,
        deterministic: bool = True,
    ) -> tuple[npt.NDArray[np.float32], Any]:
        """Actions for one observation ``(n_obs,)`` or a batch ``(n_envs, n_obs)``."""
        batch, single = as_batch(observation, self.n_obs, self.obs_what)
        starts = episode_starts(episode_start, len(batch))
        actions = np.zeros((len(batch), self.n_act), dtype=np.float32)
        for i, row in enumerate(batch):
            if starts[i]:
                self.reset(i)
            actions[i] = self.act(i, row)
        return (actions[0] if single else actions), state
