"""The industrial robot benchmark's loader: which file it reads, the shifted copy's alignment, its
splits by trajectory, and its refusals."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
from scipy.io import savemat

from robomorph.core.errors import MissingInputError
from robomorph.data import industrial

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
REAL = "/work/realdata/Physics-Guided-Recurrent-State-Space-Neural-Networks/data/IndustRobo/" + industrial.SHIFTED


def _official_trajectory(rng, n=606):
    """A trajectory from rest to rest of a toy system whose step is y[t + 1] = y[t] + 0.1 u[t]."""
    u = rng.normal(size=(n, 6))
    u[-1] = 0.0
    y = np.concatenate([np.zeros((1, 6)), np.cumsum(0.1 * u[:-1], axis=0)])
    return u, y


def _write_official(path, rng, n_train=8, n_test=6):
    train = [_official_trajectory(rng) for _ in range(n_train)]
    test = [_official_trajectory(rng) for _ in range(n_test)]
    os.makedirs(os.path.dirname(path), exist_ok=True)
    savemat(path, {f"{k}_{split}": np.concatenate([t[i] for t in trajs]).T
                   for split, trajs in (("train", train), ("test", test)) for i, k in enumerate("uy")})
    return train, test


def _write_shifted(path, rng, n_train=2, n_val=2, n_test=6, pad=8):
    parts = {}
    for split, n in (("train", n_train), ("val", n_val), ("test", n_test)):
        trajs = [industrial.shift(*_official_trajectory(rng)) for _ in range(n)]
        u, y = np.concatenate([t[0] for t in trajs]), np.concatenate([t[1] for t in trajs])
        if split == "val":  # as the copy: its last samples' torques zero-padded
            u[-pad:] = 0.0
        parts[f"u_{split}"], parts[f"y_{split}"] = u.T, y.T
    os.makedirs(os.path.dirname(path), exist_ok=True)
    savemat(path, parts)


def test_shift_puts_each_input_beside_the_output_it_drives():
    u, y = _official_trajectory(np.random.default_rng(0))
    us, ys = industrial.shift(u, y)
    assert us.shape == ys.shape == (605, 6)
    # official: y[t + 1] = y[t] + 0.1 u[t]; shifted: y_s[k] = y_s[k - 1] + 0.1 u_s[k]
    np.testing.assert_allclose(ys[1:] - ys[:-1], 0.1 * us[1:], atol=1e-12)


def test_the_shifted_copy_is_read_in_605_sample_trajectories_and_its_padding_trimmed(tmp_path):
    _write_shifted(str(tmp_path / "clone" / "data" / "IndustRobo" / industrial.SHIFTED), np.random.default_rng(1))
    b = industrial.load(str(tmp_path))
    assert b.layout == "shifted" and os.path.basename(b.path) == industrial.SHIFTED and len(b.sha256) == 64
    assert [len(u) for u, _ in b.train] == [605, 605] and [len(u) for u, _ in b.test] == [605] * 6
    assert [len(u) for u, _ in b.val] == [605, 597]  # the 8 zero-padded samples are not the robot's
    assert b.test_u.shape == (3630, 6) and "shifted layout" in b.describe()


def test_the_official_file_wins_over_the_copy_and_its_validation_is_cut_by_trajectory(tmp_path):
    rng = np.random.default_rng(2)
    _write_shifted(str(tmp_path / "clone" / "data" / "IndustRobo" / industrial.SHIFTED), rng)
    train, test = _write_official(str(tmp_path / "nonlinear_benchmarks" / industrial.OFFICIAL), rng)
    b = industrial.load(str(tmp_path))
    assert b.layout == "official" and os.path.basename(b.path) == industrial.OFFICIAL
    assert len(b.train) == 2 and len(b.val) == industrial.N_VAL and [len(u) for u, _ in b.test] == [606] * 6
    np.testing.assert_array_equal(b.val[0][1], train[2][1])  # whole trajectories, in order
    np.testing.assert_array_equal(b.test[5][0], test[5][0])


def test_the_layout_is_told_by_the_files_content_not_its_name(tmp_path):
    rng = np.random.default_rng(3)
    _write_official(str(tmp_path / "renamed.mat"), rng)
    _write_shifted(str(tmp_path / "other.mat"), rng)
    assert industrial.load(path=str(tmp_path / "renamed.mat")).layout == "official"
    assert industrial.load(path=str(tmp_path / "other.mat")).layout == "shifted"


def test_a_folder_without_the_benchmark_is_one_line_naming_the_clone(tmp_path):
    with pytest.raises(MissingInputError, match="Physics-Guided-Recurrent-State-Space-Neural-Networks"):
        industrial.load(str(tmp_path))
    out = subprocess.run([sys.executable, os.path.join(ROOT, "benchmarks", "industrial_robot.py"), "--data",
                          str(tmp_path), "--md", str(tmp_path / "x.md")], capture_output=True, text=True,
                         cwd=str(tmp_path))
    assert out.returncode == 2 and "Traceback" not in out.stderr and len(out.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "x.md").exists()


def test_a_file_without_the_benchmarks_variables_is_refused(tmp_path):
    path = tmp_path / industrial.SHIFTED
    savemat(str(path), {"u_train": np.zeros((6, 10))})
    with pytest.raises(industrial.IndustrialDataError, match="lacks"):
        industrial.load(path=str(path))


@pytest.mark.skipif(not os.path.isfile(REAL), reason="the shifted copy is not on this machine")
def test_the_real_shifted_copy_cuts_fall_on_its_rest_to_rest_boundaries():
    b = industrial.load(path=REAL)
    assert (len(b.train), len(b.val), len(b.test)) == (60, 6, 6)
    for u, y in b.train + b.val + b.test:  # each trajectory starts and ends at rest at home
        assert np.abs(y[0]).max() < 0.05 and np.abs(y[-1] - y[-2]).max() < 0.05


def test_the_benchmark_command_writes_every_reading_with_its_provenance(tmp_path):
    _write_shifted(str(tmp_path / "clone" / "data" / "IndustRobo" / industrial.SHIFTED), np.random.default_rng(4))
    md = tmp_path / "industrial_robot.md"
    out = subprocess.run([sys.executable, os.path.join(ROOT, "benchmarks", "industrial_robot.py"), "--data",
                          str(tmp_path), "--predictors", "hold,arx_ls", "--md", str(md)],
                         capture_output=True, text=True, cwd=str(tmp_path))
    assert out.returncode == 0, out.stderr[-2000:]
    text = md.read_text()
    assert text.startswith("*Produced by `") and "at commit" in text and "machine:" in text
    assert "shifted layout, sha256" in text and "(the official file was not found)" in text
    rows = {line.split("|")[1].strip(): [c.strip() for c in line.split("|")[2:-1]]
            for line in text.splitlines() if line.startswith("| hold") or line.startswith("| arx_ls")}
    assert set(rows) == {"hold", "arx_ls"}
    for name in rows:  # (a), (b), (c) and both identibench columns are numbers
        assert all(np.isfinite(float(v)) for v in rows[name][:5])
    assert "| MA-LSTM-MLP" in text and "(c), likely" in text


def test_the_meta_model_is_fine_tuned_and_scored_in_every_reading_beside_the_others(tmp_path):
    _write_shifted(str(tmp_path / "clone" / "data" / "IndustRobo" / industrial.SHIFTED), np.random.default_rng(5))
    md = tmp_path / "industrial_robot.md"
    out = subprocess.run([sys.executable, os.path.join(ROOT, "benchmarks", "industrial_robot.py"), "--data",
                          str(tmp_path), "--predictors", "hold,narx_sim,meta_finetuned", "--iterations", "2",
                          "--meta-iterations", "2", "--no-identibench", "--md", str(md)],
                         capture_output=True, text=True, cwd=str(tmp_path))
    assert out.returncode == 0, out.stderr[-2000:]
    text = md.read_text()
    rows = {line.split("|")[1].strip(): [c.strip() for c in line.split("|")[2:-1]]
            for line in text.splitlines() if line.startswith("| ") and not line.startswith("| predictor")}
    assert all(np.isfinite(float(v)) for v in rows["meta_finetuned"][:5])
    assert "`meta_finetuned`: the multi-arm meta-model `realistic-arms-60hz`" in text and "tau0..tau5" in text


def test_a_bad_meta_model_is_refused_before_any_training(tmp_path):
    _write_shifted(str(tmp_path / "clone" / "data" / "IndustRobo" / industrial.SHIFTED), np.random.default_rng(6))
    for extra, message in ((["--meta", str(tmp_path / "none")], "--meta "), (["--meta-chunk", "5000"], "chunk 5000")):
        out = subprocess.run([sys.executable, os.path.join(ROOT, "benchmarks", "industrial_robot.py"), "--data",
                              str(tmp_path), "--predictors", "gru_sim,meta_finetuned", "--md",
                              str(tmp_path / "t.md")] + extra, capture_output=True, text=True, cwd=str(tmp_path))
        assert out.returncode == 2 and "Traceback" not in out.stderr and message in out.stderr
        assert out.stderr.count("\n") == 1 and "gru_sim (seed 0)" not in out.stderr
        assert not (tmp_path / "t.md").exists()


def test_the_ensemble_is_chosen_on_validation_and_keeps_only_members_that_help():
    sys.path.insert(0, os.path.join(ROOT, "benchmarks"))
    try:
        import industrial_robot as ir
    finally:
        sys.path.pop(0)
    from robomorph.training import free_run as fr

    rng = np.random.default_rng(7)
    val = [(rng.normal(size=(50, 6)), rng.normal(size=(50, 6))) for _ in range(3)]
    truth = {u.tobytes(): y for u, y in val}

    def biased(b):  # the truth plus a constant bias after the warm-up
        def predict(u, y_init):
            out = truth[u.tobytes()] + b
            out[:len(y_init)] = y_init
            return out
        return predict

    norm = fr.Normalizer.of(val)
    # opposite biases cancel in the mean: both are kept; a far worse third one is left out
    chosen = ir.choose_ensemble([("plus", biased(0.5)), ("minus", biased(-0.5)), ("far", biased(3.0))], val, norm)
    assert sorted(chosen) == ["minus", "plus"]
    # one exact member alone beats any mean with another
    assert ir.choose_ensemble([("bad", biased(1.0)), ("exact", biased(0.0))], val, norm) == ["exact"]


def test_a_share_of_the_training_trajectories_is_a_seeded_choice_and_too_many_is_refused(tmp_path):
    sys.path.insert(0, os.path.join(ROOT, "benchmarks"))
    try:
        import industrial_robot as ir
    finally:
        sys.path.pop(0)
    _write_shifted(str(tmp_path / "clone" / "data" / "IndustRobo" / industrial.SHIFTED), np.random.default_rng(8),
                   n_train=5)
    b = industrial.load(str(tmp_path))
    a, again = ir.subset(b, 3), ir.subset(b, 3)
    assert len(a.train) == 3 and all(np.array_equal(x[0], y[0]) for x, y in zip(a.train, again.train))
    assert all(any(np.array_equal(t[0], s[0]) for s in b.train) for t in a.train)  # whole trajectories, uncut
    assert a.val is b.val and a.test is b.test and ir.subset(b, None) is b
    with pytest.raises(industrial.IndustrialDataError, match="holds 5 training trajectories"):
        ir.subset(b, 6)
