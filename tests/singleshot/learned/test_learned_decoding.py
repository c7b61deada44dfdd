"""Tests of the learned single-shot method: the decoders (decoding.py, and learned_k's decoding of the channels):
the tree, the cuts, the band, pair costs."""

from __future__ import annotations

import threading

import numpy as np
import pytest
import torch
from learned_helpers import oracle_logp, scene, spec  # tests/singleshot/learned/

from torch_modulo.cfa import interpolate_wrapped, merge_planes, mosaic, split_planes
from torch_modulo.singleshot import unwrap_single
from torch_modulo.singleshot.learned import (
    MAX_COST,
    MOSAIC_CUTS,
    EdgeJumpNet,
    decode_edges,
    decode_jumps,
    decoding,
    edge_features,
    learned_k,
    load_model,
    mosaic_spec,
    pair_costs,
    predict_edges,
    predict_jumps,
    refine_band,
    refine_cut,
    solver,
)
from torch_modulo.singleshot.learned.inference import _unflip

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/singleshot/conftest.py


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
        out = unwrap_single(m, cfa="GRBG", levels=False)  # the guide alone: no refinement of the photosites
        assert torch.equal(out, unwrap_single(m, cfa="GRBG", max_cuts=MOSAIC_CUTS, levels=False))
        guide = unwrap_single(interpolate_wrapped(m[None], "GRBG"), max_cuts=MOSAIC_CUTS, levels=False)
        assert torch.equal(out, mosaic(guide, "GRBG")[0]) and torch.equal(torch.remainder(out, 256), m)
        assert solver.refines_photosites(spec("learned")) and solver.refines_photosites(spec("learned", levels=True))
        assert not solver.refines_photosites(spec("learned", levels=False))
        assert not solver.refines_photosites(spec("learned", cells=True))
        assert not solver.refines_photosites(spec("guided"))

    def test_a_mosaics_photosites_are_refined_on_a_real_scene(self, shared_hdr) -> None:
        # park (CC0), protocol B mosaicked RGGB at 256 pixels: the guide puts a large region a period off (64% of
        # the values right); the level moves of the cells' images, started from the guide's counts, put it back.
        from torch_modulo import protocols

        path = shared_hdr / "polyhaven-cc0" / "park.exr"
        if not path.is_file():
            pytest.skip(f"{path} not found")
        image = protocols.load_scene(path, 256)
        h, w = image.shape[-2:]
        truth = mosaic(protocols.protocol_b(image[:, : h - h % 2, : w - w % 2].contiguous()), "RGGB")
        m = torch.remainder(truth, 256)[None]
        scores = [
            protocols.score_scene(split_planes(out[0]), split_planes(truth), 8, 4095.0).exact_k
            for out in (unwrap_single(m, cfa="RGGB"), unwrap_single(m, cfa="RGGB", levels=False))
        ]
        assert scores[0] > scores[1] + 0.15, scores

    def test_the_refinement_keeps_the_guides_anchor_and_leaves_thin_or_overflowing_mosaics(self) -> None:
        rgb = torch.from_numpy(np.stack([scene(48, s) for s in range(3)])).float()
        m = mosaic(rgb, "GBRG") % 256
        out, guide = unwrap_single(m, cfa="GBRG"), unwrap_single(m, cfa="GBRG", levels=False)
        assert torch.equal(torch.remainder(out, 256), m)
        # where nothing moved, the guide's counts: the two greens keep the offset the guide's green channel gave them
        moved = (split_planes(out[None]) - split_planes(guide[None]))[0] / 256
        assert all(int(torch.mode(plane.flatten()).values) == 0 for plane in moved)
        thin = m[:, :10, :]  # colour planes of 5 rows: too thin for the level head, the guide's result as it is
        assert torch.equal(unwrap_single(thin, cfa="GBRG"), unwrap_single(thin, cfa="GBRG", levels=False))
        # float16 counts past 65504 stay inf (not the bare modulus): an image beyond the dtype keeps the guide's
        big = torch.remainder((torch.arange(640.0).view(1, -1) * 110.0).expand(16, -1), 256).half()[None]
        with pytest.warns(UserWarning, match="became inf"):
            half, alone = unwrap_single(big, cfa="RGGB"), unwrap_single(big, cfa="RGGB", levels=False)
        assert bool(half.isinf().any()) and torch.equal(half, alone)

    def test_keep_anchor(self) -> None:
        from torch_modulo.singleshot.unwrap import _keep_anchor

        guide = np.array([[0, 0, 1, 1], [0, 2, 2, 1]])
        assert _keep_anchor(guide + 3, guide).tolist() == guide.tolist()  # a plane moved whole: put back
        moved = guide + 3
        moved[1, 1:3] -= 1  # one region moved down a period, the rest by the global offset
        assert _keep_anchor(moved, guide).tolist() == [[0, 0, 1, 1], [0, 1, 1, 1]]
        assert _keep_anchor(np.array([[0, 0, -1]]), np.array([[0, 0, 0]])).tolist() == [[0, 0, 0]]  # none below 0

    def test_the_options_reach_the_refinement(self, monkeypatch: pytest.MonkeyPatch) -> None:
        from torch_modulo.singleshot import unwrap as front

        seen = []

        def spy(moduli, k, chosen, channels):
            options = (chosen.option("tile"), chosen.option("threads"), chosen.option("levels"))
            seen.append((tuple(moduli.shape), *options, channels))
            return k

        monkeypatch.setattr(front, "refine_photosites", spy)
        m = mosaic(torch.from_numpy(np.stack([scene(16, s) for s in range(3)])).float(), "RGGB") % 256
        out = unwrap_single(m, cfa="RGGB", tile=64, threads=1)
        assert seen == [((3, 8, 8), 64, 1, True, (0, 1, 2)), ((3, 8, 8), 64, 1, True, (1,))]  # the cells' two images
        assert torch.equal(out, unwrap_single(m, cfa="RGGB", levels=False))  # nothing moved: the guide's

    @pytest.mark.parametrize("cfa", ["RGGB", "GRBG"])
    def test_mosaic_cells_are_two_half_resolution_colour_images(self, cfa: str) -> None:
        rgb = torch.from_numpy(np.stack([scene(32, s) for s in range(3)])).float()
        m = mosaic(rgb, cfa) % 256
        out, info = unwrap_single(m, cfa=cfa, return_info=True, cells=True)
        assert torch.equal(torch.remainder(out, 256), m) and info.iterations.shape == (1, 3)
        assert info.confidence is not None and info.confidence.shape == m.shape
        planes = split_planes(m[None])[0]  # photosites (0, 0), (0, 1), (1, 0), (1, 1)
        r, g1, g2, b = {"RGGB": (0, 1, 2, 3), "GRBG": (1, 0, 3, 2)}[cfa]
        first, second = unwrap_single(planes[[r, g1, b]]), unwrap_single(planes[[r, g2, b]])
        expected = torch.empty_like(planes)
        expected[r], expected[g1], expected[b], expected[g2] = first[0], first[1], first[2], second[1]
        assert torch.equal(out, merge_planes(expected[None])[0])
        assert torch.equal(unwrap_single(m[0], cfa=cfa, cells=True), out[0])  # (H, W) as (1, H, W)
        with pytest.raises(ValueError, match="even"):
            unwrap_single(m[:, :31], cfa=cfa, cells=True)

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
