"""The bad-input corpus: every row of ``cases.tsv`` run once, in-process, in its own folder.

A row is ``id, surface, fixture, input, expect, must_contain, outputs``:

``surface``
    ``cli`` (``input`` is an argument vector, shell-quoted, run through
    ``realitygap.cli.main``), ``importer``, ``env`` or ``effect`` (``input`` is a Python
    expression evaluated with the helpers of :func:`namespace`).
``fixture``
    The builder in ``fixtures.py`` that writes the input files into the case's folder; it
    returns the placeholders ``{file}``, ``{session}``, ``{out}`` … (``{tmp}`` is the folder).
    In a CLI row they are replaced by their paths; in a Python row they are variables.
``expect``
    ``ok``: exit status 0 / no exception. ``error``: a clear error — exit status 2 with an
    ``error:`` line on stderr (argparse's ``prog: error:`` counts), or a ``ValueError``,
    ``TypeError`` or ``FileNotFoundError`` (``LogError`` is a ``ValueError``);
    ``error[KeyError]`` also accepts the listed classes. ``clear``: either of the two.
``must_contain``
    ``|``-separated substrings every error message must hold; ``{name}`` stands for the
    file name of placeholder ``name``.
``outputs``
    ``|``-separated paths (relative to the case folder; ``dir/**`` for a folder) the case may
    create or change. Any other new file, or a changed input, fails the case.

A CLI command reaching its long-running work (the diagnosis, an experiment, a benchmark, a
training) stops there with :class:`ReachedWork`: an ``ok`` row passes, an ``error`` row fails
as ``reached-work`` (the bad input was not caught before the work started). Each case has a
time limit (``hang``). Failures start with their class: ``traceback``, ``hang``,
``reached-work``, ``unexpected-ok``, ``unexpected-error``, ``unclear-error``,
``file-changed``, ``stray-file``.

The table grows: add a row (and, if needed, a builder in ``fixtures.py``).
``RG_CORPUS_RESULTS=path`` appends one JSON line per case (id, outcome, message) there.
"""

from __future__ import annotations

import csv
import hashlib
import importlib.util
import json
import math
import os
import re
import shlex
import signal
import stat
import sys
import time
import traceback
from pathlib import Path
from typing import Any

import numpy as np
import pytest

HERE = Path(__file__).parent
TIME_LIMIT_S = 20


def _load_fixtures() -> Any:
    name = "realitygap_corpus_fixtures"
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, HERE / "fixtures.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


F = _load_fixtures()


def load_rows() -> list[dict[str, str]]:
    with open(HERE / "cases.tsv", encoding="utf-8", newline="") as fh:
        rows = list(csv.DictReader(fh, delimiter="\t", quoting=csv.QUOTE_NONE))
    for r in rows:
        for k in ("must_contain", "outputs"):
            r[k] = r.get(k) or ""
    return rows


ROWS = load_rows()


# --------------------------------------------------------------------------- outcomes
class Hang(BaseException):
    """The case ran past its time limit."""


class ReachedWork(BaseException):
    """A CLI command reached its long-running work (its inputs were accepted)."""


class CaseFailure(AssertionError):
    pass


def _on_alarm(signum: int, frame: Any) -> None:
    raise Hang()


WORK = [
    ("realitygap.diagnosis.diagnose", "diagnose"),
    ("realitygap.baselines.benchmark", "run_benchmark"),
    ("realitygap.baselines.cli", "train_for_benchmark"),
    ("realitygap.baselines.rl", "train"),
]


def _stop_at_work(monkeypatch: pytest.MonkeyPatch) -> None:
    import importlib

    for module, attr in WORK:
        mod = importlib.import_module(module)

        def stop(*args: Any, _where: str = f"{module}.{attr}", **kwargs: Any) -> Any:
            raise ReachedWork(_where)

        monkeypatch.setattr(mod, attr, stop)
    # an experiment: its name, data and options are checked by ``experiments.run`` before
    # it calls the experiment's function, which is where the work starts
    import dataclasses

    from realitygap import experiments

    real_get = experiments.get

    def get(name: str) -> Any:
        spec = real_get(name)

        def work(ctx: Any, _name: str = name) -> Any:
            raise ReachedWork(f"experiment {_name!r}")

        return dataclasses.replace(spec, func=work)

    monkeypatch.setattr(experiments, "get", get)


# --------------------------------------------------------------------------- Python rows
class _NanAction:
    pass


NAN_ACTION = _NanAction()


def namespace(places: dict[str, Path]) -> dict[str, Any]:
    import gymnasium as gym

    import realitygap  # noqa: F401  (registers the envs)
    from realitygap.diagnosis.logs.importers.column_map import ColumnMap
    from realitygap.diagnosis.logs.log import Log
    from realitygap.diagnosis.logs.read import ReadOptions, read_logs
    from realitygap.diagnosis.logs.robot_file import description_from_urdf, load_robot_file
    from realitygap.robots.effects import EFFECTS, Reality, make_effect

    def read(path: str, **opts: Any) -> Any:
        kw: dict[str, Any] = {"columns": F.CSV_MAP, "params": F.REAL_PARAMS}
        kw.update(opts)
        return read_logs(path, ReadOptions(**kw))

    def env(env_id: str, steps: int = 3, seed: Any = 0, action: Any = None, **kwargs: Any) -> None:
        e = gym.make(env_id, **kwargs)
        try:
            e.reset(seed=seed)
            e.action_space.seed(0)
            for _ in range(steps):
                a = action
                if a is None:
                    a = e.action_space.sample()
                elif a is NAN_ACTION:
                    a = np.full(e.action_space.shape, np.nan, dtype=np.float32)
                e.step(a)
        finally:
            e.close()

    def vec(env_id: str, num_envs: Any = 4, **kwargs: Any) -> None:
        e = gym.make_vec(env_id, num_envs=num_envs, **kwargs)
        try:
            e.reset(seed=0)
            e.action_space.seed(0)
            e.step(e.action_space.sample())
        finally:
            e.close()

    ns: dict[str, Any] = {
        "np": np,
        "nan": math.nan,
        "inf": math.inf,
        "MAP": F.CSV_MAP,
        "read": read,
        "read_logs": read_logs,
        "ReadOptions": ReadOptions,
        "Log": Log,
        "ColumnMap": ColumnMap,
        "load_robot_file": load_robot_file,
        "description_from_urdf": description_from_urdf,
        "make_effect": make_effect,
        "Reality": Reality,
        "EFFECTS": EFFECTS,
        "env": env,
        "vec": vec,
        "nan_action": NAN_ACTION,
    }
    ns.update({k: str(v) for k, v in places.items()})
    return ns


# --------------------------------------------------------------------------- files
def snapshot(root: Path) -> dict[str, str]:
    """``relative path → sha256`` of every regular file below ``root`` (links not followed)."""
    out: dict[str, str] = {}
    for dirpath, dirnames, filenames in os.walk(root, followlinks=False):
        for name in filenames + dirnames:
            p = Path(dirpath) / name
            rel = p.relative_to(root).as_posix()
            try:
                st = os.lstat(p)
            except OSError:
                continue
            if stat.S_ISREG(st.st_mode):
                try:
                    h = hashlib.sha256()
                    with open(p, "rb") as fh:
                        for block in iter(lambda fh=fh: fh.read(1 << 20), b""):
                            h.update(block)
                    out[rel] = h.hexdigest()
                except OSError:
                    out[rel] = "unreadable"
            elif not stat.S_ISDIR(st.st_mode):
                out[rel] = f"special:{stat.S_IFMT(st.st_mode)}"
    return out


def _allowed(rel: str, outputs: list[str]) -> bool:
    import fnmatch

    for pat in outputs:
        if pat.endswith("/**"):
            if rel.startswith(pat[:-2]):
                return True
        elif fnmatch.fnmatch(rel, pat):
            return True
    return False


def _subst(text: str, places: dict[str, Path], basename: bool = False) -> str:
    def repl(m: re.Match[str]) -> str:
        key = m.group(1)
        if key not in places:
            return m.group(0)
        return places[key].name if basename else str(places[key])

    return re.sub(r"\{(\w+)\}", repl, text)


def _error_text(stderr: str) -> str | None:
    """The error message of a CLI run: from its first ``error:`` line to the end."""
    lines = stderr.splitlines()
    for i, line in enumerate(lines):
        if line.startswith("error:") or re.match(r"^\S[^:]*: error: ", line):
            return "\n".join(lines[i:])
    return None


def _short(text: str, n: int = 300) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= n else text[: n - 3] + "..."


# --------------------------------------------------------------------------- the run
def run_case(
    row: dict[str, str], tmp: Path, monkeypatch: pytest.MonkeyPatch, capsys: Any
) -> tuple[str, str]:
    """Run one row; return ``(outcome, detail)`` where outcome is ``ok``, ``error`` or a
    failure class (``traceback``, ``hang``, ``reached-work``, ``unclear-exit``)."""
    places: dict[str, Path] = {"tmp": tmp}
    places.update(F.BUILDERS[row["fixture"]](tmp))
    before = snapshot(tmp)
    monkeypatch.chdir(tmp)
    _stop_at_work(monkeypatch)
    expect = row["expect"]
    extra = (
        tuple(
            getattr(__import__("builtins"), n)
            for n in re.findall(r"\[(\w+)\]", expect)[0].split(",")
        )
        if "[" in expect
        else ()
    )
    outcome, detail = "ok", ""
    capsys.readouterr()
    old = signal.signal(signal.SIGALRM, _on_alarm)
    signal.alarm(TIME_LIMIT_S)
    try:
        if row["surface"] == "cli":
            from realitygap.cli import main

            argv = [_subst(tok, places) for tok in shlex.split(row["input"])]
            try:
                code = main(argv)
            except SystemExit as exc:
                code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
            signal.alarm(0)
            out, err = capsys.readouterr()
            if "Traceback" in out + err:
                outcome, detail = "traceback", _short(err or out, 600)
            elif code == 0:
                outcome = "ok"
            elif code == 2 and _error_text(err) is not None:
                outcome, detail = "error", _error_text(err) or ""
            else:
                outcome, detail = "unclear-exit", f"exit {code}; stderr: {_short(err)}"
        else:
            ns = namespace(places)
            try:
                eval(row["input"], ns)
                outcome = "ok"
            except (ValueError, TypeError, FileNotFoundError, *extra) as exc:
                outcome, detail = "error", f"{type(exc).__name__}: {exc}"
            signal.alarm(0)
    except Hang:
        outcome, detail = "hang", f"no answer within {TIME_LIMIT_S} s"
    except ReachedWork as exc:
        signal.alarm(0)
        outcome, detail = "reached-work", f"reached {exc.args[0]}"
    except Exception as exc:
        signal.alarm(0)
        tb = traceback.extract_tb(exc.__traceback__)
        where = f"{Path(tb[-1].filename).name}:{tb[-1].lineno}" if tb else "?"
        outcome, detail = "traceback", f"{type(exc).__name__} at {where}: {_short(exc)}"
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
        capsys.readouterr()
    # the files: inputs unchanged, nothing but the declared outputs
    after = snapshot(tmp)
    outputs = [
        _subst(o, places).replace(str(tmp) + "/", "") for o in row["outputs"].split("|") if o
    ]
    changed = [k for k, v in before.items() if after.get(k) != v and not _allowed(k, outputs)]
    stray = [k for k in after if k not in before and not _allowed(k, outputs)]
    if changed:
        return "file-changed", f"{', '.join(changed)} (was {outcome}: {_short(detail, 200)})"
    if stray:
        return (
            "stray-file",
            f"{', '.join(sorted(stray)[:5])} (was {outcome}: {_short(detail, 200)})",
        )
    return outcome, detail


def judge(
    row: dict[str, str], outcome: str, detail: str, places_names: dict[str, Path]
) -> tuple[str, str]:
    """``("pass", "")`` or ``(failure class, message)``."""
    expect = row["expect"].split("[")[0]
    must = [_subst(m, places_names, basename=True) for m in row["must_contain"].split("|") if m]
    if outcome == "reached-work":
        return ("pass", "") if expect in ("ok", "clear") else ("reached-work", detail)
    if outcome in ("traceback", "hang", "file-changed", "stray-file", "unclear-exit"):
        return outcome, detail
    if outcome == "ok":
        return ("pass", "") if expect in ("ok", "clear") else ("unexpected-ok", "no error")
    # a clear error
    if expect == "ok":
        return "unexpected-error", _short(detail)
    missing = [m for m in must if m not in detail]
    if missing:
        return "unclear-error", f"lacks {missing}: {_short(detail)}"
    return "pass", ""


ROOT_SKIPS = {"unreadable", "out_read_only"}


@pytest.mark.parametrize("row", ROWS, ids=[r["id"] for r in ROWS])
def test_case(
    row: dict[str, str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: Any
) -> None:
    if row["fixture"] in ROOT_SKIPS and os.geteuid() == 0:
        pytest.skip("permissions do not bind root")
    case = tmp_path / "case"
    case.mkdir()
    t0 = time.perf_counter()
    places: dict[str, Path] = {}
    real_builder = F.BUILDERS[row["fixture"]]

    def remember(tmp: Path) -> dict[str, Path]:
        got = real_builder(tmp)
        places.update(got)
        return got

    monkeypatch.setitem(F.BUILDERS, row["fixture"], remember)
    try:
        outcome, detail = run_case(row, case, monkeypatch, capsys)
    finally:
        for dirpath, dirnames, _ in os.walk(case):
            for d in dirnames:
                p = Path(dirpath) / d
                if not p.is_symlink():
                    p.chmod(0o755)
    verdict, message = judge(row, outcome, detail, {"tmp": case, **places})
    results = os.environ.get("RG_CORPUS_RESULTS")
    if results:
        with open(results, "a", encoding="utf-8") as fh:
            fh.write(
                json.dumps(
                    {
                        "id": row["id"],
                        "surface": row["surface"],
                        "expect": row["expect"],
                        "verdict": verdict,
                        "outcome": outcome,
                        "message": message if verdict != "pass" else "",
                        "seconds": round(time.perf_counter() - t0, 2),
                    }
                )
                + "\n"
            )
    if verdict != "pass":
        raise CaseFailure(f"{verdict}: {message}")


def test_table_is_well_formed() -> None:
    ids = [r["id"] for r in ROWS]
    assert len(ids) == len(set(ids)), "duplicate ids"
    assert len(ROWS) >= 420
    for r in ROWS:
        assert r["surface"] in {"cli", "importer", "env", "effect"}, r["id"]
        assert r["fixture"] in F.BUILDERS, (r["id"], r["fixture"])
        assert re.fullmatch(r"(ok|clear|error)(\[\w+(,\w+)*\])?", r["expect"]), r["id"]
        if r["expect"].startswith("error"):
            assert r["must_contain"], f"{r['id']}: an error row names what its message must hold"
