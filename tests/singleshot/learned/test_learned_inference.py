"""Tests of the learned single-shot method: windowed inference (inference.py): margins, tiles, strips, flips."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from learned_helpers import scene  # tests/singleshot/learned/

from torch_modulo.singleshot import unwrap_single
from torch_modulo.singleshot.learned import (
    STRIP,
    EdgeJumpNet,
    edge_features,
    inference,
    predict_edges,
    predict_jumps,
    tile_margin,
)
from torch_modulo.singleshot.learned.inference import _unflip

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/singleshot/conftest.py


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
