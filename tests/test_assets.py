"""Tests of the data shipped with the package (torch_modulo/assets/): the embedded scene is a clean radiance map."""

from __future__ import annotations

import torch

from torch_modulo.assets import DEFAULT_SCENE, default_scene_path
from torch_modulo.io import read_image, read_metadata
from torch_modulo.metrics import exact_k_share, psnr_log


def test_the_embedded_scene_is_a_clean_radiance_map() -> None:
    path = default_scene_path()
    assert path.name == DEFAULT_SCENE and path.is_file()
    assert path.stat().st_size < 512 * 1024  # lossless but small: a few hundred KB
    image = read_image(path)  # as stored: no clamping, no replacement
    assert image.shape == (3, 256, 512)
    assert bool(torch.isfinite(image).all())
    assert float(image.min()) >= 0.0
    assert not bool(torch.signbit(image).any())  # not even -0.0
    assert float(image.max()) > 16.0  # still an HDR scene (a sunlit window)


def test_the_metrics_take_the_embedded_scene_as_it_is() -> None:
    image = read_image(default_scene_path(), dtype=torch.float64)
    counts = torch.floor(image * 4095 / float(image.max()))
    assert float(exact_k_share(counts, counts, 8)[0]) == 1.0  # refuses negative values: none to clamp first
    assert float(psnr_log(image, image)[0]) == float("inf")


def test_the_embedded_scene_is_half_float_with_lossless_compression() -> None:
    import OpenImageIO as oiio

    source = oiio.ImageInput.open(str(default_scene_path()))
    spec = source.spec()
    source.close()
    assert spec.format == oiio.HALF
    assert spec.get_string_attribute("compression") == "piz"  # what torch_modulo/assets/README.md says
    meta = read_metadata(default_scene_path())
    # The header is the source's (kept when the file was rewritten) and comes back as plain Python values (a
    # float2 as a list); the file holds one image and no torch_modulo metadata.
    assert meta["compression"] == "piz" and meta["oiio:subimages"] == 1
    assert meta["PixelAspectRatio"] == 1.0 and meta["screenWindowCenter"] == [0.0, 0.0]
    assert meta["screenWindowWidth"] == 1.0 and meta["openexr:lineOrder"] == "increasingY"
    assert not {"bits", "exposure", "exposures", "cfa"} & meta.keys()
