"""Dataset inspection: the summary's content, sampling, plots and the CLI's errors."""

import os

import matplotlib.image
import numpy as np
import pytest
import zarr

from robomorph.data.store import create_store, open_store
from robomorph.data.summary import _sample_blocks, channel_stats, params_plot_path, plot, summarize
from robomorph.inspect import main
from tests.conftest import write_store

U, Y, P = ["tau0", "tau1"], ["ee_x", "q0", "q1"], ["mass_scale_link1", "damping_q0"]
REJECTED = {"joint_limit": 4, "unstable": 2, "ee_velocity": 0}


def _store(path, n=20, steps=30, params=P, finish=True, chunk=64):
    """A schema-valid fake store: sines for u, their running sums for y, known param ranges."""
    attrs = {"dt": 0.02, "domain": "panda", "task": "multisine", "config": {"robots": n, "seed": 7},
             "seed": 7, "requested": n, "attempted": n + 6, "kept": n, "rejected": REJECTED}
    t = np.arange(steps) * 0.02
    freq = np.linspace(1.0, 3.0, n)[:, None, None] * np.array([1.0, 2.0])
    u = np.sin(2 * np.pi * freq * t[None, :, None]).astype(np.float32)  # (n, T, 2)
    y = np.concatenate([np.cumsum(u, 1)[..., :1], u], axis=2).astype(np.float32)  # (n, T, 3)
    p = np.stack([np.linspace(0.5, 1.5, n), np.linspace(-2.0, 2.0, n)], 1)[:, : len(params)]  # (n, P)
    rows = n if finish else n // 2
    write_store(path, u[:rows], y[:rows], p[:rows], U, Y, params, attrs, chunk=chunk, finish=finish, capacity=n,
                extras={"attempt": ((), "int64", np.arange(rows))})
    return str(path), u, y


def test_summary_names_counts_and_rejections(tmp_path):
    path, _, _ = _store(tmp_path / "s.zarr")
    text = summarize(open_store(path))
    for name in [*U, *Y, *P, "attempt"]:
        assert name in text
    assert "N=20  T=30  n_u=2  n_y=3  P=2" in text
    assert "dt=0.02 s, 0.6 s per trajectory" in text
    assert "requested 20, attempted 26, kept 20 (kept rate 76.9%)" in text
    assert "rejected:  6 in all" in text
    lines = text.splitlines()
    assert any(ln.split() == ["joint_limit", "4", "(15.4%", "of", "attempts)"] for ln in lines)
    assert any(ln.split()[:2] == ["unstable", "2"] for ln in lines)
    assert "no rejections for: ee_velocity" in text
    mass = next(ln for ln in lines if ln.strip().startswith("mass_scale_link1")).split()
    damping = next(ln for ln in lines if ln.strip().startswith("damping_q0")).split()
    assert [float(v) for v in mass[1:]] == pytest.approx([0.5, 1.0, 1.5])
    assert [float(v) for v in damping[1:]] == pytest.approx([-2.0, 0.0, 2.0], abs=1e-6)
    assert "over 20 trajectories (all)" in text and "status:    complete" in text


def test_channel_stats_match_numpy_over_all_rows(tmp_path):
    path, u, y = _store(tmp_path / "s.zarr", n=20, chunk=6)
    ds = open_store(path)
    blocks = _sample_blocks(ds.n, 6)
    stats = channel_stats(ds, "y", blocks)
    flat = y.reshape(-1, 3).astype(np.float64)
    np.testing.assert_allclose(stats[:, 0], flat.min(0))
    np.testing.assert_allclose(stats[:, 1], flat.mean(0), atol=1e-9)
    np.testing.assert_allclose(stats[:, 2], flat.std(0), rtol=1e-6)
    np.testing.assert_allclose(stats[:, 3], flat.max(0))
    assert not stats[:, 4].any()


def test_sampling_is_bounded_spread_and_chunk_aligned():
    blocks = _sample_blocks(10_000, 64)
    assert sum(b.stop - b.start for b in blocks) == 256
    assert all(b.start % 64 == 0 for b in blocks)
    assert blocks[0].start == 0 and blocks[-1].stop > 9_000
    assert _sample_blocks(10_000, 64) == blocks
    assert _sample_blocks(100, 64) == [slice(0, 64), slice(64, 100)]


def test_summary_says_when_it_sampled(tmp_path):
    path, _, _ = _store(tmp_path / "s.zarr", n=20, chunk=4)
    text = summarize(open_store(path), sample=8)
    assert "over 8 trajectories (sampled: 8 of 20" in text


def _assert_real_image(path):
    assert os.path.getsize(path) > 5_000
    img = matplotlib.image.imread(path)
    colors = np.unique(img.reshape(-1, img.shape[-1]), axis=0)
    assert img.std() > 0.01 and len(colors) > 20


def test_plot_writes_trajectory_and_parameter_pngs(tmp_path):
    path, _, _ = _store(tmp_path / "s.zarr")
    out = str(tmp_path / "figs" / "out.png")
    written = plot(open_store(path), out, n_traj=3)
    assert written == [out, str(tmp_path / "figs" / "out_params.png")] == [out, params_plot_path(out)]
    for f in written:
        _assert_real_image(f)


def test_plot_without_params_writes_only_trajectories(tmp_path):
    path, _, _ = _store(tmp_path / "s.zarr", params=[])
    out = str(tmp_path / "out.png")
    assert plot(open_store(path), out, n_traj=50) == [out]
    _assert_real_image(out)
    assert not os.path.exists(params_plot_path(out))


def test_cli_prints_summary_and_plots(tmp_path, capsys):
    path, _, _ = _store(tmp_path / "s.zarr")
    out = str(tmp_path / "o.png")
    assert main([path, "--plot", out, "--plot-trajectories", "2"]) == 0
    text = capsys.readouterr().out
    assert "joint_limit" in text and f"wrote {out}" in text and os.path.exists(params_plot_path(out))


def test_cli_errors_exit_2(tmp_path, capsys):
    assert main([str(tmp_path / "missing.zarr")]) == 2
    assert capsys.readouterr().err.startswith("error: dataset not found")

    other = tmp_path / "other.zarr"
    zarr.open_group(str(other), mode="w").attrs["schema"] = "someone.else"
    assert main([str(other)]) == 2
    assert "not a RoboMorph dataset" in capsys.readouterr().err

    half, _, _ = _store(tmp_path / "half.zarr", finish=False)
    assert main([half]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "incomplete" in err and "Traceback" not in err
    assert main([half, "--allow-incomplete"]) == 0
    assert "in_progress (10 of 20 trajectories valid)" in capsys.readouterr().out


def test_inspect_names_a_deleted_chunk(tmp_path, capsys):
    # It used to show only the non-finite counts the fill value leaves behind.
    path, _, _ = _store(tmp_path / "s.zarr", n=20, chunk=6)
    os.remove(os.path.join(path, "y", "c", "2", "0", "0"))
    assert main([path]) == 2
    out, err = capsys.readouterr()
    assert "damaged:   'y' chunk c/2/0/0 (trajectories 12..17) missing" in out
    assert err.startswith("error: ") and "chunk c/2/0/0" in err and len(err.strip().splitlines()) == 1


def test_inspect_names_a_truncated_chunk_in_one_line(tmp_path, capsys):
    path, _, _ = _store(tmp_path / "s.zarr", n=20, chunk=6)
    f = os.path.join(path, "u", "c", "1", "0", "0")
    data = open(f, "rb").read()
    with open(f, "wb") as out:
        out.write(data[: len(data) // 3])
    assert main([path]) == 2
    err = capsys.readouterr().err
    assert "'u' chunk c/1/0/0 (trajectories 6..11)" in err and len(err.strip().splitlines()) == 1


def test_summary_shows_the_command_beside_the_total_torque(tmp_path):
    n, steps = 4, 10
    w = create_store(str(tmp_path / "c.zarr"), n, steps, U, Y, [], {"dt": 0.1}, u_cmd_names=["cmd0", "cmd1"])
    u = np.ones((n, steps, 2), np.float32)
    w.append(u, np.zeros((n, steps, 3), np.float32), np.zeros((n, 0), np.float32), extras={"u_cmd": u * 7.5})
    w.finalize()
    text = summarize(open_store(str(tmp_path / "c.zarr")))
    assert "inputs (command) u_cmd" in text and "inputs (total torque) u" in text
    line = next(ln for ln in text.splitlines() if ln.strip().startswith("cmd1"))
    assert line.split()[1:] == ["7.5", "7.5", "0", "7.5"]
    assert "u_cmd" not in summarize(open_store(_store(tmp_path / "s.zarr")[0]))
