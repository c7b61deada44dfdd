"""Tests for the learned levels (torch_modulo/singleshot/learned/: network, inference, levels): loader, tiles and
strips, the receptive field, region moves (exact, never costlier, fixing a region a period off), the ``levels``
option of the method, and the deprecated ``torch_modulo.singleshot.levels``."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from torch_modulo.singleshot import SingleShotUnwrap, unwrap_single
from torch_modulo.singleshot.learned import (
    BAND,
    LEVEL_WEIGHTS,
    LEVELS,
    MAX_COST,
    LevelNet,
    RegionMoves,
    edge_features,
    inference,
    learned_k,
    level_margin,
    load_levels,
    load_model,
    predict_jumps,
    predict_levels,
    region_moves,
    solver,
    weights_path,
)
from torch_modulo.singleshot.learned import levels as levels_module
from torch_modulo.singleshot.learned.levels import _REACH

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/singleshot/conftest.py


def tiny(seed: int = 0, levels: int = 5) -> LevelNet:
    torch.manual_seed(seed)
    return LevelNet({"width": 4, "max_jump": 2, "dilations": (1, 2)}, width=4, levels=levels).eval()


def save(net: LevelNet, path) -> None:
    """A level weights file as research/level_head.py writes one."""
    state = net.trunk.state_dict()
    torch.save({"config": net.trunk.config, "state": state, "head": net.head.state_dict()}, path)


def lamp(size: int = 40) -> np.ndarray:
    """(size, size) counts: a ramp and a lamp several periods above it."""
    y, x = np.mgrid[0:size, 0:size].astype(np.float64)
    img = 30 + 5 * x + 1400 * ((np.abs(y - size / 2) < size / 6) & (np.abs(x - size / 2) < size / 6))
    return np.floor(img)


def energy(m, k, table, first, u, weight=1.0) -> float:
    """The cost region_moves lowers: the level costs plus the cost of every pair's jump."""
    total = weight * float(np.take_along_axis(u, np.clip(k, 0, u.shape[0] - 1)[None], 0).sum(dtype=np.float64))
    for d, (a, b) in enumerate(((np.s_[:, :-1], np.s_[:, 1:]), (np.s_[:-1, :], np.s_[1:, :]))):
        wd = np.mod(m[b] - m[a] + 128, 256) - 128
        n = (m[b] + 256 * k[b] - m[a] - 256 * k[a] - wd) // 256 - first[d][a]
        inside = (n >= 0) & (n < table.shape[1])
        c = np.take_along_axis(table[d][(slice(None), *a)], np.clip(n, 0, table.shape[1] - 1)[None], 0)[0]
        total += float(np.where(inside, np.minimum(c, MAX_COST), MAX_COST).sum())
    return total


class TestLoader:
    def test_shipped_levels_load_offline_on_cpu(self) -> None:
        net = load_levels()
        assert isinstance(net, LevelNet) and not net.training and net.head.levels == LEVELS
        assert next(net.parameters()).device.type == "cpu"
        together = sum(p.numel() for p in net.parameters()) + sum(p.numel() for p in load_model().parameters())
        assert together <= 2_000_000
        assert load_levels() is net  # cached

    def test_a_file_that_is_not_levels_is_named(self, tmp_path) -> None:
        text, edges = tmp_path / "notes.pt", tmp_path / "edges.pt"
        text.write_text("not a network")
        net = load_model()
        torch.save({"config": net.config, "state": net.state_dict()}, edges)  # an edge network: no head
        for path in (text, edges):
            with pytest.raises(ValueError, match=rf"'{path}' is not a level weights file"):
                SingleShotUnwrap(method="learned", levels=str(path))  # at construction, not at the first image
        with pytest.raises(FileNotFoundError, match="weights file not found"):
            load_levels(tmp_path / "missing.pt")

    def test_bad_option_values(self) -> None:
        m = torch.zeros(8, 8)
        with pytest.raises(ValueError, match=r"levels must be True, False or an existing level weights file"):
            unwrap_single(m, method="learned", levels="/nonexistent/levels.pt")
        for bad in (1, "yes", None):
            with pytest.raises((TypeError, ValueError), match="levels"):
                unwrap_single(m, method="learned", levels=bad)

    def test_a_file_of_levels(self, tmp_path) -> None:
        path = tmp_path / "tiny.pt"
        save(tiny(levels=5), path)
        modulus = torch.from_numpy(lamp(24) % 256)
        out = unwrap_single(modulus, method="learned", levels=str(path))
        assert out.shape == modulus.shape and torch.equal(torch.remainder(out, 256), modulus)
        assert load_levels(path).head.levels == 5


class TestPrediction:
    def test_margin_covers_the_receptive_field(self) -> None:
        net = tiny()
        reach = 0
        for at in range(120, 120 + net.stride):  # every place on the pooling grid
            x = torch.randn(1, 15, 240, 240)
            y = x.clone()
            y[..., at, at] += 10.0
            with torch.no_grad():
                changed = (net(x) - net(y)).abs().amax(dim=(0, 1, 2)) > 0  # (H / 2, W / 2) blocks
            blocks = changed.nonzero()
            reach = max(reach, int(torch.maximum((2 * blocks - at).abs(), (2 * blocks + 1 - at).abs()).max()))
        assert reach < level_margin(net) <= reach + 2 * net.stride + 8

    @pytest.mark.parametrize("channels", [1, 3, 2])
    def test_tiles_equal_the_whole_network(self, channels: int) -> None:
        net = tiny()
        rows, cols = 163, 150  # not multiples of the pooling grid
        moduli = torch.randint(0, 256, (channels, rows, cols), generator=torch.Generator().manual_seed(1))
        whole = predict_levels(net, moduli, 8, tile=0)
        assert whole.shape == (channels, 5, (rows + 1) // 2, cols // 2) and whole.dtype == np.float16
        planes = [moduli] if channels in (1, 3) else [moduli[i : i + 1] for i in range(channels)]
        direct = []
        for x in planes:
            padded = torch.nn.functional.pad(x.float()[None].expand(1, 3, rows, cols), (0, 2, 0, 1), mode="replicate")
            with torch.no_grad():
                logits = net(edge_features(padded, 8))[0, : x.shape[0]]  # one per 2 x 2 block
            cost = -torch.log_softmax(logits, dim=1)
            direct.append(cost[..., : (rows + 1) // 2, : cols // 2].numpy())
        assert np.allclose(whole, np.concatenate(direct), atol=5e-3)
        assert len(inference._tile_spans(cols, 40, level_margin(net), net.stride)) > 2  # really in tiles
        tiled = predict_levels(net, moduli, 8, tile=40)
        assert np.allclose(tiled.astype(np.float32), whole.astype(np.float32), atol=5e-3)

    @pytest.mark.parametrize("shape", [(3, 101, 90), (1, 64, 75), (2, 30, 33)])
    def test_one_run_of_the_encoder_for_both(self, shape: tuple) -> None:
        edge = load_model()
        net = load_levels()
        moduli = torch.randint(0, 256, shape, generator=torch.Generator().manual_seed(2)).float()
        for tile in (0, 40):
            jump, cost, u = predict_jumps(edge, moduli, 8, tile=tile, band=BAND, levels=net)
            alone = predict_jumps(edge, moduli, 8, tile=tile, band=BAND)
            assert np.array_equal(jump, alone[0]) and np.array_equal(cost, alone[1])
            assert np.array_equal(u, predict_levels(net, moduli, 8, tile=tile))
        with pytest.raises(ValueError, match="augment"):
            predict_jumps(edge, moduli, 8, augment=True, levels=net)

    def test_no_channels(self) -> None:
        assert predict_levels(tiny(), torch.zeros(0, 8, 8), 8).shape == (0, 5, 4, 4)
        jump, cost, u = predict_jumps(load_model(), torch.zeros(0, 8, 6), 8, band=BAND, levels=load_levels())
        assert jump.shape == (0, 2, 8, 6) and cost.shape == (0, 2, 2 * BAND + 1, 8, 6)
        assert u.shape[0] == 0 and u.shape[2:] == (4, 3)
        jump, cost = predict_jumps(load_model(), torch.zeros(0, 8, 6), 8)
        assert jump.shape == cost.shape == (0, 2, 8, 6)
        k, confidence = learned_k(np.zeros((0, 8, 8)), 8, levels=True)
        assert k.shape == confidence.shape == (0, 8, 8)

    def test_costs_are_a_distribution(self) -> None:
        costs = predict_levels(load_levels(), torch.from_numpy(lamp(32) % 256)[None], 8).astype(np.float64)
        assert costs.shape == (1, LEVELS, 16, 16)
        assert np.allclose(np.exp(-costs).sum(axis=1), 1.0, atol=1e-2)


def naive_moves(m, k, table, first, u, weight: float, sure: float) -> np.ndarray:
    """region_moves' rules, slowly: every move of every region weighed on the whole plane's cost each round."""
    h, w = m.shape
    labels = np.full((h, w), -1)
    pairs = [((y, x), (y, x + 1), table[0, :, y, x].min()) for y in range(h) for x in range(w - 1)]
    pairs += [((y, x), (y + 1, x), table[1, :, y, x].min()) for y in range(h - 1) for x in range(w)]
    count = 0
    for start in np.ndindex(h, w):  # regions: flood fill over the sure pairs
        if labels[start] >= 0:
            continue
        labels[start], todo = count, [start]
        while todo:
            p = todo.pop()
            for a, b, c in pairs:
                if c <= sure and p in (a, b) and labels[b if p == a else a] < 0:
                    labels[b if p == a else a] = count
                    todo.append(b if p == a else a)
        count += 1
    k = k + min(range(-LEVELS, LEVELS + 1), key=lambda g: (energy(m, k + g, table, first, u, 1.0), abs(g)))
    neighbours = [set() for _ in range(count)]
    for a, b, _ in pairs:
        if labels[a] != labels[b]:
            neighbours[labels[a]].add(labels[b])
            neighbours[labels[b]].add(labels[a])
    moved = np.zeros(count, dtype=int)
    for _ in range(60):
        now = energy(m, k + moved[labels], table, first, u, weight)
        best, choice = np.full(count, np.inf), np.zeros(count, dtype=int)
        for r in range(count):
            for s in (-2, -1, 1, 2):  # region_moves' order: the first of equal drops wins
                if abs(moved[r] + s) <= _REACH:
                    trial = moved.copy()
                    trial[r] += s
                    drop = energy(m, k + trial[labels], table, first, u, weight) - now
                    if drop < best[r]:
                        best[r], choice[r] = drop, s
        move = [r for r in range(count) if best[r] < -1e-6 and all(best[r] < best[q] for q in neighbours[r])]
        if not move:
            break
        moved[move] += choice[move]
    return k + moved[labels]


class TestRegionMoves:
    @pytest.mark.parametrize("seed", range(6))
    def test_the_rules_done_slowly(self, seed: int) -> None:
        # planes of many small regions that really move: the fast bookkeeping must give what the rules say
        rng = np.random.default_rng(seed)
        m = rng.integers(0, 256, (9, 11))
        k0 = rng.integers(0, 2, m.shape)
        table = rng.exponential(1.0, (2, 2 * BAND + 1, *m.shape))
        first = rng.integers(-3, 0, (2, *m.shape))
        u = (3 * rng.random((LEVELS, *m.shape))).astype(np.float16)
        expected = naive_moves(m, k0, table, first, u, 0.5, 0.2)
        assert not np.array_equal(expected - expected.min(), k0 - k0.min())  # something moved
        assert np.array_equal(region_moves(m, k0, table, first, u, 8, block=1, weight=0.5, sure=0.2), expected)

    def test_a_region_a_period_off_moves_back(self) -> None:
        truth = lamp(40)
        m = (truth % 256).astype(np.int64)
        true_k = (truth // 256).astype(np.int64)
        wrong = true_k.copy()
        wrong[true_k > 0] -= 1  # the lamp one period low, as a tree crossing its border by one bad pair would put it
        # every pair's table is centred on its true jump: sure of it inside the lamp and the floor, unsure (every
        # jump of the table equally likely) across the lamp's border and its wraps
        first, table = np.zeros((2, 40, 40), dtype=np.int64), np.full((2, 2 * BAND + 1, 40, 40), 5.0)
        for d, (a, b) in enumerate(((np.s_[:, :-1], np.s_[:, 1:]), (np.s_[:-1, :], np.s_[1:, :]))):
            first[d][a] = true_k[b] - true_k[a] - (np.mod(m[b] - m[a] + 128, 256) - 128 - (m[b] - m[a])) // 256 - BAND
            table[d, BAND][a] = np.where(true_k[a] == true_k[b], 0.0, 2.0)
            table[d][(slice(None), *a)][:, true_k[a] != true_k[b]] = 2.0
        u = np.full((LEVELS, 40, 40), 4.0, dtype=np.float16)
        np.put_along_axis(u, true_k[None], 0.5, axis=0)  # the head leans to the true level
        assert np.array_equal(region_moves(m, wrong, table, first, u, 8, block=1), true_k)
        # with no view on levels (flat costs) nothing moves: every border jump in the tables costs the same
        assert np.array_equal(region_moves(m, wrong, table, first, np.ones_like(u), 8, block=1), wrong)

    def test_pieces_give_the_whole(self, monkeypatch: pytest.MonkeyPatch) -> None:
        rng = np.random.default_rng(7)
        m = rng.integers(0, 256, (20, 23))
        k0 = rng.integers(0, 3, m.shape)
        table = rng.exponential(1.0, (2, 5, *m.shape))
        first = rng.integers(-3, 0, (2, *m.shape))
        u = (3 * rng.random((LEVELS, *m.shape))).astype(np.float16)
        whole = region_moves(m, k0, table, first, u, 8, block=1, sure=0.2)
        monkeypatch.setattr(levels_module, "_CHUNK", 7)  # pieces of 7 pairs in every round
        assert np.array_equal(region_moves(m, k0, table, first, u, 8, block=1, sure=0.2), whole)

    @pytest.mark.parametrize("seed", range(4))
    def test_exact_and_never_costlier(self, seed: int) -> None:
        rng = np.random.default_rng(seed)
        m = rng.integers(0, 256, (20, 23))
        k0 = rng.integers(0, 4, m.shape)
        table = rng.exponential(1.0, (2, 5, *m.shape))
        first = rng.integers(-3, 1, (2, *m.shape))
        u = rng.exponential(2.0, (LEVELS, *m.shape)).astype(np.float16)
        k = region_moves(m, k0, table, first, u, 8, block=1, weight=0.7, sure=0.2)
        assert k.dtype == np.int64 and k.shape == m.shape
        assert energy(m, k, table, first, u, 0.7) < energy(m, k0, table, first, u, 0.7) - 1.0  # it did move
        # a constant per region of pairs at most `sure` costly
        joined_x = table[0].min(axis=0)[:, :-1] <= 0.2
        assert np.all((k - k0)[:, :-1][joined_x] == (k - k0)[:, 1:][joined_x])

    def test_moves_stay_within_reach(self) -> None:
        m = np.zeros((1, 2), dtype=np.int64)
        table = np.full((2, 1, 1, 2), 30.0)  # the one pair is unsure of every jump
        u = np.zeros((LEVELS, 1, 2))
        u[1:, 0, 0] = 100.0  # the left pixel is sure of level 0 ...
        u[:, 0, 1] = np.arange(LEVELS)[::-1]  # ... and the right one wants the top level, beyond the reach
        k = region_moves(m, np.zeros((1, 2), int), table, np.zeros((2, 1, 2), int), u, 8, block=1)
        assert k.tolist() == [[0, _REACH]]

    def test_huge_rollover_counts(self) -> None:
        m = np.zeros((30, 30), dtype=np.int64)
        k = np.zeros((30, 30), dtype=np.int64)
        k[0, 0], k[5, 5] = 10**12, -(10**9)  # far apart, and no sure pair: 900 regions
        out = region_moves(
            m, k, np.full((2, 5, 30, 30), 5.0), np.full((2, 30, 30), -2), np.zeros((LEVELS, 30, 30)), 8, block=1
        )
        assert np.array_equal(out, k)  # flat level costs, unsure pairs: nothing to gain

    @pytest.mark.parametrize("shape", [(20, 23), (21, 22), (1, 9)])
    def test_block_costs_are_their_pixels_costs(self, shape: tuple[int, int]) -> None:
        rng = np.random.default_rng(11)
        m = rng.integers(0, 256, shape)
        k0 = rng.integers(0, 4, shape)
        table = rng.exponential(1.0, (2, 5, *shape))
        first = rng.integers(-3, 1, (2, *shape))
        blocks = rng.exponential(2.0, (LEVELS, -(-shape[0] // 2), -(-shape[1] // 2))).astype(np.float16)
        pixels = blocks.repeat(2, axis=1).repeat(2, axis=2)[:, : shape[0], : shape[1]]
        k = region_moves(m, k0, table, first, blocks, 8, weight=0.7, sure=0.2)
        assert np.array_equal(k, region_moves(m, k0, table, first, pixels, 8, weight=0.7, sure=0.2, block=1))
        assert not np.array_equal(k, k0)  # something moved
        with pytest.raises(ValueError, match="blocks of 2"):
            region_moves(m, k0, table, first, pixels, 8)  # per-pixel costs are not 2 x 2 blocks

    def test_degenerate_planes(self) -> None:
        u = np.zeros((LEVELS, 1, 1))
        assert region_moves(
            np.zeros((1, 1)), np.zeros((1, 1), int), np.zeros((2, 1, 1, 1)), np.zeros((2, 1, 1)), u, 8
        ).shape == (1, 1)
        empty = np.zeros((0, 4))
        assert region_moves(
            empty, empty.astype(int), np.zeros((2, 1, 0, 4)), np.zeros((2, 0, 4)), np.zeros((LEVELS, 0, 2)), 8
        ).shape == (0, 4)
        with pytest.raises(ValueError, match="block"):
            region_moves(
                np.zeros((1, 1)), np.zeros((1, 1), int), np.zeros((2, 1, 1, 1)), np.zeros((2, 1, 1)), u, 8, block=0
            )


class TestOption:
    def test_levels_false_runs_no_region_moves(self, monkeypatch: pytest.MonkeyPatch) -> None:
        calls = []
        real = solver.region_moves
        monkeypatch.setattr(solver, "region_moves", lambda *a, **kw: calls.append(1) or real(*a, **kw))
        modulus = torch.from_numpy(np.stack([lamp(32), lamp(32) + 7]) % 256)
        off = unwrap_single(modulus, method="learned", levels=False)
        assert not calls
        assert torch.equal(off, unwrap_single(modulus, method="learned", levels=False, tile=8))
        unwrap_single(modulus, method="learned")
        assert len(calls) == 2  # once per channel
        calls.clear()
        assert np.array_equal(learned_k(modulus, 8, levels=True)[0], learned_k(modulus, 8, levels=load_levels())[0])
        assert len(calls) == 4
        path = weights_path(None, LEVEL_WEIGHTS)
        assert np.array_equal(learned_k(modulus, 8, levels=path)[0], learned_k(modulus, 8, levels=np.True_)[0])
        assert np.array_equal(learned_k(modulus, 8, levels=np.False_)[0], learned_k(modulus, 8)[0])
        with pytest.raises(TypeError, match="levels"):
            learned_k(modulus, 8, levels=1)

    def test_default_moves_regions_exactly(self) -> None:
        truth = torch.from_numpy(np.stack([lamp(48), lamp(48) * 1.3, lamp(48) * 0.7]).round())
        modulus = truth % 256
        out = unwrap_single(modulus, method="learned", workers=1)
        k = (out - modulus) / 256
        assert torch.equal(k, torch.round(k)) and bool((k >= 0).all())
        assert torch.equal(out, unwrap_single(modulus, method="learned", levels=True, workers=1))
        batch = unwrap_single(torch.stack([modulus, modulus.flip(-1)]), method="learned", workers=1)
        assert torch.equal(batch[1], unwrap_single(modulus.flip(-1), method="learned", workers=1))


class TestRegionMovesClass:
    """:class:`RegionMoves` alone: its regions, its global offset, and its run as :func:`region_moves`."""

    def plane(self):
        m = np.array([[10, 10, 10, 10]])
        table = np.full((2, 3, 1, 4), 30.0)
        table[:, 1] = 0.0  # jumps -1, 0, 1: sure of 0 but for the middle pair
        table[0, :, 0, 1] = [30.0, 1.0, 2.0]
        return m, table, np.full((2, 1, 4), -1)

    def test_regions_and_global_offset(self) -> None:
        m, table, first = self.plane()
        u = np.full((16, 1, 2), 9.0)
        u[3] = 0.0  # every block prefers level 3
        moves = RegionMoves(m, np.zeros((1, 4), int), table, first, u, 8)
        assert moves.count == 2 and moves.labels.tolist() == [[0, 0, 1, 1]]
        assert moves.global_offset() == 3
        assert moves.run().tolist() == [[3, 3, 3, 3]]

    def test_run_is_region_moves(self) -> None:
        rng = np.random.default_rng(3)
        m = rng.integers(0, 256, (12, 10))
        k = rng.integers(0, 3, (12, 10))
        table = rng.uniform(0, 3, (2, 5, 12, 10)).astype(np.float32)
        table[:, 2] = np.where(rng.uniform(size=(2, 12, 10)) < 0.7, 0.0, table[:, 2])
        first = np.full((2, 12, 10), -2)
        u = rng.uniform(0, 5, (LEVELS, 6, 5)).astype(np.float16)
        out = RegionMoves(m, k, table, first, u, 8).run(rounds=60)
        assert np.array_equal(out, region_moves(m, k, table, first, u, 8))
        assert out.dtype == np.int64

    def test_bad_level_costs_are_named(self) -> None:
        m, table, first = self.plane()
        with pytest.raises(ValueError, match=r"level costs of shape \(16, 1, 1\) for a 1 x 4 plane"):
            RegionMoves(m, np.zeros((1, 4), int), table, first, np.zeros((16, 1, 1)), 8)

    def test_an_empty_plane(self) -> None:
        moves = RegionMoves(
            np.zeros((0, 3), int),
            np.zeros((0, 3), int),
            np.zeros((2, 1, 0, 3)),
            np.zeros((2, 0, 3)),
            np.zeros((4, 0, 2)),
            8,
        )
        assert moves.run().shape == (0, 3)


class TestDeprecatedLevelsModule:
    def test_old_names_warn_and_resolve(self) -> None:
        import torch_modulo.singleshot.learned as learned
        import torch_modulo.singleshot.levels as old

        for name in ("region_moves", "LevelNet", "LevelHead", "load_levels", "predict_levels", "LEVELS"):
            with pytest.warns(DeprecationWarning, match=f"levels.{name} is deprecated"):
                assert getattr(old, name) is getattr(learned, name)

    def test_unknown_names_raise(self) -> None:
        import torch_modulo.singleshot.levels as old

        with pytest.raises(AttributeError, match="no attribute 'nope'"):
            old.nope  # noqa: B018
