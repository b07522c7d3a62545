"""Per-log ground-truth frames: each recording's rigid body, aligned before any effect."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from realitygap.core.geometry import reframe_recorded, reframe_track
from realitygap.diagnosis.diagnose import DiagnosisSettings, diagnose
from realitygap.diagnosis.stages.frames import align_frames, frame_channel


def _track() -> np.ndarray:
    t = np.linspace(0.0, 20.0, 400)
    heading = 0.4 + 0.3 * np.sin(0.2 * t)
    return np.column_stack(
        [1.0 + np.cumsum(0.01 * np.cos(heading)), -2.0 + np.cumsum(0.01 * np.sin(heading)), heading]
    )


def test_reframing_a_record_equals_recording_under_the_other_frame() -> None:
    body = _track()
    f1, f2 = np.array([0.012, -0.007, 0.02]), np.array([-0.004, 0.003, -0.01])
    recorded = reframe_track(body, f1)
    np.testing.assert_allclose(
        reframe_recorded(recorded, f1, f2), reframe_track(body, f2), atol=1e-12
    )
    # the same frame is the identity, and headings never change
    np.testing.assert_allclose(reframe_recorded(recorded, f1, f1), recorded, atol=1e-12)
    np.testing.assert_array_equal(reframe_recorded(recorded, f1, f2)[:, 2], recorded[:, 2])
    with pytest.raises(ValueError, match=r"reframe_recorded: expected a track \(N, 3\)"):
        reframe_recorded(recorded[:, :2], f1, f2)


def test_the_frame_effect_names_the_ground_truth_channel() -> None:
    assert frame_channel("truth_frame_offset") == "pose_gt"
    assert frame_channel("wheelbase_error") is None
    assert frame_channel("no_such_effect") is None


def test_align_frames_wants_the_three_frame_parameters_of_one_effect() -> None:
    box = [(-0.02, 0.02)] * 3
    with pytest.raises(ValueError, match="align_frames: expected the x, y and yaw"):
        align_frames(None, ("truth_frame_offset.x", "truth_frame_offset.y"), box[:2])  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="align_frames: expected the x, y and yaw"):
        align_frames(None, ("truth_frame_offset.x", "truth_frame_offset.y", "a.yaw"), box)  # type: ignore[arg-type]


def _sessions(root: Path, seed: int) -> dict[str, np.ndarray]:
    """UMBmark squares under one rigid body; circles of two later sessions under another
    (origin 8 mm behind the axle, heading 9 mrad off); the axle 2 % wider throughout
    (the package's independent generator). Returns, per circle, the motion capture the
    squares' rigid body would have recorded of the same drive (same random draws)."""
    import realitygap.independent.diffdrive as dd

    rng = np.random.default_rng(seed)
    robot = dd.DriveRobot()
    h = dd.Hidden(b_true=1.02)
    squares = [
        dd.simulate_run(dd.square_path(robot, 1.0, d), robot, h, rng) for d in ("cw", "ccw") * 2
    ]
    dd.write_session(root, "010320241010", squares, robot, "square", side=1.0, rng=rng)
    moved = dd.Hidden(b_true=1.02, marker_dx=-0.008, marker_yaw=0.009)
    twins: dict[str, np.ndarray] = {}
    for sid, (r, d) in zip(("020320241220", "030320241230"), ((0.5, "cw"), (0.6, "ccw"))):
        state = rng.bit_generator.state
        twin = dd.simulate_run(dd.circle_path(robot, r, d), robot, h, rng)
        rng.bit_generator.state = state
        runs = [dd.simulate_run(dd.circle_path(robot, r, d), robot, moved, rng)]
        twins[f"{sid}_run-01"] = twin.gt
        dd.write_session(root, sid, runs, robot, "circular", rng=rng)
    return twins


@pytest.mark.slow
def test_each_session_keeps_its_own_rigid_body(tmp_path: Path) -> None:
    from realitygap.diagnosis.logs.read import logs_from_optiodom

    twins = _sessions(tmp_path, seed=3)
    logs = logs_from_optiodom(tmp_path)
    train = [lg for lg in logs if lg.meta.get("path_type") == "square"]
    held = [lg for lg in logs if lg.meta.get("path_type") != "square"]
    d = diagnose(train, held, settings=DiagnosisSettings(drive="ticks"))
    frames = d.baseline.frames
    rows = {r["log"]: r for r in frames.rows}
    assert len(rows) == len(logs)
    # the squares share the common frame: none of them is moved
    assert not any(rows[lg.meta["name"]]["applied"] for lg in train)
    assert np.abs(np.array(frames.common[:2])).max() < 0.002
    # each circle is re-framed as the squares' rigid body would have recorded it (a single
    # circle leaves origin and heading of the frame aliased: the track is what is checked)
    for lg in held:
        name = lg.meta["name"]
        row = rows[name]
        assert row["applied"], row
        gt = np.asarray(lg["pose_gt"])
        aligned = reframe_recorded(gt, np.array(row["frame"]), np.array(frames.common))
        twin = twins[name]
        n = min(len(twin), len(gt))
        before = np.abs(gt[:n, :2] - twin[:n, :2]).max()
        after = np.abs(aligned[:n, :2] - twin[:n, :2]).max()
        assert before > 0.005  # the sessions' records differ by millimetres
        assert after < min(0.003, 0.4 * before), (name, before, after)
    assert "per-log frame alignment of pose_gt: 2 of" in d.baseline.summary()
    assert d.baseline.to_json()["frame_alignment"]["channel"] == "pose_gt"
    from realitygap.diagnosis.report.writer import write_report

    write_report(d, tmp_path / "report")
    md = (tmp_path / "report" / "report.md").read_text()
    assert "Per-log frame alignment of pose_gt: 2 of" in md
    for lg in held:  # each circle's row says it was re-framed
        head = f"| {lg.meta['name']} | holdout |"
        row = next(line for line in md.splitlines() if line.startswith(head))
        assert "| yes |" in row, row
    # the robot's own error is still what the diagnosis finds
    assert d.ranking[0].effects[0] == "wheelbase_error"
    assert d.ranking[0].values["wheelbase_error.E_b"] == pytest.approx(1.02, abs=0.006)
