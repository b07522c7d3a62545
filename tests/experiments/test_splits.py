"""The session- and day-holding-out splits of ``diagnose-real-splits``
(:mod:`realitygap.experiments.splits`); no diagnosis runs here."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from realitygap.experiments.splits import (
    CROSS_DAY,
    LEAVE_ONE_SESSION_OUT,
    SessionSplit,
    budget_wheelbase_factor,
    session_day,
    session_splits,
    spread_subset,
)

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"


class FakeLog:
    """What the enumeration reads of a log: its name and meta."""

    def __init__(self, session: str, run: int, path_type: str, direction: str | None) -> None:
        self.name = f"{session}_run-{run:02d}"
        self.meta: dict[str, Any] = {
            "session": session,
            "run": run,
            "path_type": path_type,
            "direction": direction,
        }

    def __repr__(self) -> str:
        return self.name


def _square(session: str, n: int = 6) -> list[FakeLog]:
    return [FakeLog(session, r, "square", "cw" if r <= n // 2 else "ccw") for r in range(1, n + 1)]


def _fake_logs() -> list[FakeLog]:
    """Two days with squares (one with three square sessions, one with one), a day without
    squares, and other path types on the square days too."""
    logs = (
        _square("230620202042")
        + _square("230620202144")
        + _square("230620202317", n=10)
        + [FakeLog("230620202350", r, "circular", "cw") for r in (1, 2, 3)]
        + _square("231220200029")
        + [FakeLog("231220200057", r, "ivanjko", None) for r in (1, 2, 3)]
        + [FakeLog("250620202104", r, "circular", "ccw" if r > 2 else "cw") for r in (1, 2, 3, 4)]
        + [FakeLog("030120210001", r, "free", None) for r in (1, 2, 3)]
    )
    return logs[::-1]  # the enumeration must not depend on the order it is handed


def _day(lg: Any) -> str:
    return str(lg.meta["session"])[:8]


def _sessions(logs: Any) -> set[str]:
    return {str(lg.meta["session"]) for lg in logs}


def test_session_day_reads_the_first_eight_digits() -> None:
    assert session_day("230620202042") == "23062020"
    assert session_day("030120210001") == "03012021"
    for bad in ("2306202020", "23062020204a", "991320202042"):
        with pytest.raises(ValueError, match="session id"):
            session_day(bad)


def test_split_names_and_kinds() -> None:
    splits = session_splits(_fake_logs())
    assert [sp.name for sp in splits] == [
        "cross-day 23.06.2020→others",
        "cross-day 23.12.2020→others",
        "day 23.06.2020 without 230620202042",
        "day 23.06.2020 without 230620202144",
        "day 23.06.2020 without 230620202317",
    ]
    assert [sp.kind for sp in splits] == [CROSS_DAY] * 2 + [LEAVE_ONE_SESSION_OUT] * 3


def test_cross_day_splits_never_share_a_day() -> None:
    logs = _fake_logs()
    cross = [sp for sp in session_splits(logs) if sp.kind == CROSS_DAY]
    assert cross
    for sp in cross:
        train_days = {_day(lg) for lg in sp.train}
        held_days = {_day(lg) for lg in sp.holdout}
        assert train_days == {sp.day}
        assert not train_days & held_days
        # training: every run of the day's square sessions, nothing else
        assert set(sp.train) == {
            lg for lg in logs if _day(lg) == sp.day and lg.meta["path_type"] == "square"
        }
        # held out: every session of every other day, at most two runs each
        assert _sessions(sp.holdout) == {
            str(lg.meta["session"]) for lg in logs if _day(lg) != sp.day
        }
        per = {
            s: sum(str(lg.meta["session"]) == s for lg in sp.holdout) for s in sp.holdout_sessions
        }
        assert max(per.values()) <= 2


def test_cross_day_holdout_balances_directions() -> None:
    sp = session_splits(_fake_logs())[1]  # 23.12.2020 → others: holds out 23.06 squares
    held = [lg for lg in sp.holdout if lg.meta["session"] == "230620202042"]
    assert sorted(str(lg.meta["direction"]) for lg in held) == ["ccw", "cw"]


def test_leave_one_session_out_holds_out_one_session_and_trains_on_the_rest_of_the_day() -> None:
    logs = _fake_logs()
    loso = [sp for sp in session_splits(logs) if sp.kind == LEAVE_ONE_SESSION_OUT]
    squares_of_day = {
        lg for lg in logs if _day(lg) == "23062020" and lg.meta["path_type"] == "square"
    }
    assert {sp.holdout_sessions for sp in loso} == {
        ("230620202042",),
        ("230620202144",),
        ("230620202317",),
    }
    for sp in loso:
        (held,) = sp.holdout_sessions
        assert set(sp.holdout) == {lg for lg in squares_of_day if lg.meta["session"] == held}
        assert set(sp.train) == squares_of_day - set(sp.holdout)
        assert held not in sp.train_sessions
        assert {_day(lg) for lg in sp.train + sp.holdout} == {"23062020"}
    # a day with a single square session makes no leave-one-session-out split
    assert all(sp.day != "23122020" for sp in loso)


def test_no_split_is_empty_and_enumeration_is_deterministic() -> None:
    a = session_splits(_fake_logs())
    b = session_splits(list(reversed(_fake_logs())))
    assert a and all(sp.train and sp.holdout for sp in a)
    assert [
        (sp.name, [lg.name for lg in sp.train], [lg.name for lg in sp.holdout]) for sp in a
    ] == [(sp.name, [lg.name for lg in sp.train], [lg.name for lg in sp.holdout]) for sp in b]


def test_single_day_without_a_second_square_session_has_no_split() -> None:
    assert session_splits(_square("230620202042")) == []
    # another day without squares makes a cross-day split only
    logs = [*_square("230620202042"), FakeLog("250620202104", 1, "circular", "cw")]
    (sp,) = session_splits(logs)
    assert sp.kind == CROSS_DAY and sp.holdout_sessions == ("250620202104",)


def test_spread_subset_takes_both_kinds() -> None:
    splits = session_splits(_fake_logs())
    three = spread_subset(splits, 3)
    assert [sp.name for sp in three] == [
        "cross-day 23.06.2020→others",
        "cross-day 23.12.2020→others",
        "day 23.06.2020 without 230620202042",
    ]
    one_each = spread_subset(splits, 2)
    assert {sp.kind for sp in one_each} == {CROSS_DAY, LEAVE_ONE_SESSION_OUT}
    assert spread_subset(splits, 99) == splits


def _entry(effect: str, **values: float) -> Any:
    return SimpleNamespace(effect=effect, values={f"{effect}.{k}": v for k, v in values.items()})


def test_budget_wheelbase_factor_as_umbmark_defines_it() -> None:
    both = SimpleNamespace(
        entries=(_entry("wheelbase_error", E_b=1.02), _entry("wheel_radius_scale", scale=0.99))
    )
    assert budget_wheelbase_factor(both) == pytest.approx(1.02 / 0.99)
    alone = SimpleNamespace(entries=(_entry("wheelbase_error", E_b=1.02),))
    assert budget_wheelbase_factor(alone) == pytest.approx(1.02)
    # wheels 1 % small without a wheelbase entry: the ratio UMBmark sees is 1/0.99
    wheels = SimpleNamespace(entries=(_entry("wheel_radius_scale", scale=0.99),))
    assert budget_wheelbase_factor(wheels) == pytest.approx(1 / 0.99)
    # an encoder counting 1 % more per turn is a wheel 1 % larger per count
    counts = SimpleNamespace(entries=(_entry("encoder_scale", scale=1.01),))
    assert budget_wheelbase_factor(counts) == pytest.approx(1.01)
    none = SimpleNamespace(entries=(_entry("command_latency", delay=0.1),))
    assert math.isnan(budget_wheelbase_factor(none))
    assert math.isnan(budget_wheelbase_factor(None))


@pytest.mark.skipif(
    not (DATA / "optiodom_diffdrive").is_dir(),
    reason="needs the OptiOdom sessions in ../shared/data beside the checkout",
)
def test_splits_of_the_real_sessions() -> None:
    from realitygap.experiments import RunContext
    from realitygap.experiments.diagnosis import _optiodom_groups

    ctx = RunContext(data_dir=DATA, verbose=False)
    logs = [lg for runs in _optiodom_groups(ctx).values() for lg in runs]
    splits = session_splits(logs)
    assert splits and all(isinstance(sp, SessionSplit) and sp.train and sp.holdout for sp in splits)
    for sp in splits:
        assert {str(lg.meta["path_type"]) for lg in sp.train} == {"square"}
        if sp.kind == CROSS_DAY:
            assert not {_day(lg) for lg in sp.train} & {_day(lg) for lg in sp.holdout}
        else:
            assert len(sp.holdout_sessions) == 1
            assert not set(sp.holdout_sessions) & set(sp.train_sessions)
    assert [sp.name for sp in session_splits(logs[::-1])] == [sp.name for sp in splits]
