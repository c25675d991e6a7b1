"""Free-run (simulation-error) training of the small sequence models: their free runs read the
warm-up alone, the fit is deterministic under a seed, early stopping keeps the best state, and
bad settings are refused."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from robomorph.training import free_run as fr


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _toy(n, length=80, seed=0):
    """A damped second-order system driven by its input: y_t = 1.6 y_{t-1} - 0.7 y_{t-2} + 0.1 u_t."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        u = rng.normal(size=(length, 2))
        y = np.zeros((length, 2))
        for t in range(2, length):
            y[t] = 1.6 * y[t - 1] - 0.7 * y[t - 2] + 0.1 * u[t]
        out.append((u, y))
    return out


def test_the_warm_up_is_copied_and_later_outputs_never_read():
    model = fr.GRUSim(2, 2, hidden=8)
    u = torch.randn(3, 20, 2)
    y_init = torch.randn(3, 4, 2)
    out = fr.simulate(model, u, y_init)
    assert out.shape == (3, 20, 2) and torch.equal(out[:, :4], y_init)
    # a single warm-up sample stands for a robot at rest: the history repeats it
    assert torch.equal(fr._history(y_init[:, :1], 1, 3), y_init[:, :1].expand(-1, 3, -1))

    train = _toy(2)
    predict = fr.predictor(model, fr.Normalizer.of(train))
    u_np, y_np = train[0]
    a = predict(u_np, y_np[:5])
    assert np.array_equal(a[:5], y_np[:5]) and a.shape == y_np.shape


def test_least_squares_arx_recovers_a_linear_system_and_its_free_run_follows_it():
    data = _toy(4)
    model = fr.ARX(2, 2, 2, 1).fit_least_squares(data)
    w = model.lin.weight.detach().numpy()
    np.testing.assert_allclose(w[0, [0, 2, 4]], [1.6, -0.7, 0.1], atol=1e-3)  # y_{t-1}, y_{t-2}, u_t of joint 0
    u, y = data[0]
    sim = fr.simulate(model, torch.as_tensor(u[None], dtype=torch.float32), torch.as_tensor(y[None, :2],
                                                                                             dtype=torch.float32))
    assert np.abs(sim[0].detach().numpy() - y).max() < 1e-3


def test_fit_is_deterministic_under_a_seed_and_keeps_its_best_validation_state():
    train, val = _toy(6, seed=1), _toy(2, seed=2)
    cfg = fr.FreeRunConfig(warmup=2, window_min=20, tbptt=25, batch=4, iterations=6, val_every=2, patience=5, seed=3)
    runs = []
    for _ in range(2):
        torch.manual_seed(0)
        model = fr.GRUSim(2, 2, hidden=8)
        norm = fr.Normalizer.of(train)
        before = fr.validation_loss(model, [(torch.as_tensor(norm.u(u), dtype=torch.float32),
                                              torch.as_tensor(norm.y(y), dtype=torch.float32)) for u, y in val])
        rec = fr.fit(model, train, val, cfg)
        runs.append((model.state_dict(), rec))
        assert rec["best_val"] <= before  # the kept state is never worse than the start
    (a, ra), (b, rb) = runs
    assert all(torch.equal(a[k], b[k]) for k in a) and ra["best_val"] == rb["best_val"]


@pytest.mark.parametrize("field,value", [("warmup", 0), ("tbptt", 0), ("from_rest", 1.5), ("lr", 0.0)])
def test_bad_settings_are_refused(field, value):
    with pytest.raises(fr.FreeRunError, match=field):
        fr.FreeRunConfig(**{field: value})


def test_fit_without_validation_trajectories_is_refused():
    with pytest.raises(fr.FreeRunError, match="validation"):
        fr.fit(fr.ARX(2, 2), _toy(2), [])
