"""diagnose-teleop: the second independent world read back as a user's CSV logs, and its
scoring rules."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from realitygap.diagnosis.verdict.types import VerdictKind
from realitygap.experiments.teleop import read_dataset, score_teleop
from realitygap.independent.teleop import write_case
from realitygap.independent.teleop_cases import TELEOP_CASES


def _case(name: str):
    return next(c for c in TELEOP_CASES if c.name == name)


def test_the_world_reads_back_as_csv_logs_with_its_own_geometry_and_rates(tmp_path: Path) -> None:
    spec = write_case(_case("nominal_a"), tmp_path, seed=3)
    train, held = read_dataset(tmp_path)
    assert len(train) + len(held) == len(spec["runs"]) and train and held
    rates = {round(1.0 / float(np.median(np.diff(lg.t)))) for lg in train + held}
    assert rates == {25, 40}
    params = train[0].meta["params"]
    assert params["wheelbase"] == pytest.approx(0.38)
    assert params["wheel_radius_left"] == pytest.approx(0.075)
    # training and held-out days differ; sessions are named
    assert {lg.meta["day"] for lg in train}.isdisjoint({lg.meta["day"] for lg in held})
    assert all(lg.meta["session"] for lg in train + held)
    for lg in train:
        assert lg.has("cmd") and lg.has("ticks") and lg.has("pose_gt")


def _diagnosis(kind: str, named: tuple[str, ...], share: float) -> object:
    verdict = SimpleNamespace(kind=VerdictKind(kind), effects=named, label=list(named) or kind)
    budget = SimpleNamespace(
        entries=[SimpleNamespace(effect=e) for e in named],
        unexplained_share=share,
        kind=kind,
        sentence=lambda: "s",
    )
    return SimpleNamespace(verdict=verdict, budget=budget)


def test_scoring_in_and_out_of_the_library_and_nominal() -> None:
    wb = _case("wheelbase_plus_2p5pct")
    assert score_teleop(wb, _diagnosis("effects", ("wheelbase_error",), 5.0), "ticks")["right"]
    extra = score_teleop(
        wb, _diagnosis("effects", ("wheelbase_error", "encoder_scale"), 5.0), "ticks"
    )
    assert not extra["right"] and extra["false_attribution"]
    nominal = _case("nominal_a")
    assert score_teleop(nominal, _diagnosis("none", (), 0.0), "commands")["right"]
    wrong = score_teleop(nominal, _diagnosis("effects", ("wheelbase_error",), 5.0), "commands")
    assert not wrong["right"] and wrong["false_attribution"] and wrong["kind"] == "nominal"
    drag = _case("caster_side_drag")
    seen = score_teleop(drag, _diagnosis("partial", ("wheelbase_error",), 70.0), "ticks")
    assert seen["right"] and not seen["false_attribution"]
    missed = score_teleop(drag, _diagnosis("effects", ("wheelbase_error",), 20.0), "ticks")
    assert not missed["right"] and missed["false_attribution"]
    # a delay cannot show when the encoders drive the replay: there the case is nominal
    delay = _case("command_delay_120ms")
    assert score_teleop(delay, _diagnosis("none", (), 0.0), "ticks")["kind"] == "nominal"
