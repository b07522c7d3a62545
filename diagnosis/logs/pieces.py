"""Pieces of recordings that an importer cut at gaps, and which of them a diagnosis can read.

An importer never bridges a long gap with invented values: it cuts the recording
there into pieces (``meta["piece_of"]`` names the recording, see
:func:`~realitygap.diagnosis.logs.importers.csv_log.read_table_logs` and
:func:`~realitygap.diagnosis.logs.read.resample_split`). A piece may be too
short to read; it is the importer's making, not the user's episode, so it is set
aside with a message instead of stopping the diagnosis.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from realitygap.diagnosis.logs.log import Log, LogError

__all__ = ["drop_short_pieces"]


def drop_short_pieces(
    logs: Sequence[Log],
    holdout: Sequence[Log] | None,
    shortest: float,
    say: Callable[[str], None],
) -> tuple[list[Log], list[Log] | None]:
    """The logs without the pieces shorter than ``shortest`` seconds (two feature windows).

    A whole log that short is kept (the diagnosis then says it is too short).

    Raises
    ------
    LogError
        When every training log is such a piece, naming them and their lengths.
    """

    def keep(group: Sequence[Log]) -> list[Log]:
        out = []
        for lg in group:
            if lg.meta.get("piece_of") and lg.duration < shortest:
                say(
                    f"{lg.name}: a {lg.duration:.2f}-s piece of {lg.meta['piece_of']} set aside "
                    f"(the diagnosis needs {shortest:g} s: two feature windows)"
                )
                continue
            out.append(lg)
        return out

    train = keep(logs)
    held = keep(holdout) if holdout else None
    if not train:
        names = ", ".join(f"{lg.name} ({lg.duration:.2f} s)" for lg in logs)
        raise LogError(
            f"every training log is a piece too short to diagnose: {names}. Fix: raise "
            "--max-gap so fewer gaps cut the recording, or record longer episodes"
        )
    if holdout and not held:
        held = None
        say("every held-out piece was too short; holding out part of the training logs instead")
    return train, held
