"""Board geometry, colours and the half turn (interface.md, "The chessboard")."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ilcc_graph.board import Board


def boards():
    return st.builds(
        lambda r, dc, s, ml, ms, ll: Board(r, r + dc, s, ml, ms, ll),
        st.integers(2, 9),
        st.integers(0, 5),
        st.sampled_from([0.05, 0.075, 0.1]),
        st.sampled_from([0.0, 0.02, 0.045]),
        st.sampled_from([0.0, 0.01, 0.02]),
        st.sampled_from(["black", "white"]),
    )


def test_corner_layout_and_index() -> None:
    b = Board(6, 8, 0.1)
    c = b.corners_board()
    assert b.inner_shape == (5, 7) and b.n_corners == 35 and c.shape == (35, 3)
    for i, j in [(0, 0), (0, 6), (4, 0), (2, 3), (4, 6)]:
        k = int(b.corner_index(i, j))
        assert k == i * 7 + j
        np.testing.assert_allclose(c[k], [(j + 1) * 0.1, (i + 1) * 0.1, 0.0])
    assert b.pattern_size_m == pytest.approx((0.8, 0.6))
    np.testing.assert_allclose(b.pattern_centre, [0.4, 0.3, 0.0])


def test_colours_squares_margin_and_off_board() -> None:
    b = Board(6, 8, 0.1, margin_long=0.05, margin_short=0.02, lower_left="black")
    r, c = np.meshgrid(np.arange(6), np.arange(8), indexing="ij")
    centres = np.stack([(c.ravel() + 0.5) * 0.1, (r.ravel() + 0.5) * 0.1], axis=1)
    col = b.colour_at(centres)
    np.testing.assert_array_equal(col, np.where((r + c).ravel() % 2 == 0, 0.0, 1.0))
    np.testing.assert_array_equal(col, b.square_colour(r.ravel(), c.ravel()))
    # margin is white, beyond it is off the board
    margin = np.array([[-0.04, 0.3], [0.84, 0.3], [0.4, -0.015], [0.4, 0.615], [-0.05, -0.02]])
    np.testing.assert_array_equal(b.colour_at(margin), 1.0)
    off = np.array([[-0.051, 0.3], [0.851, 0.3], [0.4, -0.021], [0.4, 0.621], [np.nan, 0.1]])
    assert np.all(np.isnan(b.colour_at(off)))
    assert b.extent() == pytest.approx((-0.05, 0.85, -0.02, 0.62))
    w = Board(6, 8, 0.1, lower_left="white")
    np.testing.assert_array_equal(w.colour_at(centres), 1.0 - col)
    # (N, 3) input is accepted, z ignored
    np.testing.assert_array_equal(b.colour_at(np.c_[centres, np.ones(len(centres))]), col)


def test_outer_corner_squares() -> None:
    b = Board(6, 8, 0.1, lower_left="white")
    oc = b.outer_corner_squares()
    np.testing.assert_array_equal(oc[:, :2], [[0, 0], [0, 7], [5, 7], [5, 0]])
    assert oc[0, 2] == 1.0 and oc[2, 2] == 1.0 and oc[1, 2] == 0.0
    b = Board(5, 8, 0.1, lower_left="black")
    oc = b.outer_corner_squares()
    assert oc[0, 2] == 0.0 and oc[2, 2] == 1.0  # odd + even: opposite corners differ


@settings(max_examples=60, deadline=None, database=None)
@given(boards(), st.integers(0, 2**31 - 1))
def test_half_turn_consistent(b: Board, seed: int) -> None:
    T = b.T_half_turn()
    perm = b.half_turn_permutation()
    c = b.corners_board()
    ch = (T[:3, :3] @ c.T).T + T[:3, 3]
    np.testing.assert_allclose(ch, c[perm], atol=1e-12)
    np.testing.assert_allclose(T @ T, np.eye(4), atol=1e-12)
    assert np.isclose(np.linalg.det(T[:3, :3]), 1.0)
    assert sorted(perm.tolist()) == list(range(b.n_corners))
    # colours are invariant under the half turn exactly when the board is symmetric
    rng = np.random.default_rng(seed)
    x0, x1, y0, y1 = b.extent()
    xy = np.c_[rng.uniform(x0, x1, 400), rng.uniform(y0, y1, 400)]
    xy_turned = (T[:2, :2] @ xy.T).T + T[:2, 3]
    same = b.colour_at(xy) == b.colour_at(xy_turned)
    assert not np.any(np.isnan(b.colour_at(xy_turned)))  # the turned board covers the same area
    if b.half_turn_symmetric:
        assert same.all()
    else:
        centres = np.array([[0.5, 0.5]]) * b.square_size
        assert b.colour_at(centres)[0] != b.colour_at((T[:2, :2] @ centres.T).T + T[:2, 3])[0]
        assert not same.all()
    assert b.half_turn_symmetric == ((b.rows + b.cols) % 2 == 0)


def test_half_turn_symmetry_examples() -> None:
    assert Board(6, 8, 0.1).half_turn_symmetric
    assert Board(7, 9, 0.1).half_turn_symmetric
    assert not Board(5, 8, 0.1).half_turn_symmetric


@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(rows=1, cols=8, square_size=0.1), "rows"),
        (dict(rows=6, cols=8.0, square_size=0.1), "cols"),
        (dict(rows=9, cols=8, square_size=0.1), "rows"),
        (dict(rows=6, cols=8, square_size=0.0), "square_size"),
        (dict(rows=6, cols=8, square_size="a"), "square_size"),
        (dict(rows=6, cols=8, square_size=0.1, margin_long=-0.01), "margin_long"),
        (dict(rows=6, cols=8, square_size=0.1, margin_short=np.inf), "margin_short"),
        (dict(rows=6, cols=8, square_size=0.1, lower_left="red"), "lower_left"),
    ],
)
def test_validation_names_the_argument(kwargs: dict, name: str) -> None:
    with pytest.raises(ValueError, match=name):
        Board(**kwargs)


def test_to_dict_and_frozen() -> None:
    b = Board(6, 8, 0.095, 0.045, 0.02, "black")
    assert b.to_dict() == {
        "squares": [6, 8],
        "square_size": 0.095,
        "margin": [0.045, 0.02],
        "lower_left": "black",
    }
    with pytest.raises(AttributeError):
        b.rows = 3  # type: ignore[misc]
    assert b == Board(6, 8, 0.095, 0.045, 0.02) and hash(b) == hash(Board(6, 8, 0.095, 0.045, 0.02))
