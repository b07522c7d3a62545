"""The splits of the ``diagnose-real`` experiments on the real OptiOdom sessions."""

from __future__ import annotations

from pathlib import Path

import pytest

from realitygap.experiments import RunContext
from realitygap.experiments.diagnosis import _real_split

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"


@pytest.mark.skipif(
    not (DATA / "optiodom_diffdrive").is_dir(),
    reason="needs the OptiOdom sessions in ../shared/data beside the checkout",
)
@pytest.mark.slow
@pytest.mark.parametrize("quick", [False, True])
def test_extended_training_keeps_the_held_out_runs_and_adds_other_sessions(quick: bool) -> None:
    ctx = RunContext(quick=quick, data_dir=DATA, verbose=False)
    train, holdout = _real_split(ctx, extend_training=False)
    train_x, holdout_x = _real_split(ctx, extend_training=True)
    names = [lg.name for lg in holdout]
    assert names == [lg.name for lg in holdout_x]  # the same held-out runs, in order
    assert {str(lg.meta["path_type"]) for lg in train} == {"square"}
    base = {lg.name for lg in train}
    added = [lg for lg in train_x if lg.name not in base]
    assert base <= {lg.name for lg in train_x} and added
    # the added runs are of the held-out path types, from sessions none of which is held out
    held_sessions = {str(lg.meta["session"]) for lg in holdout}
    assert {str(lg.meta["path_type"]) for lg in added} <= {"ivanjko", "circular", "free"}
    assert not {str(lg.meta["session"]) for lg in added} & held_sessions
