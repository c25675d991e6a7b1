"""A batch of many windows shared by two hybrids on threads gives what one hybrid gives for the whole batch."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tests.inference.test_hybrid import _windows, command_store, hybrid_ckpt  # noqa: F401  (fixtures)


def _batch(store: str, n: int = 16):
    uc, yc, uq, _, _, _ = _windows(store, n=n)
    rest = np.arange(n) % 3 == 0  # windows of both kinds, so each worker must be given its own rows'
    anchor = yc[:, 0, 7:14] + 0.01 * np.arange(n)[:, None]  # and their own anchors
    return uc, yc, uq, rest, anchor


def test_two_workers_give_the_one_hybrids_prediction_and_record(hybrid_ckpt, command_store):
    from robomorph import Predictor

    uc, yc, uq, rest, anchor = _batch(command_store)
    one = Predictor.from_checkpoint(hybrid_ckpt)
    one.configure(workers=1)
    mean1, std1 = one.simulate(uc, yc, uq, at_rest=rest, anchor=anchor, return_std=True)
    two = Predictor.from_checkpoint(hybrid_ckpt)
    two.configure(workers=2)
    mean2, std2 = two.simulate(uc, yc, uq, at_rest=rest, anchor=anchor, return_std=True)
    assert len(two.hybrids) == 2 and len(one.hybrids) == 1  # the split happened, and only where asked for
    np.testing.assert_array_equal(mean2, mean1)
    np.testing.assert_array_equal(std2, std1)
    h1, h2 = one.hybrid(), two.hybrid()
    held1, covs1, _ = h1.record()
    held2, covs2, _ = h2.record()
    np.testing.assert_array_equal(held2, held1)  # the first hybrid holds the whole batch's record
    assert len(covs2) == len(uc)
    for a, b in zip(covs1, covs2):
        np.testing.assert_array_equal(a, b)
    # Each row's prediction is its own: swapping the halves swaps the outputs.
    order = np.r_[8:16, 0:8]
    swapped = two.simulate(uc[order], yc[order], uq[order], at_rest=rest[order], anchor=anchor[order])
    np.testing.assert_array_equal(swapped, mean1[order])


def test_the_workers_take_the_first_hybrids_settings(hybrid_ckpt, command_store):
    from robomorph import Predictor

    uc, yc, uq, rest, anchor = _batch(command_store)
    p = Predictor.from_checkpoint(hybrid_ckpt)
    p.configure(workers=2, members=1, substeps=2, iterations=1)
    got = p.simulate(uc, yc, uq, at_rest=rest, anchor=anchor)
    worker = p.hybrids[1]
    assert worker.settings == p.hybrids[0].settings
    assert (worker.settings.members, worker.settings.iterations, worker.backbone.coarse) == (1, 1, 2)
    p.configure(workers=1)
    np.testing.assert_array_equal(got, p.simulate(uc, yc, uq, at_rest=rest, anchor=anchor))


def test_one_context_and_small_batches_stay_whole(hybrid_ckpt, command_store):
    """A planner's candidates share one context, identified once: no split (nor a batch under two chunks)."""
    from robomorph import Predictor

    uc, yc, uq, _, _ = _batch(command_store)
    p = Predictor.from_checkpoint(hybrid_ckpt)
    p.configure(workers=2)
    rng = np.random.default_rng(0)
    cands = uq[:1] + rng.normal(0, 0.1, size=(16,) + uq.shape[1:]).astype(np.float32)
    p.simulate(np.repeat(uc[:1], 16, 0), np.repeat(yc[:1], 16, 0), cands)
    p.simulate(uc[:15], yc[:15], uq[:15])
    assert len(p.hybrids) == 1


@pytest.mark.parametrize("rows, workers, mode, draws, expected", [
    (16, 2, "regression", False, [(0, 8), (8, 16)]),
    (25, 3, "refined", False, [(0, 8), (8, 17), (17, 25)]),
    (15, 2, "regression", False, None),  # under two chunks
    (64, 1, "regression", False, None),
    (64, 2, "regression", True, None),  # random draws are drawn per batch
    (64, 2, "learned", False, None),  # reads the network
    (64, 2, "blend", False, None),
    (64, 2, "smoothed", False, None),
])
def test_splits_cover_the_rows_once_in_order(rows, workers, mode, draws, expected):
    from robomorph.inference.hybrid_split import splits

    u = torch.arange(rows * 6, dtype=torch.float32).reshape(rows, 3, 2)
    got = splits([u, u], workers, mode, draws)
    assert (None if got is None else [(s.start, s.stop) for s in got]) == expected


def test_refined_fits_of_every_chunk_are_kept_and_other_modes_leave_them(hybrid_ckpt, command_store):
    from robomorph import Predictor

    uc, yc, uq, rest, anchor = _batch(command_store)
    p = Predictor.from_checkpoint(hybrid_ckpt)
    p.configure(workers=2, members=1, mode="refined")
    p.simulate(uc, yc, uq, at_rest=rest, anchor=anchor)
    fits = p.hybrid().last_fits
    assert len(fits) == len(uc) and len(p.hybrids) == 2
    p.configure(mode="regression")  # a mode without rollout fits: the refined record stays the batch's
    p.simulate(uc, yc, uq, at_rest=rest, anchor=anchor)
    assert p.hybrid().last_fits is fits
