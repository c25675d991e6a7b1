import pickle

import numpy as np
import pytest
import torch
import zarr
from zarr.storage import LocalStore

from robomorph.data.datamodule import RoboMorphDataModule
from robomorph.data.statistics import Stats
from robomorph.data.store import SchemaError, create_store, open_store
from tests.conftest import write_store

U_NAMES, Y_NAMES = ["u0", "u1"], ["y0", "y1", "y2"]


def _values(store_id, n, steps, width, sign):
    """Values that name their (store, trajectory, step): floor(|v|) = 100000 s + 100 i + t."""
    i = np.arange(n)[:, None, None]
    t = np.arange(steps)[None, :, None]
    c = np.arange(width)[None, None, :]
    return (sign * (store_id * 100000 + i * 100 + t + 0.25 * c)).astype(np.float32)


def _store(path, store_id=0, n=20, steps=60, chunk=8, u=None, y=None, u_names=U_NAMES, y_names=Y_NAMES, dt=0.1):
    u = _values(store_id, n, steps, len(u_names), 1) if u is None else u
    y = _values(store_id, n, steps, len(y_names), -1) if y is None else y
    return write_store(path, u, y, np.zeros((n, 1)), u_names, y_names, ["p"], {"dt": dt}, chunk=chunk)


def _dm(stores, **kw):
    kw = {"context_len": 10, "horizon": 20, "batch_size": 4, **kw}
    dm = RoboMorphDataModule(stores=stores, **kw)
    dm.setup()
    return dm


def _who(u):
    """(store, trajectory, step) of each step of a u tensor (..., T, n_u)."""
    code = torch.floor(u[..., 0]).long()
    return code // 100000, (code % 100000) // 100, code % 100


def _batches(loader):
    return list(loader)


def test_splits_are_disjoint_covering_and_seeded(tmp_path):
    a = _store(tmp_path / "a.zarr")
    dm = _dm(a, seed=0)
    sp = dm.splits[0]
    assert [len(sp[k]) for k in ("train", "val", "test")] == [16, 2, 2]
    rows = np.concatenate([sp["train"], sp["val"], sp["test"]])
    assert sorted(rows.tolist()) == list(range(20))
    again = _dm(a, seed=0).splits[0]
    other = _dm(a, seed=1).splits[0]
    assert all(np.array_equal(sp[k], again[k]) for k in sp)
    assert any(not np.array_equal(sp[k], other[k]) for k in sp)


def test_loaders_follow_the_splits(tmp_path):
    dm = _dm(_store(tmp_path / "a.zarr"), train_samples_per_epoch=64)
    seen = {}
    for name, loader in (("train", dm.train_dataloader()), ("val", dm.val_dataloader()), ("test", dm.test_dataloader())):
        seen[name] = {int(i) for b in loader for i in _who(b["u_ctx"])[1][:, 0]}
    for name in ("val", "test"):
        assert seen[name] == set(dm.splits[0][name].tolist())
    assert seen["train"] <= set(dm.splits[0]["train"].tolist()) and len(seen["train"]) > 8


def test_test_store_is_the_whole_test_split(tmp_path):
    a, t = _store(tmp_path / "a.zarr"), _store(tmp_path / "t.zarr", store_id=2, n=5)
    dm = _dm(a, test_store=t)
    assert [len(dm.splits[0][k]) for k in ("train", "val", "test")] == [18, 2, 0]
    stores, trajs, _ = _who(torch.cat([b["u_ctx"] for b in dm.test_dataloader()]))
    assert (stores == 2).all() and sorted(set(trajs[:, 0].tolist())) == list(range(5))
    assert dm.describe()["test"] == 5
    with pytest.raises(ValueError, match="also a training store"):
        RoboMorphDataModule(stores=[a], test_store=a)


def test_start_windows_equal_the_stored_slices(tmp_path):
    a = _store(tmp_path / "a.zarr")
    dm = _dm(a, split=(0.5, 0.5, 0.0))
    ds = open_store(a)
    u, y = ds.read("u"), ds.read("y")
    batch = torch.cat([b["u_ctx"] for b in dm.val_dataloader()])
    rows = dm.splits[0]["val"]
    np.testing.assert_array_equal(batch.numpy(), u[rows, :10])
    b = next(iter(dm.val_dataloader()))
    r = rows[:4]
    np.testing.assert_array_equal(b["y_ctx"].numpy(), y[r, :10])
    np.testing.assert_array_equal(b["u_query"].numpy(), u[r, 10:30])
    np.testing.assert_array_equal(b["y_query"].numpy(), y[r, 10:30])


def test_batch_shapes_and_dtypes(tmp_path):
    dm = _dm(_store(tmp_path / "a.zarr"))
    b = next(iter(dm.train_dataloader()))
    shapes = {"u_ctx": (4, 10, 2), "y_ctx": (4, 10, 3), "u_query": (4, 20, 2), "y_query": (4, 20, 3)}
    assert {k: tuple(v.shape) for k, v in b.items()} == shapes
    assert all(v.dtype == torch.float32 for v in b.values())
    assert (dm.n_u, dm.n_y, dm.u_names, dm.y_names, dm.dt) == (2, 3, U_NAMES, Y_NAMES, 0.1)


def test_random_windows_stay_in_range_and_vary(tmp_path):
    dm = _dm(_store(tmp_path / "a.zarr"), window="random", train_samples_per_epoch=200)
    offsets = []
    for b in dm.train_dataloader():
        u = torch.cat([b["u_ctx"], b["u_query"]], dim=1)
        _, traj, step = _who(u)
        assert (step == step[:, :1] + torch.arange(30)).all()   # contiguous windows
        assert (traj == traj[:, :1]).all()
        offsets += step[:, 0].tolist()
    assert min(offsets) >= 0 and max(offsets) <= 60 - 30
    assert len(set(offsets)) > 10
    val_steps = _who(torch.cat([b["u_ctx"] for b in dm.val_dataloader()]))[2]
    assert (val_steps[:, 0] == 0).all()


def test_training_stream_is_seeded_per_epoch(tmp_path):
    a = _store(tmp_path / "a.zarr")

    def stream(seed, epoch):
        dm = _dm(a, seed=seed, window="random")
        dm.train_sampler.set_epoch(epoch)
        return torch.cat([b["u_ctx"] for b in dm.train_dataloader()])

    assert torch.equal(stream(0, 0), stream(0, 0))
    assert not torch.equal(stream(0, 0), stream(0, 1))
    assert not torch.equal(stream(0, 0), stream(1, 0))
    dm = _dm(a, window="random")
    first, second = (torch.cat([b["u_ctx"] for b in dm.train_dataloader()]) for _ in range(2))
    assert torch.equal(first, stream(0, 0)) and torch.equal(second, stream(0, 1))


@pytest.mark.parametrize("window", ["start", "random"])
def test_random_lengths_stay_within_the_data_one_pair_per_batch_and_seeded(tmp_path, window):
    a = _store(tmp_path / "a.zarr", steps=40)

    def stream(seed):
        dm = _dm(a, seed=seed, window=window, context_min=3, horizon_min=5, batch_size=4,
                 train_samples_per_epoch=120)
        return list(dm.train_dataloader()), dm

    batches, dm = stream(0)
    lengths = set()
    for b in batches:
        c, h = b["u_ctx"].shape[1], b["u_query"].shape[1]
        assert 3 <= c <= 10 and 5 <= h <= 20 and b["y_ctx"].shape[1] == c and b["y_query"].shape[1] == h
        lengths.add((c, h))
        _, traj, step = _who(torch.cat([b["u_ctx"], b["u_query"]], dim=1))
        assert (step == step[:, :1] + torch.arange(c + h)).all() and (traj == traj[:, :1]).all()
        assert (step[:, -1] <= 39).all()  # inside the 40 stored steps
        if window == "start":
            assert (step[:, 0] == 0).all()
    assert len(lengths) > 5
    again, _ = stream(0)
    assert all(torch.equal(x["u_query"], y["u_query"]) for x, y in zip(batches, again))
    other, _ = stream(1)
    assert [b["u_query"].shape for b in other] != [b["u_query"].shape for b in batches]
    for b in dm.val_dataloader():  # validation keeps the full lengths
        assert (b["u_ctx"].shape[1], b["u_query"].shape[1]) == (10, 20)


def test_context_frac(tmp_path):
    dm = _dm(_store(tmp_path / "a.zarr"), context_len=None, context_frac=0.25, horizon=30)
    assert dm.context_len == 15
    assert next(iter(dm.val_dataloader()))["u_ctx"].shape == (2, 15, 2)


def test_too_short_trajectories_are_refused(tmp_path):
    with pytest.raises(ValueError, match=r"T=60 steps.*context_len 50 \+ horizon 20 = 70"):
        _dm(_store(tmp_path / "a.zarr"), context_len=50)


def test_mixture_weights_set_store_frequency(tmp_path):
    a, b = _store(tmp_path / "a.zarr"), _store(tmp_path / "b.zarr", store_id=1)
    dm = _dm([a, b], weights=[0.9, 0.1], train_samples_per_epoch=4000, batch_size=500)
    stores = torch.cat([_who(x["u_ctx"])[0][:, 0] for x in dm.train_dataloader()])
    assert len(stores) == 4000
    assert 0.86 < (stores == 0).float().mean().item() < 0.94
    assert dm.describe()["weights"] == pytest.approx([0.9, 0.1])


def test_default_weights_follow_training_sizes(tmp_path):
    a, b = _store(tmp_path / "a.zarr", n=30), _store(tmp_path / "b.zarr", store_id=1, n=10)
    assert _dm([a, b]).describe()["weights"] == pytest.approx([24 / 32, 8 / 32])


def test_stats_use_the_training_split_only(tmp_path):
    a = _store(tmp_path / "a.zarr")
    dm = _dm(a)
    u, y = _values(0, 20, 60, 2, 1), _values(0, 20, 60, 3, -1)
    train = dm.splits[0]["train"]
    expect = Stats.from_arrays(u[train, :30], y[train, :30])   # start windows: steps [0, 30)
    np.testing.assert_allclose(dm.stats.u_mean, u[train, :30].astype(np.float64).mean(axis=(0, 1)), rtol=1e-12)
    np.testing.assert_allclose(dm.stats.y_std, y[train, :30].astype(np.float64).std(axis=(0, 1)), rtol=1e-9)
    held = np.concatenate([dm.splits[0]["val"], dm.splits[0]["test"]])
    u[held] *= 1e6
    y[held] = -3e7
    _store(a, u=u, y=y)
    changed = _dm(a)
    for k in ("u_mean", "u_std", "y_mean", "y_std"):
        np.testing.assert_allclose(getattr(changed.stats, k), getattr(expect, k), rtol=1e-9)
        np.testing.assert_allclose(getattr(dm.stats, k), getattr(expect, k), rtol=1e-9)


def test_random_window_stats_cover_all_steps(tmp_path):
    dm = _dm(_store(tmp_path / "a.zarr"), window="random")
    u = _values(0, 20, 60, 2, 1)[dm.splits[0]["train"]].astype(np.float64)
    np.testing.assert_allclose(dm.stats.u_mean, u.mean(axis=(0, 1)), rtol=1e-12)


def test_on_demand_reading_matches_memory(tmp_path):
    a, b = _store(tmp_path / "a.zarr", chunk=3), _store(tmp_path / "b.zarr", store_id=1, chunk=7)
    mem, disk = (_dm([a, b], in_memory=f, window="random", train_samples_per_epoch=40) for f in (True, False))
    assert mem.describe()["in_memory"] and not disk.describe()["in_memory"]
    for name in ("train_dataloader", "val_dataloader", "test_dataloader"):
        for x, z in zip(getattr(mem, name)(), getattr(disk, name)()):
            assert all(torch.equal(x[k], z[k]) for k in x)
    np.testing.assert_array_equal(mem.stats.y_std, disk.stats.y_std)


@pytest.mark.parametrize("in_memory", [True, False])
def test_workers_give_the_same_batches(tmp_path, in_memory):
    a = _store(tmp_path / "a.zarr")
    kw = dict(split=(0.5, 0.3, 0.2), window="random", train_samples_per_epoch=24, in_memory=in_memory)
    solo, multi = _dm(a, num_workers=0, **kw), _dm(a, num_workers=2, **kw)
    for name in ("val_dataloader", "train_dataloader"):
        xs, zs = _batches(getattr(solo, name)()), _batches(getattr(multi, name)())
        assert len(xs) == len(zs) > 1
        for x, z in zip(xs, zs):
            assert all(torch.equal(x[k], z[k]) for k in x)


def test_val_subset_is_fixed_and_bounded(tmp_path):
    a = _store(tmp_path / "a.zarr", n=40)
    dm = _dm(a, split=(0.5, 0.5, 0.0), val_subset=7)
    rows = dm.val_set.pairs[:, 1]
    assert len(rows) == 7 and set(rows) <= set(dm.splits[0]["val"].tolist())
    assert np.array_equal(rows, _dm(a, split=(0.5, 0.5, 0.0), val_subset=7).val_set.pairs[:, 1])
    d = dm.describe()
    assert (d["val"], d["val_used"], d["train"], d["context_len"], d["horizon"]) == (20, 7, 20, 10, 20)


def test_setup_is_idempotent(tmp_path):
    dm = _dm(_store(tmp_path / "a.zarr"))
    stats, sets = dm.stats, dm.train_set
    dm.setup("fit")
    dm.setup("validate")
    assert dm.stats is stats and dm.train_set is sets


def test_mismatched_stores_are_refused(tmp_path):
    a = _store(tmp_path / "a.zarr")
    b = _store(tmp_path / "b.zarr", y_names=["y0", "y1", "yZ"])
    with pytest.raises(ValueError, match=r"disagree on y_names.*a\.zarr.*b\.zarr"):
        _dm([a, b])
    c = _store(tmp_path / "c.zarr", dt=0.05)
    with pytest.raises(ValueError, match="disagree on dt"):
        _dm([a, c])


def test_nan_is_refused_with_store_and_trajectory(tmp_path):
    y = _values(0, 20, 60, 3, -1)
    y[13, 40, 2] = np.nan
    a = _store(tmp_path / "bad.zarr", y=y)
    for in_memory in (True, False):
        with pytest.raises(ValueError, match=r"bad\.zarr: trajectory 13 has NaN/inf values in 'y'"):
            _dm(a, in_memory=in_memory)


def test_missing_and_foreign_stores_are_refused(tmp_path):
    with pytest.raises(FileNotFoundError, match="nowhere.zarr"):
        _dm(str(tmp_path / "nowhere.zarr"))
    zarr.open_group(LocalStore(str(tmp_path / "plain.zarr")), mode="w").attrs["x"] = 1
    with pytest.raises(SchemaError, match="not a RoboMorph dataset"):
        _dm(str(tmp_path / "plain.zarr"))


@pytest.mark.parametrize("kw, match", [
    ({"context_len": None}, "exactly one of context_len and context_frac"),
    ({"context_len": 10, "context_frac": 0.2}, "exactly one of context_len and context_frac"),
    ({"context_len": None, "context_frac": 1.5}, "context_frac must be in"),
    ({"split": (0.8, 0.3, 0.1)}, "split must be three"),
    ({"split": (0.0, 0.5, 0.5)}, "split must be three"),
    ({"split": (0.8, 0.2)}, "split must be three"),
    ({"weights": [1.0, 2.0]}, "weights must be 1"),
    ({"weights": [-1.0]}, "weights must be 1"),
    ({"window": "middle"}, "window must be"),
    ({"horizon_min": 0}, "horizon_min must be in"),
    ({"horizon_min": 801}, "horizon_min must be in"),
    ({"context_min": 201}, "context_min must be in"),
    ({"horizon": 0}, "horizon must be >= 1"),
    ({"batch_size": 0}, "batch_size must be >= 1"),
    ({"stores": ["a.zarr", "./a.zarr"]}, "twice"),
    ({"stores": []}, "at least one store"),
])
def test_bad_arguments_are_refused(kw, match):
    with pytest.raises(ValueError, match=match):
        RoboMorphDataModule(**{"stores": "a.zarr", **kw})


def test_store_without_training_rows_is_refused(tmp_path):
    a, b = _store(tmp_path / "a.zarr"), _store(tmp_path / "b.zarr", store_id=1, n=1)
    with pytest.raises(ValueError, match=r"b\.zarr has no training trajectories"):
        _dm([a, b], split=(0.4, 0.6, 0.0))


@pytest.mark.filterwarnings("ignore::UserWarning")
@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_lightning_sets_the_epoch(tmp_path):
    import lightning.pytorch as L

    a = _store(tmp_path / "a.zarr")

    class Probe(L.LightningModule):
        def __init__(self):
            super().__init__()
            self.w = torch.nn.Parameter(torch.zeros(1))
            self.seen = {}

        def training_step(self, batch, i):
            self.seen.setdefault(self.current_epoch, []).append(batch["u_ctx"].clone())
            return (self.w - batch["u_ctx"].mean()).pow(2)

        def configure_optimizers(self):
            return torch.optim.SGD(self.parameters(), lr=0.0)

    dm = RoboMorphDataModule(stores=a, context_len=10, horizon=20, batch_size=4, window="random")
    probe = Probe()
    L.Trainer(max_epochs=2, logger=False, enable_checkpointing=False, enable_progress_bar=False,
              enable_model_summary=False, limit_val_batches=0).fit(probe, datamodule=dm)
    for epoch in (0, 1):
        ref = _dm(a, window="random")
        ref.train_sampler.set_epoch(epoch)
        expect = torch.cat([b["u_ctx"] for b in ref.train_dataloader()])
        assert torch.equal(torch.cat(probe.seen[epoch]), expect)


def test_datasets_pickle_for_spawned_workers(tmp_path):
    a = _store(tmp_path / "a.zarr", chunk=4)
    for in_memory in (True, False):
        dm = _dm(a, in_memory=in_memory)
        clone = pickle.loads(pickle.dumps(dm.val_set))
        assert all(torch.equal(clone[1][k], dm.val_set[1][k]) for k in clone[1])


def test_arguments_parse_from_the_command_line(tmp_path):
    from jsonargparse import ArgumentParser

    parser = ArgumentParser()
    parser.add_class_arguments(RoboMorphDataModule, "data")
    cfg = parser.parse_args(["--data.stores=[a.zarr,b.zarr]", "--data.weights=[0.7,0.3]", "--data.context_len=null",
                             "--data.context_frac=0.25", "--data.window=random", "--data.split=[0.7,0.2,0.1]"])
    init = parser.instantiate(cfg).data
    assert init.stores == ["a.zarr", "b.zarr"] and init.context_frac == 0.25 and init.split == (0.7, 0.2, 0.1)
    with pytest.raises(SystemExit):
        parser.parse_args(["--data.window=middle"])


def _recorded_store(path, lengths, steps=30, stride=10, store_id=0):
    """Overlapping windows cut from recordings, as ``ingest`` writes them: u[..., 0] holds
    1000 * recording + sample index, so a window names the samples it holds."""
    us, rec, starts = [], [], []
    for r, length in enumerate(lengths):
        for s in range(0, length - steps + 1, stride):
            t = np.arange(s, s + steps)
            us.append(np.stack([store_id * 100000 + 1000 * r + t, np.zeros(steps)], 1))
            rec.append(r)
            starts.append(s)
    n = len(us)
    u = np.asarray(us, np.float32)
    y = np.repeat(u[..., :1], 3, axis=2)
    w = create_store(str(path), n, steps, U_NAMES, Y_NAMES, [], {"dt": 0.1}, chunk=8,
                     extras={"recording_index": ((), "int32"), "window_start": ((), "int64")})
    w.append(u, y, np.zeros((n, 0), np.float32),
             extras={"recording_index": np.asarray(rec, np.int32), "window_start": np.asarray(starts)})
    w.finalize()
    return str(path)


def _samples(dm, split):
    """(recording, sample) pairs that the windows of one split hold."""
    pairs = getattr(dm, f"{split}_set").pairs
    u = np.concatenate([dm.sources[s].window(int(i), 0, dm.sources[s].steps)[0][None] for s, i in pairs])
    return set(u[..., 0].astype(np.int64).ravel().tolist())


def test_overlapping_windows_of_one_recording_stay_in_one_split(tmp_path):
    a = _recorded_store(tmp_path / "rec.zarr", lengths=[200, 150, 260, 120, 180, 220, 90, 240])
    for seed in range(3):
        dm = _dm(a, split=(0.6, 0.2, 0.2), seed=seed)
        groups = dm.sources[0].groups
        recs = {k: set(groups[dm.splits[0][k]].tolist()) for k in ("train", "val", "test")}
        assert recs["val"] and recs["test"] and recs["train"]
        assert not (recs["train"] & recs["val"]) and not (recs["train"] & recs["test"]) and not (recs["val"] & recs["test"])
        train, val = _samples(dm, "train"), _samples(dm, "val")
        assert val and not (train & val)  # no recorded sample is both trained on and validated on
        assert dm.describe()["split_by"] == ["recording"]
    again = _dm(a, split=(0.6, 0.2, 0.2), seed=2).splits[0]
    assert all(np.array_equal(again[k], dm.splits[0][k]) for k in again)  # seeded


def test_one_recording_cannot_be_split_by_recording(tmp_path):
    a = _recorded_store(tmp_path / "one.zarr", lengths=[300])
    with pytest.raises(ValueError, match="1 recording.*val_store"):
        _dm(a, split=(0.8, 0.2, 0.0))
    assert len(_dm(a, split=(1.0, 0.0, 0.0)).splits[0]["train"]) == 28


def test_validation_from_its_own_store(tmp_path):
    a = _store(tmp_path / "a.zarr")
    v = _store(tmp_path / "v.zarr", store_id=3, n=6)
    dm = _dm(a, val_store=v, split=(0.8, 0.1, 0.1), val_subset=100)
    sp = dm.splits[0]
    assert len(sp["val"]) == 0 and len(sp["train"]) + len(sp["test"]) == 20 and len(sp["test"]) >= 2
    stores, trajs, _ = _who(torch.cat([b["u_ctx"] for b in dm.val_dataloader()]))
    assert (stores == 3).all() and sorted(set(trajs[:, 0].tolist())) == list(range(6))
    # the validation store never enters the training statistics
    u = _values(0, 20, 60, 2, 1)[sp["train"], :30].astype(np.float64)
    assert np.allclose(dm.stats.u_mean, u.reshape(-1, 2).mean(0), rtol=1e-5)
    info = dm.describe()
    assert info["val_store"] == v and info["val"] == 6
    both = _dm(a, val_store=v, test_store=_store(tmp_path / "t.zarr", store_id=4, n=3))
    assert len(both.splits[0]["train"]) == 20 and len(both.test_set) == 3 and len(both.val_set) == 6
    with pytest.raises(ValueError, match="val_store .* is also a training store"):
        RoboMorphDataModule(stores=[a], val_store=a)
    with pytest.raises(ValueError, match="the same store"):
        RoboMorphDataModule(stores=[a], val_store=v, test_store=v)


def test_inputs_command_reads_u_cmd_for_batches_and_statistics(tmp_path):
    n, steps = 20, 60
    u = _values(0, n, steps, 2, 1)
    w = create_store(str(tmp_path / "c.zarr"), n, steps, U_NAMES, Y_NAMES, ["p"], {"dt": 0.1}, chunk=8,
                     u_cmd_names=["c0", "c1"])
    w.append(u, _values(0, n, steps, 3, -1), np.zeros((n, 1), np.float32), extras={"u_cmd": u - 1000.0})
    w.finalize()
    total, cmd = _dm(str(tmp_path / "c.zarr")), _dm(str(tmp_path / "c.zarr"), inputs="command")
    bt, bc = next(iter(total.val_dataloader())), next(iter(cmd.val_dataloader()))
    torch.testing.assert_close(bc["u_ctx"], bt["u_ctx"] - 1000.0)
    torch.testing.assert_close(bc["u_query"], bt["u_query"] - 1000.0)
    torch.testing.assert_close(bc["y_query"], bt["y_query"])
    assert cmd.u_names == ["c0", "c1"] and cmd.describe()["inputs"] == "command"
    np.testing.assert_allclose(np.asarray(cmd.stats.u_mean), np.asarray(total.stats.u_mean) - 1000.0, rtol=1e-6)


def test_inputs_command_on_a_store_without_u_cmd_says_to_regenerate(tmp_path):
    from robomorph.core.inputs import InputsError

    path = _store(tmp_path / "a.zarr")
    with pytest.raises(InputsError, match="no command inputs"):
        _dm(path, inputs="command")
    with pytest.raises(InputsError, match="one of total, command"):
        RoboMorphDataModule(stores=path, context_len=10, horizon=20, inputs="torque")
