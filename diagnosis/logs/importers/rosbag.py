"""Import a log from a ROS 1 bag or a ROS 2 bag through the ``rosbags`` package.

Topics (all configurable with :class:`BagTopics`):

=================  ==================================================  ============
log channel        topic and message types                              default
=================  ==================================================  ============
``cmd``            ``geometry_msgs/Twist`` or ``TwistStamped``          ``/cmd_vel``
``pose_est``       ``nav_msgs/Odometry``                                ``/odom``
``pose_gt``        a motion-capture topic (``PoseStamped``,             —
                   ``Odometry``, ``TransformStamped``) or ``/tf`` with
                   the tracked frame (``truth_frame``)
``ticks``          ``sensor_msgs/JointState`` of the two wheel joints    —
                   (positions in rad → counts)
=================  ==================================================  ============

Each topic keeps its own stamps: the log takes those of the wheel joints (else the
commands) and the others are aligned there (commands held, poses interpolated with
continuous headings, a long gap cutting the log rather than bridged); a fixed
``rate_hz`` resamples every topic instead. The bag is only read — messages are
deserialised by ``rosbags``; nothing is unpickled. A bag without the expected
topics raises :class:`~realitygap.diagnosis.logs.log.LogError` listing the topics
it has and the option to pass.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.core.checks import check_input_path, check_rows_limit
from realitygap.core.geometry import yaw_from_quat_xyzw
from realitygap.diagnosis.logs.align import align_streams, whole
from realitygap.diagnosis.logs.log import Log, LogError, sniff_file_kind
from realitygap.robots.diffdrive import DiffDriveParams
from realitygap.robots.diffdrive_replay import params_to_meta

FloatArray = npt.NDArray[np.float64]

__all__ = ["BagTopics", "read_bag", "read_bag_logs"]


@dataclass(frozen=True)
class BagTopics:
    """Which topics feed which channels.

    Attributes
    ----------
    cmd : str
        Velocity commands (``Twist`` / ``TwistStamped``).
    odom : str or None
        The robot's odometry estimate (``Odometry``); ``None`` to skip.
    truth : str or None
        Ground truth: a pose topic, or ``"/tf"`` together with ``truth_frame``.
    truth_frame : str or None
        Child frame tracked in ``/tf`` (e.g. the motion-capture rigid body).
    wheels : str or None
        ``JointState`` topic with the wheel joints; ``None`` to skip.
    wheel_joints : (str, str)
        Names of the left and right wheel joints.
    """

    cmd: str = "/cmd_vel"
    odom: str | None = "/odom"
    truth: str | None = None
    truth_frame: str | None = None
    wheels: str | None = None
    wheel_joints: tuple[str, str] = ("wheel_left_joint", "wheel_right_joint")


def _xyzw(q: Any) -> tuple[float, float, float, float]:
    """A ROS quaternion message as (x, y, z, w)."""
    return q.x, q.y, q.z, q.w


def _stamp(msg: Any, t_bag: int, use_header: bool) -> float:
    header = getattr(msg, "header", None)
    if use_header and header is not None:
        s = header.stamp
        value = float(s.sec) + 1e-9 * float(s.nanosec)
        if value > 0:
            return value
    return 1e-9 * float(t_bag)


def _pose_of(msg: Any, msgtype: str) -> tuple[float, float, float] | None:
    name = msgtype.split("/")[-1]
    if name == "Odometry":
        p = msg.pose.pose
        return (
            p.position.x,
            p.position.y,
            yaw_from_quat_xyzw(_xyzw(p.orientation)),
        )
    if name == "PoseStamped":
        p = msg.pose
        return (
            p.position.x,
            p.position.y,
            yaw_from_quat_xyzw(_xyzw(p.orientation)),
        )
    if name == "PoseWithCovarianceStamped":
        p = msg.pose.pose
        return (
            p.position.x,
            p.position.y,
            yaw_from_quat_xyzw(_xyzw(p.orientation)),
        )
    if name == "TransformStamped":
        tr = msg.transform
        return (
            tr.translation.x,
            tr.translation.y,
            yaw_from_quat_xyzw(_xyzw(tr.rotation)),
        )
    if name == "Pose":
        return (
            msg.position.x,
            msg.position.y,
            yaw_from_quat_xyzw(_xyzw(msg.orientation)),
        )
    return None


def _twist_of(msg: Any, msgtype: str) -> tuple[float, float] | None:
    name = msgtype.split("/")[-1]
    if name == "Twist":
        return msg.linear.x, msg.angular.z
    if name == "TwistStamped":
        return msg.twist.linear.x, msg.twist.angular.z
    return None


def read_bag(
    path: str | os.PathLike[str],
    topics: BagTopics | None = None,
    *,
    rate_hz: float | None = None,
    params: DiffDriveParams | Mapping[str, Any] | None = None,
    meta: Mapping[str, Any] | None = None,
    use_header_stamps: bool = True,
) -> Log:
    """Read a bag into one :class:`Log` (:func:`read_bag_logs`; an error if a topic's gaps
    would cut it into pieces)."""
    return whole(
        lambda warn: read_bag_logs(
            path,
            topics,
            rate_hz=rate_hz,
            params=params,
            meta=meta,
            use_header_stamps=use_header_stamps,
            warn=warn,
        ),
        path,
        "read_bag_logs",
    )


def read_bag_logs(
    path: str | os.PathLike[str],
    topics: BagTopics | None = None,
    *,
    rate_hz: float | None = None,
    params: DiffDriveParams | Mapping[str, Any] | None = None,
    meta: Mapping[str, Any] | None = None,
    use_header_stamps: bool = True,
    max_gap: float | None = None,
    warn: Callable[[str], None] | None = None,
) -> list[Log]:
    """Read a ROS 1 (``.bag``) or ROS 2 (folder, ``.db3``, ``.mcap``) bag into logs.

    Each topic keeps its own stamps: the log takes those of the wheel joints (else the
    commands) and the other topics are aligned there
    (:func:`~realitygap.diagnosis.logs.align.align_streams`: commands held, poses
    interpolated with continuous headings, a gap longer than ``max_gap`` cutting the log);
    ``rate_hz`` resamples every topic to a fixed rate instead.

    Parameters
    ----------
    path : path-like
        The bag file or ROS 2 bag folder.
    topics : BagTopics, optional
    rate_hz : float, optional
        Resample to this rate (Hz) instead of aligning on a topic's own stamps.
    params : DiffDriveParams or mapping, optional
        Nominal robot parameters (default: the Kobuki-like defaults); needed to
        turn wheel angles into counts.
    meta : mapping, optional
    use_header_stamps : bool
        Use message header stamps when present (else the bag's receive time).

    Raises
    ------
    LogError
        Not a bag, missing topics (the message lists those present), a topic of
        an unexpected type, or too few messages.
    ImportError
        If ``rosbags`` is not installed (``pip install 'realitygap[ros]'``).
    """
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise ImportError(
            "reading ROS bags needs the optional dependency 'rosbags'. Fix: pip install "
            "'realitygap[ros]'"
        ) from None
    topics = topics if topics is not None else BagTopics()
    p = Path(path)
    try:
        check_input_path(p, "bag", needs="a bag needs messages")
    except ValueError as exc:
        raise LogError(str(exc)) from None
    kind = sniff_file_kind(p)
    if kind == "directory":
        if not (p / "metadata.yaml").is_file():
            raise LogError(f"{p}: a folder but not a ROS 2 bag (no metadata.yaml)")
    elif kind in ("sqlite", "mcap"):
        if (p.parent / "metadata.yaml").is_file():
            p = p.parent
        else:
            raise LogError(
                f"{p}: a ROS 2 storage file without its metadata.yaml; pass the bag folder"
            )
    elif kind != "rosbag1":
        raise LogError(
            f"{p}: not a ROS bag (its content looks like {kind}); whatever its extension, pass "
            "it with the matching importer"
        )
    if rate_hz is not None and not (rate_hz > 0 and math.isfinite(rate_hz)):
        raise ValueError(f"rate_hz must be a positive number, got {rate_hz!r}")
    params_obj = (
        params
        if isinstance(params, DiffDriveParams)
        else DiffDriveParams(**{k: v for k, v in dict(params or {}).items() if k != "camera"})
    )
    wanted = {"cmd": topics.cmd}
    if topics.odom:
        wanted["odom"] = topics.odom
    if topics.truth:
        wanted["truth"] = topics.truth
    if topics.wheels:
        wanted["wheels"] = topics.wheels

    series: dict[str, list[tuple[float, tuple[float, ...]]]] = {k: [] for k in wanted}
    try:
        reader = AnyReader([p], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except Exception as exc:  # rosbags raises its own error types
        raise LogError(f"{p}: cannot open the bag ({type(exc).__name__}: {exc})") from None
    try:
        present = {c.topic: c.msgtype for c in reader.connections}
        missing = [f"{k} ({t})" for k, t in wanted.items() if t not in present and k != "odom"]
        if missing:
            listing = ", ".join(f"{t} [{m}]" for t, m in sorted(present.items())) or "none"
            raise LogError(
                f"{p}: the bag has no topic for {', '.join(missing)}; topics present: {listing}. "
                "Fix: name the topics (CLI --cmd-topic, --truth-topic, --truth-frame, "
                "--wheels-topic)"
            )
        if topics.odom and topics.odom not in present:
            wanted.pop("odom")
            series.pop("odom")
        by_topic = {t: k for k, t in wanted.items()}
        conns = [c for c in reader.connections if c.topic in by_topic]
        topic = ""
        try:
            for conn, t_bag, raw in reader.messages(connections=conns):
                topic = conn.topic
                key = by_topic[conn.topic]
                msg: Any = reader.deserialize(raw, conn.msgtype)
                if key == "cmd":
                    tw = _twist_of(msg, conn.msgtype)
                    if tw is None:
                        raise LogError(
                            f"{p}: topic {conn.topic} is {conn.msgtype}, expected geometry_msgs/Twist "
                            "or TwistStamped"
                        )
                    series[key].append((_stamp(msg, t_bag, use_header_stamps), tw))
                elif key == "wheels":
                    names = list(msg.name)
                    try:
                        il, ir = (names.index(j) for j in topics.wheel_joints)
                    except ValueError:
                        raise LogError(
                            f"{p}: {conn.topic} has joints {names}, not the wheel joints "
                            f"{topics.wheel_joints}. Fix: pass wheel_joints (CLI --wheel-joints)"
                        ) from None
                    pos = msg.position
                    series[key].append((_stamp(msg, t_bag, use_header_stamps), (pos[il], pos[ir])))
                elif conn.msgtype.endswith("TFMessage"):
                    if not topics.truth_frame:
                        raise LogError(
                            f"{p}: ground truth from {conn.topic} needs the tracked frame. Fix: pass "
                            "truth_frame (CLI --truth-frame)"
                        )
                    for tr in msg.transforms:
                        if tr.child_frame_id.strip("/") == topics.truth_frame.strip("/"):
                            pose = _pose_of(tr, "geometry_msgs/msg/TransformStamped")
                            assert pose is not None
                            series[key].append((_stamp(tr, t_bag, use_header_stamps), pose))
                else:
                    pose = _pose_of(msg, conn.msgtype)
                    if pose is None:
                        raise LogError(
                            f"{p}: topic {conn.topic} is {conn.msgtype}; expected a pose (PoseStamped, "
                            "Odometry, TransformStamped) or tf2_msgs/TFMessage"
                        )
                    series[key].append((_stamp(msg, t_bag, use_header_stamps), pose))
        except LogError:
            raise
        except Exception as exc:  # rosbags' own errors: a cut chunk, an unknown message type
            at = f" in topic {topic}" if topic else ""
            raise LogError(
                f"{p}: cannot read the bag{at} ({type(exc).__name__}: {exc}). Fix: check the "
                "bag (ros2 bag info / rosbag info; rosbag reindex repairs an unclosed ROS 1 bag), "
                "or leave that topic out"
            ) from None
    finally:
        reader.close()

    arrays: dict[str, tuple[FloatArray, FloatArray]] = {}
    for key, rows in series.items():
        if key == "truth" and topics.truth_frame and not rows:
            raise LogError(
                f"{p}: no transform to frame {topics.truth_frame!r} in {topics.truth}. Fix: check "
                "--truth-frame"
            )
        if len(rows) < 2:
            raise LogError(f"{p}: topic {wanted[key]} has {len(rows)} message(s); need at least 2")
        rows.sort(key=lambda r: r[0])
        ts = np.array([r[0] for r in rows])
        vals = np.array([r[1] for r in rows], dtype=float)
        keep = np.concatenate([[True], np.diff(ts) > 0])
        arrays[key] = (ts[keep], vals[keep])

    k_ticks = params_obj.ticks_per_rev / (2.0 * math.pi)
    full_meta: dict[str, Any] = {
        "robot": "diffdrive",
        "params": params_to_meta(params_obj),
        "name": Path(path).stem,
        "source": str(path),
        "topics": {k: v for k, v in wanted.items()},
    }
    full_meta.update(dict(meta or {}))
    if rate_hz is None:
        own: dict[str, tuple[FloatArray, FloatArray]] = {"cmd": arrays["cmd"]}
        for key, chan in (("truth", "pose_gt"), ("odom", "pose_est")):
            if key in arrays:
                ts, vals = arrays[key]
                own[chan] = (ts, np.column_stack([vals[:, :2], np.unwrap(vals[:, 2])]))
        if "wheels" in arrays:
            wt, wv = arrays["wheels"]
            # a JointState angle is a count times 2π/N: rounding gives the count back (flooring
            # would lose one wherever the division leaves 2.9999…)
            own["ticks"] = (wt, np.rint((wv - wv[0]) * k_ticks))
        return align_streams(
            own,
            name=Path(path).stem,
            source=str(path),
            meta=full_meta,
            max_gap=max_gap,
            warn=warn,
            shift_time=True,
        )
    starts = [arrays[k][0][0] for k in arrays]
    ends = [arrays[k][0][-1] for k in arrays if k != "cmd"] or [arrays["cmd"][0][-1]]
    t0, t1 = max(starts), min(ends)
    dt = 1.0 / rate_hz
    n = int(math.floor((t1 - t0) / dt + 1e-9)) + 1
    try:
        check_rows_limit(n, 3 * len(arrays), f"{p} at --rate {rate_hz:g} Hz")
    except ValueError as exc:
        raise LogError(str(exc)) from None
    if n < 3:
        raise LogError(
            f"{p}: the topics overlap for only {max(t1 - t0, 0.0):.3f} s; nothing to diagnose"
        )
    t = t0 + dt * np.arange(n)
    channels: dict[str, FloatArray] = {}
    ct, cv = arrays["cmd"]
    idx = np.clip(np.searchsorted(ct, t, side="right") - 1, 0, len(ct) - 1)
    channels["cmd"] = cv[idx]

    def interp_pose(ts: FloatArray, vals: FloatArray) -> FloatArray:
        th = np.unwrap(vals[:, 2])
        return np.column_stack(
            [np.interp(t, ts, vals[:, 0]), np.interp(t, ts, vals[:, 1]), np.interp(t, ts, th)]
        )

    if "truth" in arrays:
        channels["pose_gt"] = interp_pose(*arrays["truth"])
    if "odom" in arrays:
        channels["pose_est"] = interp_pose(*arrays["odom"])
    if "wheels" in arrays:
        wt, wv = arrays["wheels"]
        ang = np.column_stack([np.interp(t, wt, wv[:, 0]), np.interp(t, wt, wv[:, 1])])
        channels["ticks"] = np.floor((ang - ang[0]) * k_ticks)
    return [Log(t=t - t0, channels=channels, meta=full_meta, source=str(path))]
