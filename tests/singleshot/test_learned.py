"""Tests for the learned single-shot method (torch_modulo/singleshot/learned/): loader, shapes, devices, batches,
exact consistency with the modulus, the decoders, windowed inference, the confidence, and a tiny training run.

The level head and the region moves are tested in test_learned_levels.py, the training recipe in tests/references."""

from __future__ import annotations

import threading

import numpy as np
import pytest
import torch

from torch_modulo.capture import modulo_wrap
from torch_modulo.cfa import interpolate_wrapped, mosaic
from torch_modulo.singleshot import SingleShotUnwrap, unwrap_single
from torch_modulo.singleshot.learned import (
    MAX_COST,
    MOSAIC_CUTS,
    STRIP,
    EdgeJumpNet,
    LearnedConfidence,
    decode_edges,
    decode_jumps,
    decoding,
    edge_features,
    edge_loss,
    edge_targets,
    inference,
    learned_confidence,
    learned_k,
    load_model,
    mosaic_spec,
    pair_costs,
    predict_edges,
    predict_jumps,
    refine_band,
    refine_cut,
    solver,
    tile_margin,
)
from torch_modulo.singleshot.learned.inference import _unflip
from torch_modulo.singleshot.methods import make_spec

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/singleshot/conftest.py


def scene(size: int = 48, seed: int = 0) -> np.ndarray:
    """(size, size) counts: a dark floor, a smooth bump and a bright lamp whose border steps by several periods."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:size, 0:size].astype(np.float64)
    img = 20 + 8 * x + 600 * np.exp(-((y - size / 2) ** 2 + (x - size / 3) ** 2) / (size * size / 8))
    lamp = (np.abs(y - 0.7 * size) < size / 8) & (np.abs(x - 0.7 * size) < size / 8)
    img = img + 1500 * lamp + rng.uniform(0, 3, img.shape)
    return np.floor(img)


def spec(method: str, **options: object):
    """unwrap_single's settings for ``method`` with its defaults and these options."""
    return make_spec(8, method, 8, 0.1, 1e-5, None, 2, 1000, options)


def oracle_logp(counts: np.ndarray, max_jump: int = 15) -> np.ndarray:
    """(2, 2J + 1, H, W) log-probabilities that are sure of the true jump of every pair."""
    target, _ = edge_targets(torch.from_numpy(counts)[None, None], 8, max_jump)
    logp = np.full((2, 2 * max_jump + 1, *counts.shape), -20.0)
    np.put_along_axis(logp, target[0, 0].numpy()[:, None], 0.0, axis=1)
    return logp


class TestLoader:
    def test_shipped_weights_load_offline_on_cpu(self) -> None:
        net = load_model()
        assert isinstance(net, EdgeJumpNet) and not net.training
        assert next(net.parameters()).device.type == "cpu"
        assert sum(p.numel() for p in net.parameters()) <= 2_000_000
        assert load_model() is net  # cached

    def test_cpu_layout_is_the_same_network(self) -> None:
        net = load_model()
        convs = [m for m in net.modules() if isinstance(m, torch.nn.Conv2d)]
        assert all(m.weight.is_contiguous(memory_format=torch.channels_last) for m in convs if m.kernel_size == (3, 3))
        assert all(m.weight.is_contiguous() for m in convs if m.kernel_size == (1, 1))
        plain = EdgeJumpNet(**net.config).eval()
        plain.load_state_dict(net.state_dict())  # the same weights, every one channels first
        x = edge_features(torch.from_numpy(np.stack([scene(40, s) for s in range(3)]) % 256)[None].float(), 8)
        with torch.no_grad():
            assert torch.allclose(net(x), plain(x), atol=1e-4)
            assert net(x).is_contiguous()  # the jump logits come back channels first

    def test_weights_option(self, tmp_path) -> None:
        net = EdgeJumpNet(width=4, max_jump=3)
        path = tmp_path / "tiny.pt"
        torch.save({"config": net.config, "state": net.state_dict()}, path)
        out = unwrap_single(torch.from_numpy(scene(16)) % 256, method="learned", weights=str(path))
        assert out.shape == (16, 16)

    def test_a_file_that_is_not_weights_is_named(self, tmp_path) -> None:
        text, other = tmp_path / "notes.pt", tmp_path / "other.pt"
        text.write_text("not a network")
        torch.save({"state": {}}, other)
        for path in (text, other):
            with pytest.raises(ValueError, match=rf"'{path}' is not a weights file of the training recipe"):
                SingleShotUnwrap(method="learned", weights=str(path))  # at construction, not at the first image
            with pytest.raises(ValueError, match="is not a weights file"):
                load_model(path)
        with pytest.raises(FileNotFoundError, match="weights file not found"):
            load_model(tmp_path / "missing.pt")

    def test_bad_options(self) -> None:
        m = torch.zeros(8, 8)
        with pytest.raises(ValueError, match="weights"):
            unwrap_single(m, method="learned", weights="/nonexistent/w.pt")
        with pytest.raises(TypeError, match="weights"):
            unwrap_single(m, method="learned", weights=3)
        with pytest.raises(ValueError, match="max_cuts"):
            unwrap_single(m, method="learned", max_cuts=-1)
        with pytest.raises(TypeError, match="colour"):
            unwrap_single(m, method="learned", colour=True)


class TestLearnedUnwrap:
    @pytest.mark.parametrize("shape", [(20, 24), (1, 20, 24), (3, 20, 24), (2, 3, 20, 24), (1, 2, 20, 24)])
    def test_cardinality(self, shape: tuple, device: torch.device, dtype: torch.dtype) -> None:
        g = torch.Generator().manual_seed(0)
        modulus = torch.randint(0, 256, shape, generator=g).to(device=device, dtype=dtype)
        out = unwrap_single(modulus, method="learned", workers=1)
        assert out.shape == modulus.shape and out.dtype == dtype and out.device == modulus.device

    def test_consistent_with_modulus(self) -> None:
        truth = np.stack([scene(40, s) for s in range(3)])
        modulus = torch.from_numpy(truth % 256)
        out = unwrap_single(modulus, method="learned", max_cuts=2, workers=1)
        k = (out - modulus) / 256
        assert torch.equal(k, torch.round(k)) and bool((k >= 0).all())
        assert torch.equal(torch.remainder(out, 256), modulus)

    def test_batch_equals_per_image(self) -> None:
        truth = torch.from_numpy(np.stack([np.stack([scene(32, 3 * b + c) for c in range(3)]) for b in range(2)]))
        modulus = truth % 256
        batch = unwrap_single(modulus, method="learned", workers=1)
        single = torch.stack([unwrap_single(m, method="learned", workers=1) for m in modulus])
        assert torch.equal(batch, single)
        assert torch.equal(unwrap_single(modulus[:0], method="learned"), modulus[:0])

    def test_input_untouched(self) -> None:
        modulus = torch.from_numpy(scene(24) % 256)
        before = modulus.clone()
        unwrap_single(modulus, method="learned")
        assert torch.equal(modulus, before)


class TestDecoders:
    def test_tree_with_oracle_jumps_is_exact(self) -> None:
        truth = scene(48)
        m = (truth % 256).astype(np.int64)
        k, confidence = decode_edges(m, oracle_logp(truth), 8)
        restored = m + 256 * k
        assert np.array_equal(restored - restored.min(), truth - truth.min())
        assert confidence.shape == m.shape and float(confidence.min()) > 0.99

    @pytest.mark.parametrize(("h", "w"), [(61, 45), (1, 700), (700, 1)])
    def test_tree_from_blocks_is_the_whole_tree(self, monkeypatch: pytest.MonkeyPatch, h: int, w: int) -> None:
        # Distinct costs: one minimum spanning tree, whether built whole or from blocks of rows of 256 pixels.
        rng = np.random.default_rng(h * w)
        m = rng.integers(0, 256, (h, w))
        jump = rng.integers(-2, 3, (2, h, w)).astype(np.int16)
        cost = rng.random((2, h, w)).astype(np.float32) * rng.choice([0.001, 3.0], (2, h, w))
        whole = decode_jumps(m, jump, cost, 8)
        monkeypatch.setattr(decoding, "TREE_PIXELS", 256)
        blocks = decode_jumps(m, jump, cost, 8)
        assert np.array_equal(blocks[0], whole[0]) and np.array_equal(blocks[1], whole[1])
        assert blocks[0].dtype == np.int64 and blocks[1].dtype == np.float64

    def test_cut_undoes_a_wrong_region(self) -> None:
        truth = scene(32)
        m = (truth % 256).astype(np.int64)
        k_true = (truth.astype(np.int64) - m) // 256
        k = k_true.copy()
        k[8:20, 10:22] += 1  # a region shifted by one period, as one wrong tree pair does
        fixed = refine_cut(m, k, oracle_logp(truth), 8, max_cuts=4)
        assert np.array_equal(fixed - fixed[0, 0], k_true - k_true[0, 0])

    @pytest.mark.parametrize("block", [1, 3, 8])
    def test_superpixels_of_any_size_undo_a_wrong_region(self, block: int) -> None:
        truth = scene(32)
        m = (truth % 256).astype(np.int64)
        k_true = (truth.astype(np.int64) - m) // 256
        k = k_true.copy()
        k[5:19, 7:23] += 1  # not aligned with the blocks
        table = -oracle_logp(truth)
        first = np.full((2, 32, 32), -15)
        fixed = refine_band(m, k, table, first, 8, max_cuts=4, block=block)
        assert np.array_equal(fixed - fixed[0, 0], k_true - k_true[0, 0])

    def test_band_holds_the_jumps_around_the_best(self) -> None:
        net = EdgeJumpNet(width=4, max_jump=3, dilations=(1,))
        m = torch.from_numpy(np.stack([scene(20, s) for s in range(3)]) % 256)
        logp = predict_edges(net, m, 8).numpy()
        jump, cost = predict_jumps(net, m, 8, band=2)
        assert cost.shape == (3, 2, 5, 20, 20) and np.array_equal(jump, predict_jumps(net, m, 8)[0])
        for d in range(-2, 3):
            index = jump.astype(np.int64) + 3 + d
            inside = (index >= 0) & (index <= 6)
            expect = -np.take_along_axis(logp, np.clip(index, 0, 6)[:, :, None], 2)[:, :, 0]
            np.testing.assert_allclose(cost[:, :, d + 2][inside], expect[inside].clip(0, 30), atol=1e-5)
            assert bool((cost[:, :, d + 2][~inside] == 30).all())

    def test_mosaics_run_cuts_and_no_levels_by_default(self) -> None:
        learned, guided, chosen = spec("learned"), spec("guided"), spec("learned", max_cuts=0, levels=True)
        assert dict(mosaic_spec(learned).options) == {"max_cuts": MOSAIC_CUTS, "levels": False}
        assert mosaic_spec(chosen) == chosen and mosaic_spec(guided) == guided
        assert dict(mosaic_spec(spec("learned", max_cuts=0)).options) == {"max_cuts": 0, "levels": False}
        rgb = torch.from_numpy(np.stack([scene(16, s) for s in range(3)])).float()
        m = mosaic(rgb, "GRBG") % 256
        out = unwrap_single(m, cfa="GRBG")
        assert torch.equal(out, unwrap_single(m, cfa="GRBG", max_cuts=MOSAIC_CUTS, levels=False))
        assert torch.equal(torch.remainder(out, 256), m)

    @pytest.mark.parametrize("levels", [False, True])
    def test_channels_decoded_side_by_side_as_one_by_one(self, levels: bool, monkeypatch: pytest.MonkeyPatch) -> None:
        threads, side_by_side = set(), threading.Barrier(2, timeout=10)

        def decode(*args):
            me = threading.get_ident()
            if me not in threads and me != threading.main_thread().ident:
                threads.add(me)
                side_by_side.wait()  # each pool thread's first channel waits for the other's: they run at once
            threads.add(me)
            return decode_jumps(*args)

        monkeypatch.setattr(solver, "decode_jumps", decode)
        moduli = (np.stack([scene(40, s) for s in range(3)]) % 256).astype(np.int64)
        one = learned_k(moduli, 8, levels=levels)  # one_thread: the channels one after the other, here
        assert threads == {threading.get_ident()}
        threads.clear()
        torch.set_num_threads(2)  # the fixture restores the count
        two = learned_k(moduli, 8, levels=levels)
        assert len(threads) == 2 and threading.get_ident() not in threads
        assert np.array_equal(one[0], two[0])  # the same k; the confidences up to the threads' float rounding
        np.testing.assert_allclose(one[1], two[1], rtol=1e-5)

    def test_a_channel_that_fails_fails_the_call(self, monkeypatch: pytest.MonkeyPatch) -> None:
        def decode(modulus, *args):
            if modulus[0, 0] == 7:
                raise RuntimeError("channel 7 failed")
            return decode_jumps(modulus, *args)

        monkeypatch.setattr(solver, "decode_jumps", decode)
        moduli = np.zeros((3, 8, 8), dtype=np.int64)
        moduli[1] = 7
        torch.set_num_threads(2)
        with pytest.raises(RuntimeError, match="channel 7 failed"):
            learned_k(moduli, 8)

    def test_learned_k_grey_and_colour(self) -> None:
        truth = np.stack([scene(24, s) for s in range(3)])
        k, confidence = learned_k((truth % 256).astype(np.int64), 8)
        assert k.shape == confidence.shape == truth.shape and k.dtype == np.int64
        k1, _ = learned_k((truth[:1] % 256).astype(np.int64), 8)
        assert k1.shape == (1, 24, 24)

    @pytest.mark.parametrize("dims", [(-1,), (-2,), (-1, -2)])
    def test_unflip_maps_pairs_back(self, dims: tuple[int, ...]) -> None:
        truth = scene(20)
        logp = torch.from_numpy(oracle_logp(truth))[None]
        flipped = torch.from_numpy(oracle_logp(np.flip(truth, [d + 2 for d in dims]).copy()))[None]
        back = _unflip(flipped, dims)
        assert torch.equal(back[:, 0, :, :, :-1], logp[:, 0, :, :, :-1])  # the last column has no right pair
        assert torch.equal(back[:, 1, :, :-1], logp[:, 1, :, :-1])

    def test_augment_option(self) -> None:
        modulus = torch.from_numpy(np.stack([scene(24, s) for s in range(3)]) % 256)
        out = unwrap_single(modulus, method="learned", augment=True)
        assert torch.equal(torch.remainder(out, 256), modulus)
        with pytest.raises(TypeError, match="augment"):
            unwrap_single(modulus, method="learned", augment=1)

    def test_grey_computes_one_channel(self) -> None:
        net = load_model()
        grey = torch.from_numpy(scene(24) % 256).float()[None]
        features = edge_features(grey[None].expand(1, 3, 24, 24), 8)
        with torch.no_grad():
            one, three = net(features, 1), net(features)
        assert one.shape == (1, 1, 2, 2 * net.max_jump + 1, 24, 24)
        torch.testing.assert_close(one, three[:, :1])
        assert torch.equal(predict_edges(net, grey, 8), torch.log_softmax(one, dim=3)[0])

    def test_decode_of_rows_is_the_whole_trunk_there(self) -> None:
        torch.manual_seed(0)
        net = EdgeJumpNet(width=4, dilations=(1, 2))
        x = edge_features(torch.from_numpy(np.stack([scene(24, s) for s in range(3)]) % 256)[None].float(), 8)
        with torch.no_grad():
            whole = net.trunk(x)
            e1, d2 = net.encode(x)
            for start, stop in [(0, 5), (3, 11), (7, 24), (23, 24), (0, 24)]:
                torch.testing.assert_close(net.decode(e1, d2, start, stop), whole[..., start:stop, :])

    def test_predict_edges_pads_odd_sizes(self) -> None:
        net = EdgeJumpNet(width=4, max_jump=2)
        logp = predict_edges(net, torch.zeros(3, 13, 7), 8)
        assert logp.shape == (3, 2, 5, 13, 7)
        assert torch.allclose(logp.exp().sum(dim=2), torch.ones(3, 2, 13, 7), atol=1e-5)


class TestTraining:
    def test_targets_match_counts(self) -> None:
        counts = torch.from_numpy(scene(16))[None, None]
        target, hard = edge_targets(counts, 8, 15)
        wd = (torch.diff(counts % 256, dim=-1) + 128) % 256 - 128
        assert torch.equal(torch.diff(counts, dim=-1), wd + 256 * (target[:, :, 0, :, :-1] - 15))
        assert bool(hard.any())

    def test_tiny_model_learns(self) -> None:
        torch.manual_seed(0)
        counts = torch.from_numpy(np.stack([scene(24, s) for s in range(2)])).float()[:, None].expand(2, 3, 24, 24)
        net = EdgeJumpNet(width=4, max_jump=7, dilations=(1,))
        opt = torch.optim.Adam(net.parameters(), lr=1e-2)
        x = edge_features(modulo_wrap(counts, 8), 8)
        target, _ = edge_targets(counts, 8, 7)
        losses = []
        for _ in range(20):
            loss = edge_loss(net(x), target)
            opt.zero_grad()
            loss.backward()
            opt.step()
            losses.append(float(loss.detach()))
        assert losses[-1] < 0.6 * losses[0]


class TestTiles:
    """Large images are predicted in tiles with the receptive radius as context: the same pairs, bounded memory."""

    @pytest.mark.parametrize("dilations, coarse", [((1,), ()), ((1, 2, 4, 8), ()), ((1,), (1,)), ((1, 2), (1, 2))])
    def test_margin_covers_the_receptive_field(self, dilations: tuple[int, ...], coarse: tuple[int, ...]) -> None:
        torch.manual_seed(0)
        net = EdgeJumpNet(width=4, max_jump=2, dilations=dilations, coarse=coarse).eval()
        reach = 0
        for at in range(200, 200 + net.stride):  # every place on the coarsest pooling grid
            x = torch.randn(1, 15, 400, 400)
            y = x.clone()
            y[..., at, at] += 10.0
            with torch.no_grad():
                changed = (net(x) - net(y)).abs().amax(dim=(0, 1, 2, 3)) > 0
            reach = max(reach, int((changed.nonzero() - at).abs().max()))
        assert reach < tile_margin(net) <= reach + 2 * net.stride

    def test_coarse_level(self) -> None:
        plain = EdgeJumpNet(width=4, max_jump=2)
        assert "coarse" not in plain.config and plain.stride == 4  # the configs of earlier weights stay as they were
        net = EdgeJumpNet(width=4, max_jump=2, dilations=(1,), coarse=(1,)).eval()
        assert net.config["coarse"] == (1,) and net.stride == 8
        assert EdgeJumpNet(**net.config).config == net.config
        g = torch.Generator().manual_seed(3)
        moduli = torch.randint(0, 256, (1, 163, 150), generator=g)  # sides not multiples of 8: padded
        whole = predict_edges(net, moduli, 8)
        assert whole.shape == (1, 2, 5, 163, 150)
        assert len(inference._tile_spans(150, 20, tile_margin(net), net.stride)) > 2  # really in tiles
        assert torch.allclose(predict_edges(net, moduli, 8, tile=20), whole, atol=1e-4)

    def test_tiled_equals_whole(self) -> None:
        torch.manual_seed(0)
        net = EdgeJumpNet(width=4, max_jump=3).eval()
        g = torch.Generator().manual_seed(1)
        moduli = torch.randint(0, 256, (3, 290, 250), generator=g)
        whole = predict_edges(net, moduli, 8)
        tiled = predict_edges(net, moduli, 8, tile=40)
        assert torch.allclose(tiled, whole, atol=1e-4)
        jump, cost = predict_jumps(net, moduli, 8, tile=40)
        best, index = whole.max(dim=2)
        assert np.array_equal(jump, index.numpy() - 3)
        assert np.allclose(cost, -best.numpy(), atol=1e-4)

    def test_tiled_equals_whole_with_flips(self) -> None:
        # sides that are not multiples of the pooling grid: every flipped window must still see the image's grid
        torch.manual_seed(0)
        for coarse in ((), (1,)):
            net = EdgeJumpNet(width=4, max_jump=3, dilations=(1,), coarse=coarse).eval()
            moduli = torch.randint(0, 256, (3, 163, 150), generator=torch.Generator().manual_seed(4))
            assert len(inference._tile_spans(150, 20, tile_margin(net), net.stride)) > 2  # really in tiles
            whole = predict_edges(net, moduli, 8, augment=True)
            assert torch.allclose(predict_edges(net, moduli, 8, augment=True, tile=20), whole, atol=1e-4)

    def test_augment_averages_the_flips_probabilities(self) -> None:
        torch.manual_seed(1)
        net = EdgeJumpNet(width=4, max_jump=3, dilations=(1,)).eval()
        moduli = torch.randint(0, 256, (1, 24, 32), generator=torch.Generator().manual_seed(5))
        flips = []
        for dims in ((), (-1,), (-2,), (-1, -2)):
            logp = predict_edges(net, moduli.flip(dims) if dims else moduli, 8)
            flips.append(_unflip(logp, dims).exp() if dims else logp.exp())
        mean = torch.stack(flips).mean(dim=0)  # probabilities, not log-probabilities: no false certainty
        got = predict_edges(net, moduli, 8, augment=True).exp()
        assert torch.allclose(got[..., :-1], mean[..., :-1], atol=1e-5)  # the last column has no right pair
        assert torch.allclose(got.sum(dim=2), torch.ones(()), atol=1e-5)

    def test_no_grad_outside(self) -> None:
        net = EdgeJumpNet(width=4, max_jump=2).eval()
        pieces = inference._windows(net, torch.randint(0, 256, (1, 40, 30)), 8, False, 0)
        next(pieces)
        assert torch.is_grad_enabled()  # the caller's mode between the pieces

    def test_strips_equal_the_whole_head(self) -> None:
        # the head's logits are taken STRIP rows at a time; the rows below the last whole strip and the padding to a
        # multiple of 4 must come out as the network's own forward pass gives them
        torch.manual_seed(0)
        net = EdgeJumpNet(width=4, max_jump=3).eval()
        rows = 2 * STRIP + 23
        moduli = torch.randint(0, 256, (3, rows, 50), generator=torch.Generator().manual_seed(2))
        padded = torch.nn.functional.pad(moduli.float()[None], (0, 2, 0, 1), mode="replicate")
        with torch.no_grad():
            direct = torch.log_softmax(net(edge_features(padded, 8)), dim=3)[0, ..., :rows, :50]
        assert torch.allclose(predict_edges(net, moduli, 8), direct, atol=1e-5)

    def test_option(self) -> None:
        modulus = torch.from_numpy(scene(48) % 256)
        whole = unwrap_single(modulus, method="learned", tile=0)
        assert torch.equal(unwrap_single(modulus, method="learned", tile=8), whole)
        with pytest.raises(ValueError, match="tile"):
            unwrap_single(modulus, method="learned", tile=2)


class TestConfidence:
    def test_weakest_pair_on_the_path(self) -> None:
        m = np.array([[10, 20, 30, 40]])
        jump = np.zeros((2, 1, 4), dtype=np.int16)
        cost = np.zeros((2, 1, 4), dtype=np.float32)
        cost[0, 0] = [0.001, 0.001, 2.0, 0.0]  # the pair (2, 3) is unsure
        k, confidence = decode_jumps(m, jump, cost, 8)
        assert k.tolist() == [[0, 0, 0, 0]]
        assert np.allclose(confidence, np.exp(-np.array([[0.0, 0.001, 0.001, 2.0]])))

    @pytest.mark.parametrize("shape", [(24, 20), (3, 24, 20), (2, 1, 24, 20)])
    def test_learned_confidence_shapes_and_batches(self, shape: tuple, device: torch.device) -> None:
        g = torch.Generator().manual_seed(0)
        modulus = torch.randint(0, 256, shape, generator=g).double().to(device)
        confidence = learned_confidence(modulus)
        assert confidence.shape == modulus.shape and confidence.device == modulus.device
        assert bool(((confidence > 0) & (confidence <= 1)).all())
        if len(shape) == 4:
            single = torch.stack([learned_confidence(m) for m in modulus])
            assert torch.equal(confidence, single)

    def test_info_confidence_is_the_same_runs(self, device: torch.device) -> None:
        g = torch.Generator().manual_seed(1)
        batch = torch.from_numpy(np.stack([scene(40, s) for s in range(3)]) % 256)[None].repeat(2, 1, 1, 1)
        batch[1] = torch.randint(0, 256, batch.shape[1:], generator=g).double()
        batch = batch.float().to(device)
        restored, info = unwrap_single(batch, 8, return_info=True)
        assert info.confidence is not None
        assert info.confidence.shape == batch.shape and info.confidence.dtype == batch.dtype
        assert info.confidence.device == batch.device
        assert torch.equal(info.confidence, learned_confidence(batch))
        assert bool((info.confidence[0] > info.confidence[1].mean()).all())  # smooth scenes beat noise
        # the other methods have no confidence of their own
        assert unwrap_single(batch[0, 0], 8, method="guided", return_info=True)[1].confidence is None
        assert unwrap_single(batch[0, 0], 8, method="lsq", return_info=True)[1].confidence is None
        # a mosaic: the guide's confidence at each photosite, with the mosaic's shape
        guide = interpolate_wrapped(batch[0, :1], "RGGB", 8)
        _, mosaic_info = unwrap_single(batch[0, :1], 8, cfa="RGGB", return_info=True, max_cuts=0)
        expected = mosaic(learned_confidence(guide), "RGGB")
        assert torch.equal(mosaic_info.confidence, expected.reshape(batch[0, :1].shape))

    def test_learned_confidence_of_empty_inputs(self) -> None:
        with pytest.raises(ValueError, match=r"empty image; got shape \(1, 3, 0, 4\)"):
            learned_confidence(torch.zeros(1, 3, 0, 4))
        for shape in ((1, 0, 4, 4), (0, 3, 4, 4)):  # no channels, no images: nothing to be unsure of
            assert learned_confidence(torch.zeros(shape)).shape == shape

    def test_learned_confidence_is_the_decoders(self) -> None:
        truth = np.stack([scene(40, s) for s in range(3)])
        modulus = torch.from_numpy(truth % 256)
        _, expected = learned_k((truth % 256).astype(np.int64), 8)
        assert np.allclose(learned_confidence(modulus).numpy(), expected)
        with pytest.raises(ValueError, match="weights"):
            learned_confidence(modulus, weights="/nonexistent.pt")
        with pytest.raises(ValueError, match="integers"):
            learned_confidence(modulus + 0.5)


class TestLearnedConfidenceModule:
    def test_module_equals_function(self) -> None:
        m = torch.from_numpy(scene(24) % 256).float()
        layer = LearnedConfidence(bits=8, tile=16)
        assert torch.equal(layer(m), learned_confidence(m, 8, tile=16))

    @pytest.mark.parametrize(
        ("kwargs", "error", "match"),
        [
            ({"bits": 0}, ValueError, "bits"),
            ({"tile": 2}, ValueError, "tile must be 0 .* got 2"),
            ({"augment": "yes"}, TypeError, "augment"),
            ({"weights": 3}, TypeError, "weights"),
        ],
    )
    def test_bad_arguments_are_named(self, kwargs: dict, error: type, match: str) -> None:
        with pytest.raises(error, match=match):
            LearnedConfidence(**kwargs)


class TestPairCosts:
    def test_shifts_move_each_pairs_jump(self) -> None:
        m, k = np.array([[10, 20, 30]]), np.zeros((1, 3), np.int64)
        table = np.arange(2 * 3 * 1 * 3, dtype=np.float32).reshape(2, 3, 1, 3)  # jumps -1, 0, 1
        first = np.full((2, 1, 3), -1)
        right, down = pair_costs(m, k, table, first, 256)
        assert right.tolist() == [[table[0, 1, 0, 0], table[0, 1, 0, 1]]] and down.shape == (0, 3)
        up_second = pair_costs(m, k, table, first, 256, 0, 1)[0]  # the second ends a period up: jump 1
        assert up_second.tolist() == [[table[0, 2, 0, 0], table[0, 2, 0, 1]]]
        far = pair_costs(m, k, table, first, 256, 0, 2)[0]  # jump 2: outside the table
        assert far.tolist() == [[MAX_COST, MAX_COST]]
