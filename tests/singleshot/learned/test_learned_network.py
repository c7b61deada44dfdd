"""Tests of the learned single-shot method: the networks and their weights (network.py): loading, the CPU layout,
the weights option."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from learned_helpers import scene  # tests/singleshot/learned/

from torch_modulo.singleshot import SingleShotUnwrap, unwrap_single
from torch_modulo.singleshot.learned import (
    EdgeJumpNet,
    edge_features,
    load_model,
)

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/singleshot/conftest.py


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
