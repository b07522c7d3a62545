"""Pose-selection policies for ``realitygap/ArmCalib-v0``.

Both follow stable-baselines3's ``predict(obs, state=None, episode_start=None,
deterministic=True) -> (action, state)``, so the benchmark harness scores them
like a trained model.

:class:`ObservabilityGreedyPolicy`
    Picks, from a pool of candidate configurations the nominal model expects to
    see the board from, the one whose pairs with the poses measured so far make
    the identification best conditioned. With the distance residual of pair
    :math:`(i, j)`, :math:`e_{ij} = \\|p_j - p_i\\| - \\|\\delta_{ij}\\|`, its Jacobian row is

    .. math::

        r_{ij} = u_{ij}^\\top \\left(J(q_j) - J(q_i)\\right) D^{-1}, \\qquad
        u_{ij} = \\frac{p_j - p_i}{\\|p_j - p_i\\|},

    with :math:`J` the position Jacobian of the camera point with respect to the
    identifiable parameters (:func:`~realitygap.estimators.arm.mdh.jacobian_params`,
    nominal model) and :math:`D` a fixed column scaling (each column's RMS over
    pairs of the pool). The information of a pose set is
    :math:`M = \\sum r_{ij} r_{ij}^\\top`; a candidate ``c`` adds its pairs with
    every measured pose. The criterion is either the smallest singular value
    :math:`\\sigma_{\\min} = \\sqrt{\\lambda_{\\min}(M)}` (default) or the O1 index
    (Borm & Menq), the geometric mean of the singular values, through
    :math:`\\log\\det(M + \\varepsilon I)`; while :math:`M` is still rank deficient
    (fewer pairs than parameters) the smallest-singular-value criterion uses the
    O1 index too. The policy learns which of its picks were measured from the
    observation's last-outcome flags.

:class:`RandomPosePolicy`
    Uniform random configurations, either in the whole action box or drawn
    without replacement from the same candidate pool (the fair comparison of
    *selection*: equal budget of poses that can be measured).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import Enum
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.baselines.common import as_batch, episode_starts
from realitygap.estimators.arm.identification import IdentificationSettings, identify
from realitygap.estimators.arm.mdh import MDHTable, jacobian_params, tool_positions
from realitygap.estimators.arm.residuals import PairObservations, ResidualMode

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "GreedyConfig",
    "ObservabilityGreedyPolicy",
    "PairObservability",
    "RandomPosePolicy",
    "SelectionCriterion",
    "identifiable_parameters",
]

#: Index of the "last attempt gave a measurement" flag in the ArmCalib-v0 observation.
OBS_LAST_OK = 78
#: Index of "attempts left / budget".
OBS_ATTEMPTS_LEFT = 69
N_OBS = 83


class SelectionCriterion(str, Enum):
    """What the greedy policy maximises."""

    MIN_SINGULAR_VALUE = "min_singular_value"
    O1 = "o1"


def identifiable_parameters(
    table: MDHTable,
    tool: npt.ArrayLike,
    q: npt.ArrayLike,
    settings: IdentificationSettings | None = None,
) -> tuple[str, ...]:
    """Parameters the distance identification estimates from poses ``q`` (N, 6).

    Runs the identification's own identifiability analysis on exact data of the
    nominal model, so the set (and its order) is exactly what :func:`identify`
    would free.
    """
    qa = np.asarray(q, dtype=float)
    t = np.asarray(tool, dtype=float).reshape(3)
    s = settings or IdentificationSettings(mode=ResidualMode.DISTANCE)
    pos = tool_positions(table, qa, t)
    res = identify(table, PairObservations.from_positions(qa, pos), tool=t, settings=s)
    return res.free_params


def _pair_rows(p: FloatArray, J: FloatArray, i: npt.ArrayLike, j: npt.ArrayLike) -> FloatArray:
    ia, ja = np.asarray(i), np.asarray(j)
    d = p[ja] - p[ia]
    u = d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-12)
    return np.einsum("...k,...kp->...p", u, J[ja] - J[ia])


class PairObservability:
    """Distance-residual Jacobian rows of pose pairs for a pool of configurations.

    Parameters
    ----------
    table : MDHTable
        Linearisation point (the nominal geometry).
    tool : array_like, shape (3,)
        Camera point in the flange frame (m).
    pool_q : array_like, shape (n, 6)
        Candidate joint readings (rad).
    names : sequence of str
        Parameters (as :func:`identifiable_parameters` returns them).
    """

    def __init__(
        self,
        table: MDHTable,
        tool: npt.ArrayLike,
        pool_q: npt.ArrayLike,
        names: Sequence[str],
    ):
        self.q = np.asarray(pool_q, dtype=float)
        if self.q.ndim != 2 or self.q.shape[0] < 2:
            raise ValueError(f"pool_q must have shape (n >= 2, n_joints), got {self.q.shape}")
        self.names = tuple(names)
        t = np.asarray(tool, dtype=float).reshape(3)
        self.J = jacobian_params(table, self.q, self.names, tool=t)  # (n, 3, p)
        self.p = tool_positions(table, self.q, t)  # (n, 3)
        i, j = np.triu_indices(len(self.q), k=1)
        rows = self._rows_raw(i, j)
        rms = np.sqrt(np.mean(rows**2, axis=0))
        self.scale = np.where(rms > 0, rms, 1.0)

        self._table = table
        self._tool = t

    @classmethod
    def from_env(
        cls, env: Any, pool_size: int, pool_seed: int = 7, analysis_poses: int = 60
    ) -> PairObservability:
        """The observability of an ``ArmCalib-v0`` env's candidate pool (``pool_size`` poses
        drawn with ``pool_seed``), linearised at the nominal model, over the parameters the
        identification frees for the first ``analysis_poses`` of them."""
        e = env.unwrapped
        pool = e.candidate_pool(pool_size, pool_seed)
        table = e.nominal_params.mdh
        names = identifiable_parameters(table, e.tool0, pool[:analysis_poses], e.estimator.settings)
        return cls(table, e.tool0, pool, names)

    @property
    def n_params(self) -> int:
        return len(self.names)

    def _rows_raw(self, i: npt.ArrayLike, j: npt.ArrayLike) -> FloatArray:
        return _pair_rows(self.p, self.J, i, j)

    def singular_values_of(self, q: npt.ArrayLike) -> FloatArray:
        """Singular values (p,) of the scaled pair Jacobian of arbitrary poses ``q`` (N, 6),
        all pairs, same column scaling as the pool; descending."""
        qa = np.asarray(q, dtype=float)
        if qa.ndim != 2 or qa.shape[0] < 2:
            return np.zeros(self.n_params)
        J = jacobian_params(self._table, qa, self.names, tool=self._tool)
        p = tool_positions(self._table, qa, self._tool)
        i, j = np.triu_indices(len(qa), k=1)
        R = _pair_rows(p, J, i, j) / self.scale
        lam = np.linalg.eigvalsh(R.T @ R)[::-1]
        return np.sqrt(np.maximum(lam, 0.0))

    def rows(self, i: npt.ArrayLike, j: npt.ArrayLike) -> FloatArray:
        """Scaled Jacobian rows (..., p) of pairs ``(i, j)`` (pool indices, broadcast)."""
        return self._rows_raw(i, j) / self.scale

    def information(self, idx: Sequence[int]) -> FloatArray:
        """:math:`M = \\sum_{i<j} r_{ij} r_{ij}^\\top` (p, p) of pool poses ``idx``."""
        ix = np.asarray(list(idx), dtype=int)
        if ix.size < 2:
            return np.zeros((self.n_params, self.n_params))
        a, b = np.triu_indices(ix.size, k=1)
        R = self.rows(ix[a], ix[b])
        return R.T @ R

    def singular_values(self, idx: Sequence[int]) -> FloatArray:
        """Singular values (p,) of the scaled pair Jacobian of pool poses ``idx``, descending."""
        lam = np.linalg.eigvalsh(self.information(idx))[::-1]
        return np.sqrt(np.maximum(lam, 0.0))

    def gains(self, used: Sequence[int], candidates: npt.ArrayLike) -> FloatArray:
        """Information added by each candidate's pairs with the poses ``used``: (m, p, p)."""
        c = np.asarray(candidates, dtype=int)
        u = np.asarray(list(used), dtype=int)
        if u.size == 0:
            return np.zeros((c.size, self.n_params, self.n_params))
        R = self.rows(c[:, None], u[None, :])  # (m, k, p)
        return np.einsum("mkp,mkq->mpq", R, R)


@dataclass(frozen=True)
class GreedyConfig:
    """Settings of :class:`ObservabilityGreedyPolicy`.

    Attributes
    ----------
    pool_size : int
        Candidate configurations (drawn by the env's ``candidate_pool``).
    pool_seed : int
        Seed of that draw.
    criterion : SelectionCriterion
    epsilon : float
        Regulariser of :math:`\\log\\det(M + \\varepsilon I)` (scaled units).
    analysis_poses : int
        Pool poses used to find the identifiable parameters.
    """

    pool_size: int = 600
    pool_seed: int = 7
    criterion: SelectionCriterion = SelectionCriterion.MIN_SINGULAR_VALUE
    epsilon: float = 1e-6
    analysis_poses: int = 60

    def __post_init__(self) -> None:
        object.__setattr__(self, "criterion", SelectionCriterion(self.criterion))
        if self.pool_size < 2:
            raise ValueError(f"pool_size must be >= 2, got {self.pool_size}")
        if not self.epsilon > 0:
            raise ValueError(f"epsilon must be positive, got {self.epsilon}")
        if self.analysis_poses < 8:
            raise ValueError(f"analysis_poses must be >= 8, got {self.analysis_poses}")


@dataclass
class _Episode:
    used: list[int] = field(default_factory=list)
    tried: set[int] = field(default_factory=set)
    pending: int | None = None


def _check_obs(observation: npt.ArrayLike) -> tuple[FloatArray, bool]:
    return as_batch(observation, N_OBS, "ArmCalib-v0")


class _PoolEpisodes:
    """Per-env campaign bookkeeping shared by the pool policies: which poses were tried and
    which were measured (the env reports in ``OBS_LAST_OK`` whether the last one worked)."""

    _episodes: dict[int, _Episode]

    def _episode(self, k: int, start: bool, row: FloatArray) -> _Episode:
        """Env ``k``'s episode, new at a start or a full attempt budget; the pending pose
        counts as measured when the env accepted it."""
        if start or row[OBS_ATTEMPTS_LEFT] >= 1.0 - 1e-6 or k not in self._episodes:
            self._episodes[k] = _Episode()
        ep = self._episodes[k]
        if ep.pending is not None and row[OBS_LAST_OK] > 0.5:
            ep.used.append(ep.pending)
        return ep

    def chosen(self, env_index: int = 0) -> tuple[list[int], list[int]]:
        """Pool indices measured and tried so far in the current episode of ``env_index``."""
        ep = self._episodes.get(env_index, _Episode())
        return list(ep.used), sorted(ep.tried)


class ObservabilityGreedyPolicy(_PoolEpisodes):
    """Greedy observability-maximising pose selection (see the module docstring).

    Parameters
    ----------
    pool_q : array_like, shape (n, 6)
        Candidate joint commands (rad).
    joint_center, joint_half_range : array_like, shape (6,)
        The env's action box (actions are ``(q - center) / half_range``).
    observability : PairObservability
        Jacobian rows over ``pool_q``.
    config : GreedyConfig, optional

    Use :meth:`from_env` to build all of these from an ``ArmCalib-v0`` env.
    """

    def __init__(
        self,
        pool_q: npt.ArrayLike,
        joint_center: npt.ArrayLike,
        joint_half_range: npt.ArrayLike,
        observability: PairObservability,
        config: GreedyConfig | None = None,
    ):
        self.pool_q = np.asarray(pool_q, dtype=float)
        self.center = np.asarray(joint_center, dtype=float).reshape(6)
        self.half = np.asarray(joint_half_range, dtype=float).reshape(6)
        self.obs_model = observability
        if len(self.pool_q) != len(observability.q):
            raise ValueError("observability must be built over pool_q")
        self.config = config or GreedyConfig()
        self._episodes: dict[int, _Episode] = {}
        # first pick: the candidate nearest the centre of the box
        self._first = int(
            np.argmin(np.linalg.norm((self.pool_q - self.center) / self.half, axis=1))
        )

    @classmethod
    def from_env(cls, env: Any, config: GreedyConfig | None = None) -> ObservabilityGreedyPolicy:
        """Build the pool and Jacobians from an ``ArmCalib-v0`` env (nominal model only)."""
        cfg = config or GreedyConfig()
        e = env.unwrapped
        model = PairObservability.from_env(env, cfg.pool_size, cfg.pool_seed, cfg.analysis_poses)
        return cls(model.q, e.joint_center, e.joint_half_range, model, cfg)

    # ------------------------------------------------------------------ SB3 interface
    def predict(
        self,
        observation: npt.ArrayLike,
        state: Any = None,
        episode_start: npt.ArrayLike | None = None,
        deterministic: bool = True,
    ) -> tuple[npt.NDArray[np.float32], Any]:
        """Next pose as a normalised action, for one observation (83,) or a batch (n, 83)."""
        batch, single = _check_obs(observation)
        starts = episode_starts(episode_start, len(batch))
        actions = np.zeros((len(batch), 6), dtype=np.float32)
        for k, row in enumerate(batch):
            ep = self._episode(k, bool(starts[k]), row)
            ep.pending = self.select(ep.used, ep.tried)
            ep.tried.add(ep.pending)
            actions[k] = self.action_for(ep.pending)
        return (actions[0] if single else actions), state

    def reset(self) -> None:
        """Forget every episode."""
        self._episodes.clear()

    def action_for(self, index: int) -> npt.NDArray[np.float32]:
        """Normalised action of pool pose ``index``."""
        return ((self.pool_q[index] - self.center) / self.half).astype(np.float32)

    # ------------------------------------------------------------------ selection
    def select(self, used: Sequence[int], tried: set[int] | None = None) -> int:
        """The best untried pool index given the measured poses ``used``."""
        tried = tried or set()
        cand = np.array([i for i in range(len(self.pool_q)) if i not in tried], dtype=int)
        if cand.size == 0:
            raise RuntimeError("every candidate of the pool has been tried; enlarge pool_size")
        if not used:
            return self._first if self._first not in tried else int(cand[0])
        M = self.obs_model.information(used)
        Mc = M[None] + self.obs_model.gains(used, cand)
        p = M.shape[0]
        eps = self.config.epsilon * np.eye(p)
        lam = np.linalg.eigvalsh(Mc)  # ascending, (m, p)
        logdet = np.sum(np.log(np.maximum(np.linalg.eigvalsh(Mc + eps), 1e-300)), axis=1)
        if self.config.criterion is SelectionCriterion.O1:
            return int(cand[int(np.argmax(logdet))])
        full = lam[:, 0] > 1e-9 * np.maximum(lam[:, -1], 1e-300)
        if np.any(full):
            score = np.where(full, lam[:, 0], -np.inf)
            return int(cand[int(np.argmax(score))])
        return int(cand[int(np.argmax(logdet))])


class RandomPosePolicy(_PoolEpisodes):
    """Random pose selection, the comparison baseline.

    Parameters
    ----------
    seed : int
        Seed of the policy's own generator.
    pool_q : array_like, shape (n, 6), optional
        Draw from these commands without replacement (needs ``joint_center`` and
        ``joint_half_range``); otherwise uniform actions in the whole box.
    joint_center, joint_half_range : array_like, shape (6,), optional
    """

    def __init__(
        self,
        seed: int = 0,
        pool_q: npt.ArrayLike | None = None,
        joint_center: npt.ArrayLike | None = None,
        joint_half_range: npt.ArrayLike | None = None,
    ):
        self.seed = int(seed)
        self.rng = np.random.default_rng(self.seed)
        self.pool_q = None if pool_q is None else np.asarray(pool_q, dtype=float)
        if self.pool_q is not None:
            if joint_center is None or joint_half_range is None:
                raise ValueError("a pool needs joint_center and joint_half_range to form actions")
            self.center = np.asarray(joint_center, dtype=float).reshape(6)
            self.half = np.asarray(joint_half_range, dtype=float).reshape(6)
        self._episodes: dict[int, _Episode] = {}

    @classmethod
    def from_env(
        cls, env: Any, seed: int = 0, pool_size: int | None = 600, pool_seed: int = 7
    ) -> RandomPosePolicy:
        """Random picks from the env's candidate pool (``pool_size=None``: whole box)."""
        e = env.unwrapped
        if pool_size is None:
            return cls(seed)
        return cls(seed, e.candidate_pool(pool_size, pool_seed), e.joint_center, e.joint_half_range)

    def predict(
        self,
        observation: npt.ArrayLike,
        state: Any = None,
        episode_start: npt.ArrayLike | None = None,
        deterministic: bool = True,
    ) -> tuple[npt.NDArray[np.float32], Any]:
        """A random pose (``deterministic`` does not apply: the draws come from ``seed``)."""
        batch, single = _check_obs(observation)
        starts = episode_starts(episode_start, len(batch))
        actions = np.zeros((len(batch), 6), dtype=np.float32)
        for k, row in enumerate(batch):
            ep = self._episode(k, bool(starts[k]), row)
            if self.pool_q is None:
                ep.pending = None
                actions[k] = self.rng.uniform(-1.0, 1.0, 6).astype(np.float32)
                continue
            free = [i for i in range(len(self.pool_q)) if i not in ep.tried]
            if not free:
                raise RuntimeError("every candidate of the pool has been tried; enlarge the pool")
            ep.pending = int(free[int(self.rng.integers(len(free)))])
            ep.tried.add(ep.pending)
            actions[k] = ((self.pool_q[ep.pending] - self.center) / self.half).astype(np.float32)
        return (actions[0] if single else actions), state

    def reset(self) -> None:
        """Forget every episode and restart the generator from ``seed``."""
        self._episodes.clear()
        self.rng = np.random.default_rng(self.seed)
