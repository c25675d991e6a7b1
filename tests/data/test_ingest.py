"""Ingest of real-robot logs: round trips, windowing, sample time and error messages."""

import os

import numpy as np
import pytest
import scipy.io
import zarr

from robomorph.data.ingest import IngestError, ShortRecordingWarning, ingest
from robomorph.data.store import SchemaError, create_store, open_store
from robomorph.ingest import main

U, Y = ["tau1", "tau2"], ["q1", "q2", "q3"]
DT = 0.02


def _system(length, seed=0, t0=5.0):
    """A logged 2-input 3-output stable linear system: x+ = A x + B u, y = C x."""
    rng = np.random.default_rng(seed)
    A = np.array([[0.9, 0.1, 0.0], [0.0, 0.8, 0.1], [0.05, 0.0, 0.7]])
    B = rng.normal(size=(3, 2))
    C = rng.normal(size=(3, 3))
    t = t0 + DT * np.arange(length)
    u = np.stack([np.sin(2 * np.pi * 0.7 * t), np.cos(2 * np.pi * 1.3 * t + seed)], axis=1)
    x, y = np.zeros(3), np.empty((length, 3))
    for k in range(length):
        y[k] = C @ x
        x = A @ x + B @ u[k]
    return {"t": t, "tau1": u[:, 0], "tau2": u[:, 1], "q1": y[:, 0], "q2": y[:, 1], "q3": y[:, 2]}


def _csv(path, cols):
    names = list(cols)
    with open(path, "w") as f:
        f.write(",".join(names) + "\n")
        for i in range(len(cols[names[0]])):
            f.write(",".join(repr(float(cols[c][i])) for c in names) + "\n")
    return str(path)


def _npz(path, cols):
    np.savez(path, **cols)
    return str(path)


def _mat(path, cols):
    scipy.io.savemat(path, {k: v[:, None] for k, v in cols.items()})  # column vectors
    return str(path)


def _window(cols, names, start, steps):
    return np.stack([cols[c][start:start + steps] for c in names], axis=1).astype(np.float32)


@pytest.fixture
def logs(tmp_path):
    """Three recordings of lengths 250 (CSV), 180 (NPZ) and 130 (MAT)."""
    sources = [_system(250, 0), _system(180, 1), _system(130, 2)]
    files = [_csv(tmp_path / "run1.csv", sources[0]), _npz(tmp_path / "run2.npz", sources[1]),
             _mat(tmp_path / "run3.mat", sources[2])]
    return files, sources


def test_round_trip_through_the_store(tmp_path, logs):
    files, sources = logs
    ds = ingest(files, U, Y, str(tmp_path / "real.zarr"), steps=50, time_col="t")
    assert ds.n == 5 + 3 + 2 and ds.steps == 50
    assert ds.u_names == U and ds.y_names == Y and ds.param_names == []
    assert ds.read("params").shape == (10, 0)
    rec, start = ds.read("recording_index"), ds.read("window_start")
    np.testing.assert_array_equal(rec, [0] * 5 + [1] * 3 + [2] * 2)
    np.testing.assert_array_equal(start, [0, 50, 100, 150, 200, 0, 50, 100, 0, 50])
    assert rec.dtype == np.int32 and start.dtype == np.int64
    u, y = ds.read("u"), ds.read("y")
    for k in range(ds.n):
        np.testing.assert_array_equal(u[k], _window(sources[rec[k]], U, start[k], 50))
        np.testing.assert_array_equal(y[k], _window(sources[rec[k]], Y, start[k], 50))
    a = ds.attrs
    assert a["status"] == "complete" and a["domain"] == "real" and a["task"] == "ingested"
    assert a["dt"] == pytest.approx(DT, rel=1e-9) and a["seed"] is None
    assert a["sources"] == ["run1.csv", "run2.npz", "run3.mat"]
    assert a["requested"] == a["attempted"] == a["kept"] == 10 and a["rejected"] == {}
    assert a["config"]["files"] == files and a["config"]["time_col"] == "t"
    assert a["config"]["steps"] == 50 and a["config"]["stride"] == 50 and a["config"]["u_cols"] == U


@pytest.mark.parametrize("steps,stride,starts", [
    (100, None, [0, 100]),
    (100, 30, [0, 30, 60, 90, 120, 150]),
    (250, None, [0]),
    (60, 95, [0, 95, 190]),
])
def test_window_count_and_starts(tmp_path, steps, stride, starts):
    src = _system(250)
    ds = ingest([_csv(tmp_path / "a.csv", src)], U, Y, str(tmp_path / "o.zarr"), steps=steps,
                dt=DT, stride=stride)
    np.testing.assert_array_equal(ds.read("window_start"), starts)
    np.testing.assert_array_equal(ds.read("u")[-1], _window(src, U, starts[-1], steps))


def test_any_channel_counts_and_the_data_names_npz_convention(tmp_path):
    rng = np.random.default_rng(3)
    data = rng.normal(size=(40, 6))
    names = np.array(["a", "b", "c", "d", "e", "f"])
    path = tmp_path / "wide.npz"
    np.savez(path, data=data, names=names)
    ds = ingest([str(path)], ["b"], ["a", "c", "d", "e", "f"], str(tmp_path / "o.zarr"), steps=20, dt=0.5,
                name="arm7")
    assert ds.read("u").shape == (2, 20, 1) and ds.read("y").shape == (2, 20, 5)
    np.testing.assert_array_equal(ds.read("y")[1], data[20:40, [0, 2, 3, 4, 5]].astype(np.float32))
    assert ds.attrs["domain"] == "arm7" and ds.dt == 0.5


def test_dt_from_a_time_column_tolerates_small_jitter(tmp_path):
    src = _system(100)
    src["t"] = src["t"] + np.random.default_rng(0).uniform(-1e-5, 1e-5, 100)  # 0.05% of dt
    ds = ingest([_npz(tmp_path / "a.npz", src)], U, Y, str(tmp_path / "o.zarr"), steps=50, time_col="t")
    assert ds.dt == pytest.approx(DT, rel=1e-3)


def test_short_recordings_are_skipped_with_a_warning(tmp_path):
    files = [_csv(tmp_path / "long.csv", _system(120)), _csv(tmp_path / "short.csv", _system(30)),
             _csv(tmp_path / "last.csv", _system(60))]
    with pytest.warns(ShortRecordingWarning, match="short.csv"):
        ds = ingest(files, U, Y, str(tmp_path / "o.zarr"), steps=50, dt=DT)
    # Indices keep the command-line position, so index 1 (the skipped file) never appears.
    np.testing.assert_array_equal(ds.read("recording_index"), [0, 0, 2])
    assert ds.attrs["skipped_recordings"] == ["short.csv"]


def test_zero_windows_is_an_error(tmp_path):
    with pytest.warns(ShortRecordingWarning), pytest.raises(IngestError, match="no windows.*lower --steps"):
        ingest([_csv(tmp_path / "a.csv", _system(30))], U, Y, str(tmp_path / "o.zarr"), steps=50, dt=DT)
    assert not os.path.exists(tmp_path / "o.zarr")


def _edited_csv(tmp_path, name, line, text):
    """A good CSV log with one line (0 = header) replaced."""
    lines = open(_csv(tmp_path / name, _system(100))).read().splitlines()
    lines[line] = text
    (tmp_path / name).write_text("\n".join(lines) + "\n")
    return str(tmp_path / name)


def _renamed(tmp_path, name):
    """A good CSV log under a name whose extension says nothing of its format."""
    os.replace(_csv(tmp_path / "x.csv", _system(100)), tmp_path / name)
    return str(tmp_path / name)


def _nan_npz(tmp_path):
    src = _system(100)
    src["q2"][37] = np.nan
    return _npz(tmp_path / "bad.npz", src)


def _jump_npz(tmp_path):
    src = _system(100)
    src["t"][60:] += 0.5 * DT  # one late sample, then uniform again
    return _npz(tmp_path / "jump.npz", src)


def _slow_npz(tmp_path):
    src = _system(100)
    src["t"] = src["t"] * 2
    return _npz(tmp_path / "slow.npz", src)


# case -> (extra files after a good log, ingest keywords, exception, message pattern)
ERRORS = {
    "missing": (lambda p: [str(p / "nope.csv")], {}, FileNotFoundError, "log file not found: .*nope.csv"),
    "unknown_column": (lambda p: [], {"y_cols": ["q1", "q9"]}, IngestError,
                       r"no column 'q9'; available columns: t, tau1, tau2, q1, q2, q3"),
    "nan": (lambda p: [_nan_npz(p)], {}, IngestError,
            r"column 'q2' in .*bad.npz holds NaN.*first bad row: sample 37 counting from 0"),
    "empty_cell": (lambda p: [_edited_csv(p, "gap.csv", 5, "5.08,0.1,,1,2,3")], {}, IngestError,
                   r"column 'tau2' in .*gap.csv holds NaN.*sample 4"),
    "text_cell": (lambda p: [_edited_csv(p, "text.csv", 2, "0,1,2,oops,4,5")], {}, IngestError,
                  r"text.csv line 3, column 'q1': 'oops' is not a number"),
    "extension": (lambda p: [_renamed(p, "log.txt")], {}, IngestError,
                  r"cannot tell the format of .*log.txt.*--format"),
    "format": (lambda p: [], {"fmt": "xls"}, IngestError, r"unknown format 'xls'"),
    "nonuniform": (lambda p: [_jump_npz(p)], {"dt": None, "time_col": "t"}, IngestError,
                   r"jump.npz: non-uniform sampling.*sample 60.*must be resampled"),
    "two_rates": (lambda p: [_slow_npz(p)], {"dt": None, "time_col": "t"}, IngestError,
                  r"differ in sample time.*resample"),
    "dt_and_time": (lambda p: [], {"time_col": "t"}, IngestError, r"exactly one of --dt .* or --time-col"),
    "dt_inf": (lambda p: [], {"dt": float("inf")}, IngestError, r"--dt must be a positive, finite number.*got inf"),
    "dt_nan": (lambda p: [], {"dt": float("nan")}, IngestError, r"--dt must be a positive, finite number.*got nan"),
    # 1e39 is a finite float64 but inf as the store's float32: refused, naming column and row.
    "float32_overflow": (lambda p: [_edited_csv(p, "big.csv", 8, "5.14,0.1,1e39,1,2,3")], {}, IngestError,
                         r"column 'tau2' in .*big.csv: sample 7 .* is 1e\+39, beyond the float32 range"),
}


@pytest.mark.parametrize("case", sorted(ERRORS))
def test_errors_name_the_problem_and_write_nothing(tmp_path, case):
    extra, kw, exc, pattern = ERRORS[case]
    files = [_csv(tmp_path / "good.csv", _system(100)), *extra(tmp_path)]
    args = {"u_cols": U, "y_cols": Y, "dt": DT, **kw}
    with pytest.raises(exc, match=pattern):
        ingest(files, out=str(tmp_path / "o.zarr"), steps=50, **args)
    # Every input is checked before the store is created.
    assert not os.path.exists(tmp_path / "o.zarr")


def test_output_that_is_a_file_or_another_store_is_left_untouched(tmp_path):
    log = _csv(tmp_path / "a.csv", _system(100))
    precious = tmp_path / "precious.zarr"
    precious.write_bytes(b"\x00not a store\xff" * 100)
    before = precious.read_bytes()
    with pytest.raises(FileExistsError, match="is a file"):
        ingest([log], U, Y, str(precious), steps=50, dt=DT, overwrite=True)
    assert precious.read_bytes() == before

    existing = tmp_path / "old.zarr"
    w = create_store(str(existing), 1, 5, ["a"], ["b"], [], {"dt": 1.0})
    w.append(np.ones((1, 5, 1), np.float32), np.ones((1, 5, 1), np.float32), np.zeros((1, 0), np.float32))
    w.finalize()
    with pytest.raises(FileExistsError, match="--overwrite"):
        ingest([log], U, Y, str(existing), steps=50, dt=DT)
    assert open_store(str(existing)).u_names == ["a"]
    ds = ingest([log], U, Y, str(existing), steps=50, dt=DT, overwrite=True)
    assert ds.u_names == U and ds.n == 2


def test_another_schema_is_refused(tmp_path):
    other = tmp_path / "other.zarr"
    zarr.open_group(str(other), mode="w").attrs["schema"] = "someone.else"
    before = sorted(os.listdir(other))
    with pytest.raises(SchemaError, match="another schema"):
        ingest([_csv(tmp_path / "a.csv", _system(100))], U, Y, str(other), steps=50, dt=DT, overwrite=True)
    assert sorted(os.listdir(other)) == before


def test_cli_success_and_warning(tmp_path, capsys):
    files = [_csv(tmp_path / "a.csv", _system(120)), _csv(tmp_path / "b.csv", _system(20))]
    out = str(tmp_path / "real.zarr")
    rc = main([*files, "--u-cols", "tau1, tau2", "--y-cols", "q1,q2,q3", "--time-col", "t",
               "--steps", "50", "--stride", "25", "--out", out])
    cap = capsys.readouterr()
    assert rc == 0
    assert "3 windows x 50 steps" in cap.out and "from 1 of 2 recordings" in cap.out
    assert "warning: skipping" in cap.err and "b.csv" in cap.err
    assert open_store(out).read("window_start").tolist() == [0, 25, 50]


def test_cli_errors_exit_2_without_traceback(tmp_path, capsys):
    log = _csv(tmp_path / "a.csv", _system(100))
    rc = main([log, "--u-cols", "tau1,torque", "--y-cols", "q1", "--dt", "0.02", "--steps", "50",
               "--out", str(tmp_path / "o.zarr")])
    err = capsys.readouterr().err
    assert rc == 2 and err.startswith("error: ") and "'torque'" in err and "available columns" in err
    assert "Traceback" not in err

    target = tmp_path / "file.zarr"
    target.write_text("keep me")
    rc = main([log, "--u-cols", "tau1", "--y-cols", "q1", "--dt", "0.02", "--steps", "50",
               "--out", str(target), "--overwrite"])
    err = capsys.readouterr().err
    assert rc == 2 and err.startswith("error: ") and "is a file" in err
    assert target.read_text() == "keep me"


def test_tail_samples_dropped_are_reported_per_recording(tmp_path, capsys):
    files = [_csv(tmp_path / "a.csv", _system(120)), _csv(tmp_path / "b.csv", _system(20)),
             _csv(tmp_path / "c.csv", _system(100))]
    out = str(tmp_path / "real.zarr")
    rc = main([*files, "--u-cols", "tau1,tau2", "--y-cols", "q1,q2,q3", "--dt", str(DT), "--steps", "50",
               "--stride", "30", "--out", out])
    assert rc == 0
    text = capsys.readouterr().out
    # a: windows at 0, 30, 60 cover samples 0..109, 10 left; b is too short: all 20 dropped
    assert "a.csv: 120 samples -> 3 windows, 10 tail samples dropped" in text
    assert "b.csv: 20 samples -> 0 windows, 20 tail samples dropped" in text
    assert "c.csv: 100 samples -> 2 windows, 20 tail samples dropped" in text
    rec = open_store(out).attrs["recordings"]
    assert [(r["source"], r["windows"], r["tail_dropped"]) for r in rec] == [("a.csv", 3, 10), ("b.csv", 0, 20),
                                                                          ("c.csv", 2, 20)]


def _titles(monkeypatch):
    """Spies on Figure.savefig: the panel titles and axis labels of every figure written."""
    from matplotlib.figure import Figure

    seen, save = [], Figure.savefig

    def spy(fig, *args, **kwargs):
        seen.extend(ax.get_title() for ax in fig.axes)
        seen.extend(ax.get_xticklabels()[i].get_text() for ax in fig.axes for i in range(len(ax.get_xticklabels())))
        return save(fig, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", spy)
    return seen


def test_units_are_recorded_and_label_the_inspect_plot(tmp_path, monkeypatch):
    from robomorph.data.summary import plot

    out = str(tmp_path / "real.zarr")
    rc = main([_csv(tmp_path / "a.csv", _system(120)), "--u-cols", "tau1,tau2", "--y-cols", "q1,q2,q3",
               "--dt", str(DT), "--steps", "50", "--out", out, "--u-units", "N m,N m", "--y-units", "rad,rad,"])
    assert rc == 0
    ds = open_store(out)
    assert ds.attrs["u_units"] == ["N m", "N m"] and ds.attrs["y_units"] == ["rad", "rad", ""]
    seen = _titles(monkeypatch)
    plot(ds, str(tmp_path / "p.png"), n_traj=1)
    assert {"u: tau1 [N m]", "u: tau2 [N m]", "y: q1 [rad]", "y: q2 [rad]", "y: q3"} <= set(seen)
    with pytest.raises(IngestError, match="--y-units gives 2 units for 3 columns"):
        ingest([_csv(tmp_path / "a.csv", _system(120))], U, Y, str(tmp_path / "o.zarr"), steps=50, dt=DT,
               y_units=["rad", "rad"])


def _with_command(cols):
    """A log of an arm whose controller adds a known compensation to the command."""
    comp = {"tau1": 3.0 * np.sin(cols["q1"]), "tau2": 1.5 + 0.0 * cols["q2"]}
    return {**cols, "cmd1": cols["tau1"] - comp["tau1"], "cmd2": cols["tau2"] - comp["tau2"]}


def test_ingest_maps_the_command_and_the_total_torque_columns(tmp_path):
    cols = _with_command(_system(120))
    log = _csv(tmp_path / "a.csv", cols)
    out = str(tmp_path / "real.zarr")
    rc = main([log, "--u-cols", "tau1,tau2", "--u-cmd-cols", "cmd1,cmd2", "--y-cols", "q1,q2,q3",
               "--dt", str(DT), "--steps", "50", "--out", out])
    assert rc == 0
    ds = open_store(out)
    np.testing.assert_array_equal(ds.read_inputs("total")[1], _window(cols, U, 50, 50))
    np.testing.assert_array_equal(ds.read_inputs("command")[1], _window(cols, ["cmd1", "cmd2"], 50, 50))
    assert ds.input_names("command") == ["cmd1", "cmd2"] and ds.input_names("total") == U
    assert not np.allclose(ds.read("u"), ds.read("u_cmd"))  # two different column sets, not a copy


def test_a_store_without_command_columns_says_how_to_get_them(tmp_path):
    from robomorph.core.inputs import InputsError

    ds = ingest([_csv(tmp_path / "a.csv", _system(100))], U, Y, str(tmp_path / "o.zarr"), steps=50, dt=DT)
    assert not ds.has_inputs("command") and ds.has_inputs("total")
    with pytest.raises(InputsError, match="--u-cmd-cols"):
        ds.read_inputs("command")


def test_command_columns_must_match_the_torque_columns(tmp_path):
    log = _csv(tmp_path / "a.csv", _with_command(_system(100)))
    with pytest.raises(IngestError, match="one column per joint"):
        ingest([log], U, Y, str(tmp_path / "o.zarr"), steps=50, dt=DT, u_cmd_cols=["cmd1"])
    with pytest.raises(IngestError, match="'cmdX'"):
        ingest([log], U, Y, str(tmp_path / "o.zarr"), steps=50, dt=DT, u_cmd_cols=["cmd1", "cmdX"])
    assert not os.path.exists(tmp_path / "o.zarr")
