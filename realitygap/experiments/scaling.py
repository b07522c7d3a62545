"""How the diagnosis scales, and the diagnosis on a Ray cluster: ``diagnose-scaling``,
``diagnose-ray``.

Both diagnose the ``diagnose-bench`` log (:func:`bench_log`: a 90 s PyBullet drive through
six manoeuvres with a hidden wheel-diameter ratio ``E_d = 1.008`` and measurement noise),
each log from its own seed drawn from the run's seeded generator.

* ``diagnose-scaling`` times :func:`~realitygap.diagnosis.diagnose.diagnose` against the
  total log duration (1, 4, 16, 64 logs) and against the number of candidate effects
  (2, 4, 8, the whole library on one log), and fits the exponent ``k`` of
  ``time ∝ size^k`` by least squares on log-log axes (:func:`fit_power_law`).
* ``diagnose-ray`` runs one diagnosis in this process and again on a two-node Ray cluster
  (:class:`LocalRayCluster`, or the cluster ``RAY_ADDRESS`` names), checks that the two
  agree (:func:`json_differences`) and gives the speed-up.
"""

from __future__ import annotations

import contextlib
import math
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from realitygap.experiments import RunContext, experiment

HIDDEN_EFFECT = "wheel_diameter_ratio"
"""The effect realised in every bench log."""
HIDDEN_VALUES = {"E_d": 1.008}
"""Its parameters."""
BENCH_MANOEUVRES = ("tour", "square_cw", "arcs", "turns_in_place", "straight_runs", "square_ccw")
"""The manoeuvres of a bench log, in order, repeated to fill its duration."""
BENCH_DT = 0.05
"""Sample period of a bench log, s."""

TIMING_KEYS = ("timing_s",)
"""Keys of :meth:`Diagnosis.to_json` that hold wall-clock times (never equal across runs)."""

SLOPE_LIMIT = 1.1
"""The largest duration exponent counted as linear scaling."""


# --------------------------------------------------------------------------- the bench log
def bench_noise() -> Any:
    """The measurement noise of a bench log (ground truth 0.5 mm / 1 mrad, camera 1 mm / 2 mrad)."""
    from realitygap.robots.simulation import MeasurementNoise

    return MeasurementNoise(0.0005, 0.001, 0.001, 0.002)


def bench_log(rng: np.random.Generator, seconds: float = 90.0, name: str = "bench-90s") -> Any:
    """A simulated log of the nominal differential drive with the hidden effect
    (:data:`HIDDEN_EFFECT`, :data:`HIDDEN_VALUES`) and :func:`bench_noise`.

    The commands are :data:`BENCH_MANOEUVRES` one after the other, repeated or cut to
    ``seconds``, ending at rest; the noise is drawn from ``rng``.

    Raises
    ------
    TypeError
        ``rng`` is not a :class:`numpy.random.Generator`.
    ValueError
        ``seconds`` is not a finite duration of at least 1 s.
    """
    from realitygap.diagnosis.adapters.diffdrive.manoeuvres import MANOEUVRES
    from realitygap.diagnosis.adapters.diffdrive.replay import simulate
    from realitygap.robots.diffdrive import DiffDriveParams
    from realitygap.robots.effects import Reality, make_effect

    if not isinstance(rng, np.random.Generator):
        raise TypeError(
            f"rng must be a numpy.random.Generator, got {type(rng).__name__}; "
            "fix: pass np.random.default_rng(seed)"
        )
    if isinstance(seconds, bool) or not isinstance(seconds, (int, float)):
        raise ValueError(f"seconds must be a number of seconds ≥ 1, got {seconds!r}")
    if not (math.isfinite(seconds) and seconds >= 1.0):
        raise ValueError(f"seconds must be a finite duration ≥ 1 s, got {seconds!r}")
    params = DiffDriveParams()
    parts = [MANOEUVRES[m].applied(BENCH_DT, params)[1] for m in BENCH_MANOEUVRES]
    cmd = np.concatenate(parts, axis=0)
    n = int(round(seconds / BENCH_DT)) + 1
    cmd = np.resize(cmd, (n, 2)) if cmd.shape[0] < n else cmd[:n]
    cmd[-1] = 0.0
    t = BENCH_DT * np.arange(n)
    return simulate(
        t,
        params=params,
        reality=Reality((make_effect(HIDDEN_EFFECT, **HIDDEN_VALUES),)),
        commands=cmd,
        noise=bench_noise(),
        rng=rng,
        meta={"name": name},
    )


def bench_logs(
    rng: np.random.Generator, count: int, seconds: float = 90.0, prefix: str = "bench"
) -> tuple[list[Any], list[int]]:
    """``count`` bench logs, each simulated with its own seed drawn from ``rng``.

    Returns the logs and their seeds (``bench_log(np.random.default_rng(seed))`` rebuilds
    one).
    """
    if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or count < 1:
        raise ValueError(f"count must be a positive number of logs, got {count!r}")
    seeds = [int(s) for s in rng.integers(0, 2**31 - 1, size=int(count))]
    logs = [
        bench_log(np.random.default_rng(s), seconds, name=f"{prefix}-{i:02d}")
        for i, s in enumerate(seeds)
    ]
    return logs, seeds


def candidate_sets(sizes: Iterable[int], library: Sequence[str]) -> list[tuple[str, ...]]:
    """For each size, that many effects of ``library``: :data:`HIDDEN_EFFECT` first, then
    the others in library order (so every set can name the truth).

    Raises
    ------
    ValueError
        A size below 1 or above the library's, or a library without the hidden effect.
    """
    if HIDDEN_EFFECT not in library:
        raise ValueError(
            f"the candidate library must hold {HIDDEN_EFFECT!r}, the bench logs' hidden "
            f"effect; got {', '.join(library)}"
        )
    ordered = (HIDDEN_EFFECT, *(e for e in library if e != HIDDEN_EFFECT))
    out = []
    for size in sizes:
        if isinstance(size, bool) or not isinstance(size, (int, np.integer)):
            raise ValueError(f"candidate set sizes must be integers, got {size!r}")
        if not 1 <= size <= len(ordered):
            raise ValueError(
                f"candidate set size must be between 1 and the library's {len(ordered)} "
                f"effects, got {size}"
            )
        out.append(tuple(ordered[: int(size)]))
    return out


# --------------------------------------------------------------------------- power laws
@dataclass(frozen=True)
class PowerLaw:
    """``y ≈ prefactor · x^exponent``, fitted by least squares on ``log y`` against ``log x``.

    Attributes
    ----------
    exponent : the slope on log-log axes.
    stderr : its standard error (``nan`` with two points: no residual degrees of freedom).
    prefactor : ``y`` at ``x = 1``.
    r2 : coefficient of determination on log-log axes.
    points : number of points fitted.
    """

    exponent: float
    stderr: float
    prefactor: float
    r2: float
    points: int


def fit_power_law(x: Sequence[float], y: Sequence[float], what: str = "x") -> PowerLaw:
    """The exponent of ``y ∝ x^k``: least squares of ``log y = k log x + c``.

    Raises
    ------
    ValueError
        Fewer than two points, lengths that differ, values that are not finite and
        positive, or fewer than two distinct ``x`` (``what`` names ``x`` in the message).
    """
    xs = np.asarray(x, dtype=float).ravel()
    ys = np.asarray(y, dtype=float).ravel()
    if xs.size != ys.size:
        raise ValueError(f"{what} and the times must pair up, got {xs.size} and {ys.size} values")
    if xs.size < 2:
        raise ValueError(f"a power law needs at least two points, got {xs.size}")
    for name, arr in ((what, xs), ("time", ys)):
        bad = ~(np.isfinite(arr) & (arr > 0))
        if bad.any():
            raise ValueError(
                f"every {name} must be finite and > 0 to be fitted on log axes, "
                f"got {arr[bad].tolist()}"
            )
    lx, ly = np.log(xs), np.log(ys)
    sxx = float(np.sum((lx - lx.mean()) ** 2))
    if sxx <= 0.0:
        raise ValueError(
            f"a power law needs at least two distinct values of {what}, got {xs.tolist()}"
        )
    k = float(np.sum((lx - lx.mean()) * (ly - ly.mean())) / sxx)
    c = float(ly.mean() - k * lx.mean())
    resid = ly - (k * lx + c)
    ss_res = float(np.sum(resid**2))
    ss_tot = float(np.sum((ly - ly.mean()) ** 2))
    dof = xs.size - 2
    stderr = math.sqrt(ss_res / dof / sxx) if dof > 0 else math.nan
    r2 = 1.0 - ss_res / ss_tot if ss_tot > 0 else 1.0
    return PowerLaw(k, stderr, math.exp(c), r2, int(xs.size))


# --------------------------------------------------------------------------- comparing results
def strip_timing(js: Mapping[str, Any], keys: Iterable[str] = TIMING_KEYS) -> dict[str, Any]:
    """``js`` without its wall-clock entries (:data:`TIMING_KEYS`)."""
    drop = set(keys)
    return {k: v for k, v in js.items() if k not in drop}


def json_differences(
    a: Any, b: Any, tol: float = 1e-9, path: str = "$", limit: int = 50
) -> list[str]:
    """Where two JSON-like values differ: one line per difference (at most ``limit``).

    Numbers are equal within ``tol`` (relative or absolute, :func:`math.isclose`), ``nan``
    equals ``nan``; strings, booleans and ``None`` must be equal; dicts need the same keys,
    lists the same length. NumPy scalars and arrays count as their Python values.
    """
    out: list[str] = []
    _diff(a, b, tol, path, out, limit)
    return out


def _plain(v: Any) -> Any:
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, np.generic):
        return v.item()
    return v


def _diff(a: Any, b: Any, tol: float, path: str, out: list[str], limit: int) -> None:
    if len(out) >= limit:
        return
    a, b = _plain(a), _plain(b)
    numbers = (int, float)
    if isinstance(a, numbers) and isinstance(b, numbers) and not isinstance(a, bool):
        if isinstance(b, bool):
            out.append(f"{path}: {a!r} != {b!r}")
        elif not (
            (math.isnan(a) and math.isnan(b))
            or a == b
            or math.isclose(a, b, rel_tol=tol, abs_tol=tol)
        ):
            out.append(f"{path}: {a!r} != {b!r} (differ by {abs(a - b):.3g})")
        return
    if isinstance(a, Mapping) and isinstance(b, Mapping):
        for k in sorted(set(a) | set(b), key=str):
            if k not in a or k not in b:
                out.append(f"{path}.{k}: only in the {'second' if k in b else 'first'}")
            else:
                _diff(a[k], b[k], tol, f"{path}.{k}", out, limit)
            if len(out) >= limit:
                return
        return
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        if len(a) != len(b):
            out.append(f"{path}: lengths {len(a)} != {len(b)}")
            return
        for i, (u, v) in enumerate(zip(a, b)):
            _diff(u, v, tol, f"{path}[{i}]", out, limit)
        return
    if type(a) is not type(b) or a != b:
        out.append(f"{path}: {a!r} != {b!r}")


# --------------------------------------------------------------------------- a local Ray cluster
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _tail(path: Path, lines: int = 15) -> str:
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError:
        return "(no output)"
    return "\n".join(text.strip().splitlines()[-lines:]) or "(no output)"


class LocalRayCluster:
    """A Ray cluster of ``nodes`` nodes on this machine, each a ``ray start --block`` process.

    ``with LocalRayCluster() as cluster:`` starts the head (``--port`` a free port,
    ``--temp-dir`` a new temporary folder), then the other nodes, connects this process
    (``ray.init(cluster.address)``) and waits until every node is alive. Leaving the block
    disconnects, stops each node by sending its ``ray start`` process SIGTERM (it stops its
    own Ray processes; ``ray stop`` would stop every Ray process of the machine, other
    clusters' too), and removes the temporary folder.

    The nodes take this process's token authentication mode: a process that names a
    cluster's address connects without a token unless ``RAY_AUTH_MODE=token``, so by default
    the cluster runs without one (anyone who reaches its ports may submit work while it
    runs); with ``RAY_AUTH_MODE=token`` set, nodes and this process share Ray's token.

    Parameters
    ----------
    nodes : int
        Number of nodes (≥ 2 for a cluster of more than the head).
    cpus_per_node : int
        CPUs each node offers to tasks.
    object_store_mb : int
        Object store of each node, MB.
    timeout_s : float
        How long to wait for the nodes to come up before giving up.

    Raises
    ------
    ImportError
        Ray is not installed (with the fix).
    RuntimeError
        This process is already connected to Ray, or a node fails to start (with its
        output).
    """

    def __init__(
        self,
        nodes: int = 2,
        cpus_per_node: int = 1,
        object_store_mb: int = 200,
        timeout_s: float = 120.0,
    ):
        sizes = {"nodes": nodes, "cpus_per_node": cpus_per_node, "object_store_mb": object_store_mb}
        for name, value in sizes.items():
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        if not (isinstance(timeout_s, (int, float)) and timeout_s > 0):
            raise ValueError(f"timeout_s must be a positive number of seconds, got {timeout_s!r}")
        self.nodes = nodes
        self.cpus_per_node = cpus_per_node
        self.object_store_mb = object_store_mb
        self.timeout_s = float(timeout_s)
        self.address = ""
        """``host:port`` of the head's GCS, once started."""
        self.temp_dir: Path | None = None
        self._procs: list[subprocess.Popen[bytes]] = []
        self._outputs: list[Path] = []
        self._connected = False

    def __enter__(self) -> LocalRayCluster:
        try:
            self.start()
        except BaseException:
            self.stop()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def pids(self) -> list[int]:
        """Process ids of the nodes' ``ray start`` processes."""
        return [p.pid for p in self._procs]

    def _spawn(self, args: list[str], label: str) -> None:
        assert self.temp_dir is not None
        out = self.temp_dir / f"{label}.out"
        env = dict(os.environ)
        env["RAY_AUTH_MODE"] = os.environ.get("RAY_AUTH_MODE") or "disabled"
        env.pop("RAY_ADDRESS", None)
        common = (
            f"--block --num-cpus {self.cpus_per_node} --num-gpus 0 --disable-usage-stats "
            f"--object-store-memory {self.object_store_mb * 1024 * 1024} "
            f"--dashboard-agent-listen-port {_free_port()}"
        ).split()
        with open(out, "wb") as sink:
            proc = subprocess.Popen(
                [sys.executable, "-m", "ray.scripts.scripts", "start", *args, *common],
                stdout=sink,
                stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL,
                env=env,
                start_new_session=True,  # its own process group, stopped by id alone
            )
        self._procs.append(proc)
        self._outputs.append(out)

    def _check_alive(self, waiting_for: str) -> None:
        for proc, out in zip(self._procs, self._outputs):
            if proc.poll() is not None:
                raise RuntimeError(
                    f"a Ray node exited (code {proc.returncode}) while waiting for "
                    f"{waiting_for}; the end of its output:\n{_tail(out)}"
                )

    def _deadline_passed(self, deadline: float, waiting_for: str) -> None:
        if time.monotonic() > deadline:
            tails = "\n".join(f"--- {o.name}:\n{_tail(o)}" for o in self._outputs)
            raise RuntimeError(
                f"the local Ray cluster did not come up within {self.timeout_s:.0f} s "
                f"(waiting for {waiting_for}); fix: a larger timeout_s, or check the output:\n"
                f"{tails}"
            )

    def start(self) -> None:
        """Start the nodes and connect this process (see the class docstring)."""
        from realitygap.core.parallel import require_ray

        ray = require_ray()
        if ray.is_initialized():
            raise RuntimeError(
                "this process is already connected to a Ray cluster, and Ray connects a "
                "process to one cluster at a time; fix: call ray.shutdown() before starting "
                "a local cluster"
            )
        self.temp_dir = Path(tempfile.mkdtemp(prefix="rg-ray-"))
        port = _free_port()
        deadline = time.monotonic() + self.timeout_s
        head = f"--head --port {port} --include-dashboard false".split()
        self._spawn([*head, "--temp-dir", str(self.temp_dir)], "head")
        while True:  # the head's GCS answers on its port
            self._check_alive("the head node")
            try:
                with socket.create_connection(("127.0.0.1", port), timeout=1.0):
                    break
            except OSError:
                self._deadline_passed(deadline, "the head node")
                time.sleep(0.2)
        for i in range(1, self.nodes):
            self._spawn(["--address", f"127.0.0.1:{port}"], f"node{i}")
        ray.init(address=f"127.0.0.1:{port}", log_to_driver=False)
        self._connected = True
        self.address = str(ray.get_runtime_context().gcs_address)
        while len(alive_nodes()) < self.nodes:
            self._check_alive(f"{self.nodes} nodes")
            self._deadline_passed(deadline, f"{self.nodes} nodes")
            time.sleep(0.2)

    def stop(self) -> None:
        """Disconnect, stop the nodes (their own processes only) and remove the temporary
        folder; safe to call more than once."""
        if self._connected:
            import ray

            ray.shutdown()
            self._connected = False
        for proc in reversed(self._procs):
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
        for proc in reversed(self._procs):
            try:
                proc.wait(timeout=60)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=10)
            try:  # whatever the node left in its own process group
                os.killpg(proc.pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass
        self._procs.clear()
        if self.temp_dir is not None:
            shutil.rmtree(self.temp_dir, ignore_errors=True)
            self.temp_dir = None


def alive_nodes() -> list[dict[str, Any]]:
    """The alive nodes of the Ray cluster this process is connected to."""
    import ray

    return [n for n in ray.nodes() if n.get("Alive")]


def node_of(shared: Any, item: Any) -> str:
    """Which Ray node runs this task (after a short pause, so that one node cannot take
    every task of a batch)."""
    import ray

    time.sleep(0.3)
    return str(ray.get_runtime_context().get_node_id())


# --------------------------------------------------------------------------- experiments
def _timed_diagnosis(
    logs: Sequence[Any],
    effects: tuple[str, ...] | None,
    backend: Any,
    say: Callable[[str], None],
) -> tuple[float, Any]:
    from realitygap.diagnosis.diagnose import DiagnosisSettings, diagnose

    settings = DiagnosisSettings(effects=effects)
    with fresh_replay_cache():
        t0 = time.perf_counter()
        d = diagnose(list(logs), settings=settings, backend=backend, progress=say)
        return time.perf_counter() - t0, d


@contextlib.contextmanager
def fresh_replay_cache() -> Iterator[Path]:
    """Within the block, this process and the processes it starts keep replays in a new,
    empty folder (``REALITYGAP_CACHE_DIR``, :mod:`realitygap.core.cache`), removed after it:
    a diagnosis timed inside measures a first diagnosis of its logs, whatever earlier runs
    left in the cache (Ray workers keep the folder of the block they started in)."""
    from realitygap.core.cache import CACHE_DIR_ENV

    before = os.environ.get(CACHE_DIR_ENV)
    folder = Path(tempfile.mkdtemp(prefix="rg-cache-"))
    os.environ[CACHE_DIR_ENV] = str(folder)
    try:
        yield folder
    finally:
        if before is None:
            os.environ.pop(CACHE_DIR_ENV, None)
        else:
            os.environ[CACHE_DIR_ENV] = before
        shutil.rmtree(folder, ignore_errors=True)


def _sizes(ctx: RunContext, key: str, default: tuple[int, ...]) -> tuple[int, ...]:
    value = ctx.options.get(key, default)
    try:
        sizes = tuple(int(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(
            f"option {key!r} must be a sequence of positive integers, got {value!r}"
        ) from None
    if len(sizes) < 2 or min(sizes) < 1 or len(set(sizes)) != len(sizes):
        raise ValueError(
            f"option {key!r} needs at least two distinct positive sizes to fit an exponent, "
            f"got {value!r}"
        )
    return tuple(sorted(sizes))


def _verdict(d: Any) -> str:
    """The verdict of diagnosis ``d`` as a figure: its effects joined by "+", or its kind."""
    from realitygap.diagnosis.verdict.types import VerdictKind

    v = d.verdict
    return "+".join(v.effects) if v.kind is VerdictKind.EFFECTS else str(v.kind.value)


@dataclass(frozen=True)
class _Point:
    sweep: str  # "duration" or "candidates"
    logs: int
    effects: tuple[str, ...] | None  # None: the whole library


def _measure(
    ctx: RunContext, logs: Sequence[Any], point: _Point, backend: Any, repeats: int, label: str
) -> dict[str, Any]:
    """The fastest of ``repeats`` diagnoses at ``point``, as a table row with its stages."""
    from realitygap.robots.effects import library

    part = logs[: point.logs]
    total = float(sum(lg.duration for lg in part))
    asked = "all" if point.effects is None else str(len(point.effects))
    ctx.progress(
        f"{label}: {point.logs} log(s), {total:.0f} s of driving, {asked} candidate(s)"
        + (f", best of {repeats}" if repeats > 1 else "")
    )
    best: tuple[float, Any] | None = None
    for _ in range(repeats):
        seconds, d = _timed_diagnosis(
            part, point.effects, backend, lambda m: ctx.progress("  " + m)
        )
        if best is None or seconds < best[0]:
            best = (seconds, d)
    assert best is not None
    seconds, d = best
    ctx.progress(f"{label}: {seconds:.1f} s, verdict {_verdict(d)}")
    row: dict[str, Any] = {
        "logs": point.logs,
        "log_seconds": total,
        "candidates_asked": len(point.effects or library("diffdrive")),
        "candidates": len(d.candidates),
        "seconds": seconds,
        "verdict": _verdict(d),
    }
    row.update({f"{stage}_s": float(t) for stage, t in d.timing.items()})
    return row


@experiment(
    "diagnose-scaling",
    "time to diagnose against total log duration (1–64 logs of 90 s) and against the number "
    "of candidate effects; fitted exponents",
)
def diagnose_scaling(ctx: RunContext) -> dict[str, Any]:
    """Options (Python callers): ``log_counts``, ``candidate_counts`` (at least two sizes
    each), ``log_seconds`` (of each log, default 90), ``duration_effects`` (candidates of the
    duration sweep; default two with ``--quick``, else the whole library), ``repeats``
    (diagnoses per point, the fastest counts; default 2 with ``--quick``, else 1),
    ``backend``, ``workers``, ``address`` (as ``realitygap run``)."""
    from realitygap.core.parallel import RayBackend, make_backend
    from realitygap.robots.effects import library

    full = library("diffdrive")
    log_counts = _sizes(ctx, "log_counts", (1, 2, 4) if ctx.quick else (1, 4, 16, 64))
    cand_counts = _sizes(ctx, "candidate_counts", (2, 4) if ctx.quick else (2, 4, 8, len(full)))
    log_seconds = float(ctx.options.get("log_seconds", 90.0))
    repeats = int(ctx.options.get("repeats", 2 if ctx.quick else 1))
    if repeats < 1:
        raise ValueError(f"option 'repeats' must be at least 1, got {repeats}")
    duration_effects = ctx.options.get(
        "duration_effects", candidate_sets([2], full)[0] if ctx.quick else None
    )
    if duration_effects is not None:
        duration_effects = tuple(duration_effects)
    points = [_Point("duration", n, duration_effects) for n in log_counts]
    points += [_Point("candidates", 1, e) for e in candidate_sets(cand_counts, full)]
    backend_name = str(ctx.options.get("backend", "process"))
    backend = make_backend(
        backend_name, workers=ctx.options.get("workers"), address=ctx.options.get("address")
    )
    rng = np.random.default_rng(ctx.seed)
    ctx.progress(f"simulating {max(log_counts)} bench log(s) of {log_seconds:g} s")
    logs, seeds = bench_logs(rng, max(log_counts), log_seconds, prefix="scaling")

    rows: dict[str, list[dict[str, Any]]] = {"duration": [], "candidates": []}
    with fresh_replay_cache():  # the Ray workers' folder; each diagnosis has its own here
        try:
            # untimed: the first diagnosis pays for imports and starts the backend's workers
            ctx.progress("warm-up: one untimed diagnosis of one log")
            _timed_diagnosis(logs[:1], candidate_sets([1], full)[0], backend, lambda m: None)
            for i, point in enumerate(points, start=1):
                label = f"point {i}/{len(points)} ({point.sweep})"
                rows[point.sweep].append(_measure(ctx, logs, point, backend, repeats, label))
        finally:
            if isinstance(backend, RayBackend):
                backend.shutdown()

    dur_rows, cand_rows = rows["duration"], rows["candidates"]
    dur_fit = fit_power_law(
        [r["log_seconds"] for r in dur_rows], [r["seconds"] for r in dur_rows], "log duration"
    )
    cand_fit = fit_power_law(
        [r["candidates"] for r in cand_rows],
        [r["seconds"] for r in cand_rows],
        "number of candidates",
    )
    stages = [k[:-2] for r in dur_rows + cand_rows for k in r if k.endswith("_s")]
    stage_rows = []
    for stage in dict.fromkeys(stages):
        row: dict[str, Any] = {"stage": stage}
        for key, sweep, x_key in (
            ("duration_exponent", dur_rows, "log_seconds"),
            ("candidates_exponent", cand_rows, "candidates"),
        ):
            pts = [r for r in sweep if r.get(f"{stage}_s", 0.0) > 0]
            try:
                fit = fit_power_law([r[x_key] for r in pts], [r[f"{stage}_s"] for r in pts])
                row[key] = fit.exponent
            except ValueError:  # fewer than two points, or a single distinct size
                row[key] = math.nan
        stage_rows.append(row)

    linear = dur_fit.exponent <= SLOPE_LIMIT
    figures: dict[str, Any] = {
        "duration_exponent": dur_fit.exponent,
        "duration_exponent_stderr": dur_fit.stderr,
        "duration_exponent_r2": dur_fit.r2,
        "duration_exponent_le_1_1": "yes" if linear else "no",
        "candidates_exponent": cand_fit.exponent,
        "candidates_exponent_stderr": cand_fit.stderr,
        "candidates_exponent_r2": cand_fit.r2,
    }
    figures.update({f"seconds_{r['logs']}_logs": r["seconds"] for r in dur_rows})
    figures.update({f"seconds_{r['candidates_asked']}_candidates": r["seconds"] for r in cand_rows})

    def pm(fit: PowerLaw) -> str:
        return f" ± {fit.stderr:.2f}" if math.isfinite(fit.stderr) else ""

    notes = [
        f"time ∝ duration^k with k = {dur_fit.exponent:.2f}{pm(dur_fit)} (least squares on "
        f"log-log, {dur_fit.points} points, {dur_rows[0]['log_seconds']:.0f}–"
        f"{dur_rows[-1]['log_seconds']:.0f} s of logs): k ≤ {SLOPE_LIMIT}: "
        + ("yes" if linear else "NO"),
        f"time ∝ candidates^m with m = {cand_fit.exponent:.2f}{pm(cand_fit)} ({cand_fit.points} "
        f"points, {cand_rows[0]['candidates']}–{cand_rows[-1]['candidates']} candidates "
        "fitted, one log)",
    ]
    return {
        "figures": figures,
        "tables": {"duration": dur_rows, "candidates": cand_rows, "stages": stage_rows},
        "notes": notes,
        "config": {
            "backend": backend_name,
            "workers": getattr(backend, "workers", None),
            "log_counts": list(log_counts),
            "candidate_counts": list(cand_counts),
            "log_seconds": log_seconds,
            "repeats": repeats,
            "replay_cache": "a new empty folder per diagnosis (Ray workers: one for the run)",
            "log_seeds": seeds,
            "duration_effects": list(duration_effects or ["all diffdrive effects"]),
            "hidden": f"{HIDDEN_EFFECT} E_d = {HIDDEN_VALUES['E_d']}",
        },
    }


@experiment(
    "diagnose-ray",
    "the diagnosis on a two-node Ray cluster (local, or RAY_ADDRESS) against the serial "
    "backend: identical results, wall times, speed-up",
)
def diagnose_ray(ctx: RunContext) -> dict[str, Any]:
    """Options (Python callers): ``logs`` (number of bench logs, default 2 with ``--quick``,
    else 3), ``log_seconds`` (default 90), ``effects`` (candidates; default four with
    ``--quick``, else the whole library)."""
    from realitygap.core.parallel import RayBackend, SerialBackend, require_ray
    from realitygap.robots.effects import library

    require_ray()
    n_logs = int(ctx.options.get("logs", 2 if ctx.quick else 3))  # bench_logs checks it
    log_seconds = float(ctx.options.get("log_seconds", 90.0))
    effects = ctx.options.get(
        "effects", candidate_sets([4], library("diffdrive"))[0] if ctx.quick else None
    )
    effects = tuple(effects) if effects is not None else None
    rng = np.random.default_rng(ctx.seed)
    ctx.progress(f"simulating {n_logs} bench log(s) of {log_seconds:g} s")
    logs, seeds = bench_logs(rng, n_logs, log_seconds, prefix="ray")
    total = float(sum(lg.duration for lg in logs))

    def say(message: str) -> None:
        ctx.progress("  " + message)

    label = "all" if effects is None else str(len(effects))
    given = os.environ.get("RAY_ADDRESS") or None
    with contextlib.ExitStack() as stack:
        stack.enter_context(fresh_replay_cache())  # the folder of the nodes started here
        ctx.progress(f"diagnosing {total:.0f} s of logs, {label} candidates, in this process")
        serial_s, d_serial = _timed_diagnosis(logs, effects, SerialBackend(), say)
        ctx.progress(f"serial: {serial_s:.1f} s, verdict {_verdict(d_serial)}")
        if given:
            address = str(given)
            ctx.progress(f"using the Ray cluster RAY_ADDRESS names: {address}")
        else:
            ctx.progress("starting a local two-node Ray cluster (one CPU per node)")
            address = stack.enter_context(LocalRayCluster(nodes=2, cpus_per_node=1)).address
        backend = stack.enter_context(RayBackend(address))  # leaves first: disconnects
        # a first batch starts a worker on each node and shows which nodes take tasks
        used = set(backend.map(node_of, list(range(4)), None))
        nodes = alive_nodes()
        cpus = float(sum(n.get("Resources", {}).get("CPU", 0.0) for n in nodes))
        ctx.progress(
            f"cluster at {address}: {len(nodes)} node(s), {cpus:g} CPU(s); "
            f"{len(used)} node(s) took the first tasks; diagnosing on Ray"
        )
        ray_s, d_ray = _timed_diagnosis(logs, effects, backend, say)
        ctx.progress(f"ray: {ray_s:.1f} s, verdict {_verdict(d_ray)}")

    js_serial, js_ray = d_serial.to_json(), d_ray.to_json()
    differences = json_differences(strip_timing(js_serial), strip_timing(js_ray))
    rank_s, rank_r = js_serial["ranking"], js_ray["ranking"]
    names_equal = [r["name"] for r in rank_s] == [r["name"] for r in rank_r]
    scores = [abs(a["heldout_score"] - b["heldout_score"]) for a, b in zip(rank_s, rank_r)]
    identical = not differences
    ctx.add_diagnosis("serial", d_serial)
    figures: dict[str, Any] = {
        "serial_seconds": serial_s,
        "ray_seconds": ray_s,
        "speedup_serial_over_ray": serial_s / ray_s,
        "ray_nodes": len(nodes),
        "ray_cpus": cpus,
        "ray_nodes_used": len(used),
        "identical": "yes" if identical else "no",
        "differences": len(differences),
        "verdict_serial": _verdict(d_serial),
        "verdict_ray": _verdict(d_ray),
        "ranking_names_equal": "yes" if names_equal else "no",
        "heldout_score_max_diff": max(scores, default=0.0),
        "log_seconds": total,
    }
    notes = [
        f"serial {serial_s:.1f} s, Ray {ray_s:.1f} s on {len(nodes)} node(s) / {cpus:g} CPU(s): "
        f"speed-up {serial_s / ray_s:.2f}",
        "results identical (to_json without timing, numbers within 1e-9)"
        if identical
        else f"results DIFFER in {len(differences)} place(s): " + "; ".join(differences[:5]),
    ]
    return {
        "figures": figures,
        "notes": notes,
        "config": {
            "cluster": f"RAY_ADDRESS={given}" if given else "local: 2 nodes × 1 CPU (ray start)",
            "replay_cache": "a new empty folder per diagnosis"
            + (" (the cluster's nodes: their own)" if given else ", one for the nodes"),
            "logs": n_logs,
            "log_seconds": log_seconds,
            "log_seeds": seeds,
            "effects": "all diffdrive effects" if effects is None else list(effects),
            "hidden": f"{HIDDEN_EFFECT} E_d = {HIDDEN_VALUES['E_d']}",
        },
    }
