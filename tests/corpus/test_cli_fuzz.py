"""Fuzzing the command line and the column-map parser with ``hypothesis``.

(a) Argument vectors for ``diagnose``, ``inspect`` and ``calibrate umbmark`` with random
    option values (numbers, strings, paths to the corpus's fixture files): the command ends
    with exit status 0 or 2 (a clear ``error:``), never a traceback, within a time limit, and
    no input file changes. ``diagnose`` stops where its long work would start (its inputs
    were accepted), as in ``test_corpus.py``.
(b) Column-map strings, ``target=[-]COL[*F][+O][:unit]`` entries and garbage, parsed by
    ``ColumnMap.parse``: a ``ValueError`` (``LogError``) or a valid map, nothing else.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.util
import io
import os
import shutil
import signal
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

HERE = Path(__file__).parent
TIME_LIMIT_S = 20

FUZZ = settings(
    derandomize=True,
    max_examples=100,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)


def _fixtures() -> Any:
    name = "realitygap_corpus_fixtures"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, HERE / "fixtures.py")
        assert spec is not None and spec.loader is not None
        mod = importlib.util.module_from_spec(spec)
        sys.modules[name] = mod
        spec.loader.exec_module(mod)
    return sys.modules[name]


F = _fixtures()


# --------------------------------------------------------------------------- the inputs
class Inputs:
    """Fixture files built once in a scratch folder: valid ones and damaged ones."""

    def __init__(self, root: Path):
        self.root = root
        self.inputs = root / "in"
        self.outs = root / "out"
        self.cwd = root / "cwd"
        for d in (self.inputs, self.outs, self.cwd):
            d.mkdir()
        p: dict[str, Path] = {}
        for name in ("real_csv", "real_session", "saved_log", "npz_table", "csv_pose_mm"):
            sub = self.inputs / name
            sub.mkdir()
            got = F.BUILDERS[name](sub)
            p.update({f"{name}.{k}": v for k, v in got.items()})
        for name in (
            "csv_zero_bytes",
            "csv_utf16",
            "csv_nan_time",
            "npz_truncated",
            "fifo",
            "symlink_loop",
            "folder_as_file",
            "robot_valid",
            "robot_syntax",
            "urdf_valid",
            "urdf_no_joints",
            "map_json_valid",
            "map_json_list",
        ):
            sub = self.inputs / name
            sub.mkdir()
            got = F.BUILDERS[name](sub)
            p.update({f"{name}.{k}": v for k, v in got.items()})
        self.paths = p
        self.logs = [
            p["real_csv.file"],
            p["real_csv.other"],
            p["saved_log.file"],
            p["npz_table.file"],
            p["csv_pose_mm.file"],
            p["csv_zero_bytes.file"],
            p["csv_utf16.file"],
            p["csv_nan_time.file"],
            p["npz_truncated.file"],
            p["fifo.file"],
            p["symlink_loop.file"],
            p["folder_as_file.file"],
            self.inputs / "missing.csv",
        ]
        self.sessions = [
            p["real_session.square"],
            p["real_session.session"],
            p["real_csv.file"],
            p["folder_as_file.file"],
            p["fifo.file"],
            self.inputs / "no_session",
        ]
        self.robot_files = [p["robot_valid.robot"], p["robot_syntax.robot"], p["real_csv.file"]]
        self.urdfs = [p["urdf_valid.urdf"], p["urdf_no_joints.urdf"], p["real_csv.file"]]
        self.maps = [p["map_json_valid.map"], p["map_json_list.map"]]
        self.blocker = self.outs / "blocker"
        self.before = self.checksums()

    def checksums(self) -> dict[str, str]:
        out = {}
        for dirpath, _, files in os.walk(self.inputs, followlinks=False):
            for f in files:
                q = Path(dirpath) / f
                if q.is_file() and not q.is_symlink():
                    out[str(q)] = hashlib.sha256(q.read_bytes()).hexdigest()
        return out

    def output_targets(self) -> list[str]:
        return [
            str(self.outs / "a.json"),
            str(self.outs / "rep"),
            str(self.outs),
            str(self.blocker / "x.json"),
            str(self.inputs / "real_csv" / "out.json"),
            str(self.paths["real_csv.file"]),
            str(self.paths["real_session.square"] / "o.json"),
            "",
            "-",
        ]

    def reset_outputs(self) -> None:
        shutil.rmtree(self.outs, ignore_errors=True)
        self.outs.mkdir()
        self.blocker.write_text("a file\n")
        shutil.rmtree(self.cwd, ignore_errors=True)
        self.cwd.mkdir()


_INPUTS: Inputs | None = None


def inputs() -> Inputs:
    global _INPUTS
    if _INPUTS is None:
        _INPUTS = Inputs(Path(tempfile.mkdtemp(prefix="rg-corpus-fuzz-")))
    return _INPUTS


@pytest.fixture(scope="module", autouse=True)
def _cleanup() -> Iterator[None]:
    yield
    global _INPUTS
    if _INPUTS is not None:
        shutil.rmtree(_INPUTS.root, ignore_errors=True)
        _INPUTS = None


# --------------------------------------------------------------------------- running
class _Hang(BaseException):
    pass


class _ReachedWork(BaseException):
    pass


def _alarm(signum: int, frame: Any) -> None:
    raise _Hang()


def run_cli(argv: list[str]) -> tuple[str, int | None, str]:
    """Run the CLI in-process: ``(how, exit status, stderr)``; ``how`` is ``exit``, ``work``
    (the diagnosis was reached), ``hang`` or ``traceback``."""
    from realitygap import cli
    from realitygap.diagnosis import diagnose as diagnose_module

    ins = inputs()
    ins.reset_outputs()
    real = diagnose_module.diagnose

    def stop(*a: Any, **k: Any) -> Any:
        raise _ReachedWork()

    diagnose_module.diagnose = stop  # type: ignore[assignment]
    out, err = io.StringIO(), io.StringIO()
    old_cwd = os.getcwd()
    old = signal.signal(signal.SIGALRM, _alarm)
    how, code = "exit", None
    try:
        os.chdir(ins.cwd)
        signal.alarm(TIME_LIMIT_S)
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = cli.main(argv)
            except SystemExit as exc:
                code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    except _ReachedWork:
        how = "work"
    except _Hang:
        how = "hang"
    except Exception as exc:
        how = "traceback"
        err.write(f"\n{type(exc).__name__}: {exc}")
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
        os.chdir(old_cwd)
        diagnose_module.diagnose = real  # type: ignore[assignment]
    return how, code, out.getvalue() + err.getvalue()


def check(argv: list[str]) -> None:
    how, code, text = run_cli(argv)
    shown = " ".join(argv)
    assert how != "hang", f"hang: {shown}"
    assert how != "traceback" and "Traceback" not in text, f"traceback: {shown}\n{text[-800:]}"
    if how == "exit":
        assert code in (0, 2), f"exit {code}: {shown}\n{text[-800:]}"
        if code == 2:
            assert "error:" in text, f"exit 2 without an error line: {shown}\n{text[-500:]}"
    after = inputs().checksums()
    changed = [k for k, v in inputs().before.items() if after.get(k) != v]
    assert not changed, f"inputs changed: {changed}: {shown}"


# --------------------------------------------------------------------------- strategies
NUMBER_TEXT = st.one_of(
    st.integers(-(10**12), 10**12).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.sampled_from(
        [
            "nan",
            "inf",
            "-inf",
            "-0",
            "0",
            "1e309",
            "0x10",
            "1_000",
            "",
            " 1",
            "abc",
            "½",
            "1,5",
            "1e-320",
            "-1",
            "2.5",
            "999999999999999999999",
        ]
    ),
)
JUNK = st.text(
    alphabet=st.characters(blacklist_characters="\x00", blacklist_categories=("Cs",)), max_size=24
)


def _path(kind: str) -> st.SearchStrategy[str]:
    return st.deferred(lambda: st.sampled_from([str(p) for p in getattr(inputs(), kind)]))


OUT = st.deferred(lambda: st.sampled_from(inputs().output_targets()))
KV = st.one_of(
    st.lists(
        st.tuples(
            st.sampled_from(
                [
                    "wheelbase",
                    "ticks_per_rev",
                    "wheel_radius_left",
                    "a_max",
                    "alpha_max",
                    "bogus",
                    "",
                ]
            ),
            NUMBER_TEXT,
        ),
        max_size=4,
    ).map(lambda kv: ",".join(f"{k}={v}" for k, v in kv)),
    st.sampled_from(['{"wheelbase": 0.2}', '{"wheelbase": "x"}', "[1]", "{", "null", "{}"]),
    JUNK,
)

DIAGNOSE_OPTIONS: dict[str, st.SearchStrategy[str]] = {
    "--window": NUMBER_TEXT,
    "--rate": NUMBER_TEXT,
    "--resample": NUMBER_TEXT,
    "--max-gap": NUMBER_TEXT,
    "--workers": NUMBER_TEXT,
    "--params": KV,
    "--firmware": KV,
    "--effects": st.one_of(
        st.sampled_from(["command_latency", "arm_joint_offset", "nope", ",", ""]), JUNK
    ),
    "--columns": st.one_of(
        st.just(F.CSV_MAP),
        st.deferred(lambda: st.sampled_from([str(p) for p in inputs().maps])),
        JUNK,
    ),
    "--delimiter": st.one_of(st.sampled_from([",", ";", "\t", "|", " ", "", "ab"]), JUNK),
    "--decimal": st.sampled_from([".", ",", ";", ""]),
    "--nan": st.sampled_from(["raise", "interpolate", "drop", "zero"]),
    "--duplicates": st.sampled_from(["raise", "last", "mean", "first"]),
    "--robot": st.sampled_from(["diffdrive", "arm", "climber", "tank", ""]),
    "--drive": st.sampled_from(["commands", "ticks", "wheels"]),
    "--json": OUT,
    "--report": OUT,
    "--holdout": _path("logs"),
    "--robot-file": _path("robot_files"),
    "--urdf": _path("urdfs"),
}


def _argv(draw: Any, head: list[str], options: dict[str, st.SearchStrategy[str]]) -> list[str]:
    chosen = draw(st.lists(st.sampled_from(sorted(options)), max_size=5, unique=True))
    argv = list(head)
    for opt in chosen:
        value = draw(options[opt])
        argv.append(f"{opt}={value}" if value.startswith("-") or value == "" else opt)
        if not (value.startswith("-") or value == ""):
            argv.append(value)
    return argv


@st.composite
def diagnose_argv(draw: Any) -> list[str]:
    valid = st.deferred(lambda: st.just(str(inputs().paths["real_csv.file"])))
    log = draw(st.one_of(valid, _path("logs")))
    head = ["diagnose", log, "-q", "--backend", "serial"]
    if draw(st.booleans()):
        head += ["--columns", F.CSV_MAP, "--params", "ticks_per_rev=2796.8,wheelbase=0.2"]
    return _argv(draw, head, DIAGNOSE_OPTIONS)


@st.composite
def inspect_argv(draw: Any) -> list[str]:
    files = draw(st.lists(st.one_of(_path("logs"), _path("sessions")), min_size=1, max_size=2))
    return _argv(
        draw,
        ["inspect", *files, "-q"],
        {
            "--json": OUT,
            "--delimiter": DIAGNOSE_OPTIONS["--delimiter"],
            "--decimal": DIAGNOSE_OPTIONS["--decimal"],
        },
    )


@st.composite
def calibrate_argv(draw: Any) -> list[str]:
    sessions = draw(st.lists(_path("sessions"), min_size=1, max_size=2))
    return _argv(
        draw,
        ["calibrate", "umbmark", *sessions, "-q"],
        {
            "--json": OUT,
            "--side-length": NUMBER_TEXT,
        },
    )


# --------------------------------------------------------------------------- (a) the CLI
@FUZZ
@given(argv=diagnose_argv())
def test_diagnose_argv(argv: list[str]) -> None:
    check(argv)


@settings(FUZZ, max_examples=60)
@given(argv=inspect_argv())
def test_inspect_argv(argv: list[str]) -> None:
    check(argv)


@settings(FUZZ, max_examples=30)
@given(argv=calibrate_argv())
def test_calibrate_argv(argv: list[str]) -> None:
    check(argv)


# --------------------------------------------------------------------------- (b) column maps
TARGETS = st.sampled_from(
    [
        "t",
        "cmd.v",
        "cmd.w",
        "ticks.left",
        "ticks.right",
        "pose_gt.x",
        "pose_gt.y",
        "pose_gt.theta",
        "pose_est.x",
        "joints.q1",
        "tool_pos.z",
        "ticks",
        "pose_gt",
        "x",
        "",
        "cmd.q",
        "bogus.x",
    ]
)
COLUMN = st.one_of(
    st.sampled_from(["time", "x", "enc_l", "0", "3", "row", "a::b", '"x [mm]"', '"', "::", "-"]),
    st.text(alphabet='abcxyz_019 -*+:."', min_size=0, max_size=8),
)
FACTOR = st.one_of(st.just(""), NUMBER_TEXT.map(lambda v: f"*{v}"))
OFFSET = st.one_of(st.just(""), NUMBER_TEXT.map(lambda v: f"+{v}"))
UNIT = st.one_of(
    st.just(""),
    st.sampled_from(
        [
            "s",
            "ms",
            "us",
            "m",
            "mm",
            "cm",
            "deg",
            "rad",
            "deg/s",
            "mm/s",
            "rad/s",
            "parsec",
            "",
            ":",
            "m/s",
            "increments",
        ]
    ).map(lambda u: f":{u}"),
)
ENTRY = st.builds(
    lambda t, neg, c, f, o, u: f"{t}={'-' if neg else ''}{c}{f}{o}{u}",
    TARGETS,
    st.booleans(),
    COLUMN,
    FACTOR,
    OFFSET,
    UNIT,
)
MAP_TEXT = st.one_of(
    st.lists(st.one_of(ENTRY, JUNK), max_size=8).map(",".join),
    JUNK,
    st.binary(max_size=40).map(lambda b: b.decode("latin-1").replace("\x00", "")),
)


@FUZZ
@given(text=MAP_TEXT)
def test_column_map_parse(text: str) -> None:
    from realitygap.diagnosis.logs.importers.column_map import ColumnMap, check_target

    cwd = os.getcwd()
    os.chdir(inputs().cwd)  # a text ending in .json is looked up as a file: none here
    try:
        try:
            cmap = ColumnMap.parse(text)
        except ValueError:
            return
    finally:
        os.chdir(cwd)
    assert isinstance(cmap, ColumnMap)
    assert cmap.entries, f"a map without entries from {text!r}"
    for target in cmap.entries:
        check_target(target)
    assert cmap.ticks in ("cumulative", "increments")
