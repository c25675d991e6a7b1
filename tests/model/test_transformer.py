"""Behaviour of the meta-model: shapes, causality, context use, lengths, errors, learning."""

from __future__ import annotations

import dataclasses
import inspect

import pytest
import torch
import torch.nn.functional as F

from robomorph.model.transformer import MetaModel, ModelConfig

N_U, N_Y = 3, 2


def tiny_config(**overrides) -> ModelConfig:
    base = dict(n_u=N_U, n_y=N_Y, d_model=16, n_head=2, n_layer=1, max_context=40, max_horizon=60, patch=1)
    return ModelConfig(**(base | overrides))


def tiny_model(seed: int = 0, **overrides) -> MetaModel:
    torch.manual_seed(seed)
    return MetaModel(tiny_config(**overrides)).eval()


def batch(B: int, Tc: int, Th: int, seed: int = 1) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return torch.randn(B, Tc, N_U, generator=g), torch.randn(B, Tc, N_Y, generator=g), torch.randn(B, Th, N_U, generator=g)


def assert_same(a: torch.Tensor, b: torch.Tensor) -> None:
    torch.testing.assert_close(a, b, rtol=0, atol=1e-6)


def assert_differs(a: torch.Tensor, b: torch.Tensor) -> None:
    assert (a - b).abs().max() > 1e-4


# --- shapes ---------------------------------------------------------------------------

@pytest.mark.parametrize("patch, B, Tc, Th", [
    (1, 1, 1, 1), (1, 3, 17, 29), (1, 2, 40, 60),
    (4, 2, 8, 12), (4, 1, 40, 60), (4, 3, 12, 13), (4, 2, 4, 1), (5, 2, 20, 58),
])
def test_output_shape(patch, B, Tc, Th):
    model = tiny_model(patch=patch)
    with torch.no_grad():
        y = model(*batch(B, Tc, Th))
    assert y.shape == (B, Th, N_Y)
    assert torch.isfinite(y).all()


def test_decoder_layers_default_and_override():
    assert tiny_config(n_layer=3).decoder_layers == 3
    cfg = tiny_config(n_layer=1, n_layer_dec=2)
    assert cfg.decoder_layers == 2
    model = MetaModel(cfg)
    assert len(model.encoder.blocks) == 1 and len(model.decoder.blocks) == 2


# --- causality and context use ----------------------------------------------------------

@pytest.mark.parametrize("t", [1, 7, 23])
def test_decoder_is_causal_per_step(t):
    model = tiny_model(n_layer=2)
    u_ctx, y_ctx, u_q = batch(2, 16, 30)
    u_q2 = u_q.clone()
    u_q2[:, t:] += torch.randn_like(u_q2[:, t:])
    with torch.no_grad():
        a, b = model(u_ctx, y_ctx, u_q), model(u_ctx, y_ctx, u_q2)
    assert_same(a[:, :t], b[:, :t])
    assert_differs(a[:, t], b[:, t])
    assert_differs(a[:, t:], b[:, t:])


@pytest.mark.parametrize("t", [4, 10, 19])
def test_decoder_is_causal_per_patch(t):
    k = 4
    model = tiny_model(n_layer=2, patch=k)
    u_ctx, y_ctx, u_q = batch(2, 16, 30)
    u_q2 = u_q.clone()
    u_q2[:, t:] += torch.randn_like(u_q2[:, t:])
    with torch.no_grad():
        a, b = model(u_ctx, y_ctx, u_q), model(u_ctx, y_ctx, u_q2)
    start = t // k * k
    assert_same(a[:, :start], b[:, :start])
    # Steps of the patch holding t see its inputs: patches are causal between, not within.
    for s in range(start, 30):
        assert_differs(a[:, s], b[:, s])


def test_query_padding_does_not_reach_earlier_patches():
    model = tiny_model(patch=4)
    u_ctx, y_ctx, u_q = batch(2, 16, 30)
    with torch.no_grad():
        full = model(u_ctx, y_ctx, u_q)
        short = model(u_ctx, y_ctx, u_q[:, :13])  # 13 = 3 patches + 1 padded step
    assert_same(short[:, :12], full[:, :12])


def test_forward_takes_no_query_outputs():
    params = list(inspect.signature(MetaModel.forward).parameters)
    # prior: a residual model's prior prediction, made from the context and the query inputs alone (the hybrid's)
    assert params == ["self", "u_ctx", "y_ctx", "u_query", "prior"]


@pytest.mark.parametrize("which", ["u_ctx", "y_ctx"])
def test_outputs_depend_on_context(which):
    model = tiny_model()
    u_ctx, y_ctx, u_q = batch(2, 16, 20)
    changed = {"u_ctx": u_ctx, "y_ctx": y_ctx}
    changed[which] = changed[which] + torch.randn_like(changed[which])
    with torch.no_grad():
        a, b = model(u_ctx, y_ctx, u_q), model(changed["u_ctx"], changed["y_ctx"], u_q)
    assert_differs(a, b)


@pytest.mark.parametrize("patch", [1, 4])
def test_first_prediction_sees_every_context_step(patch):
    model = tiny_model(patch=patch)
    u_ctx, y_ctx, u_q = batch(1, 16, 20)
    y_ctx.requires_grad_(True)
    model(u_ctx, y_ctx, u_q)[0, 0].sum().backward()
    per_step = y_ctx.grad[0].abs().sum(dim=-1)  # (Tc,)
    assert (per_step > 0).all(), "the first query step must see the whole context"


def test_encoder_is_not_causal():
    model = tiny_model(n_layer=2)
    tokens = torch.randn(2, 10, N_U + N_Y)
    changed = tokens.clone()
    changed[:, -1] += 1.0
    with torch.no_grad():
        assert_differs(model.encoder(tokens)[:, 0], model.encoder(changed)[:, 0])


def test_batch_items_are_independent():
    model = tiny_model()
    u_ctx, y_ctx, u_q = batch(3, 16, 20)
    with torch.no_grad():
        full = model(u_ctx, y_ctx, u_q)
        one = model(u_ctx[1:2], y_ctx[1:2], u_q[1:2])
    assert_same(full[1:2], one)


def test_candidates_on_one_context_match_their_own_predictions():
    """A batch sharing one context (a controller's candidates) is encoded once, and its memory
    projected once per cross-attention; each row is still its own prediction, and the context
    still matters."""
    model = tiny_model(n_init=2)
    u_ctx, y_ctx, u_q = batch(4, 16, 20)
    shared_u, shared_y = u_ctx[:1].expand(4, -1, -1), y_ctx[:1].expand(4, -1, -1)
    rows = []
    hook = model.decoder.blocks[0].cross.c_kv.register_forward_hook(lambda m, args, out: rows.append(len(args[0])))
    with torch.no_grad():
        full = model(shared_u, shared_y, u_q)
        assert rows == [1]
        hook.remove()
        for b in range(4):
            assert_same(full[b:b + 1], model(u_ctx[:1], y_ctx[:1], u_q[b:b + 1]))
        assert_differs(full[1:2], model(u_ctx[1:2], y_ctx[1:2], u_q[1:2]))


# --- lengths ------------------------------------------------------------------------------

@pytest.mark.parametrize("patch, h", [(1, 7), (1, 59), (4, 8), (4, 36)])
def test_shorter_horizon_matches_prefix_of_longer(patch, h):
    model = tiny_model(patch=patch)
    u_ctx, y_ctx, u_q = batch(2, 16, 60)
    with torch.no_grad():
        assert_same(model(u_ctx, y_ctx, u_q[:, :h]), model(u_ctx, y_ctx, u_q)[:, :h])


@pytest.mark.parametrize("patch", [1, 4])
def test_shorter_context_and_horizon_use_first_table_rows(patch):
    """A model trained with long tables, run on short inputs, equals one built with short tables."""
    big = tiny_model(patch=patch, max_context=40, max_horizon=60)
    small = MetaModel(tiny_config(patch=patch, max_context=12, max_horizon=20)).eval()
    state = big.state_dict()
    state["encoder.pos.weight"] = state["encoder.pos.weight"][: small.cfg.context_tokens]
    state["decoder.pos.weight"] = state["decoder.pos.weight"][: small.cfg.horizon_tokens]
    small.load_state_dict(state)
    u_ctx, y_ctx, u_q = batch(2, 12, 20)
    with torch.no_grad():
        assert_same(big(u_ctx, y_ctx, u_q), small(u_ctx, y_ctx, u_q))
        # and the short input is a genuinely different problem from the long one
        u_l, y_l, q_l = batch(2, 40, 60, seed=2)
        assert_differs(big(u_ctx, y_ctx, u_q), big(u_l[:, -12:], y_l[:, -12:], u_q))


@pytest.mark.parametrize("patch", [1, 4])
def test_lengths_up_to_the_tables_work(patch):
    model = tiny_model(patch=patch, max_context=40, max_horizon=58)
    with torch.no_grad():
        assert model(*batch(1, 40, 58)).shape == (1, 58, N_Y)


@pytest.mark.parametrize("Tc, Th, match", [
    (41, 10, r"context length Tc = 41 exceeds max_context = 40.*max_context at training time"),
    (20, 61, r"query horizon Th = 61 exceeds max_horizon = 60.*max_horizon at training time"),
    (0, 10, r"at least one step"),
    (10, 0, r"at least one step"),
])
def test_lengths_beyond_the_tables_are_refused(Tc, Th, match):
    model = tiny_model()
    with pytest.raises(ValueError, match=match):
        model(*batch(1, Tc, Th))


def test_context_not_multiple_of_patch_is_refused():
    model = tiny_model(patch=4)
    with pytest.raises(ValueError, match=r"Tc = 18 is not a multiple of patch = 4.*oldest 2 steps"):
        model(*batch(1, 18, 10))


# --- shapes refused -----------------------------------------------------------------------

def test_wrong_shapes_are_refused():
    model = tiny_model()
    u_ctx, y_ctx, u_q = batch(2, 8, 10)
    cases = [
        ((u_ctx[0], y_ctx, u_q), r"u_ctx must have shape \(B, Tc, 3\), got \(8, 3\)"),
        ((u_ctx, y_ctx[..., :1], u_q), r"y_ctx must have shape \(B, Tc, 2\), got \(2, 8, 1\)"),
        ((u_ctx, y_ctx, torch.randn(2, 10, 4)), r"u_query must have shape \(B, Th, 3\), got \(2, 10, 4\)"),
        ((u_ctx, y_ctx[:1], u_q), r"y_ctx .* to match u_ctx, got \(1, 8, 2\)"),
        ((u_ctx, y_ctx[:, :5], u_q), r"y_ctx .* to match u_ctx, got \(2, 5, 2\)"),
        ((u_ctx, y_ctx, u_q[:1]), r"u_query .* B = 2 as in u_ctx, got \(1, 10, 3\)"),
    ]
    for args, match in cases:
        with pytest.raises(ValueError, match=match):
            model(*args)


# --- config validation ------------------------------------------------------------------

@pytest.mark.parametrize("overrides, match", [
    (dict(d_model=18, n_head=4), r"d_model \(18\) must be divisible by n_head \(4\)"),
    (dict(n_head=0), r"n_head must be a positive integer"),
    (dict(n_layer=0), r"n_layer must be a positive integer"),
    (dict(n_layer_dec=0), r"n_layer_dec must be a positive integer"),
    (dict(n_u=0), r"n_u must be a positive integer"),
    (dict(d_model=16.0), r"d_model must be a positive integer"),
    (dict(patch=0), r"patch must be a positive integer"),
    (dict(patch=True), r"patch must be a positive integer"),
    (dict(patch=50), r"max_context \(40\) must be at least patch \(50\)"),
    (dict(patch=8, max_context=64, max_horizon=6), r"max_horizon \(6\) must be at least patch \(8\)"),
    (dict(max_context=0), r"max_context must be a positive integer"),
    (dict(dropout=1.0), r"dropout must be a number in \[0, 1\)"),
    (dict(dropout=-0.1), r"dropout must be a number in \[0, 1\)"),
    (dict(bias="yes"), r"bias must be true or false"),
])
def test_config_validation(overrides, match):
    with pytest.raises(ValueError, match=match):
        tiny_config(**overrides)


def test_config_is_frozen_and_tables_are_ceil_sized():
    cfg = tiny_config(patch=7, max_context=40, max_horizon=60)
    assert (cfg.context_tokens, cfg.horizon_tokens) == (6, 9)
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.d_model = 32  # type: ignore[misc]


# --- determinism, init, learning -------------------------------------------------------------

def test_same_seed_same_init_other_seed_differs():
    a, b, c = tiny_model(seed=3).state_dict(), tiny_model(seed=3).state_dict(), tiny_model(seed=4).state_dict()
    assert a.keys() == b.keys()
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert not torch.equal(a["encoder.embed.weight"], c["encoder.embed.weight"])


def test_gpt2_init():
    torch.manual_seed(0)
    model = MetaModel(ModelConfig(d_model=64, n_head=4, n_layer=2, n_layer_dec=8))
    for name, p in model.named_parameters():
        if name.endswith(".bias") and "ln_" not in name:
            assert torch.count_nonzero(p) == 0, name
    assert model.encoder.blocks[0].attn.c_proj.weight.std().item() == pytest.approx(0.02 / 2, rel=0.1)
    assert model.decoder.blocks[0].mlp.c_proj.weight.std().item() == pytest.approx(0.02 / 4, rel=0.1)
    assert model.decoder.blocks[0].cross.c_q.weight.std().item() == pytest.approx(0.02, rel=0.1)


def test_eval_is_deterministic_and_dropout_only_acts_in_training():
    model = tiny_model(dropout=0.3)
    args = batch(2, 8, 12)
    with torch.no_grad():
        assert torch.equal(model(*args), model(*args))
        model.train()
        assert_differs(model(*args), model(*args))


def test_every_parameter_gets_a_gradient():
    model = tiny_model(n_layer=2, patch=2).train()
    u_ctx, y_ctx, u_q = batch(2, 8, 12)
    F.mse_loss(model(u_ctx, y_ctx, u_q), torch.randn(2, 12, N_Y)).backward()
    missing = [n for n, p in model.named_parameters() if p.grad is None or not p.grad.abs().sum() > 0]
    assert not missing


@pytest.mark.parametrize("patch", [1, 5])
def test_overfits_a_tiny_batch(patch):
    torch.manual_seed(0)
    model = MetaModel(tiny_config(d_model=32, n_head=4, n_layer=2, patch=patch)).train()
    u_ctx, y_ctx, u_q = batch(4, 20, 30)
    target = torch.randn(4, 30, N_Y, generator=torch.Generator().manual_seed(5))
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    losses = []
    for _ in range(100):
        loss = F.mse_loss(model(u_ctx, y_ctx, u_q), target)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert losses[-1] < losses[0] / 10, (losses[0], losses[-1])


def test_paper_size():
    cfg = ModelConfig(d_model=192, n_head=12, n_layer=12, max_context=200, max_horizon=800, patch=1)
    n = MetaModel(cfg).num_params()
    assert 12.5e6 < n < 12.8e6  # the paper's 12.6 M; about 0.19 M of it are the position tables


def test_num_params_trainable_only():
    model = tiny_model()
    total = model.num_params()
    assert total == sum(p.numel() for p in model.parameters())
    model.encoder.requires_grad_(False)
    assert model.num_params(trainable_only=True) == total - sum(p.numel() for p in model.encoder.parameters())


# --- initial-condition tokens (n_init) and the Gaussian head ---------------------------------

def _captured_init(model, *inputs):
    """Runs the model and returns what entered the decoder's initial-condition embedding."""
    seen = []
    handle = model.decoder.init_embed.register_forward_hook(lambda m, args, out: seen.append(args[0].clone()))
    with torch.no_grad():
        out = model(*inputs)
    handle.remove()
    return seen[0], out


@pytest.mark.parametrize("patch, n_init", [(1, 3), (4, 8)])
def test_initial_conditions_are_the_last_context_steps_and_never_the_query(patch, n_init):
    model = tiny_model(patch=patch, n_init=n_init, n_layer=2)
    u_ctx, y_ctx, u_q = batch(2, 16, 20)
    init, out = _captured_init(model, u_ctx, y_ctx, u_q)
    expected = torch.cat([u_ctx, y_ctx], dim=-1)[:, -n_init:].reshape(2, n_init // patch, -1)
    assert_same(init, expected)
    assert out.shape == (2, 20, N_Y)
    # Poisoned query: huge, different query inputs leave the initial-condition path unchanged.
    init2, out2 = _captured_init(model, u_ctx, y_ctx, 1e3 * torch.randn_like(u_q))
    assert_same(init2, init)
    assert_differs(out2, out)


def test_initial_conditions_reach_the_first_prediction_and_keep_causality():
    model = tiny_model(n_init=4, n_layer=2)
    u_ctx, y_ctx, u_q = batch(2, 16, 30)
    y2 = y_ctx.clone()
    y2[:, -1] += 1.0
    u_q2 = u_q.clone()
    u_q2[:, 11:] += torch.randn_like(u_q2[:, 11:])
    with torch.no_grad():
        a, b, c = model(u_ctx, y_ctx, u_q), model(u_ctx, y2, u_q), model(u_ctx, y_ctx, u_q2)
    assert_differs(a[:, 0], b[:, 0])
    assert_same(a[:, :11], c[:, :11])
    assert_differs(a[:, 11], c[:, 11])


def test_initial_condition_options_are_checked():
    with pytest.raises(ValueError, match="multiple of patch"):
        tiny_config(patch=4, n_init=6)
    with pytest.raises(ValueError, match="non-negative"):
        tiny_config(n_init=-1)
    with pytest.raises(ValueError, match="shorter than n_init"):
        tiny_model(n_init=8)(*batch(1, 4, 5))


def test_gaussian_head_gives_mean_and_bounded_log_variance():
    model = tiny_model(gaussian=True, patch=4)
    inputs = batch(2, 16, 13)
    with torch.no_grad():
        mean, logvar = model.forward_dist(*inputs)
        assert_same(model(*inputs), mean)
    assert mean.shape == logvar.shape == (2, 13, N_Y)
    assert torch.isfinite(logvar).all() and (logvar >= -20).all() and (logvar <= 10).all()
    assert tiny_model().forward_dist(*inputs)[1] is None


def test_default_options_keep_the_original_parameters():
    names = set(tiny_model().state_dict())
    assert not any("init_" in n for n in names)
    assert tiny_model(patch=4).head.out_features == 4 * N_Y
    assert {"decoder.init_embed.weight", "decoder.init_pos.weight"} <= set(tiny_model(n_init=2).state_dict())
