import numpy as np
import pytest

from robomorph.sim.signals import SignalConfig, chirp, multisine

DT = 1 / 60


def _dominant_hz(u, dt):
    spec = np.abs(np.fft.rfft(u - u.mean(axis=0), axis=0))
    freqs = np.fft.rfftfreq(len(u), dt)
    return freqs[np.argmax(spec, axis=0)]


def test_multisine_amplitude_and_frequency_ranges():
    cfg = SignalConfig(fm=(0.2,))
    rng = np.random.default_rng(0)
    for _ in range(50):
        u, fm = multisine(rng, 6000, DT, cfg)
        assert fm == 0.2 and u.shape == (6000, 7)
        bound = 4 * 15 * fm / np.asarray(cfg.multisine_divisor)  # four terms of |A| <= 15 fm
        assert np.all(np.abs(u).max(axis=0) <= bound + 1e-9)
        # energy sits between the lowest (f0 >= fm/1.5) and highest (3 f0 <= 4.5 fm) terms
        hz = _dominant_hz(u, DT)
        assert np.all((hz >= fm / 1.5 - 0.02) & (hz <= 4.5 * fm + 0.02))


def test_multisine_first_sample_is_the_cosine_terms():
    """At t = 0 the sine terms vanish: u(0) = (A0 + A2) / divisor."""
    cfg = SignalConfig(fm=(0.1,))
    u, _ = multisine(np.random.default_rng(5), 10, DT, cfg)
    rng = np.random.default_rng(5)
    rng.choice(cfg.fm)
    rng.uniform(size=7)  # f0
    amp = rng.uniform(-1.5, 1.5, (4, 7))
    np.testing.assert_allclose(u[0], (amp[0] + amp[2]) / np.asarray(cfg.multisine_divisor))


def test_chirp_bounds_and_frequency_band():
    cfg = SignalConfig(fm=(0.25,))
    rng = np.random.default_rng(1)
    steps = 1000
    t_max = steps * DT
    for _ in range(50):
        u, fm = chirp(rng, steps, DT, cfg)
        assert np.all(np.abs(u) <= cfg.chirp_amplitude + cfg.chirp_offset + 1e-9)
        # phase w1 (1 + cos(w2 t)/4) t: its rate is at most w1 (5/4 + w2 t / 4), which grows
        # with t (the paper's chirp sweeps upward), with f1 <= 1.5 fm and f2 <= 2 fm.
        f_max = 1.5 * fm * (1.25 + 2 * np.pi * 2 * fm * t_max / 4)
        assert np.all(_dominant_hz(u, DT) <= f_max)
        assert np.all(np.abs(u).max(axis=0) > 0)


def test_fm_list_draws_each_value_and_seed_repeats():
    cfg = SignalConfig()
    rng = np.random.default_rng(2)
    seen = {multisine(rng, 5, DT, cfg)[1] for _ in range(100)}
    assert seen == set(cfg.fm)
    a, _ = chirp(np.random.default_rng(9), 100, DT, cfg)
    b, _ = chirp(np.random.default_rng(9), 100, DT, cfg)
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("kwargs", [{"fm": ()}, {"fm": (-0.1,)}, {"scale": (1.0,)}, {"chirp_amplitude": -1.0}])
def test_bad_signal_config(kwargs):
    with pytest.raises(ValueError, match="signal"):
        SignalConfig(**kwargs)
