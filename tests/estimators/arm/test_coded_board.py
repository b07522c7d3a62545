"""Absolutely coded board: m-sequence, exhaustive window uniqueness, texture."""

from __future__ import annotations

import numpy as np
import pytest

from realitygap.estimators.arm.coded_board import (
    WINDOW,
    CodedBoard,
    lfsr_m_sequence,
    window_statistics,
)


@pytest.fixture(scope="module")
def board() -> CodedBoard:
    return CodedBoard()


def test_lfsr_is_an_m_sequence_of_period_255() -> None:
    m = lfsr_m_sequence()
    assert m.shape == (255,)
    windows = {tuple(np.roll(m, -k)[:8]) for k in range(255)}
    assert len(windows) == 255  # every non-zero 8-bit state exactly once
    assert (0,) * 8 not in windows
    assert int(m.sum()) == 128


def test_non_primitive_feedback_is_not_maximal() -> None:
    # x^8 + 1 (tap at 0 only) just repeats the seed every 8 bits
    m = lfsr_m_sequence(taps=(0,))
    assert len({tuple(np.roll(m, -k)[:8]) for k in range(255)}) < 255


def test_every_window_unique_under_all_rotations(board: CodedBoard) -> None:
    n_windows, n_distinct, min_distance = window_statistics(board)
    assert n_windows == 43 * 43
    assert n_distinct == 4 * n_windows
    assert min_distance >= 12


def test_decode_every_window_exhaustively(board: CodedBoard) -> None:
    code = board.code
    for r in range(board.cells - WINDOW + 1):
        for c in range(board.cells - WINDOW + 1):
            w = code[r : r + WINDOW, c : c + WINDOW]
            assert board.decode_window(w) == (r, c)
    w = code[10:18, 20:28]
    assert board.decode_window(np.rot90(w, 1)) is None
    assert board.decode_window_rotated(np.rot90(w, 3)) == (10, 20, 3)
    assert board.decode_window(np.zeros((8, 8), dtype=int)) is None


def test_match_bits_tolerates_errors_and_rotation(board: CodedBoard) -> None:
    rng = np.random.default_rng(0)
    obs = board.code[5:16, 30:42].copy()  # 11 x 12 cells
    flip = rng.choice(obs.size, 2, replace=False)
    obs.flat[flip] ^= 1
    valid = np.ones(obs.shape, dtype=bool)
    valid[0, :3] = False
    (r, c, k, mism), second = board.match_bits(np.rot90(obs, 1), np.rot90(valid, 1))
    assert (r, c) == (5, 30)
    assert np.array_equal(np.rot90(np.rot90(obs, 1), k), obs)
    assert mism == 2
    assert second >= 20


def test_geometry_and_texture(board: CodedBoard) -> None:
    P = board.corner_positions()
    assert P.shape == (51 * 51, 3)
    np.testing.assert_allclose(P[51 * 3 + 7], [7 * 0.02, 3 * 0.02, 0.0])
    assert board.side == pytest.approx(1.0)
    ppc = 16
    tex = board.texture(ppc)
    assert tex.shape == (800, 800) and tex.dtype == np.uint8
    i, j = np.meshgrid(np.arange(50), np.arange(50), indexing="ij")
    centre = tex[i * ppc + ppc // 2, j * ppc + ppc // 2] > 127
    edge = tex[i * ppc + 2, j * ppc + ppc // 2] > 127  # background of the cell
    dark = board.cell_is_dark(i, j)
    np.testing.assert_array_equal(edge, ~dark)
    np.testing.assert_array_equal(centre != edge, board.code.astype(bool))


def test_errors() -> None:
    with pytest.raises(ValueError, match="cells must be an int"):
        CodedBoard(cells=5)
    with pytest.raises(ValueError, match="cell_size"):
        CodedBoard(cell_size=-0.02)
    with pytest.raises(ValueError, match="dot_radius"):
        CodedBoard(dot_radius=0.45)
    with pytest.raises(ValueError, match=r"shape \(8, 8\)"):
        CodedBoard().decode_window(np.zeros((7, 8)))
    with pytest.raises(ValueError, match="0 or 1"):
        CodedBoard().decode_window(np.full((8, 8), 2))
    with pytest.raises(ValueError, match="px_per_cell"):
        CodedBoard().texture(4)
