"""Tests for torch_modulo.singleshot.lsq and unwrap_single(method="lsq"): least-squares unwrapping with the DCT."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from torch_modulo.singleshot import SingleShotInfo, SingleShotUnwrap, unwrap_energy, unwrap_single
from torch_modulo.singleshot.lsq import (
    LSQ_OPTIONS,
    dct,
    idct,
    lsq_k,
    lsq_phase,
    poisson_neumann,
    snap_k,
    work_dtype,
    wrapped_gradients,
)
from torch_modulo.singleshot.methods import REGISTRY, make_spec, solve_plane

CUDA = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")


def smooth(kind: str, size: int = 48) -> torch.Tensor:
    """Smooth float64 counts (size, size) with a dark corner at k = 0 and no neighbour step of half a period."""
    y, x = np.mgrid[0:size, 0:size].astype(np.float64)
    if kind == "ramp":  # 1 .. 5641, steps of 60
        img = 1 + 60 * x + 60 * y
    elif kind == "bump":  # a Gaussian bump of 1800 counts on a floor of 1 count
        img = 1 + 1800 * np.exp(-((y - 28) ** 2 + (x - 22) ** 2) / (2 * 12.0**2))
    elif kind == "bumps":  # two bumps on a gentle ramp
        g = np.exp(-((y - 12) ** 2 + (x - 34) ** 2) / (2 * 8.0**2))
        img = 1 + 5 * x + 3 * y + 1200 * g + 1800 * np.exp(-((y - 32) ** 2 + (x - 14) ** 2) / (2 * 10.0**2))
    else:
        raise ValueError(kind)
    return torch.from_numpy(np.floor(img))


def faded_cliff() -> torch.Tensor:
    """A ramp with a cliff at x = 32 that grows from 0 to 400 counts down the image: the wrapped differences hold
    residues where the cliff passes half a period, and the unweighted solution smears them."""
    y, x = np.mgrid[0:64, 0:64].astype(np.float64)
    return torch.from_numpy(np.floor(1 + 3 * x + 2 * y + 400 * (x >= 32) * np.clip((y - 30) / 20, 0, 1)))


def exact_share(restored: torch.Tensor, truth: torch.Tensor) -> float:
    """Share of pixels whose k is right after aligning the most common offset (one plane)."""
    d = torch.floor(restored / 256) - torch.floor(truth / 256)
    return float((d == torch.mode(d.flatten()).values).double().mean())


def consistent(restored: torch.Tensor, modulus: torch.Tensor, bits: int = 8) -> bool:
    """``restored == modulus + k 2**bits`` with integer ``k >= 0`` everywhere."""
    k = (restored.double() - modulus.double()) / 2**bits
    return bool(torch.equal(k, torch.round(k)) and (k >= 0).all())


class TestTransforms:
    @pytest.mark.parametrize("n", [1, 2, 3, 8, 17])
    def test_dct_matches_the_definition(self, n: int) -> None:
        x = torch.randn(4, n, dtype=torch.float64, generator=torch.Generator().manual_seed(n))
        idx = torch.arange(n, dtype=torch.float64)
        basis = torch.cos(math.pi * idx[:, None] * (2 * idx[None, :] + 1) / (2 * n))  # [k, n]
        torch.testing.assert_close(dct(x), x @ basis.T)
        torch.testing.assert_close(idct(dct(x)), x)
        torch.testing.assert_close(dct(x.T, dim=0), (x @ basis.T).T)

    @pytest.mark.parametrize("shape", [(1, 1), (1, 7), (5, 1), (6, 9), (2, 3, 8, 5)])
    def test_poisson_inverts_the_neumann_laplacian(self, shape: tuple[int, ...]) -> None:
        phi = torch.randn(shape, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
        phi = phi - phi.mean(dim=(-2, -1), keepdim=True)
        gx, gy = wrapped_gradients(phi, 1e9)  # no wrapping: the plain forward differences
        lap = gx.clone()
        lap[..., :, 1:] -= gx[..., :, :-1]
        lap += gy
        lap[..., 1:, :] -= gy[..., :-1, :]
        torch.testing.assert_close(poisson_neumann(lap), phi)

    def test_wrapped_gradients_range(self) -> None:
        m = torch.randint(0, 256, (3, 20, 30)).double()
        for g in wrapped_gradients(m, 256):
            assert bool((g >= -128).all() and (g < 128).all())

    def test_work_dtype(self) -> None:
        assert work_dtype(torch.device("cpu")) == torch.float64
        assert work_dtype(torch.device("mps")) == torch.float32


class TestLsqK:
    @pytest.mark.parametrize("kind", ["ramp", "bump", "bumps"])
    @pytest.mark.parametrize("iterations", [0, 3])
    def test_exact_on_smooth_scenes(self, kind: str, iterations: int) -> None:
        truth = smooth(kind)
        k = lsq_k(truth % 256, 8, iterations=iterations)
        assert torch.equal(truth % 256 + 256 * k, truth)  # min k = 0 and the truth's dark corner is at k = 0

    def test_phase_is_exact_without_residues(self) -> None:
        truth = smooth("bumps")
        phi = lsq_phase(truth % 256, 8)
        torch.testing.assert_close(phi, truth - truth.mean())

    def test_snap_finds_the_offset_near_half_a_period(self) -> None:
        truth = smooth("ramp", 16)
        # phi off by 127.6 counts plus noise: a rounding without the circular mean would split the image.
        phi = truth - 1000 + 127.6 + 0.3 * torch.randn(truth.shape, generator=torch.Generator().manual_seed(0))
        assert torch.equal(truth % 256 + 256 * snap_k(truth % 256, phi.double(), 8), truth)

    def test_reweighting_helps_across_a_faded_cliff(self) -> None:
        truth = faded_cliff()
        plain = exact_share(truth % 256 + 256 * lsq_k(truth % 256, 8), truth)
        weighted = exact_share(truth % 256 + 256 * lsq_k(truth % 256, 8, iterations=3), truth)
        assert plain < 0.8 < 0.95 < weighted

    def test_colour_shares_weights(self) -> None:
        truth = torch.stack([faded_cliff(), faded_cliff() * 0 + smooth("ramp", 64) // 4])
        alone = lsq_k(truth % 256, 8, iterations=3, colour=False)
        for c in range(2):  # colour=False: every channel as if alone
            assert torch.equal(alone[c], lsq_k(truth[c] % 256, 8, iterations=3))
        one = lsq_k(truth[:1] % 256, 8, iterations=3, colour=True)
        assert torch.equal(one, alone[:1])  # one channel: nothing to share

    def test_empty(self) -> None:
        assert lsq_k(torch.zeros(0, 3, 5, 5), 8).shape == (0, 3, 5, 5)


class TestUnwrapSingleLsq:
    @pytest.mark.parametrize("kind", ["ramp", "bump", "bumps"])
    def test_recovers_smooth_scenes(self, kind: str) -> None:
        truth = smooth(kind)
        assert torch.equal(unwrap_single(truth % 256, 8, method="lsq"), truth)

    def test_shapes_dtype_device(self, device: torch.device, dtype: torch.dtype) -> None:
        truth = smooth("bumps", 24).to(device, dtype)
        for shape in [(24, 24), (1, 24, 24), (2, 3, 24, 24)]:
            x = truth.expand(shape) % 256
            out = unwrap_single(x, 8, method="lsq")
            assert out.shape == x.shape and out.dtype == dtype and out.device == x.device
            assert torch.equal(out, truth.expand(shape))

    def test_device_matches_cpu(self, device: torch.device) -> None:
        m = torch.randint(0, 256, (2, 3, 20, 30), generator=torch.Generator().manual_seed(3)).double()
        cpu = unwrap_single(m, 8, method="lsq")
        assert torch.equal(unwrap_single(m.to(device), 8, method="lsq").cpu(), cpu)

    @CUDA
    def test_cuda_float32_matches_cpu(self) -> None:
        truth = torch.stack([faded_cliff(), smooth("bumps", 64), smooth("ramp", 64) // 2]).float()
        cpu = unwrap_single(truth % 256, 8, method="lsq")
        gpu = unwrap_single((truth % 256).cuda(), 8, method="lsq")
        assert gpu.is_cuda and torch.equal(gpu.cpu(), cpu)

    @pytest.mark.parametrize("seed", [0, 1])
    def test_output_is_consistent_with_the_measurement(self, seed: int) -> None:
        gen = torch.Generator().manual_seed(seed)
        noise = torch.randint(0, 256, (2, 3, 33, 17), generator=gen).double()  # residues everywhere
        for m in (noise, faded_cliff() % 256):
            out = unwrap_single(m, 8, method="lsq")
            assert consistent(out, m)
            flat = (out.double() - m.double()).flatten(-2)
            assert bool((flat.amin(-1) == 0).all())  # anchored: some pixels at k = 0

    def test_batched_equals_per_image(self) -> None:
        gen = torch.Generator().manual_seed(2)
        batch = torch.stack(
            [
                torch.stack([faded_cliff(), smooth("bumps", 64), smooth("ramp", 64) // 2]) % 256,
                torch.randint(0, 256, (3, 64, 64), generator=gen).double(),
            ]
        )
        out = unwrap_single(batch, 8, method="lsq")
        for b in range(2):
            assert torch.equal(out[b], unwrap_single(batch[b], 8, method="lsq"))
        alone = unwrap_single(batch, 8, method="lsq", colour=False)
        for c in range(3):
            assert torch.equal(alone[:, c : c + 1], unwrap_single(batch[:, c : c + 1], 8, method="lsq"))

    def test_empty_batch(self) -> None:
        out, info = unwrap_single(torch.zeros(0, 3, 8, 8), 8, method="lsq", return_info=True)
        assert out.shape == (0, 3, 8, 8) and info.seconds.shape == (0, 3) and info.energies == []

    def test_options_change_the_result(self) -> None:
        truth = faded_cliff()
        plain = unwrap_single(truth % 256, 8, method="lsq", iterations=0)
        assert exact_share(plain, truth) < 0.8 < 0.95 < exact_share(unwrap_single(truth % 256, 8, method="lsq"), truth)

    def test_info(self) -> None:
        truth = smooth("bumps", 24).expand(2, 3, 24, 24)
        out, info = unwrap_single(truth % 256, 8, method="lsq", return_info=True)
        assert isinstance(info, SingleShotInfo) and info.method == "lsq"
        assert info.iterations.shape == (2, 3) and not info.iterations.any() and not info.cuts.any()
        torch.testing.assert_close(info.energy, unwrap_energy(out, 8))
        assert info.energies[1][2] == [float(info.energy[1, 2])]
        assert bool((info.seconds > 0).all())

    def test_workers_is_accepted(self) -> None:
        truth = smooth("ramp", 16)
        assert torch.equal(unwrap_single(truth % 256, 8, method="lsq", workers=2), truth)

    def test_module_equals_function(self) -> None:
        m = torch.stack([faded_cliff(), smooth("bumps", 64)])[None] % 256
        module = SingleShotUnwrap(bits=8, method="lsq", iterations=2, colour=False)
        assert torch.equal(module(m), unwrap_single(m, 8, method="lsq", iterations=2, colour=False))

    def test_group_solver_equals_the_tensor_path(self) -> None:
        m = (torch.stack([faded_cliff(), smooth("bumps", 64)]) % 256)[None]
        spec = make_spec(8, "lsq", 8, 0.1, 1e-5, None, 2, 1000, {})
        restored, info = solve_plane(m[0, 0].numpy(), spec)
        assert np.array_equal(restored, unwrap_single(m[0, :1], 8, method="lsq")[0].numpy())
        assert info["energies"] and info["steps"] == []

    def test_registry_entry(self) -> None:
        entry = REGISTRY["lsq"]
        assert entry.solve_tensor is not None and not entry.joint_channels
        assert {name: option.default for name, option in entry.options.items()} == {
            name: default for name, (default, _) in LSQ_OPTIONS.items()
        }

    @pytest.mark.parametrize(
        ("options", "error", "text"),
        [
            ({"iterations": -1}, ValueError, "-1"),
            ({"iterations": 1.5}, TypeError, "1.5"),
            ({"cg_iterations": 0}, ValueError, "0"),
            ({"colour": "no"}, TypeError, "'no'"),
            ({"colour": 1}, TypeError, "1"),
            ({"tile": 8}, TypeError, "cg_iterations, colour, iterations"),
        ],
    )
    def test_bad_options_refused(self, options: dict, error: type, text: str) -> None:
        with pytest.raises(error, match=text):
            unwrap_single(torch.zeros(4, 4), 8, method="lsq", **options)
        with pytest.raises(error, match=text):
            SingleShotUnwrap(8, method="lsq", **options)

    def test_bad_input_refused(self) -> None:
        with pytest.raises(ValueError, match="300"):
            unwrap_single(torch.full((4, 4), 300.0), 8, method="lsq")
        with pytest.raises(TypeError, match="int64"):
            unwrap_single(torch.zeros(4, 4, dtype=torch.int64), 8, method="lsq")
