"""Builders of the input files of the bad-input corpus (``cases.tsv``, column ``fixture``).

Every builder takes the case's empty folder ``tmp`` and returns the placeholders the case's
input may use (``{file}``, ``{other}``, ``{session}`` …; ``{tmp}`` is always there). The valid
baselines are REAL data: the OptiOdom sample shipped with the package
(``realitygap sample``), a run of it re-written as a plain CSV with a header
(:func:`real_csv`), and small files in ``tests/corpus/data/`` (a diff-drive URDF, an arm
URDF and an arm's laser-tracker table written by ``realitygap.independent.recordings``).

A builder named ``csv_<damage>`` starts from the valid CSV and damages it one way.
"""

from __future__ import annotations

import functools
import json
import os
import shutil
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

DATA = Path(__file__).parent / "data"

#: The column map of :func:`real_csv`.
CSV_MAP = (
    "t=time,cmd.v=v,cmd.w=w,pose_gt.x=x,pose_gt.y=y,pose_gt.theta=yaw,"
    "ticks.left=enc_l,ticks.right=enc_r"
)
#: The nominal geometry of the OptiOdom robot (its metadata: Di 0.084 m, Li 0.2 m, 43.7·64 ticks).
REAL_PARAMS = {
    "wheel_radius_left": 0.042,
    "wheel_radius_right": 0.042,
    "wheelbase": 0.2,
    "ticks_per_rev": 2796.8,
}
HEADER = ["time", "v", "w", "x", "y", "yaw", "enc_l", "enc_r"]

BUILDERS: dict[str, Callable[[Path], dict[str, Path]]] = {}


def builder(fn: Callable[[Path], dict[str, Path]]) -> Callable[[Path], dict[str, Path]]:
    BUILDERS[fn.__name__] = fn
    return fn


# --------------------------------------------------------------------------- real data
@functools.lru_cache(maxsize=1)
def sample_root() -> Path:
    from realitygap.samples import sample_dir

    return Path(sample_dir("optiodom_diffdrive"))


CIRCULAR = "circular/231220200157"
SQUARE = "square/231220200029"


@functools.lru_cache(maxsize=1)
def real_columns() -> dict[str, np.ndarray]:
    """Run 1 of the circular OptiOdom sample session as columns: 20 Hz, ground truth in m/rad,
    the commanded twist estimated from the ground truth, cumulative encoder counts."""
    raw = np.loadtxt(sample_root() / CIRCULAR / "231220200157_run-01.csv", delimiter=",")
    t, x, y, th = raw[:, 0], raw[:, 1], raw[:, 2], raw[:, 3]
    enc_r, enc_l = np.cumsum(raw[:, 4]), np.cumsum(raw[:, 5])
    dt = np.gradient(t)
    v = np.hypot(np.gradient(x), np.gradient(y)) / dt
    w = np.gradient(th) / dt
    return {
        "time": np.round(t, 3),
        "v": v,
        "w": w,
        "x": x,
        "y": y,
        "yaw": th,
        "enc_l": enc_l,
        "enc_r": enc_r,
    }


def csv_rows(cols: dict[str, np.ndarray] | None = None) -> list[list[str]]:
    c = cols if cols is not None else real_columns()
    n = len(c["time"])
    out = []
    for k in range(n):
        out.append(
            [
                f"{c['time'][k]:.3f}",
                f"{c['v'][k]:.5f}",
                f"{c['w'][k]:.5f}",
                f"{c['x'][k]:.6f}",
                f"{c['y'][k]:.6f}",
                f"{c['yaw'][k]:.6f}",
                f"{c['enc_l'][k]:.0f}",
                f"{c['enc_r'][k]:.0f}",
            ]
        )
    return out


def write_csv(
    path: Path,
    rows: list[list[str]] | None = None,
    header: list[str] | None = None,
    sep: str = ",",
    encoding: str = "utf-8",
    title: str = "",
) -> Path:
    body = rows if rows is not None else csv_rows()
    lines = [sep.join(header if header is not None else HEADER)] + [sep.join(r) for r in body]
    path.write_bytes((title + "\n".join(lines) + "\n").encode(encoding))
    return path


def with_cols(**change: Callable[[np.ndarray], np.ndarray]) -> dict[str, np.ndarray]:
    c = dict(real_columns())
    for k, f in change.items():
        c[k] = f(c[k].copy())
    return c


# --------------------------------------------------------------------------- basics
@builder
def none(tmp: Path) -> dict[str, Path]:
    return {}


@builder
def real_csv(tmp: Path) -> dict[str, Path]:
    """A valid diff-drive CSV (real OptiOdom run, 525 rows) and a second run of it."""
    f = write_csv(tmp / "run.csv")
    other = write_csv(tmp / "run2.csv")
    return {"file": f, "other": other}


@builder
def real_session(tmp: Path) -> dict[str, Path]:
    """A copy of the circular OptiOdom sample session (2 runs) and of a square one."""
    dst = tmp / "data" / "231220200157"
    shutil.copytree(sample_root() / CIRCULAR, dst)
    sq = tmp / "data" / "231220200029"
    shutil.copytree(sample_root() / SQUARE, sq)
    return {"session": dst, "square": sq, "file": dst}


@builder
def saved_log(tmp: Path) -> dict[str, Path]:
    """A valid ``.npz`` log written by ``Log.save`` from the real run."""
    from realitygap.diagnosis.logs.read import ReadOptions, read_logs

    src = write_csv(tmp / "src.csv")
    log = read_logs(src, ReadOptions(columns=CSV_MAP, params=REAL_PARAMS))[0]
    f = tmp / "log.npz"
    log.save(f)
    src.unlink()
    return {"file": f}


@builder
def arm_table(tmp: Path) -> dict[str, Path]:
    f = tmp / "measurements.csv"
    shutil.copy(DATA / "arm_measurements.csv", f)
    return {"file": f, "urdf": _copy(DATA / "arm.urdf", tmp / "arm.urdf")}


def _copy(src: Path, dst: Path) -> Path:
    shutil.copy(src, dst)
    return dst


# --------------------------------------------------------------------------- damaged CSVs
@builder
def csv_zero_bytes(tmp: Path) -> dict[str, Path]:
    f = tmp / "run.csv"
    f.write_bytes(b"")
    return {"file": f}


@builder
def csv_header_only(tmp: Path) -> dict[str, Path]:
    return {"file": write_csv(tmp / "run.csv", rows=[])}


@builder
def csv_whitespace_only(tmp: Path) -> dict[str, Path]:
    f = tmp / "run.csv"
    f.write_text("\n\n   \n\t\n")
    return {"file": f}


@builder
def csv_one_row(tmp: Path) -> dict[str, Path]:
    return {"file": write_csv(tmp / "run.csv", rows=csv_rows()[:1])}


@builder
def csv_utf16(tmp: Path) -> dict[str, Path]:
    return {"file": write_csv(tmp / "run.csv", encoding="utf-16")}


@builder
def csv_utf8_bom(tmp: Path) -> dict[str, Path]:
    return {"file": write_csv(tmp / "run.csv", encoding="utf-8-sig")}


@builder
def csv_latin1(tmp: Path) -> dict[str, Path]:
    """A header with a degree sign and a title line in latin-1 (not valid UTF-8)."""
    header = [*HEADER[:5], "yaw [°]", *HEADER[6:]]
    return {
        "file": write_csv(
            tmp / "run.csv", header=header, encoding="latin-1", title="Messung Ä, Fahrt 1\n"
        )
    }


@builder
def csv_title_lines(tmp: Path) -> dict[str, Path]:
    return {
        "file": write_csv(
            tmp / "run.csv", title="Kobuki logger v2.1  2024-03-05 09:02\nunits: time s, pose m\n"
        )
    }


@builder
def csv_semicolon_decimal_comma(tmp: Path) -> dict[str, Path]:
    rows = [[c.replace(".", ",") for c in r] for r in csv_rows()]
    return {"file": write_csv(tmp / "run.csv", rows=rows, sep=";")}


@builder
def csv_huge_cell(tmp: Path) -> dict[str, Path]:
    rows = csv_rows()
    rows[10][3] = "x" * 2_000_000
    return {"file": write_csv(tmp / "run.csv", rows=rows)}


@builder
def csv_huge_number(tmp: Path) -> dict[str, Path]:
    rows = csv_rows()
    rows[10][3] = "9" * 400
    return {"file": write_csv(tmp / "run.csv", rows=rows)}


@builder
def csv_huge_header(tmp: Path) -> dict[str, Path]:
    return {"file": write_csv(tmp / "run.csv", header=[*HEADER, "c" * 1_000_000])}


@builder
def csv_binary_garbage(tmp: Path) -> dict[str, Path]:
    f = tmp / "run.csv"
    f.write_bytes(bytes(range(256)) * 64)
    return {"file": f}


@builder
def csv_nan_time(tmp: Path) -> dict[str, Path]:
    rows = csv_rows()
    rows[100][0] = "nan"
    return {"file": write_csv(tmp / "run.csv", rows=rows)}


@builder
def csv_empty_time_cell(tmp: Path) -> dict[str, Path]:
    rows = csv_rows()
    rows[100][0] = ""
    return {"file": write_csv(tmp / "run.csv", rows=rows)}


@builder
def csv_inf_pose(tmp: Path) -> dict[str, Path]:
    rows = csv_rows()
    rows[100][3] = "inf"
    return {"file": write_csv(tmp / "run.csv", rows=rows)}


@builder
def csv_nan_pose(tmp: Path) -> dict[str, Path]:
    rows = csv_rows()
    rows[100][3] = "nan"
    return {"file": write_csv(tmp / "run.csv", rows=rows)}


@builder
def csv_text_in_number(tmp: Path) -> dict[str, Path]:
    rows = csv_rows()
    rows[100][4] = "twelve"
    return {"file": write_csv(tmp / "run.csv", rows=rows)}


@builder
def csv_time_backwards(tmp: Path) -> dict[str, Path]:
    rows = csv_rows()
    rows[200][0], rows[201][0] = rows[201][0], rows[200][0]
    return {"file": write_csv(tmp / "run.csv", rows=rows)}


@builder
def csv_time_reset(tmp: Path) -> dict[str, Path]:
    """The clock restarts at 0 half-way (a logger restarted)."""
    return {"file": write_csv(tmp / "run.csv", rows=csv_rows()[:250] + csv_rows()[:250])}


@builder
def csv_duplicate_stamps(tmp: Path) -> dict[str, Path]:
    rows = csv_rows()
    rows = [*rows[:150], list(rows[150]), *rows[150:]]
    return {"file": write_csv(tmp / "run.csv", rows=rows)}


@builder
def csv_constant_time(tmp: Path) -> dict[str, Path]:
    rows = [["0.000", *r[1:]] for r in csv_rows()]
    return {"file": write_csv(tmp / "run.csv", rows=rows)}


@builder
def csv_time_ms(tmp: Path) -> dict[str, Path]:
    """The time in ms, the map saying nothing: rows 50 'seconds' apart."""
    return {"file": write_csv(tmp / "run.csv", csv_rows(with_cols(time=lambda t: t * 1000)))}


@builder
def csv_heading_degrees(tmp: Path) -> dict[str, Path]:
    return {"file": write_csv(tmp / "run.csv", csv_rows(with_cols(yaw=np.degrees)))}


@builder
def csv_turn_rate_degs(tmp: Path) -> dict[str, Path]:
    return {"file": write_csv(tmp / "run.csv", csv_rows(with_cols(w=np.degrees)))}


@builder
def csv_pose_mm(tmp: Path) -> dict[str, Path]:
    return {
        "file": write_csv(
            tmp / "run.csv", csv_rows(with_cols(x=lambda a: a * 1000, y=lambda a: a * 1000))
        )
    }


@builder
def csv_speed_mm_s(tmp: Path) -> dict[str, Path]:
    return {"file": write_csv(tmp / "run.csv", csv_rows(with_cols(v=lambda a: a * 1000)))}


@builder
def csv_ticks_wrap16(tmp: Path) -> dict[str, Path]:
    """Encoders as a 16-bit counter that wraps (starting near the top so it wraps early)."""
    return {
        "file": write_csv(
            tmp / "run.csv",
            csv_rows(
                with_cols(enc_l=lambda a: (a + 65000) % 65536, enc_r=lambda a: (a + 65200) % 65536)
            ),
        )
    }


@builder
def csv_missing_column(tmp: Path) -> dict[str, Path]:
    header = [h for h in HEADER if h != "yaw"]
    rows = [r[:5] + r[6:] for r in csv_rows()]
    return {"file": write_csv(tmp / "run.csv", rows=rows, header=header)}


@builder
def csv_duplicate_header(tmp: Path) -> dict[str, Path]:
    return {"file": write_csv(tmp / "run.csv", header=[*HEADER[:7], "enc_l"])}


@builder
def csv_ragged(tmp: Path) -> dict[str, Path]:
    rows = csv_rows()
    rows[50] = rows[50][:3]
    rows[60] = [*rows[60], "1", "2"]
    return {"file": write_csv(tmp / "run.csv", rows=rows)}


@builder
def csv_truncated_mid_row(tmp: Path) -> dict[str, Path]:
    f = write_csv(tmp / "run.csv")
    data = f.read_bytes()
    f.write_bytes(data[: len(data) // 2 + 7])
    return {"file": f}


@builder
def csv_nul_bytes(tmp: Path) -> dict[str, Path]:
    f = write_csv(tmp / "run.csv")
    data = bytearray(f.read_bytes())
    data[2000:2010] = b"\0" * 10
    f.write_bytes(bytes(data))
    return {"file": f}


@builder
def csv_crlf(tmp: Path) -> dict[str, Path]:
    f = write_csv(tmp / "run.csv")
    f.write_bytes(f.read_bytes().replace(b"\n", b"\r\n"))
    return {"file": f}


@builder
def csv_long_gap(tmp: Path) -> dict[str, Path]:
    """30 s without rows in the middle."""
    c = with_cols(time=lambda t: np.where(np.arange(len(t)) >= 260, t + 30.0, t))
    return {"file": write_csv(tmp / "run.csv", csv_rows(c))}


@builder
def csv_as_npz_ext(tmp: Path) -> dict[str, Path]:
    """A text file named .npz (extension contradicts content)."""
    return {"file": write_csv(tmp / "run.npz")}


@builder
def csv_as_bag_ext(tmp: Path) -> dict[str, Path]:
    return {"file": write_csv(tmp / "run.bag")}


@builder
def csv_with_odd_name(tmp: Path) -> dict[str, Path]:
    """A valid CSV whose name has spaces, a plus sign and non-ASCII letters."""
    return {"file": write_csv(tmp / "Fahrt 1+Ü (copy).csv")}


# --------------------------------------------------------------------------- npz tables
def _npz_cols() -> dict[str, np.ndarray]:
    return {k: np.asarray(v, dtype=float) for k, v in real_columns().items()}


def _npz(tmp: Path, **change: object) -> dict[str, Path]:
    cols: dict[str, object] = dict(_npz_cols())
    cols.update(change)
    f = tmp / "table.npz"
    np.savez(f, **cols)  # type: ignore[arg-type]
    return {"file": f}


@builder
def npz_table(tmp: Path) -> dict[str, Path]:
    return _npz(tmp)


@builder
def npz_complex(tmp: Path) -> dict[str, Path]:
    return _npz(tmp, x=_npz_cols()["x"] + 1j)


@builder
def npz_bool(tmp: Path) -> dict[str, Path]:
    return _npz(tmp, x=_npz_cols()["x"] > 0)


@builder
def npz_object(tmp: Path) -> dict[str, Path]:
    f = tmp / "table.npz"
    cols: dict[str, object] = dict(_npz_cols())
    cols["x"] = np.array([{"a": 1}] * len(_npz_cols()["x"]), dtype=object)
    np.savez(f, **cols)  # type: ignore[arg-type]
    return {"file": f}


@builder
def npz_datetime(tmp: Path) -> dict[str, Path]:
    t = np.datetime64("2024-03-05T09:02:00") + (_npz_cols()["time"] * 1000).astype(
        "timedelta64[ms]"
    )
    return _npz(tmp, time=t)


@builder
def npz_string(tmp: Path) -> dict[str, Path]:
    return _npz(tmp, x=_npz_cols()["x"].astype(str))


@builder
def npz_2d(tmp: Path) -> dict[str, Path]:
    return _npz(tmp, x=np.stack([_npz_cols()["x"]] * 3, axis=1))


@builder
def npz_lengths_differ(tmp: Path) -> dict[str, Path]:
    return _npz(tmp, x=_npz_cols()["x"][:100])


@builder
def npz_truncated(tmp: Path) -> dict[str, Path]:
    f = _npz(tmp)["file"]
    data = f.read_bytes()
    f.write_bytes(data[: len(data) // 2])
    return {"file": f}


@builder
def npz_saved_log_truncated(tmp: Path) -> dict[str, Path]:
    f = saved_log(tmp)["file"]
    data = f.read_bytes()
    f.write_bytes(data[: len(data) - 200])
    return {"file": f}


@builder
def npz_empty_zip(tmp: Path) -> dict[str, Path]:
    f = tmp / "table.npz"
    with zipfile.ZipFile(f, "w"):
        pass
    return {"file": f}


@builder
def npz_zip_of_text(tmp: Path) -> dict[str, Path]:
    """A zip whose member is not an .npy array."""
    f = tmp / "table.npz"
    with zipfile.ZipFile(f, "w") as zf:
        zf.writestr("time.npy", b"this is not an array")
    return {"file": f}


@builder
def npz_huge_shape(tmp: Path) -> dict[str, Path]:
    """A 1 MB .npz whose array header declares 10**12 rows (8 TB): refused, not allocated."""
    f = tmp / "table.npz"
    header = b"{'descr': '<f8', 'fortran_order': False, 'shape': (1000000000000,), }"
    header = header + b" " * (118 - len(header)) + b"\n"
    npy = b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header
    with zipfile.ZipFile(f, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("time.npy", npy + b"\0" * (1 << 20))
        for k, v in _npz_cols().items():
            if k != "time":
                import io

                buf = io.BytesIO()
                np.save(buf, v)
                zf.writestr(f"{k}.npy", buf.getvalue())
    return {"file": f}


# --------------------------------------------------------------------------- odd paths
@builder
def symlink_loop(tmp: Path) -> dict[str, Path]:
    f = tmp / "loop.csv"
    os.symlink("loop.csv", f)
    return {"file": f}


@builder
def dangling_symlink(tmp: Path) -> dict[str, Path]:
    f = tmp / "gone.csv"
    os.symlink("nowhere.csv", f)
    return {"file": f}


@builder
def folder_as_file(tmp: Path) -> dict[str, Path]:
    f = tmp / "run.csv"
    f.mkdir()
    (f / "inner.txt").write_text("x\n")
    return {"file": f}


@builder
def empty_folder(tmp: Path) -> dict[str, Path]:
    f = tmp / "logs"
    f.mkdir()
    return {"file": f}


@builder
def fifo(tmp: Path) -> dict[str, Path]:
    f = tmp / "run.csv"
    os.mkfifo(f)
    return {"file": f}


@builder
def unreadable(tmp: Path) -> dict[str, Path]:
    f = write_csv(tmp / "run.csv")
    f.chmod(0)
    return {"file": f}


@builder
def missing(tmp: Path) -> dict[str, Path]:
    return {"file": tmp / "no_such_run.csv"}


@builder
def session_damaged_metadata(tmp: Path) -> dict[str, Path]:
    d = real_session(tmp)
    meta = d["session"] / "231220200157_metadata.csv"
    meta.write_text("type,diff,\nngear,lots,\n")
    return d


@builder
def session_missing_run(tmp: Path) -> dict[str, Path]:
    d = real_session(tmp)
    (d["session"] / "231220200157_run-02.csv").unlink()
    (d["session"] / "231220200157_run-01.csv").write_text("")
    return d


@builder
def session_empty_square(tmp: Path) -> dict[str, Path]:
    """A folder named like a session holding only its metadata."""
    d = tmp / "data" / "231220200029"
    d.mkdir(parents=True)
    shutil.copy(sample_root() / SQUARE / "231220200029_metadata.csv", d)
    return {"session": d, "file": d}


# --------------------------------------------------------------------------- outputs
@builder
def out_existing_file(tmp: Path) -> dict[str, Path]:
    d = real_csv(tmp)
    d["out"] = tmp / "existing.json"
    d["out"].write_text('{"keep": true}\n')
    sess = real_session(tmp)
    d["session"], d["square"] = sess["session"], sess["square"]
    return d


@builder
def out_existing_folder(tmp: Path) -> dict[str, Path]:
    d = real_csv(tmp)
    d["out"] = tmp / "outdir"
    d["out"].mkdir()
    (d["out"] / "keep.txt").write_text("keep\n")
    sess = real_session(tmp)
    d["session"], d["square"] = sess["session"], sess["square"]
    return d


@builder
def out_under_file(tmp: Path) -> dict[str, Path]:
    d = real_csv(tmp)
    blocker = tmp / "blocker"
    blocker.write_text("a file\n")
    d["out"] = blocker / "sub" / "out.json"
    sess = real_session(tmp)
    d["session"], d["square"] = sess["session"], sess["square"]
    return d


@builder
def out_read_only(tmp: Path) -> dict[str, Path]:
    d = real_csv(tmp)
    ro = tmp / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    d["out"] = ro / "out.json"
    sess = real_session(tmp)
    d["session"], d["square"] = sess["session"], sess["square"]
    return d


# --------------------------------------------------------------------------- column maps (JSON)
def _json(tmp: Path, obj: object, name: str = "map.json") -> dict[str, Path]:
    d = real_csv(tmp)
    d["map"] = tmp / name
    d["map"].write_text(obj if isinstance(obj, str) else json.dumps(obj))
    return d


@builder
def map_json_valid(tmp: Path) -> dict[str, Path]:
    return _json(
        tmp,
        {
            "t": "time",
            "cmd.v": "v",
            "cmd.w": "w",
            "pose_gt.x": ["x", "m"],
            "pose_gt.y": "y",
            "pose_gt.theta": "yaw",
            "ticks.left": "enc_l",
            "ticks.right": "enc_r",
        },
    )


@builder
def map_json_list(tmp: Path) -> dict[str, Path]:
    return _json(tmp, [["t", "time"], ["pose_gt.x", "x"]])


@builder
def map_json_number(tmp: Path) -> dict[str, Path]:
    return _json(tmp, 42)


@builder
def map_json_string(tmp: Path) -> dict[str, Path]:
    return _json(tmp, "t=time,pose_gt.x=x")


@builder
def map_json_null(tmp: Path) -> dict[str, Path]:
    return _json(tmp, None)


@builder
def map_json_invalid(tmp: Path) -> dict[str, Path]:
    return _json(tmp, "{'t': 'time', pose_gt.x: x")


@builder
def map_json_value_number(tmp: Path) -> dict[str, Path]:
    return _json(tmp, {"t": "time", "pose_gt.x": 3.5, "pose_gt.y": "y", "pose_gt.theta": "yaw"})


@builder
def map_json_value_dict(tmp: Path) -> dict[str, Path]:
    return _json(tmp, {"t": "time", "pose_gt.x": {"col": "x"}, "pose_gt.y": "y"})


@builder
def map_json_value_bool(tmp: Path) -> dict[str, Path]:
    return _json(tmp, {"t": "time", "pose_gt.x": True, "pose_gt.y": "y"})


@builder
def map_json_value_long_list(tmp: Path) -> dict[str, Path]:
    return _json(tmp, {"t": "time", "pose_gt.x": ["x", "m", "extra"], "pose_gt.y": "y"})


@builder
def map_json_unknown_unit(tmp: Path) -> dict[str, Path]:
    return _json(
        tmp,
        {"t": ["time", "fortnights"], "pose_gt.x": "x", "pose_gt.y": "y", "pose_gt.theta": "yaw"},
    )


@builder
def map_json_ticks_bad(tmp: Path) -> dict[str, Path]:
    return _json(tmp, {"t": "time", "ticks.left": "enc_l", "ticks.right": "enc_r", "ticks": 5})


@builder
def map_json_empty_object(tmp: Path) -> dict[str, Path]:
    return _json(tmp, {})


@builder
def map_json_utf16(tmp: Path) -> dict[str, Path]:
    d = real_csv(tmp)
    d["map"] = tmp / "map.json"
    d["map"].write_bytes(json.dumps({"t": "time", "pose_gt.x": "x"}).encode("utf-16"))
    return d


# --------------------------------------------------------------------------- robot files
def _robot(tmp: Path, text: str | bytes, name: str = "robot.yaml") -> dict[str, Path]:
    d = real_csv(tmp)
    d["robot"] = tmp / name
    if isinstance(text, bytes):
        d["robot"].write_bytes(text)
    else:
        d["robot"].write_text(text)
    d["urdf"] = _copy(DATA / "diffdrive.urdf", tmp / "robot.urdf")
    return d


GOOD_YAML = """\
robot: diffdrive
name: optiodom
wheels:
  radius: 0.042
  track: 0.2
  ticks_per_rev: 2796.8
firmware:
  a_max: 1.0
  alpha_max: 4.0
ground_truth:
  tracked_point: {x: 0.0, y: 0.0, yaw: 0.0}
"""

ROBOT_YAMLS: dict[str, str | bytes] = {
    "valid": GOOD_YAML,
    "valid_json": json.dumps(
        {"robot": "diffdrive", "wheels": {"radius": 0.042, "track": 0.2, "ticks_per_rev": 2796.8}}
    ),
    "with_urdf": "robot: diffdrive\nurdf: robot.urdf\nwheels:\n  ticks_per_rev: 4096\n",
    "empty": "",
    "a_list": "- robot: diffdrive\n- wheels: {}\n",
    "a_scalar": "diffdrive\n",
    "syntax": "robot: diffdrive\nwheels:\n  radius: [0.042\n  track: 0.2\n",
    "tabs": "robot: diffdrive\nwheels:\n\tradius: 0.042\n",
    "unknown_key": GOOD_YAML + "wheel_size: 3\n",
    "unknown_wheel_key": GOOD_YAML.replace("track: 0.2", "track: 0.2\n  trakc: 0.3"),
    "kind_unknown": GOOD_YAML.replace("robot: diffdrive", "robot: tank"),
    "kind_missing": GOOD_YAML.replace("robot: diffdrive\n", ""),
    "radius_negative": GOOD_YAML.replace("radius: 0.042", "radius: -0.042"),
    "radius_zero": GOOD_YAML.replace("radius: 0.042", "radius: 0"),
    "radius_string": GOOD_YAML.replace("radius: 0.042", "radius: big"),
    "radius_nan": GOOD_YAML.replace("radius: 0.042", "radius: .nan"),
    "radius_inf": GOOD_YAML.replace("radius: 0.042", "radius: .inf"),
    "radius_bool": GOOD_YAML.replace("radius: 0.042", "radius: true"),
    "radius_list": GOOD_YAML.replace("radius: 0.042", "radius: [0.04, 0.05]"),
    "radius_mm": GOOD_YAML.replace("radius: 0.042", "radius: 42"),
    "track_negative": GOOD_YAML.replace("track: 0.2", "track: -0.2"),
    "ticks_zero": GOOD_YAML.replace("ticks_per_rev: 2796.8", "ticks_per_rev: 0"),
    "ticks_negative": GOOD_YAML.replace("ticks_per_rev: 2796.8", "ticks_per_rev: -100"),
    "wheels_not_mapping": GOOD_YAML.replace(
        "wheels:\n  radius: 0.042\n  track: 0.2\n  ticks_per_rev: 2796.8\n", "wheels: 5\n"
    ),
    "firmware_negative": GOOD_YAML.replace("a_max: 1.0", "a_max: -1.0"),
    "firmware_string": GOOD_YAML.replace("a_max: 1.0", "a_max: fast"),
    "tracked_far": GOOD_YAML.replace("{x: 0.0, y: 0.0, yaw: 0.0}", "{x: 5.0, y: 0.0, yaw: 0.0}"),
    "tracked_nan": GOOD_YAML.replace("{x: 0.0, y: 0.0, yaw: 0.0}", "{x: .nan, y: 0.0, yaw: 0.0}"),
    "tracked_list": GOOD_YAML.replace("{x: 0.0, y: 0.0, yaw: 0.0}", "[0.0, 0.0, 0.0]"),
    "urdf_missing": "robot: diffdrive\nurdf: no_such.urdf\n",
    "urdf_number": "robot: diffdrive\nurdf: 5\n",
    "arm_with_wheels": "robot: arm\nwheels:\n  radius: 0.04\n",
    "arm_without_urdf": "robot: arm\narm:\n  noise: 2.0e-5\n",
    "python_tag": "robot: !!python/object/apply:os.system ['echo pwned > pwned.txt']\n",
    "anchor_bomb": "a: &a [x,x,x,x,x,x,x,x,x]\nb: &b [*a,*a,*a,*a,*a,*a,*a,*a,*a]\n"
    "c: &c [*b,*b,*b,*b,*b,*b,*b,*b,*b]\nd: &d [*c,*c,*c,*c,*c,*c,*c,*c,*c]\n"
    "e: &e [*d,*d,*d,*d,*d,*d,*d,*d,*d]\nf: &f [*e,*e,*e,*e,*e,*e,*e,*e,*e]\n"
    "g: &g [*f,*f,*f,*f,*f,*f,*f,*f,*f]\nh: &h [*g,*g,*g,*g,*g,*g,*g,*g,*g]\n"
    "robot: diffdrive\n",
    "duplicate_key": GOOD_YAML + "robot: arm\n",
    "binary": bytes(range(256)) * 8,
    "utf16": GOOD_YAML.encode("utf-16"),
    "huge": "robot: diffdrive\nname: " + "n" * 3_000_000 + "\n",
}


def _robot_builder(key: str) -> Callable[[Path], dict[str, Path]]:
    def build(tmp: Path) -> dict[str, Path]:
        name = "robot.json" if key == "valid_json" else "robot.yaml"
        return _robot(tmp, ROBOT_YAMLS[key], name)

    build.__name__ = f"robot_{key}"
    return build


for _key in ROBOT_YAMLS:
    BUILDERS[f"robot_{_key}"] = _robot_builder(_key)


# --------------------------------------------------------------------------- URDFs
GOOD_URDF = (DATA / "diffdrive.urdf").read_text()

URDFS: dict[str, str] = {
    "valid": GOOD_URDF,
    "no_joints": "<?xml version='1.0'?><robot name='r'><link name='base_link'/></robot>",
    "one_wheel": GOOD_URDF.split('<joint name="wheel_right_joint"')[0] + "</robot>"
    if 'joint name="wheel_right_joint"' in GOOD_URDF
    else GOOD_URDF,
    "malformed": GOOD_URDF[: len(GOOD_URDF) // 2],
    "empty": "",
    "not_robot": "<?xml version='1.0'?><html><body>hi</body></html>",
    "missing_link": GOOD_URDF.replace('<child link="wheel_left_link"/>', '<child link="nope"/>'),
    "negative_radius": GOOD_URDF.replace('radius="0.035000"', 'radius="-0.035000"'),
    "nan_radius": GOOD_URDF.replace('radius="0.035000"', 'radius="nan"'),
    "text_radius": GOOD_URDF.replace('radius="0.035000"', 'radius="big"'),
    "zero_track": GOOD_URDF.replace('xyz="0 0.115000 0"', 'xyz="0 0 0"').replace(
        'xyz="0 -0.115000 0"', 'xyz="0 0 0"'
    ),
    "entity_bomb": "<?xml version='1.0'?><!DOCTYPE r [<!ENTITY a 'aaaaaaaaaa'>"
    "<!ENTITY b '&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;'><!ENTITY c '&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;'>"
    "<!ENTITY d '&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;'><!ENTITY e '&d;&d;&d;&d;&d;&d;&d;&d;&d;&d;'>"
    "<!ENTITY f '&e;&e;&e;&e;&e;&e;&e;&e;&e;&e;'><!ENTITY g '&f;&f;&f;&f;&f;&f;&f;&f;&f;&f;'>"
    "<!ENTITY h '&g;&g;&g;&g;&g;&g;&g;&g;&g;&g;'>]><robot name='&h;'><link name='base_link'/></robot>",
    "external_entity": "<?xml version='1.0'?><!DOCTYPE r [<!ENTITY x SYSTEM 'file:///etc/passwd'>]>"
    "<robot name='&x;'><link name='base_link'/></robot>",
}


def _urdf_builder(key: str) -> Callable[[Path], dict[str, Path]]:
    def build(tmp: Path) -> dict[str, Path]:
        d = real_csv(tmp)
        d["urdf"] = tmp / "robot.urdf"
        d["urdf"].write_text(URDFS[key])
        return d

    build.__name__ = f"urdf_{key}"
    return build


for _key in URDFS:
    BUILDERS[f"urdf_{_key}"] = _urdf_builder(_key)


# --------------------------------------------------------------------------- params / reality JSON
@builder
def params_json_list(tmp: Path) -> dict[str, Path]:
    d = real_csv(tmp)
    d["params"] = tmp / "params.json"
    d["params"].write_text("[0.042, 0.2]")
    return d


@builder
def params_json_invalid(tmp: Path) -> dict[str, Path]:
    d = real_csv(tmp)
    d["params"] = tmp / "params.json"
    d["params"].write_text("{wheelbase: 0.2")
    return d


@builder
def hyperparams_invalid(tmp: Path) -> dict[str, Path]:
    d = {"hp": tmp / "hp.json"}
    d["hp"].write_text("{not json")
    return d


@builder
def hyperparams_list(tmp: Path) -> dict[str, Path]:
    d = {"hp": tmp / "hp.json"}
    d["hp"].write_text("[1, 2, 3]")
    return d


@builder
def reality_json_bad(tmp: Path) -> dict[str, Path]:
    d = {"reality": tmp / "reality.json"}
    d["reality"].write_text('{"effects": [{"name": "no_such_effect", "values": {}}]}')
    return d


@builder
def reality_json_out_of_bounds(tmp: Path) -> dict[str, Path]:
    d = {"reality": tmp / "reality.json"}
    d["reality"].write_text('{"effects": [{"name": "command_latency", "values": {"delay": -5.0}}]}')
    return d


@builder
def model_zip_garbage(tmp: Path) -> dict[str, Path]:
    d = {"model": tmp / "model.zip"}
    d["model"].write_bytes(b"PK\x03\x04 not really a zip")
    return d
