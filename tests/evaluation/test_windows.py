import numpy as np
import pytest

from robomorph.data.store import create_store
from robomorph.evaluation.windows import WindowError, cut, load_window, parse_offset, window_starts

N, T = 12, 50


@pytest.fixture(scope="module")
def clock_store(tmp_path_factory):
    """A real store whose outputs are the step number (y[i, t] = t) and inputs 100 i + t."""
    path = str(tmp_path_factory.mktemp("win") / "clock.zarr")
    w = create_store(path, N, T, ["tau0"], ["a", "b"], [], {"dt": 0.1, "domain": "real"})
    t = np.arange(T, dtype=np.float32)
    y = np.repeat(np.stack([t, -t], -1)[None], N, axis=0)
    u = (100 * np.arange(N, dtype=np.float32)[:, None] + t)[..., None]
    w.append(u, y, np.zeros((N, 0), np.float32))
    w.finalize()
    return path


def test_parse_offset():
    assert parse_offset(None) == parse_offset("start") == parse_offset("0") == parse_offset(0) == "start"
    assert parse_offset("Random") == "random" and parse_offset("7") == 7 and parse_offset(3) == 3
    for bad in ("later", "-2", "1.5"):
        with pytest.raises(WindowError, match="offset"):
            parse_offset(bad)


def test_random_starts_stay_inside_the_data_and_are_seeded():
    a = window_starts("random", 500, steps=T, length=30, seed=3)
    assert a.min() >= 0 and a.max() <= T - 30 and len(np.unique(a)) == T - 30 + 1  # every start is reachable
    assert np.array_equal(a, window_starts("random", 500, T, 30, seed=3))
    assert not np.array_equal(a, window_starts("random", 500, T, 30, seed=4))
    assert np.array_equal(window_starts("random", 5, T, T, seed=1), np.zeros(5))  # no room: from the start
    assert np.array_equal(window_starts(20, 3, T, 30), [20, 20, 20])
    assert np.array_equal(window_starts("start", 2, T, 30), [0, 0])
    with pytest.raises(WindowError, match="offset <= 20"):
        window_starts(21, 3, T, 30)


def test_cut_takes_each_rows_own_window():
    a = np.arange(2 * 6).reshape(2, 6, 1)
    assert cut(a, np.array([0, 3]), 3)[..., 0].tolist() == [[0, 1, 2], [9, 10, 11]]


def test_load_window_from_random_offsets_reads_the_right_steps(clock_store):
    w = load_window(clock_store, 10, 20, None, None, 1, 2, offset="random", seed=5)
    assert w.u.shape == (N, 30, 1) and w.y.shape == (N, 30, 2)
    assert w.starts.min() >= 0 and w.starts.max() <= T - 30 and len(set(w.starts.tolist())) > 1
    for i, s in enumerate(w.starts):
        assert w.y[i, :, 0].tolist() == list(range(s, s + 30))
        assert w.u[i, :, 0].tolist() == [100 * i + t for t in range(s, s + 30)]
    u_ctx, y_ctx, u_q, y_q = w.split()
    assert np.array_equal(y_q[:, 0, 0], w.starts + 10) and np.array_equal(y_ctx[:, -1, 0], w.starts + 9)
    again = load_window(clock_store, 10, 20, None, None, 1, 2, offset="random", seed=5)
    assert np.array_equal(again.starts, w.starts)
    fixed = load_window(clock_store, 10, 20, 4, None, 1, 2, offset=20)
    assert fixed.y[:, 0, 0].tolist() == [20] * 4 and fixed.y[:, -1, 0].tolist() == [49] * 4
    with pytest.raises(WindowError, match="exceeds the store's T=50"):
        load_window(clock_store, 10, 20, None, None, 1, 2, offset=21)
    start = load_window(clock_store, 10, 20, None, None, 1, 2)
    assert start.starts.tolist() == [0] * N and start.y[:, 0, 0].tolist() == [0] * N
